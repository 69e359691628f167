//! Exposure planning: the exposure and frame count of each (pose, polarizer
//! angle) block so that its wall image reaches a target signal.
//!
//! Why it can be planned before any capture: the hidden scene is bounded,
//! `0 <= l <= 1` (MODEL.md Eq. 12), so the brightest a block's wall element
//! can be is `max_j (T_b 1)_j`; with the radiometric calibration (fraction of
//! full scale per microsecond per unit of `T l`) that fixes the exposure at
//! which no admissible scene saturates and a fully lit one reaches the target
//! fraction. The crossed-polarizer blocks are darker, so they get longer
//! exposures (or more frames where the camera's longest exposure is reached).
//! Frames are then added until shot and read noise allow the target SNR at
//! that peak.

use crate::transport::Transport;

/// What the camera allows and how noisy it is.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct CameraLimits {
    /// Shortest and longest exposure, microseconds.
    pub exposure_us: (f64, f64),
    /// Most frames a capture may average.
    pub max_frames: usize,
    /// Full-well capacity, electrons (full scale).
    pub full_well_e: f64,
    /// Read noise, electrons RMS.
    pub read_noise_e: f64,
}

/// The signal each block should reach.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct ExposureTarget {
    /// Brightest admissible wall element, as a fraction of full scale (0-1).
    pub peak_fraction: f64,
    /// Signal-to-noise ratio wanted at that element after averaging.
    pub snr: f64,
}

impl Default for ExposureTarget {
    fn default() -> Self {
        Self {
            peak_fraction: 0.8,
            snr: 100.0,
        }
    }
}

/// The plan of one block.
#[derive(Debug, Clone, PartialEq, serde::Serialize, utoipa::ToSchema)]
pub struct BlockExposure {
    /// Pose name.
    pub pose: String,
    /// The analyzer of the block (a sheet's angle, a mosaic's micro-polarizer, none).
    #[schema(value_type = Object)]
    pub channel: crate::scene::Channel,
    /// Fraction of full scale per microsecond at the brightest element when `l = 1`.
    pub peak_rate_per_us: f64,
    /// Proposed exposure per frame, microseconds.
    pub exposure_us: f64,
    /// Proposed number of frames.
    pub frames: usize,
    /// Fraction of full scale the brightest element reaches per frame.
    pub peak_fraction: f64,
    /// SNR at that element after averaging the frames.
    pub snr: f64,
    /// What stopped the plan short of the target, if anything.
    pub limited_by: Option<String>,
}

/// Why no plan could be made.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum ExposureError {
    /// A parameter is out of range.
    #[error("{name} = {value}: {reason}")]
    Parameter {
        /// Parameter name.
        name: &'static str,
        /// Given value.
        value: f64,
        /// Acceptable range.
        reason: &'static str,
    },
}

fn check(
    name: &'static str,
    value: f64,
    ok: bool,
    reason: &'static str,
) -> Result<(), ExposureError> {
    if ok {
        Ok(())
    } else {
        Err(ExposureError::Parameter {
            name,
            value,
            reason,
        })
    }
}

