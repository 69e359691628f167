//! Fresnel reflection of a dielectric wall at the microfacet angle `phi`
//! (MODEL.md Eqs. 6-8), in a form that is exact at `phi -> 0`.
//!
//! MODEL.md writes `Rs = sin^2(phi - phi')/sin^2(phi + phi')` and
//! `Rp = tan^2(phi - phi')/tan^2(phi + phi')`. Expanding with
//! `sin phi' = sin phi / eta` cancels the common `sin phi` factor and gives the
//! textbook cosine forms used here,
//! `r_s = (cos phi - eta cos phi')/(cos phi + eta cos phi')` and
//! `r_p = (eta cos phi - cos phi')/(eta cos phi + cos phi')`,
//! which are algebraically identical for `phi > 0`, reach the MODEL.md limit
//! `((eta - 1)/(eta + 1))^2` continuously at `phi = 0` (no 0/0), and need only
//! square roots when `cos 2phi = w_i . w_o` is known (the hot path of `T`).

/// Fresnel amplitude coefficients at one incidence angle (Jones calculus, MODEL.md Eq. 11).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FresnelAmplitudes {
    /// `r_s = -sin(phi - phi')/sin(phi + phi')`.
    pub rs: f64,
    /// `r_p = tan(phi - phi')/tan(phi + phi')`.
    pub rp: f64,
}

impl FresnelAmplitudes {
    /// Amplitudes from `cos phi` (in [0, 1]) and the wall index `eta > 1`.
    #[inline(always)]
    pub fn from_cos(cos_phi: f64, eta: f64) -> Self {
        let c = cos_phi.clamp(0.0, 1.0);
        let sin2 = (1.0 - c * c).max(0.0);
        // Snell: sin phi' = sin phi / eta, so cos phi' = sqrt(1 - sin^2 phi / eta^2).
        let ct = (1.0 - sin2 / (eta * eta)).max(0.0).sqrt();
        // One division for both ratios (this sits in the transport kernel).
        let (ds, dp) = (c + eta * ct, eta * c + ct);
        let inv = 1.0 / (ds * dp);
        Self {
            rs: (c - eta * ct) * dp * inv,
            rp: (eta * c - ct) * ds * inv,
        }
    }

    /// Amplitudes at the half angle `phi = 1/2 acos(cos_2phi)` (MODEL.md Eq. 9),
    /// computed without trigonometric calls: `cos phi = sqrt((1 + cos 2phi)/2)`.
    #[inline(always)]
    pub fn from_cos_2phi(cos_2phi: f64, eta: f64) -> Self {
        let c2 = cos_2phi.clamp(-1.0, 1.0);
        Self::from_cos((0.5 * (1.0 + c2)).sqrt(), eta)
    }

    /// Amplitudes at the angle `phi` in radians.
    pub fn at_angle(phi: f64, eta: f64) -> Self {
        Self::from_cos(phi.cos(), eta)
    }

    /// Power reflectances `(Rs, Rp)`.
    #[inline(always)]
    pub fn reflectances(self) -> FresnelHalf {
        FresnelHalf {
            rs: self.rs * self.rs,
            rp: self.rp * self.rp,
        }
    }
}

/// Power reflectances of the s and p components (MODEL.md Eqs. 7-8).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FresnelHalf {
    /// `Rs`.
    pub rs: f64,
    /// `Rp`.
    pub rp: f64,
}

impl FresnelHalf {
    /// Reflectances at the angle `phi` in radians.
    pub fn at_angle(phi: f64, eta: f64) -> Self {
        FresnelAmplitudes::at_angle(phi, eta).reflectances()
    }

    /// Unpolarized reflectance `(Rs + Rp)/2`.
    pub fn mean(self) -> f64 {
        0.5 * (self.rs + self.rp)
    }
}

/// Brewster angle `atan(eta)` in radians, where `Rp = 0` (the tests' check).
#[cfg(test)]
fn brewster_angle(eta: f64) -> f64 {
    eta.atan()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The MODEL.md trigonometric form, evaluated directly (valid away from 0).
    fn trig(phi: f64, eta: f64) -> (f64, f64) {
        let pt = (phi.sin() / eta).asin();
        let rs = ((phi - pt).sin() / (phi + pt).sin()).powi(2);
        let rp = ((phi - pt).tan() / (phi + pt).tan()).powi(2);
        (rs, rp)
    }

    #[test]
    fn normal_incidence_limit_is_the_textbook_value() {
        let eta: f64 = 1.5;
        let r0 = ((eta - 1.0) / (eta + 1.0)).powi(2);
        for phi in [0.0, 1e-12, 1e-8, 1e-7] {
            let f = FresnelHalf::at_angle(phi, eta);
            assert!((f.rs - r0).abs() < 1e-13, "Rs at {phi}: {}", f.rs);
            assert!((f.rp - r0).abs() < 1e-13, "Rp at {phi}: {}", f.rp);
        }
        assert!((r0 - 0.04).abs() < 1e-15);
    }

    #[test]
    fn rp_vanishes_at_brewster() {
        for eta in [1.3, 1.5, 2.4] {
            let f = FresnelHalf::at_angle(brewster_angle(eta), eta);
            assert!(f.rp < 1e-28, "Rp at Brewster for eta {eta}: {}", f.rp);
            assert!(f.rs > 0.05);
        }
    }

    #[test]
    fn matches_the_trigonometric_form_of_the_model() {
        for i in 1..90 {
            let phi = (i as f64).to_radians();
            for eta in [1.2, 1.5, 3.0] {
                let (rs, rp) = trig(phi, eta);
                let f = FresnelHalf::at_angle(phi, eta);
                assert!((f.rs - rs).abs() <= 1e-12 * rs.max(1e-300), "{phi} {eta}");
                assert!((f.rp - rp).abs() <= 1e-12 * rp.max(1e-15), "{phi} {eta}");
            }
        }
    }

    #[test]
    fn amplitude_signs_follow_the_model_convention() {
        // r_s = -sin(phi - phi')/sin(phi + phi') is negative for every phi in (0, 90).
        let a = FresnelAmplitudes::at_angle(0.5, 1.5);
        assert!(a.rs < 0.0);
        // r_p = tan(phi - phi')/tan(phi + phi') changes sign at Brewster.
        assert!(FresnelAmplitudes::at_angle(0.5, 1.5).rp > 0.0);
        assert!(FresnelAmplitudes::at_angle(1.2, 1.5).rp < 0.0);
    }

    #[test]
    fn grazing_incidence_reflects_everything() {
        let f = FresnelHalf::at_angle(std::f64::consts::FRAC_PI_2, 1.5);
        assert!((f.rs - 1.0).abs() < 1e-12 && (f.rp - 1.0).abs() < 1e-12);
    }

    #[test]
    fn half_angle_entry_point_agrees() {
        let phi: f64 = 0.7;
        let a = FresnelAmplitudes::from_cos_2phi((2.0 * phi).cos(), 1.5);
        let b = FresnelAmplitudes::at_angle(phi, 1.5);
        assert!((a.rs - b.rs).abs() < 1e-14 && (a.rp - b.rp).abs() < 1e-14);
    }

    proptest::proptest! {
        #[test]
        fn reflectances_are_probabilities(phi in 0.0f64..std::f64::consts::FRAC_PI_2, eta in 1.0001f64..5.0) {
            let f = FresnelHalf::at_angle(phi, eta);
            proptest::prop_assert!((0.0..=1.0).contains(&f.rs));
            proptest::prop_assert!((0.0..=1.0).contains(&f.rp));
            proptest::prop_assert!(f.rp <= f.rs + 1e-15);
        }
    }
}
