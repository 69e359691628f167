//! A discretized plane (wall or hidden screen): element centres and
//! supersampling points (MODEL.md "Geometry of a scene file").

use crate::optics::Vec3;

/// Elements along u and v; flattened row-major (v outer, u inner), as `T`'s rows and columns.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub struct Grid {
    /// Elements along u (columns of an image).
    pub nu: usize,
    /// Elements along v (rows of an image).
    pub nv: usize,
}

impl Grid {
    /// Number of elements.
    pub fn count(&self) -> usize {
        self.nu * self.nv
    }

    /// Flat index of element (iu, iv): `iv * nu + iu`.
    pub fn index(&self, iu: usize, iv: usize) -> usize {
        iv * self.nu + iu
    }

    /// Element (iu, iv) of a flat index.
    pub fn coords(&self, j: usize) -> (usize, usize) {
        (j % self.nu, j / self.nu)
    }

    /// The grid's element order (row `iv` = 0 at the plane's -v edge) as an
    /// image with the top row first (+v up), `channels` values an element.
    /// Why: `T`'s columns start at the bottom of the hidden plane; people
    /// store and look at images top first (docs/formats.md "Which way is up").
    pub fn to_top_first<T: Copy>(&self, values: &[T], channels: usize) -> Vec<T> {
        let row = (self.nu * channels).max(1);
        values.chunks(row).rev().flatten().copied().collect()
    }

    /// An image with its top row first as the grid's element order: the
    /// inverse of [`Grid::to_top_first`] (the same reversal of rows).
    /// Why: a truth image or pattern as people draw it becomes a scene `l`.
    pub fn from_top_first<T: Copy>(&self, values: &[T], channels: usize) -> Vec<T> {
        self.to_top_first(values, channels)
    }
}

/// A rectangle in space: centre, orthonormal frame, metric size and grid.
#[derive(Debug, Clone, PartialEq)]
pub struct Plane {
    /// Centre point.
    pub center: Vec3,
    /// Unit normal.
    pub normal: Vec3,
    /// Unit in-plane axis u (orthogonal to `normal`).
    pub u: Vec3,
    /// `v = normal x u`.
    pub v: Vec3,
    /// Size along (u, v), metres.
    pub size: [f64; 2],
    /// Elements along (u, v).
    pub grid: Grid,
    /// `m`: each element is averaged over m x m sub-samples.
    pub supersample: usize,
}

impl Plane {
    /// Area of one element, `size_u/nu * size_v/nv` (MODEL.md `a_k`).
    pub fn element_area(&self) -> f64 {
        self.size[0] / self.grid.nu as f64 * self.size[1] / self.grid.nv as f64
    }

    /// Sub-samples per element, `m^2`.
    pub fn samples_per_element(&self) -> usize {
        self.supersample * self.supersample
    }

    /// In-plane coordinates (metres from the centre, along u and v) of
    /// sub-sample `(a, b)` of element `(iu, iv)`; with `m = 1` the element centre
    /// `((iu + 0.5)/nu - 0.5) size_u`.
    pub fn local(&self, iu: usize, iv: usize, a: usize, b: usize) -> (f64, f64) {
        let m = self.supersample as f64;
        let fu = (iu as f64 + (a as f64 + 0.5) / m) / self.grid.nu as f64;
        let fv = (iv as f64 + (b as f64 + 0.5) / m) / self.grid.nv as f64;
        ((fu - 0.5) * self.size[0], (fv - 0.5) * self.size[1])
    }

    /// World point at in-plane coordinates (u, v).
    pub fn point(&self, u: f64, v: f64) -> Vec3 {
        self.center + self.u * u + self.v * v
    }

    /// In-plane coordinates of every sub-sample, element-major (element j's
    /// samples at `j m^2 .. (j + 1) m^2`, sub-samples v outer, u inner).
    pub fn sample_uv(&self) -> Vec<(f64, f64)> {
        let m = self.supersample;
        let mut out = Vec::with_capacity(self.grid.count() * m * m);
        for iv in 0..self.grid.nv {
            for iu in 0..self.grid.nu {
                for b in 0..m {
                    for a in 0..m {
                        out.push(self.local(iu, iv, a, b));
                    }
                }
            }
        }
        out
    }

    /// World positions of every sub-sample, in the order of [`Plane::sample_uv`].
    pub fn sample_points(&self) -> Vec<Vec3> {
        self.sample_uv()
            .into_iter()
            .map(|(u, v)| self.point(u, v))
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn plane(m: usize) -> Plane {
        Plane {
            center: Vec3::new(1.0, 2.0, 3.0),
            normal: Vec3::z(),
            u: Vec3::x(),
            v: Vec3::y(),
            size: [0.3, 0.2],
            grid: Grid { nu: 3, nv: 2 },
            supersample: m,
        }
    }

    #[test]
    fn element_centres_and_order() {
        let p = plane(1);
        let pts = p.sample_points();
        assert_eq!(pts.len(), 6);
        // Element (0, 0) sits at the (-u, -v) corner, one half-element in.
        assert!((pts[0] - Vec3::new(0.9, 1.95, 3.0)).norm() < 1e-15);
        // Row-major: index 1 is (iu = 1, iv = 0), index 3 is (iu = 0, iv = 1).
        assert!((pts[1] - Vec3::new(1.0, 1.95, 3.0)).norm() < 1e-15);
        assert!((pts[3] - Vec3::new(0.9, 2.05, 3.0)).norm() < 1e-15);
        assert_eq!(p.grid.index(2, 1), 5);
        assert_eq!(p.grid.coords(5), (2, 1));
    }

    #[test]
    fn the_top_first_image_starts_at_the_plane_s_plus_v_edge() {
        let p = plane(1);
        // Values = each element's v coordinate: the image's first row is the
        // largest v (the top), its columns still run along +u.
        let v: Vec<f64> = p.sample_points().iter().map(|s| s.y).collect();
        let top = p.grid.to_top_first(&v, 1);
        assert!(
            top[..3].iter().all(|&y| (y - 2.05).abs() < 1e-15),
            "{top:?}"
        );
        assert!(
            top[3..].iter().all(|&y| (y - 1.95).abs() < 1e-15),
            "{top:?}"
        );
        // Two channels an element: each pixel's values stay together.
        let rgb = [0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11];
        let flipped = p.grid.to_top_first(&rgb, 2);
        assert_eq!(flipped, [6, 7, 8, 9, 10, 11, 0, 1, 2, 3, 4, 5]);
        assert_eq!(p.grid.from_top_first(&flipped, 2), rgb);
    }

    #[test]
    fn subsamples_average_to_the_centre() {
        let (p1, p3) = (plane(1), plane(3));
        let c = p1.sample_points();
        let s = p3.sample_points();
        for j in 0..6 {
            let mean: Vec3 = s[j * 9..(j + 1) * 9].iter().sum::<Vec3>() / 9.0;
            assert!((mean - c[j]).norm() < 1e-15);
        }
        assert!((p3.element_area() - 0.01).abs() < 1e-15);
    }
}
