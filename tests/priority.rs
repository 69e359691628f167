//! The suite's two kinds of test on two cores: the tests on Aravis's fake
//! camera wait on a real frame stream and must get a core the moment a
//! frame is due; the others only need CPU time. The others call
//! [`background`] first, so they use the cores the camera tests leave idle
//! and no capture misses a frame because of them (docs/test-times.md).

/// Moves the calling test thread, and every thread and process it starts
/// from now on, to Linux's `SCHED_IDLE` class: it runs only when no thread
/// of the normal class wants the core, and a normal thread that wakes takes
/// the core from it at once.
///
/// Also builds rayon's global pool (the numeric core's parallel loops) in
/// that class, unless a test built it already: the camera tests do not use
/// it.
pub fn background() {
    idle();
    let _ = rayon::ThreadPoolBuilder::new()
        .start_handler(|_| idle())
        .build_global();
}

/// The calling thread to `SCHED_IDLE` (no privilege is needed to lower a
/// thread's class; a failure leaves it in the normal class, which changes
/// no result, only the suite's time).
fn idle() {
    let param = libc::sched_param { sched_priority: 0 };
    // SAFETY: `param` is a valid, initialized `sched_param` that lives for
    // the whole call, and SCHED_IDLE requires its priority to be 0, as set;
    // pid 0 names the calling thread, which exists.
    unsafe {
        libc::sched_setscheduler(0, libc::SCHED_IDLE, &param);
    }
}
