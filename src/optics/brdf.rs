//! The wall's BRDF as seen through the camera's polarizer (MODEL.md "One entry of T"):
//!
//! `f = ks D(h) G2 / (4 (n.w_i)(n.w_o)) P_spec + (kd/pi) P_diff`, with
//! `P_diff` from [`super::diffuse`] (revision 2: `fresnel` by default).
//!
//! One implementation serves every caller: [`Brdf::eval`] for a single pair of
//! directions, [`Brdf::eval_at`] for the transport builder, which already holds
//! the cosines and Smith terms of each direction and must not recompute them.

use std::f64::consts::PI;

use super::diffuse::{self, DiffuseModel};
use super::fresnel::FresnelAmplitudes;
use super::ggx;
use super::polarizer::{analyzer_factor, s_direction, source_field};
use super::Vec3;

/// Material of the wall: GGX roughness, refractive index, specular and diffuse weights.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Brdf {
    /// GGX `alpha` in (0, 1].
    pub alpha: f64,
    /// Refractive index `eta > 1`.
    pub eta: f64,
    /// Specular weight `ks` (MODEL.md default 1).
    pub ks: f64,
    /// Diffuse weight `kd` (MODEL.md default 0).
    pub kd: f64,
    /// How the diffuse light is polarized (MODEL.md `[wall] diffuse`).
    pub diffuse: DiffuseModel,
}

/// The polarization state that the light and the camera impose on one entry.
#[derive(Debug, Clone, Copy, Default)]
pub struct Polarization<'a> {
    /// Effective transmission axis `t` of the camera polarizer (unit, normal to
    /// `w_o`), or `None` with no polarizer.
    pub analyzer: Option<&'a Vec3>,
    /// Field direction `e_src` of a linearly polarized scene (MODEL.md Eq. 11),
    /// or `None` for unpolarized light.
    pub source: Option<&'a Vec3>,
}

/// One direction leaving the wall element: unit vector, `n.w`, Smith `G1(w)`.
#[derive(Debug, Clone, Copy)]
pub struct Direction {
    /// Unit direction from the wall point.
    pub w: Vec3,
    /// `n.w`, positive above the wall.
    pub cos: f64,
    /// Smith masking `G1(w)` for the wall's roughness.
    pub g1: f64,
}

impl Brdf {
    /// A direction `w` (unit) seen from a wall of normal `n`, with its Smith term.
    #[inline]
    pub fn direction(&self, n: &Vec3, w: Vec3) -> Direction {
        let cos = n.dot(&w);
        Direction {
            w,
            cos,
            g1: ggx::smith_g1(cos, self.alpha),
        }
    }

    /// `f(w_i, w_o)` for unit directions above a wall of normal `n`; zero below the horizon.
    pub fn eval(&self, n: &Vec3, w_i: &Vec3, w_o: &Vec3, pol: Polarization<'_>) -> f64 {
        let i = self.direction(n, *w_i);
        let o = self.direction(n, *w_o);
        if i.cos <= 0.0 || o.cos <= 0.0 {
            return 0.0;
        }
        self.eval_at(n, &i, &o, pol)
    }

    /// `f` for two directions already known to be above the wall of normal `n`.
    #[inline]
    pub fn eval_at(&self, n: &Vec3, i: &Direction, o: &Direction, pol: Polarization<'_>) -> f64 {
        let lobe = self.lobe(i, o);
        self.finish(&lobe, n, i, o, pol)
    }

    /// The unpolarized part of the specular term for a pair of directions:
    /// everything but `P_spec`, computed once and shared by all polarizer angles.
    #[inline]
    pub fn lobe(&self, i: &Direction, o: &Direction) -> SpecularLobe {
        self.lobe_from_cosines(i.cos, i.g1, o.cos, o.g1, i.w.dot(&o.w))
    }

