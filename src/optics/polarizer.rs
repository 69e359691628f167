//! The camera polarizer seen by one reflected ray: the effective axis of a
//! tilted sheet (MODEL.md "One entry of T", revision 2) and the facet s/p basis.
//!
//! MODEL.md: with transmission axis `q` in a sheet of normal `n_p`,
//! `absorbing` (default) `t = normalize(w_o x (n_p x q))`, `transmitting`
//! `t = normalize(q - (q.w_o) w_o)`; `e_s = normalize(w_i x w_o)`,
//! `e_p = e_s x w_o`. `e_s` is undefined when `|w_i x w_o| < 1e-12`.

use super::Vec3;

/// Below this `|w_i x w_o|` the plane of incidence, and so `e_s`, is undefined (MODEL.md).
pub(crate) const DEGENERATE_CROSS: f64 = 1e-12;

/// How a tilted polarizer sheet acts on an oblique ray (MODEL.md `[polarizer] model`).
///
/// Both readings agree for rays in the plane of `q` and `n_p`; across the
/// reference wall they differ by up to about 4 degrees, which under crossed
/// extinction is a 6 % structured error, so the choice is part of the model.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum PolarizerModel {
    /// The sheet absorbs the field along its absorbing axis `a = n_p x q`
    /// projected on the wave plane and passes the field normal to it: a
    /// dichroic or wire-grid sheet as measured (Korger et al. 2013; Mitsuba 3).
    #[default]
    Absorbing,
    /// The transmission axis `q` projected on the wave plane (revision 1).
    Transmitting,
}

impl PolarizerModel {
    /// Every model, default first.
    pub const ALL: [PolarizerModel; 2] = [PolarizerModel::Absorbing, PolarizerModel::Transmitting];

    /// The model's name as a scene file writes it.
    pub fn name(self) -> &'static str {
        match self {
            PolarizerModel::Absorbing => "absorbing",
            PolarizerModel::Transmitting => "transmitting",
        }
    }

    /// The model a scene file names, or `None` for an unknown name.
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|m| m.name() == name)
    }

    /// Effective axis `t` (unit, normal to `w_o`) of a sheet with transmission
    /// axis `q` and normal `n_p` for the ray that reaches the camera along `w_o`.
    ///
    /// Returns `None` when the ray runs along the axis that defines `t` (the
    /// sheet seen edge-on), which cannot happen for a sheet facing the wall
    /// but is not assumed.
    #[inline]
    pub fn effective_axis(self, q: &Vec3, n_p: &Vec3, w_o: &Vec3) -> Option<Vec3> {
        let t = match self {
            PolarizerModel::Absorbing => w_o.cross(&n_p.cross(q)),
            PolarizerModel::Transmitting => q - q.dot(w_o) * w_o,
        };
        let n = t.norm();
        (n > 1e-300).then(|| t / n)
    }
}

/// The s direction of the facet, `normalize(w_i x w_o)`, or `None` when degenerate.
#[inline]
pub(crate) fn s_direction(w_i: &Vec3, w_o: &Vec3) -> Option<Vec3> {
    let x = w_i.cross(w_o);
    let n = x.norm();
    (n >= DEGENERATE_CROSS).then(|| x / n)
}

/// `P_spec` for unpolarized light through an analyzer, without normalizing `e_s`.
///
/// With `x = w_i x w_o`, `e_s = x/|x|` and `e_p = e_s x w_o`, the projections
/// of the effective axis `t` are `t.e_s = w_i.(w_o x t)/|x|` and
/// `t.e_p = -w_i.t/|x|` (because `w_o x (w_o x t) = -t` for `t` normal to
/// `w_o`). So MODEL.md's `(Rs (t.e_s)^2 + Rp (t.e_p)^2)/2` is
/// `(Rs (w_i.b)^2 + Rp (w_i.t)^2) / (2 |x|^2)` with `b = w_o x t`, which
/// needs no square root. Below `|x| = 1e-12` it returns `Rs/2` (MODEL.md).
#[inline(always)]
pub(crate) fn analyzer_factor(rs: f64, rp: f64, wi_dot_b: f64, wi_dot_t: f64, cross2: f64) -> f64 {
    if cross2 < DEGENERATE_CROSS * DEGENERATE_CROSS {
        0.5 * rs
    } else {
        (rs * wi_dot_b * wi_dot_b + rp * wi_dot_t * wi_dot_t) / (2.0 * cross2)
    }
}

