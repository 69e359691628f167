//! The layers as the crate graph sees them: the numeric core (the crate
//! without its `daemon` feature) links no camera library, database, async
//! runtime or HTTP stack, and the daemon below the HTTP API never names it.

use std::path::Path;
use std::process::Command;

/// Crates only the daemon may pull in.
const DAEMON_ONLY: &[&str] = &[
    "aravis",
    "aravis-sys",
    "libusb1-sys",
    "rusqlite",
    "libsqlite3-sys",
    "tokio",
    "axum",
    "hyper",
    "tower-http",
];

/// Names of every crate in `cargo tree` for these arguments.
fn tree(args: &[&str]) -> Vec<String> {
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let out = Command::new(cargo)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .args([
            "tree",
            "--offline",
            "--locked",
            "--prefix",
            "none",
            "-e",
            "normal",
        ])
        .args(args)
        .output()
        .expect("cargo runs");
    assert!(
        out.status.success(),
        "cargo tree failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout)
        .lines()
        .filter_map(|l| l.split_whitespace().next().map(String::from))
        .collect()
}

#[test]
fn the_core_links_no_camera_database_runtime_or_http() {
    let core = tree(&["--no-default-features"]);
    assert!(core.iter().any(|c| c == "faer"), "{core:?}");
    for c in DAEMON_ONLY {
        assert!(!core.iter().any(|k| k == c), "the core depends on {c}");
    }
    // The default build (the daemon) does have them: the check above is not
    // vacuous.
    let full = tree(&[]);
    for c in ["aravis", "rusqlite", "tokio", "axum"] {
        assert!(full.iter().any(|k| k == c), "default build lacks {c}");
    }
}

/// Every `.rs` file under `src/<dir>`.
fn sources(dir: &str) -> Vec<(String, String)> {
    let mut out = Vec::new();
    let mut stack = vec![Path::new(env!("CARGO_MANIFEST_DIR")).join("src").join(dir)];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).expect("src folder") {
            let p = e.expect("entry").path();
            if p.is_dir() {
                stack.push(p);
            } else if p.extension().is_some_and(|x| x == "rs") {
                let text = std::fs::read_to_string(&p).expect("source");
                out.push((p.display().to_string(), text));
            }
        }
    }
    out
}

#[test]
fn the_core_names_no_service_layer() {
    for dir in [
        "optics",
        "scene",
        "transport",
        "solve",
        "simulate",
        "measure",
        "calibrate",
        "files",
    ] {
        for (path, text) in sources(dir) {
            for upper in [
                "crate::camera",
                "crate::store",
                "crate::daemon",
                "crate::api",
                "crate::cli",
                "crate::bench",
            ] {
                assert!(!text.contains(upper), "{path} names {upper}");
            }
        }
    }
}

#[test]
fn the_daemon_names_no_http_layer() {
    for (path, text) in sources("daemon") {
        assert!(!text.contains("crate::api"), "{path} names crate::api");
    }
}
