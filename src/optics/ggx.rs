//! GGX (Trowbridge-Reitz) microfacet distribution and Smith shadowing
//! (MODEL.md "One entry of T": `D(h)`, `G1`, `G2`).

#[cfg(test)]
use std::f64::consts::PI;

/// GGX normal distribution `D = alpha^2 / (pi ((n.h)^2 (alpha^2 - 1) + 1)^2)`.
///
/// `cos_h = n.h`; `alpha` in (0, 1]. Normalized so that the projected area of
/// the microfacets integrates to one over the hemisphere. The tests' reference:
/// `brdf.rs` evaluates it fused with the lobe's cosines.
#[cfg(test)]
fn distribution(cos_h: f64, alpha: f64) -> f64 {
    let a2 = alpha * alpha;
    let d = cos_h * cos_h * (a2 - 1.0) + 1.0;
    a2 / (PI * d * d)
}

/// Smith masking for one direction, `G1(w) = 2 (n.w) / ((n.w) + sqrt(alpha^2 + (1 - alpha^2)(n.w)^2))`.
#[inline(always)]
pub(crate) fn smith_g1(cos_w: f64, alpha: f64) -> f64 {
    let a2 = alpha * alpha;
    2.0 * cos_w / (cos_w + (a2 + (1.0 - a2) * cos_w * cos_w).sqrt())
}

/// Separable Smith shadowing-masking `G2 = G1(w_i) G1(w_o)`; the tests'
/// reference (`brdf.rs` multiplies the two `G1`s it keeps per direction).
#[cfg(test)]
fn smith_g2(cos_i: f64, cos_o: f64, alpha: f64) -> f64 {
    smith_g1(cos_i, alpha) * smith_g1(cos_o, alpha)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn distribution_integrates_to_one_in_projected_area() {
        // int D(h) (n.h) dw_h over the hemisphere = 1.
        for alpha in [0.05, 0.3, 1.0] {
            let n = 200_000;
            let mut sum = 0.0;
            for i in 0..n {
                // substitute mu = cos theta, dw = 2 pi dmu.
                let mu = (i as f64 + 0.5) / n as f64;
                sum += distribution(mu, alpha) * mu * 2.0 * PI / n as f64;
            }
            assert!((sum - 1.0).abs() < 2e-3, "alpha {alpha}: {sum}");
        }
    }

    #[test]
    fn alpha_one_is_uniform() {
        for c in [0.0, 0.3, 1.0] {
            assert!((distribution(c, 1.0) - 1.0 / PI).abs() < 1e-15);
        }
    }

    #[test]
    fn peak_value_at_the_normal() {
        let alpha: f64 = 0.3;
        assert!((distribution(1.0, alpha) - 1.0 / (PI * alpha * alpha)).abs() < 1e-12);
    }

    #[test]
    fn masking_limits() {
        // Head-on: no masking. Grazing: fully masked.
        for alpha in [0.01, 0.3, 1.0] {
            assert!((smith_g1(1.0, alpha) - 1.0).abs() < 1e-15);
            assert_eq!(smith_g1(0.0, alpha), 0.0);
        }
        // Smoother surfaces mask less.
        assert!(smith_g1(0.3, 0.1) > smith_g1(0.3, 0.9));
        assert_eq!(smith_g2(0.4, 0.7, 0.3), smith_g2(0.7, 0.4, 0.3));
    }
}
