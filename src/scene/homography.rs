//! Projective map from wall coordinates (u, v) in metres, relative to the wall
//! centre, to image pixels (x, y) (MODEL.md "From camera frames to i").

/// A 3x3 homography `H` with `[x w, y w, w]^T = H [u, v, 1]^T`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Homography {
    h: [[f64; 3]; 3],
    inv: [[f64; 3]; 3],
}

impl Homography {
    /// Builds `H`; `None` when it is singular or not finite.
    pub fn new(h: [[f64; 3]; 3]) -> Option<Self> {
        if h.iter().flatten().any(|x| !x.is_finite()) {
            return None;
        }
        let m = nalgebra::Matrix3::from_fn(|r, c| h[r][c]);
        let scale = m.abs().max();
        if scale == 0.0 || m.determinant().abs() <= 1e-12 * scale.powi(3) {
            return None;
        }
        let i = m.try_inverse()?;
        Some(Self {
            h,
            inv: std::array::from_fn(|r| std::array::from_fn(|c| i[(r, c)])),
        })
    }

    /// The matrix as given.
    pub fn matrix(&self) -> [[f64; 3]; 3] {
        self.h
    }

    /// Pixel (x, y) of wall point (u, v); `None` where the point maps to infinity
    /// or behind the camera (`w <= 0`).
    pub fn apply(&self, u: f64, v: f64) -> Option<(f64, f64)> {
        project(&self.h, u, v)
    }

    /// `H^-1`, pixels to wall metres (up to scale).
    pub fn inverse_matrix(&self) -> [[f64; 3]; 3] {
        self.inv
    }

    /// `det H^-1`: with `w` the third coordinate of `H^-1 [x, y, 1]`, the
    /// footprint of pixel (x, y) on the wall is `|det H^-1| / |w|^3` m^2
    /// (the Jacobian determinant of a projective map; MODEL.md `a_p`).
    pub fn inverse_determinant(&self) -> f64 {
        let m = nalgebra::Matrix3::from_fn(|r, c| self.inv[r][c]);
        m.determinant()
    }

    /// Wall point (u, v) seen at pixel (x, y); `None` off the wall's plane.
    pub fn invert(&self, x: f64, y: f64) -> Option<(f64, f64)> {
        let (a, b, w) = mul(&self.inv, x, y);
        (w.abs() > 1e-300).then(|| (a / w, b / w))
    }
}

fn mul(h: &[[f64; 3]; 3], a: f64, b: f64) -> (f64, f64, f64) {
    let r = |i: usize| h[i][0] * a + h[i][1] * b + h[i][2];
    (r(0), r(1), r(2))
}

fn project(h: &[[f64; 3]; 3], u: f64, v: f64) -> Option<(f64, f64)> {
    let (x, y, w) = mul(h, u, v);
    (w > 1e-300).then(|| (x / w, y / w))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bench_homography_maps_the_wall_centre_to_the_image_centre() {
        let h = Homography::new([
            [-425.517945, 1220.52494, 255.5],
            [250.943812, 0.0, 255.5],
            [-1.66543227, 0.0, 1.0],
        ])
        .unwrap();
        let (x, y) = h.apply(0.0, 0.0).unwrap();
        assert_eq!((x, y), (255.5, 255.5));
        let (u, v) = h.invert(100.0, 300.0).unwrap();
        let (x, y) = h.apply(u, v).unwrap();
        assert!((x - 100.0).abs() < 1e-9 && (y - 300.0).abs() < 1e-9);
    }

    #[test]
    fn singular_is_rejected() {
        assert!(Homography::new([[1.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 0.0, 1.0]]).is_none());
        assert!(
            Homography::new([[f64::NAN, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]).is_none()
        );
    }
}
