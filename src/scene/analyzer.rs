//! What a pose's light passes through before the sensor: a polarizer sheet
//! at some angles, an on-chip micro-polarizer mosaic, or nothing (MODEL.md
//! "The crossed polarizer of a pose", "On-chip polarizer mosaic").
//!
//! Each [`Analyzer`] is one row block of `T`; a [`Channel`] names that block
//! in the terms a capture records, so the measurement can match the two.

use crate::optics::{PolarizerModel, Vec3};

/// The four micro-polarizer angles of a mosaic, degrees from the sensor's
/// 0-degree micro-polarizer, in block order (MODEL.md "On-chip polarizer mosaic").
pub const MOSAIC_DEGREES: [f64; 4] = [0.0, 45.0, 90.0, 135.0];

/// Which analyzer one row block of a pose saw: how a capture's blocks are
/// matched to a scene's (a sheet capture yields one, a mosaic capture four).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(tag = "analyzer", rename_all = "lowercase", deny_unknown_fields)]
pub enum Channel {
    /// No polarizer: the pose's one block.
    None,
    /// A polarizer sheet `deg` from crossed.
    Sheet {
        /// Degrees from crossed, as the scene file lists it.
        deg: f64,
    },
    /// The pixels of a mosaic behind its `deg` micro-polarizers (0, 45, 90 or 135).
    Mosaic {
        /// Degrees from the sensor's 0-degree micro-polarizer.
        deg: f64,
    },
}

/// An analyzer name that is no angle, `none` or `mosaic` (the name as given).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{0:?} is not an angle in degrees (-360..360), `none` or `mosaic`")]
pub struct UnknownAnalyzer(pub String);

impl Channel {
    /// The channel a capture through a sheet at `polarizer_deg` (or none) yields.
    pub fn sheet(polarizer_deg: Option<f64>) -> Self {
        polarizer_deg.map_or(Channel::None, |deg| Channel::Sheet { deg })
    }

    /// The four channels of one mosaic exposure, in block order.
    pub fn mosaic() -> [Self; 4] {
        MOSAIC_DEGREES.map(|deg| Channel::Mosaic { deg })
    }

    /// The channels a capture yields, from how its analyzer is named:
    /// degrees from crossed (-360..360) for a sheet, `none`, or `mosaic`
    /// for a polarizer-mosaic sensor's four; the error says what is accepted.
    pub fn of_capture(angle: &str) -> Result<Vec<Self>, UnknownAnalyzer> {
        match angle {
            "none" => Ok(vec![Channel::None]),
            "mosaic" => Ok(Self::mosaic().to_vec()),
            _ => match angle.trim().parse::<f64>() {
                Ok(deg) if deg.is_finite() && deg.abs() <= 360.0 => {
                    Ok(vec![Channel::Sheet { deg }])
                }
                _ => Err(UnknownAnalyzer(angle.to_string())),
            },
        }
    }

    /// The sheet's angle from crossed, for a sheet channel.
    pub fn sheet_deg(self) -> Option<f64> {
        match self {
            Channel::Sheet { deg } => Some(deg),
            _ => None,
        }
    }

    /// Whether two channels are the same setting (angles 1e-6 degrees apart at most).
    pub fn same(self, other: Channel) -> bool {
        match (self, other) {
            (Channel::None, Channel::None) => true,
            (Channel::Sheet { deg: a }, Channel::Sheet { deg: b })
            | (Channel::Mosaic { deg: a }, Channel::Mosaic { deg: b }) => (a - b).abs() < 1e-6,
            _ => false,
        }
    }

    /// A file-name-safe suffix: `pol0`, `pol22.5`, `nopol`, `mosaic45`.
    pub fn label(self) -> String {
        match self {
            Channel::None => "nopol".to_string(),
            Channel::Sheet { deg } => format!("pol{deg}"),
            Channel::Mosaic { deg } => format!("mosaic{deg}"),
        }
    }
}

/// The 2x2 pattern of a mosaic sensor's micro-polarizers (MODEL.md `layout`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum MosaicLayout {
    /// Sony Polarsens (IMX250MZR and kin): pixel (row, col) mod 2 is
    /// (0,0) = 90, (0,1) = 45, (1,0) = 135, (1,1) = 0 degrees.
    #[default]
    Polarsens,
}

impl MosaicLayout {
    /// Every layout, default first.
    pub const ALL: [MosaicLayout; 1] = [MosaicLayout::Polarsens];

