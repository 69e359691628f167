//! Checking a progressive reconstruction asked for with a capture: the
//! capture and the other captures named must cover every block of the
//! scene once, at the frames the poses' homographies map to.

use super::reconstruction::{blocks_served, cover, uncovered};
use super::{invalid, RequestError};
use crate::daemon::requests::{DifferenceBody, ProgressiveBody, RecordBody};
use crate::scene::Scene;
use crate::store::{CaptureRecord, CaptureRequest};

/// What a capture's progressive reconstruction will use, resolved.
#[derive(Debug, Clone, PartialEq)]
pub struct ProgressiveSpec {
    /// Re-solve after every this many frames.
    pub every: usize,
    /// The other blocks' captures.
    pub captures: Vec<i64>,
    /// TV weight (None: the default relative to `T`).
    pub lambda: Option<f64>,
    /// Iteration cap of each step.
    pub max_iter: usize,
    /// Truth pattern name.
    pub truth: Option<String>,
    /// Live view's difference mode: the background's time constant,
    /// seconds (`None`: each window as it is).
    pub difference: Option<f64>,
    /// The radiometry asked for (`None`: chosen as a reconstruction's is).
    pub radiometry: Option<crate::solve::radiometry::Radiometry>,
}

/// Checks `p` for capture request `r` of `scene`; `capture` looks up the
/// other captures.
pub fn progressive(
    p: &ProgressiveBody,
    r: &CaptureRequest,
    scene: &Scene,
    capture: impl Fn(i64) -> Result<Option<CaptureRecord>, RequestError>,
) -> Result<ProgressiveSpec, RequestError> {
    if r.kind == crate::store::CaptureKind::Dark {
        return Err(invalid(
            "a dark capture has no scene to reconstruct: progressive is for light captures",
        ));
    }
    let (every, max_iter) = check_numbers(p, r)?;
    let blocks = crate::transport::blocks_of(scene);
    let mut covered = vec![false; blocks.len()];
    let own = crate::transport::Block::taken(&blocks, &r.pose, &r.channels);
    if own.len() != r.channels.len() {
        return Err(invalid("the capture's blocks are not blocks of its scene"));
    }
    cover(&mut covered, &own, &blocks, "progressive.captures: ")?;
    if let Some(frame) = scene.pose(&r.pose).and_then(|p| p.frame) {
        if (r.acquisition.region, r.acquisition.binning) != (frame.region, frame.binning) {
            return Err(invalid(format!(
                "progressive reconstruction samples this capture through pose {:?}'s homography, which maps into region {:?} binning {:?}; this capture uses region {:?} binning {:?}",
                r.pose, frame.region, frame.binning, r.acquisition.region, r.acquisition.binning
            )));
        }
    }
    for &id in &p.captures {
        let c = capture(id)?
            .ok_or_else(|| RequestError::NotFound(format!("no capture with id {id}")))?;
        let served = blocks_served(&c, &r.scene, scene, &blocks)?;
        cover(&mut covered, &served, &blocks, "progressive.captures: ")?;
    }
    let missing = uncovered(&covered, &blocks);
    if !missing.is_empty() {
        return Err(invalid(format!(
            "progressive reconstruction of scene {:?} needs a done capture of every other block in progressive.captures; missing: {}",
            r.scene,
            missing.join("; ")
        )));
    }
    Ok(ProgressiveSpec {
        every,
        captures: p.captures.clone(),
        lambda: p.lambda,
        max_iter,
        truth: p.truth.clone(),
        difference: None,
        radiometry: p.radiometry,
    })
}

/// The background time constant of live view's difference mode, seconds:
/// the request's (0.1 to 3600) or [`DEFAULT_BACKGROUND_S`].
pub(crate) fn difference(d: &DifferenceBody) -> Result<f64, RequestError> {
    match d.background_s {
        None => Ok(DEFAULT_BACKGROUND_S),
        Some(s) if s.is_finite() && (0.1..=3600.0).contains(&s) => Ok(s),
        Some(s) => Err(invalid(format!(
            "difference.background_s = {s}: give 0.1 to 3600 seconds"
        ))),
    }
}

/// The frames a live session records: 1 to `max` with its dark frames,
/// as a capture's frames (`[queue] max_frames_per_capture`).
/// Why the capture's bound: the recording is a capture, kept and reserved as one.
pub(crate) fn recording(
    r: &RecordBody,
    dark_frames: usize,
    max: usize,
) -> Result<usize, RequestError> {
    let n = r.frames;
    if n == 0 || n.saturating_add(dark_frames) > max {
        return Err(invalid(format!(
            "record.frames = {n}: a recording is 1 to {} frames (with the session's {dark_frames} dark frames, at most {max} in all, as a capture: [queue] max_frames_per_capture)",
            max.saturating_sub(dark_frames)
        )));
    }
    Ok(n)
}

/// The background's default time constant, seconds.
/// Why 10: a person crossing a room moves within it, a lamp's drift does not.
const DEFAULT_BACKGROUND_S: f64 = 10.0;

