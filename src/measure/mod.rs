//! Between camera frames and the measurement vector `i` (MODEL.md "From
//! camera frames to i"): sampling frames through a pose's homography, and
//! rendering the frame a wall image implies (for simulation and the fake camera).

mod assemble;
mod average;
pub mod colour;
pub mod exposure;
pub mod given;
/// The daemon's display levels for a camera frame (only the daemon shows frames).
#[cfg(feature = "daemon")]
pub(crate) mod levels;
mod load;
/// A polarizer-mosaic frame's views for the daemon's camera page.
#[cfg(feature = "daemon")]
pub(crate) mod mosaic;
mod stack;
/// The live view's rolling window of frames.
#[cfg(feature = "daemon")]
pub(crate) mod window;

pub use assemble::to_model_units;
pub use assemble::{assemble, assemble_colour, CaptureFrames, Units};
#[cfg(feature = "daemon")]
pub(crate) use average::Clipping;
pub use average::FrameStack;
pub use load::load;
pub(crate) use load::{CaptureInfo, CaptureSource};
#[cfg(feature = "daemon")]
pub(crate) use stack::with_rounding_bias;
pub(crate) use stack::BlockFrames;
pub use stack::{stack, Measurement, PixelMaps};

use crate::scene::{Frame, Homography, Plane};

/// Why a frame could not be turned into a measurement.
#[derive(Debug, thiserror::Error)]
pub enum MeasureError {
    /// The pose has no homography in the scene file.
    #[error("pose {pose:?} has no homography in the scene file; add `homography = [[...], [...], [...]]` (wall metres to pixels) to its [[pose]]")]
    NoHomography {
        /// Pose name.
        pose: String,
    },
    /// No capture was taken at a block's pose and polarizer angle.
    #[error("no capture for block {block}; take one at that pose and polarizer angle, or remove the angle from the scene's pose")]
    NoCapture {
        /// The block's label, e.g. `A-pol0`.
        block: String,
    },
    /// Two captures were taken at the same block.
    #[error("block {block} has two captures, {first} and {second}; name only one")]
    TwoCaptures {
        /// The block's label.
        block: String,
        /// The first capture's name.
        first: String,
        /// The second.
        second: String,
    },
    /// A capture serves no block of the scene.
    #[error("{capture} was taken at {block}, which is not a block of the scene; its blocks are {blocks}")]
    NoBlock {
        /// The capture's name.
        capture: String,
        /// Its pose and angle as a block label, e.g. `C-pol45`.
        block: String,
        /// The scene's block labels.
        blocks: String,
    },
    /// A capture's files cannot serve it (unreadable, or not its frame).
    #[error("{capture}: {reason}")]
    Capture {
        /// The capture's name.
        capture: String,
        /// What is wrong, and with which file.
        reason: String,
    },
    /// A capture names a pose the scene does not have.
    #[error("{capture} was taken at pose {pose:?}, which the scene does not have")]
    UnknownPose {
        /// The capture's name.
        capture: String,
        /// Its pose.
        pose: String,
    },
    /// The dark frame does not have the frames' size.
    #[error("the dark frame is {}x{} but the frames are {}x{}; take the dark with the same region and binning", dark[0], dark[1], frames[0], frames[1])]
    DarkSize {
        /// Dark frame width, height.
        dark: [usize; 2],
        /// Frame width, height.
        frames: [usize; 2],
    },
    /// The wall's pixels could not be found in the frame.
    #[error(transparent)]
    Footprint(#[from] crate::scene::FootprintError),
    /// A variance frame of another size than its mean.
    #[error("pose {pose:?}: the variance frame is {}x{} but the mean is {}x{}; the files do not belong together", variance[0], variance[1], mean[0], mean[1])]
    VarianceSize {
        /// Pose name.
        pose: String,
        /// Variance frame width, height.
        variance: [usize; 2],
        /// Mean frame width, height.
        mean: [usize; 2],
    },
}

/// The footprint-weighted mean of each wall element's pixels in `frame`, a
/// whole unbinned frame at the sensor's origin (MODEL.md `i_j`): one block's
/// wall image in DN, as [`stack`] makes it before the units.
pub fn wall_means(
    frame: &Frame,
    h: &Homography,
    wall: &Plane,
    pose: &str,
) -> Result<Vec<f64>, MeasureError> {
    let g = crate::scene::FrameGeometry::plain(frame.width, frame.height);
    let map = crate::scene::PixelMap::frame(h, wall, g, pose)?;
    Ok(map.average(&frame.pixels, None).0)
}
