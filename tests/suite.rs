//! The integration suite, one test binary: the numeric core and the
//! offline tools (`offline`, from `tests/core/`), and the daemon with what
//! it drives (`daemon`, from `tests/daemon/`, with the `daemon` feature).
//! libtest starts tests in name order: the daemon's first. The tests that
//! only compute (the core's cases, the in-process daemons and what they
//! start) call `priority::background()`, so they take the cores only when
//! the tests on Aravis's fake camera leave them idle.
//!
//! Why one binary: cargo runs test binaries one after the other, so the
//! core's CPU-bound cases and the daemon's tests that wait (on the Aravis
//! lock, a camera's real exposure time, a browser) could not overlap; in
//! one binary libtest runs them side by side (docs/test-times.md).

#[cfg_attr(not(feature = "daemon"), allow(dead_code))]
mod png;
mod priority;

#[path = "core/main.rs"]
mod offline;

#[cfg(feature = "daemon")]
#[path = "daemon/main.rs"]
mod daemon;