    /// The value as a scene file writes it.
    pub fn name(self) -> &'static str {
        match self {
            MosaicLayout::Polarsens => "polarsens",
        }
    }

    /// The layout a scene file names, or `None` for an unknown name.
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|l| l.name() == name)
    }

    /// The micro-polarizer angle (degrees, one of [`MOSAIC_DEGREES`]) over
    /// the sensor pixel at column `x`, row `y` (counted from the sensor's
    /// first pixel).
    pub fn degrees_at(self, x: i64, y: i64) -> f64 {
        match self {
            MosaicLayout::Polarsens => match (y.rem_euclid(2), x.rem_euclid(2)) {
                (0, 0) => 90.0,
                (0, _) => 45.0,
                (_, 0) => 135.0,
                _ => 0.0,
            },
        }
    }

    /// The index in [`MOSAIC_DEGREES`] (the pose's block) of the
    /// micro-polarizer over sensor pixel `(x, y)`.
    pub fn block_at(self, x: i64, y: i64) -> usize {
        (self.degrees_at(x, y) / 45.0).round() as usize % 4
    }

    /// The pixel `[col, row]` mod 2 of the micro-polarizer at `deg`, or
    /// `None` when `deg` is not one of [`MOSAIC_DEGREES`].
    pub fn cell_of(self, deg: f64) -> Option<[u32; 2]> {
        (0..4u32)
            .map(|k| [k % 2, k / 2])
            .find(|&[x, y]| (self.degrees_at(i64::from(x), i64::from(y)) - deg).abs() < 1e-6)
    }
}

/// A pose's on-chip polarizer mosaic (MODEL.md "On-chip polarizer mosaic").
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Mosaic {
    /// Angle of the sensor's 0-degree micro-polarizer from crossed, degrees.
    pub sensor_deg: f64,
    /// Extinction ratio `E` of each micro-polarizer; `None`: ideal.
    pub extinction: Option<f64>,
    /// Which pixel sits behind which angle.
    pub layout: MosaicLayout,
}

/// One analyzer of a pose (one row block of `T`): the setting a capture
/// records and the polarizer it means.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Analyzer {
    /// Rotation of the transmission axis from the crossed setting, degrees
    /// (`psi`: a sheet's angle as in the file; a mosaic's `sensor_deg + theta_k`).
    pub angle_deg: f64,
    /// Transmission axis `q(psi)` in world coordinates (unit, in the polarizer plane).
    pub axis: Vec3,
    /// The polarizer plane's normal `n_p = normalize(c0 - o)` (MODEL.md "The crossed polarizer of a pose").
    pub normal: Vec3,
    /// The block's name in captures.
    pub channel: Channel,
    /// Extinction ratio `E` of a partial polarizer; `None`: ideal.
    pub extinction: Option<f64>,
    /// The sensor pixels `[x, y]` mod 2 behind it, for a mosaic's micro-polarizer.
    pub cell: Option<[u32; 2]>,
}

impl Analyzer {
    /// The sheet of a pose with its camera at `camera`, set `angle_deg` from
    /// crossed (MODEL.md "The crossed polarizer of a pose"); `None` when the
    /// crossed axis is undefined (`w_i0` parallel to `w_o0`).
    pub fn at(
        wall_center: &Vec3,
        scene_center: &Vec3,
        camera: &Vec3,
        angle_deg: f64,
    ) -> Option<Self> {
        let q0 = crossed_axis(wall_center, scene_center, camera)?;
        Some(Self {
            angle_deg,
            axis: analyzer_axis(&q0, wall_center, camera, angle_deg.to_radians()),
            normal: (wall_center - camera).normalize(),
            channel: Channel::Sheet { deg: angle_deg },
            extinction: None,
            cell: None,
        })
    }

    /// The four micro-polarizers of `mosaic` on a pose with its camera at
    /// `camera`, in block order 0, 45, 90, 135: each the sheet's axis at
    /// `psi = sensor_deg + theta_k` (MODEL.md "On-chip polarizer mosaic");
    /// `None` when the crossed axis is undefined.
    pub fn mosaic(
        wall_center: &Vec3,
        scene_center: &Vec3,
        camera: &Vec3,
        mosaic: &Mosaic,
    ) -> Option<[Self; 4]> {
        let sheet = Self::at(wall_center, scene_center, camera, mosaic.sensor_deg)?;
        Some(MOSAIC_DEGREES.map(|theta| {
            let psi = mosaic.sensor_deg + theta;
            Self {
                angle_deg: psi,
                axis: crate::optics::polarizer::rotate(
                    &sheet.axis,
                    &sheet.normal,
                    theta.to_radians(),
                ),
                channel: Channel::Mosaic { deg: theta },
                extinction: mosaic.extinction,
                cell: mosaic.layout.cell_of(theta),
                ..sheet
            }
        }))
    }

