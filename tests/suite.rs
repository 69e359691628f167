//! The integration suite, one test binary: the numeric core and the
//! offline tools (`offline`, from `tests/core/`), and the daemon with what
//! it drives (`daemon`, from `tests/daemon/`, with the `daemon` feature).
//! libtest starts tests in name order: the daemon's first. Started first,
//! the core's CPU-bound cases (each solve on every core) took the CPU from
//! the fake camera's stream and a capture did not start within 10 s; the
//! whole run was no shorter (313 s against 304 s).
//!
//! Why one binary: cargo runs test binaries one after the other, so the
//! core's CPU-bound cases and the daemon's tests that wait (on the Aravis
//! lock, a camera's real exposure time, a browser) could not overlap; in
//! one binary libtest runs them side by side (docs/test-times.md).

#[path = "core/main.rs"]
mod offline;

#[cfg(feature = "daemon")]
#[path = "daemon/main.rs"]
mod daemon;
