//! One capture read for a measurement, wherever its frames are kept (the
//! daemon's store, a user's TIFF files): the checks and the warnings every
//! reader owes the user, in one place.

use super::{CaptureFrames, MeasureError};
use crate::scene::{Frame, Scene};

/// What a capture recorded about itself.
#[derive(Debug, Clone, PartialEq)]
pub struct CaptureInfo {
    /// How errors and warnings name it: `capture 12`, `frames-A.tiff`.
    pub name: String,
    /// Pose name in the scene.
    pub pose: String,
    /// The blocks its frames hold (one through a sheet or none, four from a mosaic sensor).
    pub channels: Vec<crate::scene::Channel>,
    /// Frames averaged into its mean.
    pub frames: usize,
    /// Full scale of its pixel format, DN.
    pub full_scale: f64,
    /// Exposure per frame, microseconds.
    pub exposure_us: f64,
    /// The region `[x, y, width, height]` it recorded, when it did: its
    /// mean frame must have that size, and its offset places the pixels on
    /// the sensor (MODEL.md "From camera frames to i").
    pub region: Option<[u32; 4]>,
    /// The binning it recorded, when it did (`[1, 1]` otherwise).
    pub binning: Option<[u32; 2]>,
    /// `None` when a dark level was subtracted from its mean; else how to
    /// take one next time (the daemon's and the CLI's ways differ).
    pub missing_dark: Option<&'static str>,
    /// The sensor's Bayer filter, for a colour camera's raw frames.
    pub bayer: Option<crate::measure::colour::BayerPattern>,
}

/// Where a capture's averaged frames are read from.
pub trait CaptureSource {
    /// Why its frames could not be read (which file, and why).
    type Error: std::error::Error;
    /// What the capture recorded.
    fn info(&self) -> CaptureInfo;
    /// Its mean frame (minus the dark level, when it has one), DN.
    fn mean(&self) -> Result<Frame, Self::Error>;
    /// The variance of that mean, DN², when there were 2 frames or more.
    fn variance(&self) -> Result<Option<Frame>, Self::Error>;
}

/// Reads `source` for `scene`: its pose must be one of the scene's and its
/// mean frame the size of the region it recorded; what the user should know
/// (no dark subtraction, a homography that does not say which camera frame
/// it maps to) is added to `warnings`.
pub fn load(
    scene: &Scene,
    source: &impl CaptureSource,
    warnings: &mut Vec<String>,
) -> Result<CaptureFrames, MeasureError> {
    let info = source.info();
    let fail = |reason: String| MeasureError::Capture {
        capture: info.name.clone(),
        reason,
    };
    let pose = scene
        .pose(&info.pose)
        .ok_or_else(|| MeasureError::UnknownPose {
            capture: info.name.clone(),
            pose: info.pose.clone(),
        })?;
    let mean = source.mean().map_err(|e| fail(e.to_string()))?;
    if let Some([_, _, w, h]) = info.region {
        if (mean.width, mean.height) != (w as usize, h as usize) {
            return Err(fail(format!(
                "its mean frame is {}x{}, but it recorded a {w}x{h} region; the files do not belong to it",
                mean.width, mean.height
            )));
        }
    }
    if let Some(how) = info.missing_dark {
        warnings.push(format!(
            "{} has no dark subtraction: the camera's dark level is an offset that T cannot explain, and it can dominate the result; {how}",
            info.name
        ));
    }
    if pose.frame.is_none() {
        warnings.push(format!(
            "pose {:?} does not say which camera frame its homography maps to (scene file keys region and binning), so the frame of {} ({}) could not be checked against it",
            pose.name,
            info.name,
            info.region
                .map_or(format!("{}x{}", mean.width, mean.height), |r| format!("region {r:?}"))
        ));
    }
    let variance = source.variance().map_err(|e| fail(e.to_string()))?;
    Ok(CaptureFrames {
        name: info.name,
        pose: info.pose,
        channels: info.channels,
        mean,
        variance,
        frames: info.frames,
        full_scale: info.full_scale,
        exposure_us: info.exposure_us,
        offset: info.region.map_or([0, 0], |r| [r[0], r[1]]),
        binning: info.binning.unwrap_or([1, 1]),
        bayer: info.bayer,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    struct Fake {
        info: CaptureInfo,
        size: (usize, usize),
    }

    impl CaptureSource for Fake {
        type Error = std::io::Error;
        fn info(&self) -> CaptureInfo {
            self.info.clone()
        }
        fn mean(&self) -> Result<Frame, std::io::Error> {
            Ok(Frame {
                width: self.size.0,
                height: self.size.1,
                pixels: vec![1.0; self.size.0 * self.size.1],
            })
        }
        fn variance(&self) -> Result<Option<Frame>, std::io::Error> {
            Err(std::io::Error::other("variance.tiff: truncated"))
        }
    }

    fn fake(pose: &str, region: Option<[u32; 4]>, size: (usize, usize)) -> Fake {
        Fake {
            info: CaptureInfo {
                name: "capture 4".into(),
                pose: pose.into(),
                channels: vec![crate::scene::Channel::Sheet { deg: 0.0 }],
                frames: 2,
                full_scale: 65535.0,
                exposure_us: 100.0,
                region,
                binning: None,
                missing_dark: Some("take dark frames"),
                bayer: None,
            },
            size,
        }
    }

    #[test]
    fn a_capture_is_held_to_its_pose_its_region_and_its_files() {
        let scene = Scene::builtin("brewster-crossed").unwrap().unwrap();
        let mut w = Vec::new();
        let e = load(&scene, &fake("Z", None, (4, 4)), &mut w).unwrap_err();
        assert!(matches!(e, MeasureError::UnknownPose { .. }), "{e}");
        let e = load(&scene, &fake("A", Some([0, 0, 8, 4]), (4, 4)), &mut w).unwrap_err();
        assert!(
            e.to_string()
                .contains("capture 4: its mean frame is 4x4, but it recorded a 8x4 region"),
            "{e}"
        );
        // Right size: the unreadable variance is the error, after the warnings.
        let e = load(&scene, &fake("A", Some([0, 0, 4, 4]), (4, 4)), &mut w).unwrap_err();
        assert_eq!(e.to_string(), "capture 4: variance.tiff: truncated");
        assert!(
            w[0].starts_with("capture 4 has no dark subtraction")
                && w[0].ends_with("take dark frames"),
            "{w:?}"
        );
    }
}