/// [`analyzer_factor`] of a partial polarizer, `P(t) + leak P(t_perp)` with
/// `leak = 1/E` (MODEL.md "On-chip polarizer mosaic"): along `t_perp = b`
/// (unit, as `t` is) `w_o x t_perp = -t`, so the second factor swaps `w_i.b`
/// and `w_i.t`, and both fold into one expression.
#[inline(always)]
pub(crate) fn partial_analyzer_factor(
    rs: f64,
    rp: f64,
    wi_dot_b: f64,
    wi_dot_t: f64,
    cross2: f64,
    leak: f64,
) -> f64 {
    if cross2 < DEGENERATE_CROSS * DEGENERATE_CROSS {
        0.5 * rs * (1.0 + leak)
    } else {
        let (b2, t2) = (wi_dot_b * wi_dot_b, wi_dot_t * wi_dot_t);
        (rs * (b2 + leak * t2) + rp * (t2 + leak * b2)) / (2.0 * cross2)
    }
}

/// Projects a polarized source's field direction onto the plane normal to `w_i`
/// and normalizes it; zero when it is parallel to `w_i` (MODEL.md edge cases).
#[inline]
pub(crate) fn source_field(e_src: &Vec3, w_i: &Vec3) -> Vec3 {
    let e = e_src - e_src.dot(w_i) * w_i;
    let n = e.norm();
    if n > 1e-12 {
        e / n
    } else {
        Vec3::zeros()
    }
}

/// Rodrigues rotation of `v` by `angle` (right hand) about the unit `axis`.
pub(crate) fn rotate(v: &Vec3, axis: &Vec3, angle: f64) -> Vec3 {
    let (s, c) = angle.sin_cos();
    v * c + axis.cross(v) * s + axis * (axis.dot(v) * (1.0 - c))
}

/// The intensity through a linear polarizer turned by θ, `a + b cos 2θ +
/// c sin 2θ` (the Stokes parameters of the light reaching it), fitted by
/// least squares over the angles it was measured at.
///
/// Why here: the fake bench draws between its rendered angles with it and a
/// mount's zero is found at its minimum; both fit the same law.
#[derive(Debug, Clone)]
pub struct IntensityLaw {
    rows: Vec<nalgebra::Vector3<f64>>,
    inverse: nalgebra::Matrix3<f64>,
}

impl IntensityLaw {
    /// The fit over `angles_deg`; `None` with fewer than three distinct
    /// angles (mod 180 degrees), which leave the law undetermined.
    pub fn over(angles_deg: impl IntoIterator<Item = f64>) -> Option<Self> {
        let rows: Vec<_> = angles_deg.into_iter().map(Self::basis).collect();
        let normal = rows
            .iter()
            .fold(nalgebra::Matrix3::zeros(), |m, v| m + v * v.transpose());
        let inverse = normal
            .try_inverse()
            .filter(|_| normal.determinant().abs() > 1e-12)?;
        Some(Self { rows, inverse })
    }

    /// `[1, cos 2θ, sin 2θ]`.
    fn basis(deg: f64) -> nalgebra::Vector3<f64> {
        let t = 2.0 * deg.to_radians();
        nalgebra::Vector3::new(1.0, t.cos(), t.sin())
    }

    /// The weights `w_k` with `I(deg) = sum_k w_k I_k` for intensities
    /// `I_k` measured at the fit's angles.
    pub fn weights(&self, deg: f64) -> Vec<f64> {
        let q = self.inverse * Self::basis(deg);
        self.rows.iter().map(|r| r.dot(&q)).collect()
    }

    /// `[a, b, c]` of `values` measured at the fit's angles (in their order).
    pub fn coefficients(&self, values: &[f64]) -> [f64; 3] {
        let rhs = self
            .rows
            .iter()
            .zip(values)
            .fold(nalgebra::Vector3::zeros(), |acc, (r, &v)| acc + r * v);
        (self.inverse * rhs).into()
    }

    /// The law with `coefficients` at `deg`.
    pub fn value(coefficients: [f64; 3], deg: f64) -> f64 {
        Self::basis(deg).dot(&nalgebra::Vector3::from(coefficients))
    }

