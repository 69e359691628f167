//! Camera stages: the `CameraStage` that carries the camera between a
//! scene's poses, and a simulated one (`SimulatedStage`) for the fake
//! bench and the tests.
//!
//! Why read back: a stage that stopped short would put the camera at
//! another pose than the capture records, and the homography of the pose
//! would no longer map its wall; every move reads the position back, and a
//! capture whose camera missed its pose by more than `TOLERANCE_M` fails.

mod service;

pub use service::StageService;
pub(crate) use service::{StageConfig, StageKind, StageView};

/// Metres a stage may miss a pose's centre of projection by.
pub(crate) const TOLERANCE_M: f64 = 1e-3;

/// A stage that moves the camera to a position and says where it is.
pub(crate) trait CameraStage: Send {
    /// Moves the camera's centre of projection to `camera` (metres, the
    /// scene's frame, MODEL.md's `o` of a pose); returns the position read back.
    fn move_to(&mut self, camera: [f64; 3]) -> Result<[f64; 3], StageError>;
}

/// What went wrong with a stage, naming the pose and the positions.
#[derive(Debug, thiserror::Error)]
pub enum StageError {
    /// The move ended farther than `TOLERANCE_M` from the pose.
    #[error("the camera stage did not reach pose {pose}: asked {asked:?} m, read back {read:?} m, {miss_mm:.2} mm off (tolerance {} mm); check for an obstruction or lost steps, then press Continue", TOLERANCE_M * 1e3)]
    Missed {
        /// The pose asked for.
        pose: String,
        /// Its centre of projection, metres.
        asked: [f64; 3],
        /// Where the stage says it is, metres.
        read: [f64; 3],
        /// The distance between them, millimetres.
        miss_mm: f64,
    },
    /// A position that is no position (a non-finite coordinate).
    #[error(
        "the camera stage cannot move to {0:?}: every coordinate must be a finite number of metres"
    )]
    Invalid([f64; 3]),
    /// The device failed.
    #[error("the camera stage failed: {0}")]
    Device(String),
}

/// Distance between two positions, metres.
pub fn distance(a: [f64; 3], b: [f64; 3]) -> f64 {
    a.iter()
        .zip(&b)
        .map(|(x, y)| (x - y) * (x - y))
        .sum::<f64>()
        .sqrt()
}

/// A stage that goes where it is sent, short by `slip_m` along the way
/// when told to (a stage that lost steps), and starts at the origin.
#[derive(Debug, Clone, Default)]
pub(crate) struct SimulatedStage {
    at: [f64; 3],
    slip_m: f64,
}

impl SimulatedStage {
    /// A stage at the origin that reaches every position.
    pub fn new() -> Self {
        Self::default()
    }

    /// From now on each move stops `slip_m` metres short of its target.
    pub fn slip(&mut self, slip_m: f64) {
        self.slip_m = slip_m.max(0.0);
    }
}

impl CameraStage for SimulatedStage {
    fn move_to(&mut self, camera: [f64; 3]) -> Result<[f64; 3], StageError> {
        if camera.iter().any(|c| !c.is_finite()) {
            return Err(StageError::Invalid(camera));
        }
        let d = distance(self.at, camera);
        let reach = if d > 0.0 {
            ((d - self.slip_m) / d).max(0.0)
        } else {
            1.0
        };
        for (a, c) in self.at.iter_mut().zip(camera) {
            *a += (c - *a) * reach;
        }
        Ok(self.at)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_simulated_stage_reaches_its_target_unless_it_slips() {
        let mut s = SimulatedStage::new();
        let target = [0.3, -1.2, 2.0];
        assert_eq!(s.move_to(target).unwrap(), target);
        assert_eq!(s.at, target);
        s.slip(0.002);
        let next = [0.3, -1.2, 3.0];
        let read = s.move_to(next).unwrap();
        assert!((distance(read, next) - 0.002).abs() < 1e-12, "{read:?}");
        assert!(matches!(
            s.move_to([f64::NAN, 0.0, 0.0]),
            Err(StageError::Invalid(_))
        ));
    }
}
