//! Where a reconstruction's gain and background come from: a calibration
//! (the bench's radiometric gain, dark frames for the offset; MODEL.md Eq. 12
//! in units of `T l`) or a fit to the data itself (the photo model of
//! docs/realphoto.md: `i_c = g_c T l_c + b_{p,c}`).
//!
//! Why: the bench, an imported photo and an uncalibrated camera go through
//! one reconstruction, and its report must say which radiometry made its
//! numbers and why, so that the same inputs give the same numbers through
//! every door (CLI, HTTP, plans, Python).

use serde::{Deserialize, Serialize};

/// How a measurement is put into the model's units.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, utoipa::ToSchema, clap::ValueEnum,
)]
#[serde(rename_all = "lowercase")]
pub enum Radiometry {
    /// Divided by a calibrated gain into units of `T l`, dark frames
    /// subtracted; solved with the box `0 <= l <= 1` (MODEL.md Eq. 12).
    Calibrated,
    /// Gain and background per channel fitted with the scene, on the first
    /// differences of each block (docs/realphoto.md): for a photo, an
    /// imported measurement or an uncalibrated camera.
    Fitted,
}

impl Radiometry {
    /// The name in requests and reports.
    pub fn name(self) -> &'static str {
        match self {
            Radiometry::Calibrated => "calibrated",
            Radiometry::Fitted => "fitted",
        }
    }
}

/// What is known of a reconstruction's data when its radiometry is chosen.
#[derive(Debug, Clone, Copy, Default)]
pub struct Known<'a> {
    /// A capture that was imported (its label, e.g. `capture 4`): its gain
    /// and ambient light are unknown.
    pub imported: Option<&'a str>,
    /// The calibrated gain of the scene, if one exists.
    pub gain: Option<f64>,
    /// The scene's name, for the reason.
    pub scene: &'a str,
    /// Colours in the measurement (0 or 1: grey).
    pub colours: usize,
    /// Where each colour's gain comes from when there are several (e.g.
    /// `the colour calibration of capture 3`); `None`: no colour calibration.
    pub colour_calibration: Option<&'a str>,
}

/// How to calibrate a colour camera, said wherever one is missing.
const COLOUR_FIX: &str =
    "POST /calibrations/colour with a capture of a white or grey field calibrates each colour";

/// The radiometry a reconstruction used, whether the request named it, and why.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct RadiometryChoice {
    /// `calibrated` or `fitted`.
    pub mode: Radiometry,
    /// Whether the request named it (else the daemon chose it).
    pub given: bool,
    /// Why, in words.
    pub reason: String,
}