    /// Standard error, degrees, of the law's extremum angle `atan2(c, b) / 2`
    /// when each value carries noise of `variance`: the coefficients'
    /// covariance `variance (A^T A)^-1` through the angle's gradient.
    ///
    /// Why: a sweep's minimum is only as good as its noise lets it be; the
    /// mount's zero is reported with it.
    pub fn extremum_sigma_deg(&self, coefficients: [f64; 3], variance: f64) -> f64 {
        let [_, b, c] = coefficients;
        let r2 = b * b + c * c;
        if r2 <= 0.0 {
            return f64::INFINITY;
        }
        let g = nalgebra::Vector3::new(0.0, -c, b) / (2.0 * r2);
        (variance * (g.transpose() * self.inverse * g)[(0, 0)])
            .max(0.0)
            .sqrt()
            .to_degrees()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn unit(x: f64, y: f64, z: f64) -> Vec3 {
        Vec3::new(x, y, z).normalize()
    }

    #[test]
    fn rotation_by_quarter_turn() {
        let r = rotate(&Vec3::x(), &Vec3::z(), std::f64::consts::FRAC_PI_2);
        assert!((r - Vec3::y()).norm() < 1e-15);
    }

    #[test]
    fn degenerate_plane_of_incidence() {
        let w = unit(0.2, 0.1, 1.0);
        assert!(s_direction(&w, &w).is_none());
        assert!(s_direction(&w, &unit(0.2, 0.1 + 1e-9, 1.0)).is_some());
    }

    #[test]
    fn source_field_parallel_to_ray_is_zero() {
        let w = unit(0.0, 0.0, 1.0);
        assert_eq!(source_field(&Vec3::z(), &w), Vec3::zeros());
        let e = source_field(&unit(1.0, 0.0, 1.0), &w);
        assert!((e - Vec3::x()).norm() < 1e-15);
    }

    #[test]
    fn the_two_models_agree_in_the_plane_of_q_and_the_sheet_normal_only() {
        let n_p = unit(0.0, 0.0, -1.0);
        let q = Vec3::x();
        let abs = PolarizerModel::Absorbing;
        let tra = PolarizerModel::Transmitting;
        // Along the sheet normal and tilted within the (q, n_p) plane: the same axis.
        for w in [
            unit(0.0, 0.0, 1.0),
            unit(0.4, 0.0, 1.0),
            unit(-0.7, 0.0, 1.0),
        ] {
            let (a, t) = (
                abs.effective_axis(&q, &n_p, &w).unwrap(),
                tra.effective_axis(&q, &n_p, &w).unwrap(),
            );
            assert!((a - t).norm() < 1e-15, "{w:?}");
        }
        // A ray tilted 20 deg towards x and 20 deg towards y: the absorbing
        // reading passes the field normal to the projected absorbing axis
        // a = n_p x q = -y, so t.a = 0; the transmitting one does not.
        let w = unit(20f64.to_radians().tan(), 20f64.to_radians().tan(), 1.0);
        let a_axis = n_p.cross(&q);
        let t_abs = abs.effective_axis(&q, &n_p, &w).unwrap();
        let t_tra = tra.effective_axis(&q, &n_p, &w).unwrap();
        assert!(t_abs.dot(&a_axis).abs() < 1e-15);
        assert!(t_tra.dot(&a_axis).abs() > 0.05);
        // Both stay on q's side; they differ by a few degrees, as MODEL.md says.
        let deg = t_abs.dot(&t_tra).clamp(-1.0, 1.0).acos().to_degrees();
        assert!(t_abs.dot(&q) > 0.0 && (3.0..10.0).contains(&deg), "{deg}");
    }

    #[test]
    fn model_names_round_trip() {
        for m in PolarizerModel::ALL {
            assert_eq!(PolarizerModel::from_name(m.name()), Some(m));
        }
        assert_eq!(PolarizerModel::from_name("absorbant"), None);
        assert_eq!(PolarizerModel::default(), PolarizerModel::Absorbing);
    }

    proptest! {
        #[test]
        fn absorbing_axis_is_unit_transverse_and_normal_to_the_absorbing_axis(
            psi in -3.2f64..3.2, wx in -0.8f64..0.8, wy in -0.8f64..0.8,
        ) {
            // A sheet facing -z, its transmission axis in the sheet at angle psi.
            let n_p = -Vec3::z();
            let q = Vec3::new(psi.cos(), psi.sin(), 0.0);
            let w = Vec3::new(wx, wy, 1.0).normalize();
            let t = PolarizerModel::Absorbing.effective_axis(&q, &n_p, &w).unwrap();
            prop_assert!((t.norm() - 1.0).abs() < 1e-12);
            prop_assert!(t.dot(&w).abs() < 1e-12);
            prop_assert!(t.dot(&n_p.cross(&q)).abs() < 1e-12);
            prop_assert!(t.dot(&q) > 0.0);
        }

        #[test]
        fn effective_axis_is_unit_and_transverse(
            qx in -1.0f64..1.0, qy in -1.0f64..1.0, qz in -1.0f64..1.0,
            wx in -1.0f64..1.0, wy in -1.0f64..1.0, wz in 0.05f64..1.0,
        ) {
            let q = Vec3::new(qx, qy, qz);
            prop_assume!(q.norm() > 1e-3);
            let q = q.normalize();
            let w = Vec3::new(wx, wy, wz).normalize();
            prop_assume!(q.cross(&w).norm() > 1e-6);
            let t = PolarizerModel::Transmitting.effective_axis(&q, &Vec3::z(), &w).unwrap();
            prop_assert!((t.norm() - 1.0).abs() < 1e-12);
            prop_assert!(t.dot(&w).abs() < 1e-12);
            // t stays on q's side: projection never flips the axis.
            prop_assert!(t.dot(&q) >= 0.0);
        }
    }
}
