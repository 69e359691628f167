//! Procedures that string jobs together: acquisition plans, the pose,
//! wall and colour calibrations, and finding the mount's crossed angle.

pub(crate) mod calibration;
pub(crate) mod colour;
pub(crate) mod mount_zero;
pub(crate) mod plans;
