//! Frames to the measurement vector `i` (MODEL.md "From camera frames to i"):
//! each block's mean frame sampled at the wall elements through its pose's
//! homography, in fractions of full scale per microsecond, stacked in block
//! order, with the variance of each element when every block has one.
//!
//! The variance of a mean of frames is not the frame-to-frame variance over
//! the frame count alone: where the noise per frame is below one DN the
//! digitizer does not dither, every frame rounds the same way, and the mean
//! keeps a bias of up to half a DN that no number of frames averages away
//! (and that the sample variance does not see). Each element's variance
//! therefore adds that bias's variance, `(1/12) exp(-2 pi^2 s^2)` DN² for a
//! per-frame noise of `s` DN (the residual of Gaussian-dithered rounding:
//! the first Fourier term of the quantizer's error, Widrow & Kollár 2008).

use super::{sample_wall, MeasureError};
use crate::measure::Frame;
use crate::scene::{Homography, Plane};

/// One (pose, polarizer angle) block's frames, as a capture gives them.
#[derive(Debug, Clone, Copy)]
pub struct BlockFrames<'a> {
    /// Pose name (for errors).
    pub pose: &'a str,
    /// The pose's camera→wall homography.
    pub homography: &'a Homography,
    /// Mean dark-subtracted frame, DN.
    pub mean: &'a Frame,
    /// Variance of the mean frame, DN², when the capture had 2 frames or more.
    pub variance: Option<&'a Frame>,
    /// Frames averaged into the mean (for the quantization floor of the variance).
    pub frames: usize,
    /// Full scale of the pixel format, DN.
    pub full_scale: f64,
    /// Exposure per frame, microseconds.
    pub exposure_us: f64,
}

/// A stacked measurement.
#[derive(Debug, Clone, PartialEq)]
pub struct Measurement {
    /// `i`, fractions of full scale per microsecond, MODEL.md row order.
    pub i: Vec<f64>,
    /// Variance of each element of `i`, when every block had one.
    pub variance: Option<Vec<f64>>,
}

/// Stacks `blocks` (in MODEL.md block order) into a measurement: dividing by
/// full scale and exposure makes captures of different exposures and pixel
/// formats comparable, and variances scale by the square of the same factor.
pub fn stack(blocks: &[BlockFrames<'_>], wall: &Plane) -> Result<Measurement, MeasureError> {
    let mut i = Vec::with_capacity(blocks.len() * wall.grid.nu * wall.grid.nv);
    let mut variance = Some(Vec::with_capacity(i.capacity()));
    for b in blocks {
        let to_units = 1.0 / b.full_scale / b.exposure_us;
        let values = sample_wall(b.mean, b.homography, wall, b.pose)?;
        i.extend(values.into_iter().map(|v| v * to_units));
        match (b.variance, variance.as_mut()) {
            (Some(f), Some(acc)) => {
                let values = sample_wall(f, b.homography, wall, b.pose)?;
                let n = b.frames.max(1) as f64;
                acc.extend(
                    values
                        .into_iter()
                        .map(|v| with_rounding_bias(v, n) * to_units * to_units),
                );
            }
            _ => variance = None,
        }
    }
    Ok(Measurement { i, variance })
}

/// The variance of a mean of `n` frames, `var_mean` DN² as measured, plus the
/// variance of the rounding bias the mean keeps when the per-frame noise
/// `s = sqrt(n var_mean)` does not dither the digitizer (module docs).
pub fn with_rounding_bias(var_mean: f64, n: f64) -> f64 {
    let var_mean = var_mean.max(0.0);
    let s2 = n * var_mean;
    var_mean + (-2.0 * std::f64::consts::PI.powi(2) * s2).exp() / 12.0
}

#[cfg(test)]
mod tests {
    use super::*;

    fn wall() -> Plane {
        match crate::scene::Scene::builtin("brewster-multi-3x3") {
            Some(Ok(s)) => s.wall().plane.clone(),
            _ => panic!("built-in scene"),
        }
    }

    fn flat(value: f32) -> Frame {
        Frame {
            width: 512,
            height: 512,
            pixels: vec![value; 512 * 512],
        }
    }

    fn homography() -> Homography {
        match crate::scene::Scene::builtin("brewster-multi-3x3") {
            Some(Ok(s)) => s.poses()[0].homography.expect("pose B has a homography"),
            _ => panic!("built-in scene"),
        }
    }

    #[test]
    fn blocks_stack_in_order_in_units_of_full_scale_per_microsecond() {
        let (w, h) = (wall(), homography());
        let (a, b, var) = (flat(1000.0), flat(500.0), flat(4.0));
        let block = |mean, variance, exposure_us| BlockFrames {
            pose: "B",
            homography: &h,
            mean,
            variance,
            frames: 8,
            full_scale: 1000.0,
            exposure_us,
        };
        let m = stack(
            &[block(&a, Some(&var), 10.0), block(&b, Some(&var), 5.0)],
            &w,
        )
        .expect("inside the frame");
        let n = w.grid.nu * w.grid.nv;
        assert_eq!(m.i.len(), 2 * n);
        // 1000 DN of 1000 in 10 us and 500 DN in 5 us: both 0.1 per us.
        assert!(m.i.iter().all(|v| (v - 0.1).abs() < 1e-12), "{:?}", m.i);
        let var = m.variance.expect("both blocks have a variance");
        assert!((var[0] - 4.0 / 1e8).abs() < 1e-20);
        assert!((var[n] - 4.0 / 1e6 / 25.0).abs() < 1e-20);
        // One block without a variance: the measurement has none.
        let m = stack(
            &[block(&a, Some(&var_frame()), 10.0), block(&b, None, 5.0)],
            &w,
        );
        assert_eq!(m.expect("inside").variance, None);
    }

    #[test]
    fn the_variance_keeps_the_rounding_bias_that_frames_do_not_average() {
        // Noiseless frames: the mean is known to the digitizer's 1/12 DN², not 0.
        assert!((with_rounding_bias(0.0, 32.0) - 1.0 / 12.0).abs() < 1e-15);
        // 0.2 DN of noise per frame dithers a little: part of the floor remains.
        let b = with_rounding_bias(0.04 / 32.0, 32.0) - 0.04 / 32.0;
        assert!(b > 0.01 && b < 1.0 / 12.0, "{b}");
        // 2 DN per frame dithers fully: the measured variance stands.
        let v = 4.0 / 32.0;
        assert!((with_rounding_bias(v, 32.0) - v).abs() < 1e-30);
    }

    fn var_frame() -> Frame {
        flat(1.0)
    }

    #[test]
    fn a_frame_too_small_for_the_homography_is_an_error_naming_the_pose() {
        let (w, h) = (wall(), homography());
        let small = Frame {
            width: 16,
            height: 16,
            pixels: vec![0.0; 256],
        };
        let block = BlockFrames {
            pose: "B",
            homography: &h,
            mean: &small,
            variance: None,
            frames: 1,
            full_scale: 1.0,
            exposure_us: 1.0,
        };
        let e = stack(&[block], &w).expect_err("outside");
        assert!(e.to_string().starts_with("pose \"B\""), "{e}");
    }
}
