//! The integration suite, one test binary: the numeric core and the
//! offline tools (`core`, from `tests/core/`), and the daemon with what
//! it drives (`daemon`, from `tests/daemon/`, with the `daemon` feature).
//! libtest starts tests in name order: the core's first, so its CPU-bound
//! cases start at once. The tests that only compute (the core's cases, the
//! in-process daemons and what they start) call `priority::background()`,
//! so they take the cores only when the tests on Aravis's fake camera leave
//! them idle; the daemon tests run eight at a time
//! (`daemon::common::slot`) however many test threads there are.
//!
//! Why one binary: cargo runs test binaries one after the other, so the
//! core's CPU-bound cases and the daemon's tests that wait (on the Aravis
//! lock, a camera's real exposure time, a browser) could not overlap; in
//! one binary libtest runs them side by side (docs/test-times.md).

#[cfg_attr(not(feature = "daemon"), allow(dead_code))]
mod png;
mod priority;

#[path = "core/main.rs"]
mod core;

#[cfg(feature = "daemon")]
#[path = "daemon/main.rs"]
mod daemon;
