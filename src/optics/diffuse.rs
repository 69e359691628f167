//! The wall's diffuse term `P_diff` (MODEL.md "One entry of T", revision 2,
//! `[wall] diffuse`): light that enters the wall, is depolarized by
//! subsurface scattering and leaves it.
//!
//! `fresnel` (default, the pBRDF of Baek et al. 2018 and Mitsuba 3's
//! `pplastic`): the light crosses the interface twice, so it is weakened by
//! the transmittance in and out and leaves partly p-polarized:
//! `P_diff = T_in (Ts(θo)(t.e_so)² + Tp(θo)(t.e_po)²)/2` through a polarizer,
//! `T_in (1 - (Rs(θo) + Rp(θo))/2)` without, with `T_in = 1 - (Rs(θi) + Rp(θi))/2`
//! for unpolarized light and `Ts(θi)(e_src.e_si)² + Tp(θi)(e_src.e_pii)²` for a
//! linearly polarized scene. `lambert`: `P_diff = 1`, or `1/2` through a polarizer.

use super::fresnel::FresnelAmplitudes;
use super::Vec3;

/// Below this `|n x w|` the plane of exit (or entry) is undefined; there
/// `Ts = Tp`, so any basis serves (MODEL.md).
const DEGENERATE_PLANE: f64 = 1e-12;

/// How the wall's diffuse light is polarized (MODEL.md `[wall] diffuse`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum DiffuseModel {
    /// Both interfaces of the wall: Fresnel transmittance in and out.
    #[default]
    Fresnel,
    /// Ideal depolarized Lambertian: `P_diff = 1`, `1/2` through a polarizer (revision 1).
    Lambert,
}

impl DiffuseModel {
    /// Every model, default first.
    pub const ALL: [DiffuseModel; 2] = [DiffuseModel::Fresnel, DiffuseModel::Lambert];

    /// The model's name as a scene file writes it.
    pub fn name(self) -> &'static str {
        match self {
            DiffuseModel::Fresnel => "fresnel",
            DiffuseModel::Lambert => "lambert",
        }
    }

    /// The model a scene file names, or `None` for an unknown name.
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|m| m.name() == name)
    }
}

/// Power transmittances `(Ts, Tp)` of the wall interface at `cos θ` (MODEL.md
/// `Ts = 1 - Rs`, `Tp = 1 - Rp`, Fresnel at the macroscopic angle θ).
#[inline(always)]
pub(crate) fn transmittances(cos: f64, eta: f64) -> (f64, f64) {
    let r = FresnelAmplitudes::from_cos(cos, eta).reflectances();
    (1.0 - r.rs, 1.0 - r.rp)
}

/// Squared projections of `v` on `e_s = normalize(n x w)` and `e_p = e_s x w`,
/// the s and p directions of the plane (n, w); all of `v`'s part normal to
/// `w` counts as s where that plane is undefined (there `Ts = Tp`).
#[inline]
fn split(n: &Vec3, w: &Vec3, v: &Vec3) -> (f64, f64) {
    let x = n.cross(w);
    let len = x.norm();
    if len < DEGENERATE_PLANE {
        let perp = v - v.dot(w) * w;
        return (perp.norm_squared(), 0.0);
    }
    let e_s = x / len;
    let e_p = e_s.cross(w);
    (v.dot(&e_s).powi(2), v.dot(&e_p).powi(2))
}

/// `T_in` for light arriving along `w_i` (`cos_i = n.w_i`): unpolarized, or
/// with the field direction `e` (already projected normal to `w_i`, MODEL.md
/// edge cases) of a linearly polarized scene.
#[inline]
pub fn entry(n: &Vec3, w_i: &Vec3, cos_i: f64, eta: f64, e: Option<&Vec3>) -> f64 {
    let (ts, tp) = transmittances(cos_i, eta);
    match e {
        None => 0.5 * (ts + tp),
        Some(e) => {
            let (s2, p2) = split(n, w_i, e);
            ts * s2 + tp * p2
        }
    }
}

