//! The rotation mount through the daemon (issue 28): a capture turns a
//! simulated Elliptec ELL14 on a pseudo-terminal (the driver's real serial
//! code) to its polarizer angle and records the angle read back; a mount
//! that slips, answers an error or is unplugged fails the capture with the
//! angles named, and the daemon goes on. Real HTTP on 127.0.0.1.

mod common;

use std::time::Duration;

use common::{config, lock, Daemon};
use polnlos::mount::simulated::{Fault, SimulatedEll14};

const CAPTURE: &str = r#"{"scene": "brewster-rotating", "pose": "A", "polarizer_deg": 45, "exposure_us": 1000, "frames": 1}"#;

#[test]
fn captures_turn_the_mount_record_the_angle_read_back_and_fail_when_it_slips() {
    let _g = lock();
    let mut device = SimulatedEll14::start().unwrap();
    let dir = tempfile::tempdir().unwrap();
    let port = format!("kind = \"elliptec\"\nport = \"{}\"", device.path());
    let cfg = config(
        dir.path(),
        &[
            ("kind = \"simulated\"", port.as_str()),
            ("zero_deg = 0.0", "zero_deg = 10.0"),
            (
                "scene = \"brewster-crossed\"",
                "scene = \"brewster-rotating\"",
            ),
        ],
    );
    let d = Daemon::start(&cfg, &dir.path().join("data"));
    let long = Duration::from_secs(30);

    // Turned to zero + 45 = 55 degrees on the mount, read back, recorded.
    let c = d.run_job("/captures", CAPTURE, long);
    assert_eq!(c["state"], "done", "{c}");
    let measured = c["polarizer_measured_deg"].as_f64().unwrap();
    assert!((measured - 45.0).abs() <= 0.05, "{c}");
    assert!((device.angle() - 55.0).abs() <= 0.05, "{}", device.angle());
    let m = d.json("/mount");
    assert_eq!(
        (m["kind"].as_str(), m["connected"].as_bool()),
        (Some("elliptec"), Some(true)),
        "{m}"
    );
    assert!(
        (m["polarizer_deg"].as_f64().unwrap() - 45.0).abs() <= 0.05,
        "{m}"
    );

    // Slipped by 2 degrees: the capture fails naming both angles; no frame is kept.
    // 143360 pulses per turn: 796 pulses are 2 degrees.
    device.set_fault(Fault::Slip(796));
    let body = CAPTURE.replace("\"polarizer_deg\": 45", "\"polarizer_deg\": 90");
    let c = d.run_job("/captures", &body, long);
    assert_eq!(c["state"], "failed", "{c}");
    let e = c["error"].as_str().unwrap_or("");
    assert!(
        e.contains("could not be turned to 90°") && e.contains("slipped"),
        "{e}"
    );
    assert!(c["polarizer_measured_deg"].is_null(), "{c}");

    // An error status from the device: named with the protocol's meaning.
    device.set_fault(Fault::Error(2));
    let c = d.run_job("/captures", &body, long);
    assert_eq!(c["state"], "failed", "{c}");
    assert!(c["error"].as_str().unwrap_or("").contains("error 2"), "{c}");

    // Unplugged: the capture fails in bounded time, the daemon answers, and
    // /mount says what is wrong.
    device.set_fault(Fault::None);
    device.unplug();
    let c = d.run_job("/captures", CAPTURE, long);
    assert_eq!(c["state"], "failed", "{c}");
    assert!(
        c["error"].as_str().unwrap_or("").contains("rotation mount"),
        "{c}"
    );
    let m = d.json("/mount");
    assert_eq!(m["connected"], false, "{m}");
    assert!(
        m["last_error"].as_str().is_some_and(|e| !e.is_empty()),
        "{m}"
    );
}

#[test]
fn the_shipped_daemon_turns_its_simulated_mount() {
    let _g = lock();
    let dir = tempfile::tempdir().unwrap();
    let cfg = config(
        dir.path(),
        &[(
            "scene = \"brewster-crossed\"",
            "scene = \"brewster-rotating\"",
        )],
    );
    let d = Daemon::start(&cfg, &dir.path().join("data"));
    let c = d.run_job("/captures", CAPTURE, Duration::from_secs(30));
    assert_eq!(c["state"], "done", "{c}");
    let measured = c["polarizer_measured_deg"].as_f64().unwrap();
    assert!((measured - 45.0).abs() <= 0.05, "{c}");
    let m = d.json("/mount");
    assert_eq!(m["kind"], "simulated", "{m}");
    assert!(
        m["port"]
            .as_str()
            .is_some_and(|p| p.starts_with("/dev/pts/")),
        "{m}"
    );
}
