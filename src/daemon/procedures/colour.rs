//! The colour calibration: a colour camera's balance measured from a
//! capture of a white or grey field, stored for the scene, and the gain of
//! each colour a calibrated reconstruction divides by.
//!
//! Why: one gain for every colour turns a white object the colour of the
//! camera's filter (green on the fake bench, whose filter passes 0.55, 1
//! and 0.7); a flat field measures each colour's response once per bench.

use serde::Serialize;

use crate::calibrate::colour::{balance, ColourBalance, ColourValues};
use crate::daemon::requests::validate::RequestError;
use crate::scene::Colour;
use crate::store::{CaptureKind, ColourCalibrationRow, JobState};

/// One colour of a colour calibration.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct ColourGain {
    /// The colour.
    pub colour: Colour,
    /// Its response over the strongest colour's (1 for that one).
    pub ratio: f64,
    /// Standard error of `ratio`, from the frames' noise.
    pub sigma: f64,
    /// The gain a calibrated reconstruction divides this colour by: the
    /// scene's gain times `ratio` (absent while the scene has no gain).
    pub gain: Option<f64>,
}

/// A scene's colour calibration, as `POST /calibrations/colour` measured it.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct ColourCalibration {
    /// Its id.
    pub id: i64,
    /// The scene.
    pub scene: String,
    /// The capture of the white or grey field it was measured from.
    pub capture: i64,
    /// When.
    pub created_at: String,
    /// The colour with ratio 1, whose gain the scene's one gain is.
    pub reference: Colour,
    /// Wall elements measured in every colour, over which it was summed.
    pub rows: usize,
    /// Red, green, blue.
    pub colours: Vec<ColourGain>,
    /// What loading the capture found (saturation, lost frames).
    pub warnings: Vec<String>,
}

impl ColourCalibration {
    /// The calibration `row` with the scene's gain `gain`.
    pub(crate) fn of(row: ColourCalibrationRow, gain: Option<f64>, warnings: Vec<String>) -> Self {
        let colours = row
            .balance
            .colours
            .iter()
            .map(|c| ColourGain {
                colour: c.colour,
                ratio: c.ratio,
                sigma: c.sigma,
                gain: gain.map(|g| row.balance.gain(c.colour, g)),
            })
            .collect();
        Self {
            id: row.id,
            scene: row.scene,
            capture: row.capture,
            created_at: row.created_at,
            reference: row.balance.reference,
            rows: row.balance.rows,
            colours,
            warnings,
        }
    }
}

impl super::Procedures {
    /// Measures the colour balance of capture `capture`'s scene from that
    /// capture (a done light capture of a white or grey field through a
    /// colour camera) and stores it: calibrated reconstructions of the
    /// scene then divide each colour by its own gain.
    pub fn calibrate_colour(&self, capture: i64) -> Result<ColourCalibration, RequestError> {
        let invalid = RequestError::Invalid;
        let c = self.services.require_capture(capture)?;
        if c.kind != CaptureKind::Light || c.state != JobState::Done {
            return Err(invalid(format!(
                "capture {capture} is a {} capture in state {}; a colour calibration needs a done light capture of a white or grey field (a white card, or the bench lit evenly)",
                c.kind.name(),
                c.state.name()
            )));
        }
        if c.is_imported() {
            return Err(invalid(format!(
                "capture {capture} was imported: a colour calibration is of the daemon's camera, so take a capture of a white or grey field with it"
            )));
        }
        let scene_name = c.scene.clone();
        let scene = self.services.scenes.now().scene(&scene_name)?;
        let blocks: Vec<_> = crate::transport::blocks_of(&scene)
            .into_iter()
            .filter(|b| b.taken_by(&c.pose, &c.channels))
            .collect();
        let stacked = crate::daemon::jobs::reconstruction::stack_records(
            &self.services.store,
            vec![c],
            &scene,
            &blocks,
            &self.services.scenes.now().pixel_maps(&scene_name),
            true,
            true,
        )
        .map_err(|e| invalid(e.to_string()))?;
        let colours: Vec<ColourValues> = Colour::ALL
            .iter()
            .zip(&stacked.measurements)
            .map(|(k, m)| (*k, m.i.as_slice(), m.variance.as_deref()))
            .collect();
        let measured: ColourBalance = balance(match stacked.measurements.len() {
            1 => &colours[..1],
            _ => &colours,
        })
        .map_err(|e| invalid(format!("capture {capture}: {e}")))?;
        let row = self
            .services
            .store
            .insert_colour_calibration(&scene_name, capture, &measured)
            .map_err(|e| {
                RequestError::Store(format!(
                    "the colour calibration could not be stored: {}",
                    self.services.store.describe(&e)
                ))
            })?;
        tracing::info!(
            "colour calibration {} of scene {scene_name:?} from capture {capture}: ratios {:?}",
            row.id,
            measured
                .colours
                .iter()
                .map(|c| format!("{:?} {:.4}", c.colour, c.ratio))
                .collect::<Vec<_>>()
        );
        let gain = self.services.calibration.get(&scene_name).copied();
        Ok(ColourCalibration::of(row, gain, stacked.warnings))
    }
}