/// Plans every block of `t` (see the module doc). `pixels` gives each row's
/// effective number of camera pixels (`crate::scene::effective_pixels`):
/// an element measured from all its pixels (MODEL.md revision 3) collects
/// their photons, so its SNR is `sqrt(pixels)` times one pixel's; without
/// it every element is one pixel.
pub(crate) fn plan_exposure(
    t: &Transport,
    calibration: f64,
    limits: &CameraLimits,
    target: &ExposureTarget,
    pixels: Option<&[f64]>,
) -> Result<Vec<BlockExposure>, ExposureError> {
    check(
        "calibration",
        calibration,
        calibration > 0.0 && calibration.is_finite(),
        "must be a positive fraction of full scale per microsecond per unit of T l",
    )?;
    let f = target.peak_fraction;
    check("peak_fraction", f, f > 0.0 && f <= 1.0, "must be in (0, 1]")?;
    check(
        "snr",
        target.snr,
        target.snr > 0.0 && target.snr.is_finite(),
        "must be a positive number",
    )?;
    let (lo, hi) = limits.exposure_us;
    check(
        "exposure range",
        lo,
        lo > 0.0 && hi >= lo && hi.is_finite(),
        "the camera's shortest exposure must be positive and below its longest",
    )?;
    check(
        "full_well_e",
        limits.full_well_e,
        limits.full_well_e > 0.0 && limits.full_well_e.is_finite(),
        "must be a positive number of electrons",
    )?;
    let ones = vec![1.0; t.cols()];
    let lit = t.apply(&ones);
    let mut out = Vec::with_capacity(t.blocks().len());
    for (b, block) in t.blocks().iter().enumerate() {
        let rows = t.block_rows(b);
        let (at, peak) = lit[rows.clone()]
            .iter()
            .copied()
            .enumerate()
            .fold((0, 0.0), |m, (j, v)| if v > m.1 { (j, v) } else { m });
        let n_pixels = pixels
            .and_then(|p| p.get(rows.start + at))
            .copied()
            .filter(|n| *n >= 1.0)
            .unwrap_or(1.0);
        let rate = calibration * peak;
        let mut limited_by = None;
        let exposure_us = if rate > 0.0 {
            let want = f / rate;
            if want > hi {
                limited_by = Some(format!(
                    "the camera's longest exposure ({hi} us) reaches only {:.3} of full scale",
                    rate * hi
                ));
            } else if want < lo {
                limited_by = Some(format!(
                    "the camera's shortest exposure ({lo} us) already reaches {:.3} of full scale",
                    rate * lo
                ));
            }
            // A camera sets exposures in steps far coarser than f64: 0.1 us.
            ((want * 10.0).round() / 10.0).clamp(lo, hi)
        } else {
            limited_by = Some("no scene element lights this block's wall image".into());
            hi
        };
        let fraction = rate * exposure_us;
        let electrons = fraction.min(1.0) * limits.full_well_e;
        let read2 = limits.read_noise_e * limits.read_noise_e;
        // One frame's SNR at the peak element: the mean of its pixels.
        let snr1 = if electrons > 0.0 {
            n_pixels.sqrt() * electrons / (electrons + read2).sqrt()
        } else {
            0.0
        };
        let frames_wanted = if snr1 > 0.0 {
            (target.snr / snr1).powi(2).ceil().max(1.0)
        } else {
            f64::INFINITY
        };
        let frames = if frames_wanted > limits.max_frames as f64 {
            if limited_by.is_none() {
                limited_by = Some(format!(
                    "{} frames would be needed for SNR {}; capped at {}",
                    frames_wanted, target.snr, limits.max_frames
                ));
            }
            limits.max_frames
        } else {
            frames_wanted as usize
        };
        out.push(BlockExposure {
            pose: block.pose.clone(),
            channel: block.channel,
            peak_rate_per_us: rate,
            exposure_us,
            frames,
            peak_fraction: fraction,
            snr: snr1 * (frames as f64).sqrt(),
            limited_by,
        });
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::Scene;
    use crate::transport::build;
    use crate::transport::MemoryBudget;

    fn limits() -> CameraLimits {
        CameraLimits {
            exposure_us: (10.0, 1e7),
            max_frames: 1000,
            full_well_e: 1e4,
            read_noise_e: 5.0,
        }
    }

    #[test]
    fn the_brightest_admissible_scene_reaches_the_target_and_darker_blocks_wait_longer() {
        let t = build(
            &Scene::builtin("brewster-rotating-3x3").unwrap().unwrap(),
            MemoryBudget::DEFAULT,
        )
        .unwrap();
        let peak = t.apply(&[1.0; 9]);
        let p0 = peak[t.block_rows(0)].iter().copied().fold(0.0, f64::max);
        let cal = 0.5 / p0 / 1000.0; // block 0 reaches half scale in 1 ms
        let plan = plan_exposure(&t, cal, &limits(), &ExposureTarget::default(), None).unwrap();
        assert_eq!(plan.len(), 4);
        assert!((plan[0].exposure_us - 1600.0).abs() < 1e-6, "{:?}", plan[0]);
        for p in &plan {
            // Exposures come in 0.1 us steps: the peak is 0.8 to half a step.
            assert!((p.peak_fraction - 0.8).abs() <= 0.8 * 0.05 / p.exposure_us + 1e-12);
            assert_eq!((p.exposure_us * 10.0).round(), p.exposure_us * 10.0);
            assert!(p.limited_by.is_none());
            // 8000 e- per frame: SNR 89.4 per frame, 2 frames for 100.
            assert_eq!(p.frames, 2);
            assert!(p.snr >= 100.0);
        }
        // The crossed block (0 deg) is the darkest of the four.
        let longest = plan
            .iter()
            .max_by(|a, b| a.exposure_us.total_cmp(&b.exposure_us))
            .unwrap();
        assert_eq!(longest.channel, crate::scene::Channel::Sheet { deg: 0.0 });
        // Measured from all of its pixels, the peak element collects dozens
        // of pixels' photons: one frame reaches SNR 100 where one pixel needed 2.
        let scene = Scene::builtin("brewster-rotating-3x3").unwrap().unwrap();
        let pixels = crate::scene::effective_pixels(&scene).unwrap().unwrap();
        assert_eq!(pixels.len(), t.rows());
        assert!(
            pixels.iter().all(|&n| n > 30.0 && n < 200.0),
            "{:?}",
            &pixels[..4]
        );
        let plan = plan_exposure(
            &t,
            cal,
            &limits(),
            &ExposureTarget::default(),
            Some(&pixels),
        )
        .unwrap();
        for p in &plan {
            assert_eq!(p.frames, 1, "{p:?}");
            assert!(p.snr > 89.4 * 30f64.sqrt(), "{p:?}");
        }
    }

    #[test]
    fn camera_limits_are_reported_not_exceeded() {
        let t = build(
            &Scene::builtin("brewster-crossed-3x3").unwrap().unwrap(),
            MemoryBudget::DEFAULT,
        )
        .unwrap();
        let tiny = plan_exposure(&t, 1e-30, &limits(), &ExposureTarget::default(), None).unwrap();
        assert_eq!(tiny[0].exposure_us, 1e7);
        assert!(tiny[0]
            .limited_by
            .as_deref()
            .unwrap()
            .contains("longest exposure"));
        assert_eq!(tiny[0].frames, 1000);
        let huge = plan_exposure(&t, 1e30, &limits(), &ExposureTarget::default(), None).unwrap();
        assert_eq!(huge[0].exposure_us, 10.0);
        assert!(huge[0]
            .limited_by
            .as_deref()
            .unwrap()
            .contains("shortest exposure"));
        let e = plan_exposure(
            &t,
            1.0,
            &limits(),
            &ExposureTarget {
                peak_fraction: 1.5,
                snr: 10.0,
            },
            None,
        )
        .unwrap_err();
        assert!(e.to_string().starts_with("peak_fraction = 1.5"));
        assert!(plan_exposure(&t, f64::NAN, &limits(), &ExposureTarget::default(), None).is_err());
    }
}
