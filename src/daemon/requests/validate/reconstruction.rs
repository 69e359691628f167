//! Checking a reconstruction request against its scene and captures.

use super::{invalid, RequestError};
use crate::daemon::jobs::{block_label, capture_label};
use crate::daemon::requests::ReconstructionBody;
use crate::scene::Scene;
use crate::store::{CaptureRecord, JobState, ReconstructionParams, ReconstructionRequest};
use crate::transport::{blocks_of, Block};

/// Marks the blocks `served` as `covered`, refusing one already covered.
pub(super) fn cover(
    covered: &mut [bool],
    served: &[usize],
    blocks: &[Block],
    what: &str,
) -> Result<(), RequestError> {
    for &k in served {
        if covered[k] {
            return Err(invalid(format!(
                "{what}two captures for block {}; give one per block",
                label(&blocks[k])
            )));
        }
        covered[k] = true;
    }
    Ok(())
}

/// The blocks not `covered`, as people read them.
pub(super) fn uncovered(covered: &[bool], blocks: &[Block]) -> Vec<String> {
    blocks
        .iter()
        .zip(covered)
        .filter(|(_, c)| !**c)
        .map(|(b, _)| label(b))
        .collect()
}

/// A block as people read it.
pub(super) fn label(b: &Block) -> String {
    block_label(&b.pose, b.channel)
}

/// Checks a reconstruction request: solver parameters, the truth's name, and
/// one done light capture of this scene for every (pose, angle) block (for
/// a `partial` request, for the blocks it gives, at least one), taken at the
/// frame the pose's homography maps to. `capture` looks captures up.
pub fn reconstruction(
    b: &ReconstructionBody,
    scene: &Scene,
    capture: impl Fn(i64) -> Result<Option<CaptureRecord>, RequestError>,
) -> Result<ReconstructionRequest, RequestError> {
    let solve = b.solve;
    solve.check().map_err(|e| invalid(e.to_string()))?;
    if let Some(t) = &b.truth {
        t.check(scene.hidden().plane.grid, "truth")
            .map_err(|e| invalid(e.to_string()))?;
    }
    let blocks = blocks_of(scene);
    let mut covered = vec![false; blocks.len()];
    let (mut imported, mut taken) = (None, None);
    for &id in &b.captures {
        let c = capture(id)?
            .ok_or_else(|| RequestError::NotFound(format!("no capture with id {id}")))?;
        let served = blocks_served(&c, &b.scene, scene, &blocks)?;
        cover(&mut covered, &served, &blocks, "")?;
        match c.is_imported() {
            true => imported.get_or_insert(id),
            false => taken.get_or_insert(id),
        };
    }
    if let (Some(i), Some(t)) = (imported, taken) {
        return Err(invalid(format!(
            "capture {i} was imported and capture {t} taken by the camera: their units differ, so they cannot be reconstructed together; import every block, or capture every block"
        )));
    }
    if b.radiometry == Some(crate::solve::radiometry::Radiometry::Fitted)
        && b.solve.solver != crate::solve::Solver::ADMM_TV
    {
        return Err(invalid(format!(
            "solver {:?} with radiometry \"fitted\": a fitted reconstruction solves with admm-tv on the differences of each block (docs/realphoto.md); leave solver out",
            b.solve.solver.name()
        )));
    }
    let missing = uncovered(&covered, &blocks);
    if b.partial && b.captures.is_empty() {
        return Err(invalid(format!(
            "a partial reconstruction of scene {:?} needs at least one capture",
            b.scene
        )));
    }
    if !missing.is_empty() && !b.partial {
        return Err(invalid(format!(
            "scene {:?} has {} (pose, polarizer) blocks ({}); give one capture for each (a polarizer-mosaic capture gives its pose's four); missing: {}",
            b.scene,
            blocks.len(),
            blocks.iter().map(label).collect::<Vec<_>>().join("; "),
            missing.join("; ")
        )));
    }
    Ok(ReconstructionRequest {
        scene: b.scene.clone(),
        captures: b.captures.clone(),
        params: ReconstructionParams {
            // A partial request that gives every block is a whole one.
            partial: !missing.is_empty(),
            radiometry: b.radiometry,
            ..ReconstructionParams::new(solve, b.truth.clone())
        },
    })
}

/// The blocks a capture serves (one, or a mosaic pose's four), after
/// checking it can serve them: done, light, of this scene, at the pose's
/// camera frame.
pub(super) fn blocks_served(
    c: &CaptureRecord,
    scene_name: &str,
    scene: &Scene,
    blocks: &[Block],
) -> Result<Vec<usize>, RequestError> {
    let id = c.id;
    if c.state != JobState::Done {
        return Err(invalid(format!(
            "capture {id} is {}, not done",
            c.state.name()
        )));
    }
    if !c.is_light() {
        return Err(invalid(format!(
            "capture {id} is a {} capture; give light captures (subtract darks with dark_capture when capturing; target captures are for POST /calibrations)",
            c.kind.name()
        )));
    }
    if c.scene != scene_name {
        return Err(invalid(format!(
            "capture {id} belongs to scene {:?}, not {scene_name:?}",
            c.scene
        )));
    }
    let served = Block::taken(blocks, &c.pose, &c.channels);
    if served.len() != c.channels.len() {
        return Err(invalid(format!(
            "capture {id} ({}) is not {} of scene {scene_name:?}",
            capture_label(&c.pose, &c.channels),
            if c.channels.len() == 1 {
                "a block"
            } else {
                "a pose's blocks"
            }
        )));
    }
    // An import was sampled (or given) at the scene's wall elements already.
    if let Some(frame) = scene
        .pose(&c.pose)
        .and_then(|p| p.frame)
        .filter(|_| !c.is_imported())
    {
        let s = &c.settings;
        if (s.region, s.binning) != (Some(frame.region), Some(frame.binning)) {
            return Err(invalid(format!(
                "capture {id} was taken at region {} binning {}, but pose {:?}'s homography maps the wall into region {:?} binning {:?} (scene file keys region and binning): sampling it would read the wrong pixels; capture again with that region and binning, or calibrate the pose for this frame",
                s.region.map_or("unknown".into(), |r| format!("{r:?}")),
                s.binning.map_or("unknown".into(), |r| format!("{r:?}")),
                c.pose,
                frame.region,
                frame.binning
            )));
        }
    }
    Ok(served)
}