    /// [`Brdf::lobe`] from scalars: `n.w_i`, `G1(w_i)`, `n.w_o`, `G1(w_o)` and
    /// `w_i.w_o`; branch-free so that the transport builder's loops vectorize.
    #[inline(always)]
    pub fn lobe_from_cosines(
        &self,
        cos_i: f64,
        g1_i: f64,
        cos_o: f64,
        g1_o: f64,
        wi_dot_wo: f64,
    ) -> SpecularLobe {
        // cos(2 theta_h) = w_i.w_o (Eq. 9) and (n.h)^2 = (n.w_i + n.w_o)^2 / |w_i + w_o|^2
        // with |w_i + w_o|^2 = 2 + 2 w_i.w_o. Substituting into
        // ks D G2 / (4 (n.w_i)(n.w_o)), D = a^2 / (pi ((n.h)^2 (a^2 - 1) + 1)^2),
        // and clearing the inner fraction leaves a single division:
        // ks a^2 G2 m^2 / (4 pi (s^2 (a^2 - 1) + m)^2 (n.w_i)(n.w_o)), s = n.w_i + n.w_o, m = 2 + 2 w_i.w_o.
        let c2 = wi_dot_wo.clamp(-1.0, 1.0);
        let a2 = self.alpha * self.alpha;
        let sum = cos_i + cos_o;
        let m = 2.0 + 2.0 * c2;
        let den = sum * sum * (a2 - 1.0) + m;
        SpecularLobe {
            weight: self.ks * a2 * g1_i * g1_o * m * m / (4.0 * PI * den * den * cos_i * cos_o),
            fresnel: FresnelAmplitudes::from_cos_2phi(c2, self.eta),
        }
    }

    /// `f = weight P_spec + (kd/pi) P_diff` for one polarization state.
    #[inline]
    pub fn finish(
        &self,
        lobe: &SpecularLobe,
        n: &Vec3,
        i: &Direction,
        o: &Direction,
        pol: Polarization<'_>,
    ) -> f64 {
        let mut f = 0.0;
        if self.ks != 0.0 {
            f += lobe.weight * specular_factor(lobe.fresnel, &i.w, &o.w, pol);
        }
        if self.kd != 0.0 {
            f += self.kd / PI * self.diffuse_factor(n, i, o, pol);
        }
        f
    }

    /// `P_diff` (MODEL.md "Diffuse term") for one polarization state.
    pub fn diffuse_factor(
        &self,
        n: &Vec3,
        i: &Direction,
        o: &Direction,
        pol: Polarization<'_>,
    ) -> f64 {
        match self.diffuse {
            DiffuseModel::Lambert => {
                if pol.analyzer.is_some() {
                    0.5
                } else {
                    1.0
                }
            }
            DiffuseModel::Fresnel => {
                let e = pol.source.map(|e_src| source_field(e_src, &i.w));
                diffuse::entry(n, &i.w, i.cos, self.eta, e.as_ref())
                    * diffuse::exit(n, &o.w, o.cos, self.eta, pol.analyzer)
            }
        }
    }
}

/// `ks D(h) G2 / (4 (n.w_i)(n.w_o))` and the Fresnel amplitudes at `theta_h`.
#[derive(Debug, Clone, Copy)]
pub struct SpecularLobe {
    /// Specular weight before the polarization factor.
    pub weight: f64,
    /// Fresnel amplitudes at the half angle.
    pub fresnel: FresnelAmplitudes,
}