impl RadiometryChoice {
    /// `given` when the request names one; else fitted for an imported
    /// capture, a scene with no calibrated gain, or colours with no colour
    /// calibration; calibrated otherwise.
    pub fn choose(given: Option<Radiometry>, known: Known<'_>) -> Self {
        let calibrated = known.gain.filter(|g| g.is_finite() && *g > 0.0);
        let uncalibrated_colours = known.colours > 1 && known.colour_calibration.is_none();
        if let Some(mode) = given {
            let reason = match (mode, known.imported, calibrated) {
                (Radiometry::Calibrated, Some(c), _) => format!(
                    "asked for: {c} was imported, so its values are taken as already in units of T l"
                ),
                (Radiometry::Calibrated, None, None) => format!(
                    "asked for: scene {:?} has no calibrated gain, so the measurement is scaled so that its brightest element is about 1",
                    known.scene
                ),
                (Radiometry::Calibrated, None, Some(_)) if uncalibrated_colours => format!(
                    "asked for: scene {:?} has no colour calibration, so every colour is divided by its one gain and keeps the camera's own colour response ({COLOUR_FIX})",
                    known.scene
                ),
                (Radiometry::Calibrated, None, Some(_)) => match known.colour_calibration {
                    Some(from) if known.colours > 1 => format!("asked for: each colour divided by its gain from {from}"),
                    _ => "asked for".to_string(),
                },
                _ => "asked for".to_string(),
            };
            return Self {
                mode,
                given: true,
                reason,
            };
        }
        let (mode, reason) = match (known.imported, calibrated) {
            (Some(c), _) => (
                Radiometry::Fitted,
                format!("{c} was imported: its gain and ambient light are unknown, so they are fitted with the scene"),
            ),
            (None, Some(_)) if uncalibrated_colours => (
                Radiometry::Fitted,
                format!(
                    "the measurement has {} colours and scene {:?} has one calibrated gain but no colour calibration, so the colours are fitted with one rule ({COLOUR_FIX})",
                    known.colours, known.scene
                ),
            ),
            (None, Some(g)) => (
                Radiometry::Calibrated,
                match (known.colours > 1, known.colour_calibration) {
                    (true, Some(from)) => format!(
                        "scene {:?} has a calibrated gain ({g:.6e}) and each colour its own from {from}",
                        known.scene
                    ),
                    _ => format!("scene {:?} has a calibrated gain ({g:.6e})", known.scene),
                },
            ),
            (None, None) => (
                Radiometry::Fitted,
                format!(
                    "scene {:?} has no calibrated gain: gain and background are fitted with the scene (calibrate the wall, or set [calibration] in the daemon's configuration, for calibrated units)",
                    known.scene
                ),
            ),
        };
        Self {
            mode,
            given: false,
            reason,
        }
    }

    /// The choice `polnlos reconstruct --photo` makes.
    pub fn photo_flag() -> Self {
        Self {
            mode: Radiometry::Fitted,
            given: true,
            reason: "asked for (--photo)".into(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_import_is_fitted_a_calibrated_scene_calibrated_and_a_request_wins() {
        let import = Known {
            imported: Some("capture 3"),
            gain: Some(0.5),
            scene: "s",
            ..Known::default()
        };
        let c = RadiometryChoice::choose(None, import);
        assert_eq!((c.mode, c.given), (Radiometry::Fitted, false));
        assert!(c.reason.contains("capture 3 was imported"), "{}", c.reason);
        let bench = Known {
            gain: Some(0.5),
            ..import
        };
        let bench = Known {
            imported: None,
            ..bench
        };
        assert_eq!(
            RadiometryChoice::choose(None, bench).mode,
            Radiometry::Calibrated
        );
        let uncalibrated = Known {
            gain: Some(f64::NAN),
            ..bench
        };
        let c = RadiometryChoice::choose(None, uncalibrated);
        assert_eq!(c.mode, Radiometry::Fitted);
        assert!(c.reason.contains("no calibrated gain"), "{}", c.reason);
        // Colours with one gain and no colour calibration are fitted; with
        // one, calibrated, and the reason names it.
        let colour = Known {
            colours: 3,
            ..bench
        };
        let c = RadiometryChoice::choose(None, colour);
        assert_eq!(c.mode, Radiometry::Fitted);
        assert!(c.reason.contains("no colour calibration"), "{}", c.reason);
        assert!(
            c.reason.contains("POST /calibrations/colour"),
            "{}",
            c.reason
        );
        let c = RadiometryChoice::choose(Some(Radiometry::Calibrated), colour);
        assert_eq!(c.mode, Radiometry::Calibrated);
        assert!(
            c.reason.contains("keeps the camera's own colour response"),
            "{}",
            c.reason
        );
        let balanced = Known {
            colour_calibration: Some("the colour calibration of capture 2"),
            ..colour
        };
        let c = RadiometryChoice::choose(None, balanced);
        assert_eq!(c.mode, Radiometry::Calibrated);
        assert!(c.reason.contains("capture 2"), "{}", c.reason);
        let asked = RadiometryChoice::choose(Some(Radiometry::Calibrated), import);
        assert_eq!((asked.mode, asked.given), (Radiometry::Calibrated, true));
        assert!(asked.reason.contains("units of T l"), "{}", asked.reason);
    }
}
