//! Between camera frames and the measurement vector `i` (MODEL.md "From
//! camera frames to i"): sampling frames through a pose's homography, and
//! rendering the frame a wall image implies (for simulation and the fake camera).

mod assemble;
mod average;
pub mod exposure;
mod frame;
pub mod levels;
mod load;
mod stack;

pub use assemble::{assemble, match_blocks, same_angle, to_model_units, CaptureFrames, Units};
pub use average::FrameStack;
pub use frame::Frame;
pub use load::{load, CaptureInfo, CaptureSource};
pub use stack::{stack, with_rounding_bias, BlockFrames, Measurement};

use crate::scene::{Homography, Plane};

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
    /// A wall sample maps outside the frame.
    #[error("pose {pose:?}: wall element {element} (u = {u:.4} m, v = {v:.4} m) maps to pixel ({x:.1}, {y:.1}), outside the {width}x{height} frame; check the homography and the region of interest")]
    OutsideFrame {
        /// Pose name.
        pose: String,
        /// Wall element index.
        element: usize,
        /// Wall coordinate u.
        u: f64,
        /// Wall coordinate v.
        v: f64,
        /// Pixel x.
        x: f64,
        /// Pixel y.
        y: f64,
        /// Frame width.
        width: usize,
        /// Frame height.
        height: usize,
    },
}

/// One wall value per element: the mean of the frame bilinearly sampled at
/// the element's sub-sample points through `h`.
pub fn sample_wall(
    frame: &Frame,
    h: &Homography,
    wall: &Plane,
    pose: &str,
) -> Result<Vec<f64>, MeasureError> {
    let m2 = wall.samples_per_element();
    let uv = wall.sample_uv();
    let mut out = vec![0.0; wall.grid.count()];
    for (s, &(u, v)) in uv.iter().enumerate() {
        let element = s / m2;
        let outside = |x: f64, y: f64| MeasureError::OutsideFrame {
            pose: pose.to_string(),
            element,
            u,
            v,
            x,
            y,
            width: frame.width,
            height: frame.height,
        };
        let (x, y) = h.apply(u, v).ok_or_else(|| outside(f64::NAN, f64::NAN))?;
        let value = frame.bilinear(x, y).ok_or_else(|| outside(x, y))?;
        out[element] += value / m2 as f64;
    }
    Ok(out)
}

/// The camera frame showing a wall whose elements have the given values:
/// each pixel shows the wall element it sees (piecewise constant), `background`
/// where it sees no wall.
pub fn render_wall(
    values: &[f64],
    h: &Homography,
    wall: &Plane,
    width: usize,
    height: usize,
    background: f64,
) -> Frame {
    let mut frame = Frame::zeros(width, height);
    let (nu, nv) = (wall.grid.nu as f64, wall.grid.nv as f64);
    for y in 0..height {
        for x in 0..width {
            let value = h.invert(x as f64, y as f64).and_then(|(u, v)| {
                let fu = (u / wall.size[0] + 0.5) * nu;
                let fv = (v / wall.size[1] + 0.5) * nv;
                (fu >= 0.0 && fv >= 0.0 && fu < nu && fv < nv)
                    .then(|| values[wall.grid.index(fu as usize, fv as usize)])
            });
            frame.pixels[y * width + x] = value.unwrap_or(background) as f32;
        }
    }
    frame
}