#[cfg(test)]
mod tests {
    use super::super::fixtures::{record, scene};
    use super::*;
    use crate::solve::Solver;

    fn reconstruction_body(captures: &[i64]) -> ReconstructionBody {
        serde_json::from_value(serde_json::json!({
            "scene": "brewster-multi-3x3", "captures": captures
        }))
        .expect("a well-formed body")
    }

    #[test]
    fn a_reconstruction_needs_one_done_light_capture_per_block() {
        let mut c = record(2, "light", 5000.0, JobState::Done);
        c.pose = "C".into();
        let captures = [record(1, "light", 5000.0, JobState::Done), c];
        let lookup = |id: i64| Ok(captures.iter().find(|c| c.id == id).cloned());
        let s = scene();
        let r = reconstruction(&reconstruction_body(&[1, 2]), &s, lookup).expect("accepted");
        assert_eq!(r.params.solve.solver, Solver::ADMM_TV);
        assert_eq!(r.captures, vec![1, 2]);
        let err = |ids: &[i64]| match reconstruction(&reconstruction_body(ids), &s, lookup) {
            Err(RequestError::Invalid(m)) | Err(RequestError::NotFound(m)) => m,
            Ok(_) => panic!("{ids:?} accepted"),
            Err(e) => panic!("{e:?}"),
        };
        assert!(err(&[1]).contains("2 (pose, polarizer) blocks (pose B at 0°; pose C at 0°)"));
        assert!(err(&[1]).contains("missing: pose C at 0°"));
        assert!(err(&[1, 1]).contains("two captures for block pose B at 0°"));
        assert!(err(&[1, 9]).contains("no capture with id 9"));
        // Partial: the blocks given are enough, and only an incomplete set is marked so.
        let partial = |ids: &[i64]| {
            let mut b = reconstruction_body(ids);
            b.partial = true;
            reconstruction(&b, &s, lookup)
        };
        assert!(partial(&[1]).expect("one block of two").params.partial);
        assert!(!partial(&[1, 2]).expect("every block").params.partial);
        assert!(
            matches!(partial(&[]), Err(RequestError::Invalid(m)) if m.contains("at least one capture"))
        );
        assert!(
            matches!(partial(&[1, 1]), Err(RequestError::Invalid(m)) if m.contains("two captures"))
        );
        // A catalogue that cannot be read is passed on, not called a missing capture.
        let unreadable = |_| Err(RequestError::Store("disk I/O error".into()));
        let r = reconstruction(&reconstruction_body(&[1, 2]), &s, unreadable);
        assert!(matches!(r, Err(RequestError::Store(m)) if m == "disk I/O error"));
    }

    #[test]
    fn a_capture_at_another_frame_or_state_cannot_serve_a_block() {
        let s = scene();
        let mut cropped = record(1, "light", 5000.0, JobState::Done);
        cropped.settings.region = Some([0, 0, 256, 256]);
        let blocks = blocks_of(&s);
        let m = blocks_served(&cropped, "brewster-multi-3x3", &s, &blocks)
            .expect_err("a cropped capture");
        assert!(m.to_string().contains("region [0, 0, 256, 256]"), "{m}");
        let running = record(1, "light", 5000.0, JobState::Running);
        let m = blocks_served(&running, "brewster-multi-3x3", &s, &blocks).expect_err("running");
        assert!(m.to_string().contains("is running, not done"), "{m}");
        let dark = record(1, "dark", 5000.0, JobState::Done);
        let m = blocks_served(&dark, "brewster-multi-3x3", &s, &blocks).expect_err("dark");
        assert!(m.to_string().contains("is a dark capture"), "{m}");
        let m = blocks_served(&dark, "brewster-crossed-3x3", &s, &blocks).expect_err("scene");
        assert!(m.to_string().contains("dark capture"), "{m}");
    }

    #[test]
    fn solver_parameters_and_truth_names_are_checked() {
        let s = scene();
        let mut b = reconstruction_body(&[]);
        b.truth = Some("cat".into());
        let r = reconstruction(&b, &s, |_| Ok(None));
        assert!(matches!(r, Err(RequestError::Invalid(m)) if m.contains("truth = \"cat\"")));
        let mut b = reconstruction_body(&[]);
        b.solve.tol = Some(2.0);
        assert!(matches!(
            reconstruction(&b, &s, |_| Ok(None)),
            Err(RequestError::Invalid(_))
        ));
    }
}