/// The exit factor for light leaving along `w_o` (`cos_o = n.w_o`) through a
/// polarizer of effective axis `t`, or without one: `(Ts (t.e_so)² + Tp
/// (t.e_po)²)/2`, or `(Ts + Tp)/2 = 1 - (Rs + Rp)/2`.
#[inline]
pub fn exit(n: &Vec3, w_o: &Vec3, cos_o: f64, eta: f64, t: Option<&Vec3>) -> f64 {
    let (ts, tp) = transmittances(cos_o, eta);
    match t {
        None => 0.5 * (ts + tp),
        Some(t) => {
            let (s2, p2) = split(n, w_o, t);
            0.5 * (ts * s2 + tp * p2)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    const N: Vec3 = Vec3::new(0.0, 0.0, 1.0);

    fn dir(theta: f64, az: f64) -> Vec3 {
        Vec3::new(theta.sin() * az.cos(), theta.sin() * az.sin(), theta.cos())
    }

    #[test]
    fn normal_incidence_passes_one_minus_r0() {
        // R0 = ((1.5 - 1)/(1.5 + 1))^2 = 0.04 both ways at normal incidence.
        let t = entry(&N, &N, 1.0, 1.5, None);
        assert!((t - 0.96).abs() < 1e-15);
        let out = exit(&N, &N, 1.0, 1.5, Some(&Vec3::x()));
        assert!((out - 0.48).abs() < 1e-15);
        assert!((exit(&N, &N, 1.0, 1.5, None) - 0.96).abs() < 1e-15);
    }

    #[test]
    fn exit_at_brewster_passes_all_p_light() {
        // At the Brewster angle Rp = 0: an analyzer along e_po passes Tp/2 = 1/2,
        // along e_so it passes Ts/2 < 1/2.
        let tb = 1.5f64.atan();
        let w = dir(tb, 0.0);
        let e_so = N.cross(&w).normalize();
        let e_po = e_so.cross(&w);
        let p = exit(&N, &w, tb.cos(), 1.5, Some(&e_po));
        let s = exit(&N, &w, tb.cos(), 1.5, Some(&e_so));
        assert!((p - 0.5).abs() < 1e-15, "{p}");
        let rs = crate::optics::fresnel::FresnelHalf::at_angle(tb, 1.5).rs;
        assert!((s - 0.5 * (1.0 - rs)).abs() < 1e-15, "{s}");
    }

    #[test]
    fn orthogonal_analyzers_sum_to_the_open_exit() {
        let w = dir(0.9, 0.7);
        let a = w.cross(&Vec3::new(0.3, -0.2, 0.9)).normalize();
        let b = w.cross(&a);
        let sum = exit(&N, &w, w.z, 1.5, Some(&a)) + exit(&N, &w, w.z, 1.5, Some(&b));
        assert!((sum - exit(&N, &w, w.z, 1.5, None)).abs() < 1e-15);
    }

    #[test]
    fn polarized_entry_averages_to_unpolarized() {
        let w = dir(1.1, -2.0);
        let a = w.cross(&Vec3::new(0.1, 0.8, 0.2)).normalize();
        let b = w.cross(&a);
        let mean = 0.5 * (entry(&N, &w, w.z, 1.5, Some(&a)) + entry(&N, &w, w.z, 1.5, Some(&b)));
        assert!((mean - entry(&N, &w, w.z, 1.5, None)).abs() < 1e-15);
    }

    #[test]
    fn model_names_round_trip() {
        for m in DiffuseModel::ALL {
            assert_eq!(DiffuseModel::from_name(m.name()), Some(m));
        }
        assert_eq!(DiffuseModel::from_name("lambertian"), None);
    }

    proptest! {
        #[test]
        fn factors_are_fractions(theta in 0.0f64..1.57, az in -3.2f64..3.2, psi in -3.2f64..3.2, eta in 1.01f64..4.0) {
            let w = dir(theta, az);
            let e1 = if theta > 1e-6 { N.cross(&w).normalize() } else { Vec3::x() };
            let e2 = e1.cross(&w);
            let t = e1 * psi.cos() + e2 * psi.sin();
            let open = exit(&N, &w, w.z, eta, None);
            let pol = exit(&N, &w, w.z, eta, Some(&t));
            prop_assert!((0.0..=1.0).contains(&open));
            prop_assert!(pol >= 0.0 && pol <= open + 1e-15);
            prop_assert!((0.0..=1.0).contains(&entry(&N, &w, w.z, eta, Some(&t))));
        }
    }
}