    /// Effective axis `t` for the ray that reaches the camera along `w_o`
    /// under `model` (MODEL.md "One entry of T"); zero when the polarizer is
    /// seen edge-on, so that such a ray passes no light.
    #[inline]
    pub fn effective_axis(&self, model: PolarizerModel, w_o: &Vec3) -> Vec3 {
        model
            .effective_axis(&self.axis, &self.normal, w_o)
            .unwrap_or_else(Vec3::zeros)
    }

    /// `P(t) + P(t_perp) / E` for a polarization factor `p` of the analyzer
    /// axis (MODEL.md "On-chip polarizer mosaic", `t_perp = normalize(w_o x
    /// t)`): a partial polarizer also passes `1/E` of the crossed light. Only
    /// `P(t)` for an ideal one.
    pub fn weigh(&self, t: &Vec3, w_o: &Vec3, p: impl Fn(&Vec3) -> f64) -> f64 {
        match self.extinction {
            None => p(t),
            Some(e) => p(t) + p(&perpendicular(t, w_o)) / e,
        }
    }
}

/// `t_perp = normalize(w_o x t)`, zero when `t` is (the ray passes no light).
pub(crate) fn perpendicular(t: &Vec3, w_o: &Vec3) -> Vec3 {
    let b = w_o.cross(t);
    let n = b.norm();
    if n > 0.0 {
        b / n
    } else {
        Vec3::zeros()
    }
}

/// Crossed polarizer axis of a pose, `q(0) = normalize(e_s0 x n_p)` (MODEL.md
/// "The crossed polarizer of a pose"); `None` when `w_i0` is parallel to `w_o0`.
pub(crate) fn crossed_axis(wall_center: &Vec3, scene_center: &Vec3, camera: &Vec3) -> Option<Vec3> {
    let n_p = (wall_center - camera).normalize();
    let w_i0 = (scene_center - wall_center).normalize();
    let w_o0 = (camera - wall_center).normalize();
    let e_s0 = crate::optics::polarizer::s_direction(&w_i0, &w_o0)?;
    Some(e_s0.cross(&n_p).normalize())
}

/// `q(psi)`: the crossed axis rotated by `+psi` about `n_p = normalize(c0 - o)` (Rodrigues).
pub(crate) fn analyzer_axis(q0: &Vec3, wall_center: &Vec3, camera: &Vec3, psi: f64) -> Vec3 {
    let n_p = (wall_center - camera).normalize();
    crate::optics::polarizer::rotate(q0, &n_p, psi)
}

#[cfg(test)]
mod tests {
    use super::*;

    proptest::proptest! {
        /// Whatever a user types for a capture's analyzer, it is a sheet at
        /// exactly that angle (within -360..360), `none`, `mosaic`'s four,
        /// or an error that says what is accepted.
        #[test]
        fn a_capture_s_analyzer_parses_or_says_what_is_accepted(text in "\\PC{0,12}", deg in -400.0f64..400.0) {
            match Channel::of_capture(&text) {
                Ok(c) => {
                    let sheet = matches!(c[..], [Channel::Sheet { deg }] if deg.abs() <= 360.0);
                    let named = c == vec![Channel::None] || c == Channel::mosaic().to_vec();
                    proptest::prop_assert!(sheet || named, "{:?}", c);
                }
                Err(e) => proptest::prop_assert!(e.to_string().contains("`none` or `mosaic`"), "{}", e),
            }
            let parsed = Channel::of_capture(&deg.to_string());
            if deg.abs() <= 360.0 {
                proptest::prop_assert_eq!(parsed, Ok(vec![Channel::Sheet { deg }]));
            } else {
                proptest::prop_assert!(parsed.is_err());
            }
        }
    }

