//! The camera polarizer seen by one reflected ray: the effective transmission
//! axis (supplementary Eqs. 16-17, vector form) and the facet s/p basis.
//!
//! MODEL.md: `t = normalize(q - (q.w_o) w_o)`, `e_s = normalize(w_i x w_o)`,
//! `e_p = e_s x w_o`. `e_s` is undefined when `|w_i x w_o| < 1e-12`.

use super::Vec3;

/// Below this `|w_i x w_o|` the plane of incidence, and so `e_s`, is undefined (MODEL.md).
pub const DEGENERATE_CROSS: f64 = 1e-12;

/// Effective axis `t`: the polarizer axis `q` projected on the wave plane of
/// the ray that reaches the camera along `w_o`, normalized.
///
/// Returns `None` when `q` is parallel to `w_o` (the polarizer seen edge-on),
/// which cannot happen for a polarizer facing the wall but is not assumed.
#[inline]
pub fn effective_axis(q: &Vec3, w_o: &Vec3) -> Option<Vec3> {
    let t = q - q.dot(w_o) * w_o;
    let n = t.norm();
    (n > 1e-300).then(|| t / n)
}

/// The s direction of the facet, `normalize(w_i x w_o)`, or `None` when degenerate.
#[inline]
pub fn s_direction(w_i: &Vec3, w_o: &Vec3) -> Option<Vec3> {
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
pub fn analyzer_factor(rs: f64, rp: f64, wi_dot_b: f64, wi_dot_t: f64, cross2: f64) -> f64 {
    if cross2 < DEGENERATE_CROSS * DEGENERATE_CROSS {
        0.5 * rs
    } else {
        (rs * wi_dot_b * wi_dot_b + rp * wi_dot_t * wi_dot_t) / (2.0 * cross2)
    }
}

/// Projects a polarized source's field direction onto the plane normal to `w_i`
/// and normalizes it; zero when it is parallel to `w_i` (MODEL.md edge cases).
#[inline]
pub fn source_field(e_src: &Vec3, w_i: &Vec3) -> Vec3 {
    let e = e_src - e_src.dot(w_i) * w_i;
    let n = e.norm();
    if n > 1e-12 {
        e / n
    } else {
        Vec3::zeros()
    }
}

/// Rodrigues rotation of `v` by `angle` (right hand) about the unit `axis`.
pub fn rotate(v: &Vec3, axis: &Vec3, angle: f64) -> Vec3 {
    let (s, c) = angle.sin_cos();
    v * c + axis.cross(v) * s + axis * (axis.dot(v) * (1.0 - c))
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

    proptest! {
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
            let t = effective_axis(&q, &w).unwrap();
            prop_assert!((t.norm() - 1.0).abs() < 1e-12);
            prop_assert!(t.dot(&w).abs() < 1e-12);
            // t stays on q's side: projection never flips the axis.
            prop_assert!(t.dot(&q) >= 0.0);
        }
    }
}
