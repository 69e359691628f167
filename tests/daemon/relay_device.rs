//! The Devantech relay driver's real serial code (the `serialport` crate on
//! a tty) against the simulated USB-RLY02 on a pseudo-terminal: switches
//! read back, and every fault a bench can have gets a clear error in
//! bounded time.

use std::time::{Duration, Instant};

use polnlos::rig::relay::devantech::{Devantech, QUERY_TIMEOUT};
use polnlos::rig::relay::simulated::{Fault, SimulatedRelay};
use polnlos::rig::relay::{LightSwitch, RelayError};

#[test]
fn the_driver_switches_each_relay_and_the_module_is_where_it_says() {
    let sim = SimulatedRelay::start().expect("a pseudo-terminal");
    let mut one = Devantech::open(sim.path(), 1).expect("the module");
    assert_eq!(one.module(), "USB-RLY02");
    for on in [true, false, true] {
        assert_eq!(one.set(on).unwrap(), on);
        assert_eq!(sim.is_on(1), on);
        assert_eq!(one.state().unwrap(), on);
    }
    // Relay 2 is its own: switching it leaves relay 1 as it was.
    drop(one);
    let mut two = Devantech::open(sim.path(), 2).expect("the module again");
    assert!(two.set(true).unwrap());
    assert!(sim.is_on(1) && sim.is_on(2));
    assert!(!two.set(false).unwrap());
    assert!(sim.is_on(1) && !sim.is_on(2));
    // A USB-RLY02 has no relay 3.
    drop(two);
    let e = Devantech::open(sim.path(), 3).err().expect("no relay 3");
    assert!(e.to_string().contains("relays 1 to 2"), "{e}");
}

#[test]
fn faults_are_named_and_bounded_in_time() {
    let mut sim = SimulatedRelay::start().expect("a pseudo-terminal");
    let mut m = Devantech::open(sim.path(), 1).expect("the module");
    // A relay that does not switch: the read-back catches it.
    sim.set_fault(Fault::Stuck);
    let e = m.set(true).unwrap_err();
    assert!(
        matches!(
            e,
            RelayError::Stuck {
                relay: 1,
                wanted: true,
                ..
            }
        ),
        "{e}"
    );
    assert!(e.to_string().contains("switched on but reads off"), "{e}");
    // No reply: within the query timeout (plus scheduling), naming the command.
    sim.set_fault(Fault::Silent);
    let t = Instant::now();
    let e = m.state().unwrap_err();
    assert!(
        matches!(e, RelayError::NoReply { command: 0x5B, .. }),
        "{e}"
    );
    assert!(
        t.elapsed() < QUERY_TIMEOUT + Duration::from_secs(2),
        "{:?}",
        t.elapsed()
    );
    // Behaving again, it answers again.
    sim.set_fault(Fault::None);
    assert!(m.set(true).unwrap());
    // The cable pulled: an error, not a hang.
    let path = sim.path().to_string();
    sim.unplug();
    let t = Instant::now();
    assert!(m.set(false).is_err());
    assert!(
        t.elapsed() < QUERY_TIMEOUT + Duration::from_secs(2),
        "{:?}",
        t.elapsed()
    );
    // A port that is not there names the dialout group.
    let e = Devantech::open(&format!("{path}-gone"), 1)
        .err()
        .expect("no port");
    assert!(e.to_string().contains("dialout"), "{e}");
}
