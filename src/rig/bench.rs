//! What a capture asks of the bench around the camera before it acquires
//! (pose, polarizer angle, the hidden scene on or off, the target or the
//! point source in place), and the bench set by hand that only logs it.
//! The fake camera's bench (`camera::fake::FakeBench`) and the synthetic
//! camera's implement the same trait.

/// What a capture asks of the bench before acquiring.
pub trait Bench: Send + Sync {
    /// Puts the camera at `pose` with the polarizer at `polarizer_deg` (None: no polarizer).
    fn select(&self, pose: &str, polarizer_deg: Option<f64>);
    /// Turns the hidden scene on (captures) or off (dark frames).
    fn scene_on(&self, on: bool);
    /// Whether [`Bench::scene_on`] really switches the scene (a motorized
    /// shutter, the fake camera); when not, dark frames need the user.
    fn switches_scene(&self) -> bool;
    /// Puts the calibration target on the wall (target captures) or takes
    /// it away; on a bench set by hand the operator does.
    fn show_target(&self, on: bool) {
        tracing::info!(
            on,
            "capture expects the calibration target {} the wall",
            if on { "on" } else { "off" }
        );
    }
    /// Puts the calibration point source in place of the hidden scene, or
    /// back; on a bench set by hand the operator does.
    fn show_source(&self, on: bool) {
        tracing::info!(
            on,
            "capture expects the calibration point source {}",
            if on { "in place" } else { "removed" }
        );
    }
}

/// A bench set by hand: polnlos logs what the operator should have done.
pub struct ManualBench;

impl Bench for ManualBench {
    fn select(&self, pose: &str, polarizer_deg: Option<f64>) {
        tracing::info!(
            pose,
            ?polarizer_deg,
            "capture expects the camera at this pose and polarizer angle"
        );
    }
    fn scene_on(&self, on: bool) {
        tracing::info!(
            on,
            "capture expects the hidden scene switched {}",
            if on { "on" } else { "off" }
        );
    }
    fn switches_scene(&self) -> bool {
        false
    }
}
