//! The camera stage that carries the camera between a scene's poses:
//! opened from `[stage]`, moved by a capture to its pose before the first
//! frame, and shown by `GET /stage`.
//!
//! Why here: with a stage a plan walks a multi-pose scene unattended (no
//! "move the camera" step), and a capture whose camera missed its pose
//! fails naming the positions instead of measuring the wall through the
//! wrong homography. Without a stage (`kind = "none"`) the operator moves
//! the camera and the daemon trusts the capture's `pose`.

use std::sync::Mutex;

use serde::{Deserialize, Serialize};

use crate::rig::stage::{distance, CameraStage, SimulatedStage, StageError, TOLERANCE_M};
use crate::scene::Pose;

/// Which stage moves the camera (`[stage]`).
#[derive(Debug, Clone, Default, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StageConfig {
    /// `none` (the operator moves the camera) or `simulated` (a stage that
    /// goes where it is sent, for the fake bench).
    #[serde(default)]
    pub kind: StageKind,
    /// Millimetres each move of the *simulated* stage stops short (plays a
    /// stage that loses steps; 0 by default).
    #[serde(default)]
    pub simulated_slip_mm: f64,
}

/// The kinds of stage.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize, Serialize, utoipa::ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum StageKind {
    /// No stage: the operator moves the camera between poses.
    #[default]
    None,
    /// A simulated stage (the fake bench's).
    Simulated,
}

impl StageConfig {
    /// Checks the values a config file gave, naming the key.
    pub fn check(&self) -> Result<(), crate::rig::RigConfigError> {
        let slip = self.simulated_slip_mm;
        if !(slip.is_finite() && (0.0..=1000.0).contains(&slip)) {
            return Err(crate::rig::RigConfigError::new(
                "stage",
                format!("simulated_slip_mm = {slip}:"),
                "must be millimetres from 0 to 1000",
            ));
        }
        Ok(())
    }
}

/// The stage now, as `GET /stage` shows it.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct StageView {
    /// Which stage is configured.
    pub kind: StageKind,
    /// The pose the camera was last moved to and reached.
    pub pose: Option<String>,
    /// The position last read back, metres (the scene's frame).
    pub position_m: Option<[f64; 3]>,
    /// What went wrong last, if the last move failed.
    pub last_error: Option<String>,
}

/// The stage and what it last said.
struct State {
    device: Option<Box<dyn CameraStage>>,
    pose: Option<String>,
    position_m: Option<[f64; 3]>,
    last_error: Option<String>,
}

/// Owns the stage; one move at a time behind its lock.
pub struct StageService {
    kind: StageKind,
    state: Mutex<State>,
}

impl StageService {
    /// Starts the configured stage.
    pub fn start(config: &StageConfig) -> Self {
        let device: Option<Box<dyn CameraStage>> = match config.kind {
            StageKind::None => None,
            StageKind::Simulated => {
                let mut s = SimulatedStage::new();
                s.slip(config.simulated_slip_mm * 1e-3);
                Some(Box::new(s))
            }
        };
        Self {
            kind: config.kind,
            state: Mutex::new(State {
                device,
                pose: None,
                position_m: None,
                last_error: None,
            }),
        }
    }

    /// Whether a stage moves the camera (else the operator does).
    pub fn present(&self) -> bool {
        self.kind != StageKind::None
    }

    /// Moves the camera to `pose` and returns the position read back, or
    /// why it is not there (blocking: a real stage takes seconds).
    pub fn move_to(&self, pose: &Pose) -> Result<[f64; 3], StageError> {
        let asked = [pose.camera.x, pose.camera.y, pose.camera.z];
        let mut s = self.state.lock().unwrap_or_else(|e| e.into_inner());
        let Some(device) = s.device.as_mut() else {
            return Err(StageError::Device("no camera stage is configured".into()));
        };
        let result = device.move_to(asked).and_then(|read| {
            let miss = distance(read, asked);
            if miss > TOLERANCE_M {
                Err(StageError::Missed {
                    pose: pose.name.clone(),
                    asked,
                    read,
                    miss_mm: miss * 1e3,
                })
            } else {
                Ok(read)
            }
        });
        match &result {
            Ok(read) => {
                s.pose = Some(pose.name.clone());
                s.position_m = Some(*read);
                s.last_error = None;
            }
            Err(e) => {
                s.pose = None;
                if let StageError::Missed { read, .. } = e {
                    s.position_m = Some(*read);
                }
                s.last_error = Some(e.to_string());
            }
        }
        result
    }

    /// The stage as last seen (no I/O).
    pub fn view(&self) -> StageView {
        let s = self.state.lock().unwrap_or_else(|e| e.into_inner());
        StageView {
            kind: self.kind,
            pose: s.pose.clone(),
            position_m: s.position_m,
            last_error: s.last_error.clone(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pose(name: &str, z: f64) -> Pose {
        crate::scene::Scene::builtin("brewster-multi")
            .and_then(Result::ok)
            .expect("built-in scene")
            .poses()
            .iter()
            .find(|p| p.name == name)
            .cloned()
            .map(|mut p| {
                p.camera.z += z;
                p
            })
            .expect("the pose")
    }

    #[test]
    fn a_stage_reaches_each_pose_and_one_that_slips_names_the_miss() {
        let none = StageService::start(&StageConfig::default());
        assert!(!none.present());
        assert!(none.move_to(&pose("B", 0.0)).is_err());
        let s = StageService::start(&StageConfig {
            kind: StageKind::Simulated,
            simulated_slip_mm: 0.0,
        });
        let b = pose("B", 0.0);
        let read = s.move_to(&b).expect("reached");
        assert_eq!(read, [b.camera.x, b.camera.y, b.camera.z]);
        assert_eq!(s.view().pose.as_deref(), Some("B"));
        let slips = StageService::start(&StageConfig {
            kind: StageKind::Simulated,
            simulated_slip_mm: 2.0,
        });
        let e = slips.move_to(&pose("C", 0.0)).unwrap_err().to_string();
        assert!(
            e.contains("did not reach pose C") && e.contains("2.00 mm off"),
            "{e}"
        );
        let v = slips.view();
        assert_eq!(v.pose, None);
        assert!(v.last_error.is_some_and(|m| m.contains("pose C")));
        assert!(StageConfig {
            kind: StageKind::Simulated,
            simulated_slip_mm: -1.0
        }
        .check()
        .unwrap_err()
        .to_string()
        .contains("simulated_slip_mm"));
    }
}
