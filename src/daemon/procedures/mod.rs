//! Procedures that string jobs together: acquisition plans, the pose,
//! wall and colour calibrations, and finding the mount's crossed angle.

pub(crate) mod calibration;
pub(crate) mod colour;
pub(crate) mod mount_zero;
pub(crate) mod plans;
pub(crate) mod scene_fit;

use std::sync::Arc;

use crate::daemon::requests::admission::Admission;

/// The bench procedures' handle (the pose, wall and colour calibrations and
/// the mount's crossed angle), over the services admission shares: the
/// catalogue, the scenes, their calibrations, the camera and the rig.
///
/// Why a handle: the API reaches each concept through its own, as it
/// reaches requests and plans, and none of them holds the daemon.
#[derive(Clone)]
pub(crate) struct Procedures {
    services: Arc<Admission>,
}

impl Procedures {
    /// The procedures over `services`.
    pub(crate) fn new(services: Arc<Admission>) -> Self {
        Self { services }
    }
}