/// The step interval and iteration cap, with lambda and truth checked.
fn check_numbers(p: &ProgressiveBody, r: &CaptureRequest) -> Result<(usize, usize), RequestError> {
    let every = p.every.unwrap_or((r.frames / 10).max(1));
    if every == 0 || every > r.frames {
        return Err(invalid(format!(
            "progressive.every = {every}: must be from 1 to frames ({})",
            r.frames
        )));
    }
    let max_iter = p.max_iter.unwrap_or(500);
    if !(1..=100_000).contains(&max_iter) {
        return Err(invalid(format!(
            "progressive.max_iter = {max_iter}: must be from 1 to 100000"
        )));
    }
    if let Some(l) = p.lambda {
        if !(l >= 0.0 && l.is_finite()) {
            return Err(invalid(format!(
                "progressive.lambda = {l}: must be a finite number >= 0"
            )));
        }
    }
    if let Some(t) = &p.truth {
        if crate::simulate::patterns::Pattern::from_name(t).is_none() {
            return Err(invalid(format!(
                "progressive.truth = {t:?}: must be a test pattern name (disk, bars, letter, flat)"
            )));
        }
    }
    Ok((every, max_iter))
}

#[cfg(test)]
mod tests {
    use super::super::fixtures::{record, scene};
    use super::*;
    use crate::store::JobState;

    fn request(pose: &str) -> CaptureRequest {
        let example = CaptureRequest::example();
        CaptureRequest {
            scene: "brewster-multi-3x3".into(),
            pose: pose.into(),
            acquisition: crate::camera::Acquisition {
                exposure_us: 5000.0,
                region: [0, 0, 512, 512],
                ..example.acquisition
            },
            frames: 40,
            dark_frames: 2,
            ..example
        }
    }

    fn body(json: serde_json::Value) -> ProgressiveBody {
        serde_json::from_value(json).expect("a well-formed body")
    }

    #[test]
    fn a_difference_background_is_0_1_to_3600_seconds_or_the_default() {
        let d = |v: serde_json::Value| -> DifferenceBody { serde_json::from_value(v).unwrap() };
        assert_eq!(difference(&d(serde_json::json!({}))).unwrap(), 10.0);
        assert_eq!(
            difference(&d(serde_json::json!({"background_s": 2.5}))).unwrap(),
            2.5
        );
        for bad in [0.0, -1.0, 1e5] {
            let e = difference(&d(serde_json::json!({ "background_s": bad }))).unwrap_err();
            assert!(e.to_string().contains("difference.background_s"), "{e}");
        }
        assert!(serde_json::from_value::<DifferenceBody>(serde_json::json!({"tau": 1})).is_err());
    }

    #[test]
    fn a_recording_is_1_to_the_capture_bound_with_its_dark_frames() {
        let r = |frames: usize| RecordBody { frames };
        assert_eq!(recording(&r(1), 0, 1000).unwrap(), 1);
        assert_eq!(recording(&r(998), 2, 1000).unwrap(), 998);
        for (n, dark) in [(0, 0), (999, 2), (1001, 0), (usize::MAX, 2)] {
            let e = recording(&r(n), dark, 1000).unwrap_err().to_string();
            assert!(e.starts_with(&format!("record.frames = {n}: ")), "{e}");
            assert!(e.contains(&format!("1 to {}", 1000 - dark)), "{e}");
        }
    }

    #[test]
    fn the_other_blocks_must_be_covered_by_done_captures() {
        let s = scene();
        let b_done = record(1, "light", 5000.0, JobState::Done);
        let lookup = |id: i64| Ok((id == 1).then(|| b_done.clone()));
        // Capturing C: B must come from capture 1.
        let spec = progressive(
            &body(serde_json::json!({ "captures": [1] })),
            &request("C"),
            &s,
            lookup,
        )
        .expect("accepted");
        assert_eq!((spec.every, spec.max_iter), (4, 500));
        let e = progressive(&body(serde_json::json!({})), &request("C"), &s, lookup)
            .expect_err("B missing");
        assert!(e.to_string().contains("missing: pose B at 0°"), "{e}");
        // Capturing B with capture 1 (also B): two captures for one block.
        let e = progressive(
            &body(serde_json::json!({ "captures": [1] })),
            &request("B"),
            &s,
            lookup,
        )
        .expect_err("twice");
        assert!(
            e.to_string()
                .contains("two captures for block pose B at 0°"),
            "{e}"
        );
    }

    #[test]
    fn steps_and_truth_are_checked() {
        let s = scene();
        let lookup = |_| Ok(None);
        for (json, needle) in [
            (serde_json::json!({ "every": 0 }), "every = 0"),
            (serde_json::json!({ "every": 41 }), "every = 41"),
            (serde_json::json!({ "max_iter": 0 }), "max_iter = 0"),
            (serde_json::json!({ "lambda": -1.0 }), "lambda = -1"),
            (serde_json::json!({ "truth": "cat" }), "truth = \"cat\""),
        ] {
            let e = progressive(&body(json), &request("C"), &s, lookup).expect_err(needle);
            assert!(e.to_string().contains(needle), "{e}");
        }
    }
}