/// `P_spec`: the fraction of the Fresnel-reflected specular power that passes
/// the camera polarizer, for unpolarized or linearly polarized light.
///
/// MODEL.md gives every case but one: a polarized source on the degenerate
/// path `w_i = w_o`. There `e_pi = -e_pr` and `r_p = -r_s`, so the Jones sum
/// collapses to `A = r_s (e_src.t)` for any choice of `e_s`; we use that (and
/// `r_s^2 |e_src|^2` without a polarizer), which is the continuous limit.
#[inline]
pub(crate) fn specular_factor(
    fresnel: FresnelAmplitudes,
    w_i: &Vec3,
    w_o: &Vec3,
    pol: Polarization<'_>,
) -> f64 {
    let e_s = s_direction(w_i, w_o);
    match (pol.source, pol.analyzer, e_s) {
        (None, None, _) => fresnel.reflectances().mean(),
        (None, Some(t), _) => {
            let r = fresnel.reflectances();
            let b = w_o.cross(t);
            analyzer_factor(
                r.rs,
                r.rp,
                w_i.dot(&b),
                w_i.dot(t),
                w_i.cross(w_o).norm_squared(),
            )
        }
        (Some(e_src), analyzer, None) => {
            let e = source_field(e_src, w_i);
            match analyzer {
                Some(t) => (fresnel.rs * e.dot(t)).powi(2),
                None => fresnel.rs * fresnel.rs * e.norm_squared(),
            }
        }
        (Some(e_src), analyzer, Some(e_s)) => {
            let e = source_field(e_src, w_i);
            let e_pi = (-w_i).cross(&e_s);
            let es = e.dot(&e_s);
            let ep = e.dot(&e_pi);
            match analyzer {
                Some(t) => {
                    let e_pr = w_o.cross(&e_s);
                    let a = fresnel.rs * es * t.dot(&e_s) + fresnel.rp * ep * t.dot(&e_pr);
                    a * a
                }
                None => fresnel.rs * fresnel.rs * es * es + fresnel.rp * fresnel.rp * ep * ep,
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::fresnel::FresnelHalf;
    use super::super::polarizer::PolarizerModel;
    use super::*;

    /// The transmitting reading's effective axis (the tests here are about the
    /// wall, not the sheet: any axis normal to `w` serves).
    fn effective_axis(q: &Vec3, w: &Vec3) -> Option<Vec3> {
        PolarizerModel::Transmitting.effective_axis(q, &-w, w)
    }
    use proptest::prelude::*;

    const N: Vec3 = Vec3::new(0.0, 0.0, 1.0);

    fn wall() -> Brdf {
        Brdf {
            alpha: 0.3,
            eta: 1.5,
            ks: 1.0,
            kd: 0.0,
            diffuse: DiffuseModel::Fresnel,
        }
    }

    fn dir(theta: f64, az: f64) -> Vec3 {
        Vec3::new(theta.sin() * az.cos(), theta.sin() * az.sin(), theta.cos())
    }

    #[test]
    fn reciprocity_without_polarizer() {
        let b = Brdf { kd: 0.2, ..wall() };
        for (ti, ai, to, ao) in [
            (0.3, 0.0, 1.1, 2.0),
            (1.4, 1.0, 0.1, -2.5),
            (0.9, 0.2, 0.9, 3.0),
        ] {
            let (i, o) = (dir(ti, ai), dir(to, ao));
            let f1 = b.eval(&N, &i, &o, Polarization::default());
            let f2 = b.eval(&N, &o, &i, Polarization::default());
            assert!((f1 - f2).abs() <= 1e-14 * f1, "{f1} vs {f2}");
        }
    }

    #[test]
    fn below_the_horizon_is_black() {
        let b = Brdf { kd: 1.0, ..wall() };
        assert_eq!(
            b.eval(&N, &dir(1.7, 0.0), &dir(0.3, 0.0), Polarization::default()),
            0.0
        );
        assert_eq!(
            b.eval(&N, &dir(0.3, 0.0), &dir(1.6, 0.0), Polarization::default()),
            0.0
        );
    }

    #[test]
    fn mirror_peak_value_by_hand() {
        // w_i = w_o mirrored about n at 30 deg: h = n, D = 1/(pi a^2), theta_h = 30 deg.
        let b = wall();
        let t = 30f64.to_radians();
        let (i, o) = (dir(t, std::f64::consts::PI), dir(t, 0.0));
        let g1 = ggx::smith_g1(t.cos(), 0.3);
        let fr = FresnelHalf::at_angle(t, 1.5).mean();
        let expect = 1.0 / (PI * 0.09) * g1 * g1 / (4.0 * t.cos() * t.cos()) * fr;
        let f = b.eval(&N, &i, &o, Polarization::default());
        assert!((f - expect).abs() < 1e-13 * expect, "{f} vs {expect}");
    }

    #[test]
    fn crossed_polarizer_blocks_the_brewster_mirror_path() {
        // Mirror path at the Brewster angle: Rp = 0, and an analyzer crossed to
        // e_s passes only p light, so the specular term vanishes.
        let b = wall();
        let tb = 1.5f64.atan();
        let (i, o) = (dir(tb, std::f64::consts::PI), dir(tb, 0.0));
        let e_s = i.cross(&o).normalize();
        let n_p = -o;
        let q = e_s.cross(&n_p).normalize();
        let t = effective_axis(&q, &o).unwrap();
        let crossed = b.eval(
            &N,
            &i,
            &o,
            Polarization {
                analyzer: Some(&t),
                source: None,
            },
        );
        let open = b.eval(&N, &i, &o, Polarization::default());
        assert!(
            crossed < 1e-28 * open.max(1.0),
            "crossed {crossed} open {open}"
        );
        // The parallel analyzer passes the s light: half of the unpolarized power, all of it Rs.
        let par = b.eval(
            &N,
            &i,
            &o,
            Polarization {
                analyzer: Some(&e_s),
                source: None,
            },
        );
        assert!(
            (par - open).abs() < 1e-12 * open,
            "parallel {par} open {open}"
        );
    }

    #[test]
    fn lambert_diffuse_light_is_halved_by_any_polarizer() {
        let b = Brdf {
            ks: 0.0,
            kd: 0.7,
            diffuse: DiffuseModel::Lambert,
            ..wall()
        };
        let (i, o) = (dir(0.4, 1.0), dir(0.8, -1.0));
        let t = effective_axis(&Vec3::new(0.3, 0.8, 0.1), &o).unwrap();
        let open = b.eval(&N, &i, &o, Polarization::default());
        let pol = b.eval(
            &N,
            &i,
            &o,
            Polarization {
                analyzer: Some(&t),
                source: None,
            },
        );
        assert!((open - 0.7 / PI).abs() < 1e-15);
        assert!((pol - 0.35 / PI).abs() < 1e-15);
    }

    #[test]
    fn fresnel_diffuse_light_crosses_both_interfaces() {
        // Without a polarizer: kd/pi (1 - R(theta_i)) (1 - R(theta_o)), with the
        // reflectances at the macroscopic angles (not the half angle).
        let b = Brdf {
            ks: 0.0,
            kd: 0.7,
            ..wall()
        };
        let (ti, to) = (0.4, 0.8);
        let (i, o) = (dir(ti, 1.0), dir(to, -1.0));
        let r = |t: f64| FresnelHalf::at_angle(t, 1.5).mean();
        let open = b.eval(&N, &i, &o, Polarization::default());
        let expect = 0.7 / PI * (1.0 - r(ti)) * (1.0 - r(to));
        assert!((open - expect).abs() < 1e-15, "{open} vs {expect}");
        // Through analyzers along the exit plane's s and p directions.
        let e_so = N.cross(&o).normalize();
        let e_po = e_so.cross(&o);
        let f = FresnelHalf::at_angle(to, 1.5);
        for (t, tr) in [(e_so, 1.0 - f.rs), (e_po, 1.0 - f.rp)] {
            let got = b.eval(
                &N,
                &i,
                &o,
                Polarization {
                    analyzer: Some(&t),
                    source: None,
                },
            );
            let expect = 0.7 / PI * (1.0 - r(ti)) * tr / 2.0;
            assert!((got - expect).abs() < 1e-15, "{got} vs {expect}");
        }
    }

    #[test]
    fn degenerate_backscatter_uses_rs_over_two() {
        let w = dir(0.5, 0.3);
        let f = FresnelAmplitudes::from_cos(1.0, 1.5);
        let t = effective_axis(&Vec3::x(), &w).unwrap();
        let p = specular_factor(
            f,
            &w,
            &w,
            Polarization {
                analyzer: Some(&t),
                source: None,
            },
        );
        assert!((p - 0.02).abs() < 1e-15);
    }

    #[test]
    fn polarized_source_averages_to_unpolarized() {
        // Two orthogonal source polarizations, each carrying the full power,
        // average to the unpolarized factor, with and without an analyzer.
        let (i, o) = (dir(0.9, 2.9), dir(1.0, 0.1));
        let fr = FresnelAmplitudes::from_cos_2phi(i.dot(&o), 1.5);
        let a = i.cross(&Vec3::z()).normalize();
        let b = i.cross(&a);
        let t = effective_axis(&Vec3::new(0.2, 0.9, -0.3), &o).unwrap();
        for analyzer in [None, Some(&t)] {
            let pa = specular_factor(
                fr,
                &i,
                &o,
                Polarization {
                    analyzer,
                    source: Some(&a),
                },
            );
            let pb = specular_factor(
                fr,
                &i,
                &o,
                Polarization {
                    analyzer,
                    source: Some(&b),
                },
            );
            let pu = specular_factor(
                fr,
                &i,
                &o,
                Polarization {
                    analyzer,
                    source: None,
                },
            );
            assert!((0.5 * (pa + pb) - pu).abs() < 1e-14, "{pa} {pb} {pu}");
        }
    }

    proptest! {
        #[test]
        fn polarizer_never_passes_more_than_unpolarized(
            ti in 0.0f64..1.55, ai in -3.2f64..3.2, to in 0.0f64..1.55, ao in -3.2f64..3.2,
            qx in -1.0f64..1.0, qy in -1.0f64..1.0, qz in -1.0f64..1.0, eta in 1.01f64..3.0,
        ) {
            let (i, o) = (dir(ti, ai), dir(to, ao));
            let q = Vec3::new(qx, qy, qz);
            prop_assume!(q.cross(&o).norm() > 1e-3);
            let t = effective_axis(&q.normalize(), &o).unwrap();
            let fr = FresnelAmplitudes::from_cos_2phi(i.dot(&o), eta);
            let p = specular_factor(fr, &i, &o, Polarization { analyzer: Some(&t), source: None });
            let r = fr.reflectances();
            prop_assert!(p >= 0.0);
            prop_assert!(p <= r.mean() + 1e-15);
        }
    }
}
