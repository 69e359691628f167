//! The HTTP API held to its own OpenAPI document by a third-party fuzzer:
//! schemathesis (PyPI, pinned in requirements-test.txt, which `.ci/run`
//! installs) generates requests from `/openapi.json` and checks every answer
//! for server errors, status codes, content types and response schemas the
//! document does not declare.
//!
//! Bounded by counts: 127.0.0.1 only, a fixed seed, 25 examples per
//! operation, one worker and 30 s per request. `GET /events` is left out: it
//! is a stream with no parameters, so every case only waits for the request
//! timeout to end it (92 s of a 123 s run); tests/daemon/live.rs and
//! service.rs read it. `POST /scenes` and `PUT /scenes/{name}` are left out
//! too: their bodies are `application/toml`, which schemathesis has no
//! serializer for ("Serialization not possible"); tests/daemon/scenes.rs
//! sends them malformed and of the wrong type. A run that does not end within [`HUNG`] is a hung
//! fuzzer or daemon, not a slow one, and fails.
//! 30 s per request, not 10: `POST /mount/zero` answers within the request
//! after its sweep (up to 5 s waiting for the camera, then the sweep's
//! exposures), and a live session the fuzzer started shares the daemon's
//! cores.

use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use crate::daemon::common::{config, scratch, Client, InProcess};

/// How long a run may go before it is taken for hung: ten times the longest
/// run measured in the loaded suite (about 225 s with `/events` in it).
const HUNG: Duration = Duration::from_secs(40 * 60);

/// Runs schemathesis against `d` (with `extra` arguments) and returns its
/// exit status and output; fails the test if it overruns its bound.
fn schemathesis(d: &Client, extra: &[&str]) -> (bool, String) {
    let out_file = tempfile::NamedTempFile::new().unwrap();
    let mut child = Command::new("schemathesis")
        .args(["run", &format!("{}/openapi.json", d.base)])
        .args([
            "--checks",
            "not_a_server_error,status_code_conformance,content_type_conformance,response_schema_conformance",
            "--max-examples",
            "25",
            "--workers",
            "1",
            "--request-timeout",
            "30",
            "--seed",
            "1",
            "--exclude-path",
            "/events",
            "--exclude-name",
            "POST /scenes",
            "--exclude-name",
            "PUT /scenes/{name}",
        ])
        .args(extra)
        .env("NO_COLOR", "1")
        .stdout(out_file.reopen().unwrap())
        .stderr(Stdio::null())
        .spawn()
        .unwrap_or_else(|e| {
            panic!("schemathesis could not be run ({e}): install it with `python3 -m pip install schemathesis` (.ci/run does)")
        });
    let start = Instant::now();
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        if start.elapsed() > HUNG {
            let _ = child.kill();
            let _ = child.wait();
            panic!("schemathesis did not end within {HUNG:?}: hung");
        }
        std::thread::sleep(Duration::from_millis(200));
    };
    let text = std::fs::read_to_string(out_file.path()).unwrap_or_default();
    (status.success(), text)
}

/// The summary: from the line that says so to the end.
fn summary(text: &str) -> &str {
    text.find("SUMMARY").map_or(text, |k| &text[k..])
}

// Two tests, not one: their daemons are in this process on the synthetic
// camera, so the two schemathesis runs go side by side.
#[test]
fn schemathesis_finds_no_failure_without_a_token() {
    let dir = scratch();
    let open = config(dir.path(), &[]);
    let d = InProcess::start(&open, &dir.path().join("data"));
    let (ok, text) = schemathesis(&d, &[]);
    println!("without a token:\n{}", summary(&text));
    assert!(ok, "schemathesis found failures without a token:\n{text}");
    assert!(text.contains("passed"), "{text}");
}

#[test]
fn schemathesis_finds_no_failure_with_a_token() {
    let dir = scratch();
    let guarded = config(dir.path(), &[("token = \"\"", "token = \"fuzz-token\"")]);
    let mut d = InProcess::start(&guarded, &dir.path().join("data"));
    d.token = Some("fuzz-token".into());
    let (ok, text) = schemathesis(&d, &["-H", "Authorization: Bearer fuzz-token"]);
    println!("with the token:\n{}", summary(&text));
    assert!(ok, "schemathesis found failures with the token:\n{text}");
    assert!(text.contains("passed"), "{text}");
}
