//! The Python package (`python/`) as a lab user gets it: built and installed
//! with pip from this repository into a fresh virtual environment, its pytest
//! suite run against this build's `polnlos` binary and a real daemon (Aravis's
//! fake camera, HTTP on 127.0.0.1), and the notebook in docs/ executed.
//!
//! Needs what the README's set-up line installs: python3 with maturin,
//! pytest, nbclient and ipykernel.

use crate::daemon::common::{config, scratch, InProcess};
use std::path::{Path, PathBuf};
use std::process::Command;

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// Runs `cmd` and fails the test with its output when it fails.
fn run(cmd: &mut Command, what: &str) {
    let out = cmd
        .output()
        .unwrap_or_else(|e| panic!("{what}: cannot start ({e})"));
    assert!(
        out.status.success(),
        "{what} failed ({}):\n{}\n{}",
        out.status,
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}

/// The target folder of this build: the test binary is
/// `<target>/<profile>/deps/suite-<hash>`.
fn target_dir() -> PathBuf {
    let exe = std::env::current_exe().expect("the test binary's path");
    exe.ancestors()
        .nth(3)
        .map(Path::to_path_buf)
        .expect("the test binary sits in <target>/<profile>/deps")
}

/// A virtual environment with the package installed from `python/`, seeing
/// the system's NumPy, maturin, pytest and nbclient.
///
/// The extension builds into the target folder this test binary was built
/// in (`target/`, or wherever `CARGO_TARGET_DIR` put it), as
/// [`MATURIN_ARGS`] and [`shared_profile`] say: `cargo test` holds the
/// build lock only while it compiles, so the core and the dependencies it
/// already built (faer and the rest, same settings) are reused instead of a
/// second release build in a folder of its own (327 s of a clean suite's 20
/// minutes, measured 2026-11-26). A fixed `target/` rebuilt them all when
/// `CARGO_TARGET_DIR` pointed elsewhere.
fn venv() -> PathBuf {
    let venv = target_dir().join("python-venv");
    let python = venv.join("bin/python");
    if !python.exists() {
        run(
            Command::new("python3")
                .args(["-m", "venv", "--system-site-packages"])
                .arg(&venv),
            "python3 -m venv",
        );
    }
    for module in ["maturin", "pytest", "nbclient", "ipykernel", "numpy"] {
        let ok = Command::new(&python)
            .args(["-c", &format!("import {module}")])
            .status()
            .is_ok_and(|s| s.success());
        assert!(
            ok,
            "python3 has no {module}: run the README's set-up line (python3 -m pip install maturin pytest nbclient ipykernel numpy)"
        );
    }
    run(
        Command::new(&python)
            .args([
                "-m",
                "pip",
                "install",
                "--quiet",
                "--no-build-isolation",
                "--no-deps",
                "--force-reinstall",
            ])
            .arg(root().join("python"))
            .env("CARGO_TARGET_DIR", target_dir())
            .env("MATURIN_PEP517_ARGS", MATURIN_ARGS)
            .envs(shared_profile())
            // The per-test timing script (scripts/test-times.sh) runs this
            // binary with it; cargo would rebuild every dependency for it.
            .env_remove("RUSTC_BOOTSTRAP"),
        "pip install ./python",
    );
    python
}

/// The extension's build: the dev profile (`--profile test` would build the
/// library as a test harness), the `shared-test-core` feature (the core
/// with the features `cargo test` gives it) and the library stripped (no
/// symbols or debug info written twice, as a wheel and as an install, on
/// a disk where such writes stalled the daemon tests' fsyncs).
pub const MATURIN_ARGS: &str = "--profile dev --features shared-test-core --strip";

/// The dev profile's settings made those of `[profile.test]` (read from
/// `Cargo.toml`, each as `CARGO_PROFILE_DEV_<KEY>`), so that the core is the
/// same unit (features, settings, dependencies) as the one `cargo test`
/// compiled, and cargo links it instead of compiling it again
/// (`core::layers::the_python_extension_reuses_what_cargo_test_built`
/// holds this). Its tests run at the test build's opt-level.
pub fn shared_profile() -> Vec<(String, String)> {
    let manifest = std::fs::read_to_string(root().join("Cargo.toml")).expect("Cargo.toml");
    let manifest: toml::Table = manifest.parse().expect("Cargo.toml parses");
    let test = manifest
        .get("profile")
        .and_then(|p| p.get("test"))
        .and_then(toml::Value::as_table)
        .expect("Cargo.toml has [profile.test]");
    test.iter()
        .filter_map(|(key, value)| {
            let value = match value {
                toml::Value::String(s) => s.clone(),
                toml::Value::Integer(_) | toml::Value::Boolean(_) => value.to_string(),
                _ => return None,
            };
            let key = key.to_uppercase().replace('-', "_");
            Some((format!("CARGO_PROFILE_DEV_{key}"), value))
        })
        .collect()
}

/// PATH with the environment's bin folder first: a kernel spec that names
/// plain `python` starts the environment's.
fn path_with(python: &Path) -> std::ffi::OsString {
    let bin = python.parent().map(Path::to_path_buf).unwrap_or_default();
    let mut paths = vec![bin];
    paths.extend(std::env::split_paths(
        &std::env::var_os("PATH").unwrap_or_default(),
    ));
    std::env::join_paths(paths).unwrap_or_default()
}

#[test]
fn the_python_package_matches_the_cli_talks_to_the_daemon_and_runs_the_notebook() {
    crate::priority::background();
    let python = venv();
    let dir = scratch();
    let cfg = config(dir.path(), &[]);
    let d = InProcess::start(&cfg, &dir.path().join("data"));
    run(
        Command::new(&python)
            .args(["-m", "pytest", "-q", "-p", "no:cacheprovider"])
            .arg(root().join("python/tests"))
            .env("POLNLOS_BIN", env!("CARGO_BIN_EXE_polnlos"))
            .env("POLNLOS_URL", &d.base)
            .current_dir(dir.path()),
        "pytest python/tests",
    );
    let executed = dir.path().join("python.ipynb");
    run(
        Command::new(&python)
            .args([
                "-c",
                "import sys, nbformat, nbclient\n\
                 nb = nbformat.read(sys.argv[1], as_version=4)\n\
                 nbclient.NotebookClient(nb, timeout=600, kernel_name='python3').execute()\n\
                 nbformat.write(nb, sys.argv[2])",
            ])
            .arg(root().join("docs/python.ipynb"))
            .arg(&executed)
            .env("POLNLOS_URL", &d.base)
            .env("PATH", path_with(&python))
            .current_dir(dir.path()),
        "executing docs/python.ipynb",
    );
    // The notebook reached its last cell and printed the comparison.
    let text = std::fs::read_to_string(&executed).unwrap();
    assert!(text.contains("the crossed polarizer gains"), "{text}");
    assert!(text.contains("largest difference to the daemon"), "{text}");
    drop(d);
}