    #[test]
    fn a_capture_s_analyzer_by_name() {
        assert_eq!(Channel::of_capture("none"), Ok(vec![Channel::None]));
        assert_eq!(
            Channel::of_capture("mosaic"),
            Ok(Channel::mosaic().to_vec())
        );
        assert_eq!(
            Channel::of_capture("22.5"),
            Ok(vec![Channel::Sheet { deg: 22.5 }])
        );
        assert!(Channel::of_capture("NaN").is_err());
        assert!(Channel::of_capture("crossed")
            .unwrap_err()
            .to_string()
            .contains("\"crossed\""));
    }

    #[test]
    fn the_polarsens_layout_is_the_documented_pattern() {
        let l = MosaicLayout::Polarsens;
        // (row, col): (0,0) = 90, (0,1) = 45, (1,0) = 135, (1,1) = 0.
        assert_eq!(l.degrees_at(0, 0), 90.0);
        assert_eq!(l.degrees_at(1, 0), 45.0);
        assert_eq!(l.degrees_at(0, 1), 135.0);
        assert_eq!(l.degrees_at(1, 1), 0.0);
        assert_eq!(l.degrees_at(-1, 3), 0.0);
        assert_eq!(l.cell_of(0.0), Some([1, 1]));
        assert_eq!(l.cell_of(45.0), Some([1, 0]));
        assert_eq!(l.cell_of(90.0), Some([0, 0]));
        assert_eq!(l.cell_of(135.0), Some([0, 1]));
        assert_eq!(l.cell_of(30.0), None);
        assert_eq!(MosaicLayout::from_name("polarsens"), Some(l));
        assert_eq!(MosaicLayout::from_name("bayer"), None);
    }

    #[test]
    fn a_mosaic_is_the_sheet_turned_by_each_micro_polarizer() {
        let (c0, s0, o) = (
            Vec3::zeros(),
            Vec3::new(-0.374, 0.0, 0.25),
            Vec3::new(0.416, 0.0, 0.277),
        );
        let m = Mosaic {
            sensor_deg: 10.0,
            extinction: Some(300.0),
            layout: MosaicLayout::Polarsens,
        };
        let four = Analyzer::mosaic(&c0, &s0, &o, &m).unwrap();
        for (a, theta) in four.iter().zip(MOSAIC_DEGREES) {
            let sheet = Analyzer::at(&c0, &s0, &o, 10.0 + theta).unwrap();
            assert!((a.axis - sheet.axis).norm() < 1e-12, "{theta}");
            assert_eq!(a.channel, Channel::Mosaic { deg: theta });
            assert_eq!(a.extinction, Some(300.0));
        }
        assert_eq!(four[0].cell, Some([1, 1]));
    }

    #[test]
    fn a_partial_polarizer_adds_the_crossed_axis_over_e() {
        let w_o = Vec3::new(0.0, 0.0, 1.0);
        let t = Vec3::new(1.0, 0.0, 0.0);
        let mut a = Analyzer::at(
            &Vec3::zeros(),
            &Vec3::new(-0.374, 0.0, 0.25),
            &Vec3::new(0.416, 0.0, 0.277),
            0.0,
        )
        .unwrap();
        // p(t) = t.x^2: 1 along t, 0 along t_perp = y.
        let p = |t: &Vec3| t.x * t.x + 3.0 * t.y * t.y;
        assert_eq!(a.weigh(&t, &w_o, p), 1.0);
        a.extinction = Some(100.0);
        assert!((a.weigh(&t, &w_o, p) - 1.03).abs() < 1e-15);
        assert_eq!(perpendicular(&Vec3::zeros(), &w_o), Vec3::zeros());
    }

    #[test]
    fn channels_read_and_write_as_json_and_match_by_angle() {
        let c: Channel = serde_json::from_str(r#"{"analyzer":"mosaic","deg":45}"#).unwrap();
        assert_eq!(c, Channel::Mosaic { deg: 45.0 });
        assert_eq!(
            serde_json::to_string(&Channel::None).unwrap(),
            r#"{"analyzer":"none"}"#
        );
        assert!(Channel::sheet(Some(0.0)).same(Channel::Sheet { deg: 1e-9 }));
        assert!(!Channel::Sheet { deg: 0.0 }.same(Channel::Mosaic { deg: 0.0 }));
        assert_eq!(Channel::Mosaic { deg: 135.0 }.label(), "mosaic135");
        assert_eq!(Channel::sheet(None).label(), "nopol");
    }
}
