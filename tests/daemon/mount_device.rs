//! The Elliptec driver's real serial code (the `serialport` crate on a tty)
//! against the simulated ELL14 on a pseudo-terminal: moves read back,
//! and every fault a bench can have gets a clear error in bounded time.

use std::time::{Duration, Instant};

use polnlos::rig::mount::elliptec::{Elliptec, MOVE_TIMEOUT, QUERY_TIMEOUT};
use polnlos::rig::mount::simulated::{Fault, SimulatedEll14, PULSES};
use polnlos::rig::mount::{angle_between, MountError, RotationMount};

#[test]
fn the_driver_reads_the_device_homes_moves_and_reads_back() {
    let sim = SimulatedEll14::start().expect("a pseudo-terminal");
    let mut m = Elliptec::open(sim.path(), '0').expect("the mount");
    // The pulses per turn come from the device, not from a constant.
    assert_eq!(
        (m.info().motor_type, m.info().travel, m.info().pulses),
        (14, 360, PULSES)
    );
    assert_eq!(m.home().unwrap(), 0.0);
    for deg in [45.0, 90.0, 135.0, 0.0, 359.5, -10.0, 725.0] {
        let got = m.move_to(deg).unwrap();
        let want = deg.rem_euclid(360.0);
        assert!(angle_between(got, want) < 0.01, "{deg}: {got}");
        // The device is where the driver says.
        assert!(
            angle_between(sim.angle(), got) < 1e-9,
            "{deg}: {}",
            sim.angle()
        );
        assert!(angle_between(m.position().unwrap(), want) < 0.01);
    }
}

#[test]
fn faults_are_named_and_bounded_in_time() {
    let mut sim = SimulatedEll14::start().expect("a pseudo-terminal");
    let mut m = Elliptec::open(sim.path(), '0').expect("the mount");
    // An error status: the code and its meaning, no move recorded.
    sim.set_fault(Fault::Error(2));
    match m.move_to(90.0) {
        Err(MountError::Device {
            code: 2, meaning, ..
        }) => assert_eq!(meaning, "mechanical timeout"),
        other => panic!("{other:?}"),
    }
    // A move that lands off target: the read-back catches it.
    sim.set_fault(Fault::Slip(800));
    match m.move_to(45.0) {
        Err(e @ MountError::Missed { .. }) => {
            let text = e.to_string();
            assert!(
                text.contains("sent to 45.000°") && text.contains("slipped"),
                "{text}"
            );
        }
        other => panic!("{other:?}"),
    }
    // No reply: within the query timeout (plus scheduling), naming the command.
    sim.set_fault(Fault::Silent);
    let t = Instant::now();
    match m.position() {
        Err(e @ MountError::NoReply { .. }) => assert!(e.to_string().contains("\"0gp\""), "{e}"),
        other => panic!("{other:?}"),
    }
    assert!(
        t.elapsed() < QUERY_TIMEOUT + Duration::from_millis(500),
        "{:?}",
        t.elapsed()
    );
    // Behaving again, it answers again (no stale bytes in the way).
    sim.set_fault(Fault::None);
    assert!(angle_between(m.move_to(30.0).unwrap(), 30.0) < 0.01);
    // The cable pulled: an error within the move timeout, not a hang.
    sim.unplug();
    let t = Instant::now();
    let e = m.move_to(60.0).expect_err("a pulled cable");
    assert!(
        matches!(e, MountError::Io { .. } | MountError::NoReply { .. }),
        "{e:?}"
    );
    assert!(
        t.elapsed() < MOVE_TIMEOUT + Duration::from_secs(1),
        "{:?}",
        t.elapsed()
    );
    // A port that is not there is named with what to check.
    let e = match Elliptec::open("/dev/polnlos-no-such-port", '0') {
        Err(e) => e.to_string(),
        Ok(_) => panic!("opened a port that does not exist"),
    };
    assert!(
        e.contains("/dev/polnlos-no-such-port") && e.contains("dialout"),
        "{e}"
    );
}
