//! Occluders between the hidden scene and the wall (MODEL.md `V(s, c)`):
//! closed parallelograms, closed balls and closed triangle meshes against
//! the open segment s -> c.

use std::sync::Arc;

use crate::optics::Vec3;

/// How far outside its edges a triangle still blocks, in barycentric units
/// (fractions of an edge): half the rectangle's `1e-12` of a half-extent, so
/// that a rectangle written as two triangles blocks what the rectangle blocks.
const TRIANGLE_TOLERANCE: f64 = 0.5e-12;

/// A blocker of light paths.
#[derive(Debug, Clone, PartialEq)]
pub enum Occluder {
    /// Parallelogram `center + a half_u + b half_v`, `|a|, |b| <= 1`.
    Rect {
        /// Centre point.
        center: Vec3,
        /// Half-extent along the first edge.
        half_u: Vec3,
        /// Half-extent along the second edge.
        half_v: Vec3,
    },
    /// Ball of radius `radius`.
    Sphere {
        /// Centre point.
        center: Vec3,
        /// Radius, metres.
        radius: f64,
    },
    /// Closed triangles read from an OBJ or STL file (scene key `mesh`).
    Mesh(Arc<Mesh>),
}

/// A triangle mesh occluder: its triangles in metres and where they came from.
#[derive(Clone, PartialEq)]
pub struct Mesh {
    triangles: Vec<[Vec3; 3]>,
    source: MeshSource,
}

/// The scene file's keys of a mesh occluder, as written: kept so that an
/// edited scene is written back with the same keys.
#[derive(Debug, Clone, PartialEq)]
pub struct MeshSource {
    /// `mesh`: the path as the scene file gives it.
    pub path: String,
    /// `scale`, when given.
    pub scale: Option<f64>,
    /// `offset`, when given.
    pub offset: Option<[f64; 3]>,
}

impl Mesh {
    /// A mesh of these triangles (non-degenerate, in metres), read from `source`.
    pub fn new(triangles: Vec<[Vec3; 3]>, source: MeshSource) -> Self {
        Mesh { triangles, source }
    }

    /// Its triangles, metres.
    pub fn triangles(&self) -> &[[Vec3; 3]] {
        &self.triangles
    }

    /// The scene file's keys it was read from.
    pub fn source(&self) -> &MeshSource {
        &self.source
    }
}

impl std::fmt::Debug for Mesh {
    /// The source and the count: a million triangles do not belong in a log line.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Mesh")
            .field("source", &self.source)
            .field("triangles", &self.triangles.len())
            .finish()
    }
}

/// Where the open segment `s + t d`, `0 < t < 1`, crosses the plane through
/// `origin` spanned by `e1`, `e2`: its coordinates `(a, b)` in that (possibly
/// skew) basis, or `None` when it does not cross or lies in the plane.
#[inline]
fn plane_hit(origin: &Vec3, e1: &Vec3, e2: &Vec3, s: &Vec3, d: &Vec3) -> Option<(f64, f64)> {
    let m = e1.cross(e2);
    let denom = m.dot(d);
    if denom.abs() <= 1e-14 * m.norm() * d.norm() {
        return None;
    }
    let t = m.dot(&(origin - s)) / denom;
    if t <= 0.0 || t >= 1.0 {
        return None;
    }
    // Solve p = a e1 + b e2 in the (possibly skew) edge basis.
    let p = s + d * t - origin;
    let (uu, uv, vv) = (e1.dot(e1), e1.dot(e2), e2.dot(e2));
    let (pu, pv) = (p.dot(e1), p.dot(e2));
    let det = uu * vv - uv * uv;
    Some(((pu * vv - pv * uv) / det, (pv * uu - pu * uv) / det))
}

/// Whether the open segment from `s` to `s + d` meets the closed triangle
/// `tri`, its edges widened by `TRIANGLE_TOLERANCE`.
#[inline]
pub(crate) fn triangle_blocks(tri: &[Vec3; 3], s: &Vec3, d: &Vec3) -> bool {
    let (e1, e2) = (tri[1] - tri[0], tri[2] - tri[0]);
    match plane_hit(&tri[0], &e1, &e2, s, d) {
        Some((a, b)) => {
            a >= -TRIANGLE_TOLERANCE
                && b >= -TRIANGLE_TOLERANCE
                && a + b <= 1.0 + TRIANGLE_TOLERANCE
        }
        None => false,
    }
}

impl Occluder {
    /// Whether the open segment from `s` to `c` meets the occluder.
    ///
    /// A segment that touches only at an end point, or that lies in a
    /// rectangle's or a triangle's plane, is not blocked (MODEL.md "Edge cases").
    pub fn blocks(&self, s: &Vec3, c: &Vec3) -> bool {
        let d = c - s;
        match *self {
            Occluder::Rect {
                center,
                half_u,
                half_v,
            } => match plane_hit(&center, &half_u, &half_v, s, &d) {
                Some((a, b)) => {
                    let tol = 1e-12;
                    a.abs() <= 1.0 + tol && b.abs() <= 1.0 + tol
                }
                None => false,
            },
            Occluder::Sphere { center, radius } => {
                let dd = d.norm_squared();
                let t = (center - s).dot(&d) / dd;
                let r2 = radius * radius;
                if t > 0.0 && t < 1.0 {
                    (s + d * t - center).norm_squared() <= r2
                } else {
                    // The infimum over the open segment is at an end point: it
                    // blocks only when that end point is strictly inside.
                    let e = if t <= 0.0 { s } else { c };
                    (e - center).norm_squared() < r2
                }
            }
            Occluder::Mesh(ref mesh) => mesh.triangles.iter().any(|t| triangle_blocks(t, s, &d)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn square() -> Occluder {
        Occluder::Rect {
            center: Vec3::new(0.0, 0.0, 0.5),
            half_u: Vec3::new(0.1, 0.0, 0.0),
            half_v: Vec3::new(0.0, 0.1, 0.0),
        }
    }

    #[test]
    fn rect_blocks_through_the_middle_and_not_beside() {
        let o = square();
        assert!(o.blocks(&Vec3::new(0.0, 0.0, 1.0), &Vec3::zeros()));
        assert!(!o.blocks(&Vec3::new(0.3, 0.0, 1.0), &Vec3::new(0.3, 0.0, 0.0)));
        // The closed edge blocks.
        assert!(o.blocks(&Vec3::new(0.1, 0.0, 1.0), &Vec3::new(0.1, 0.0, 0.0)));
    }

    #[test]
    fn rect_touching_at_an_end_or_in_plane_does_not_block() {
        let o = square();
        assert!(!o.blocks(&Vec3::new(0.0, 0.0, 1.0), &Vec3::new(0.0, 0.0, 0.5)));
        assert!(!o.blocks(&Vec3::new(-1.0, 0.0, 0.5), &Vec3::new(1.0, 0.0, 0.5)));
        // Segment ending before the plane.
        assert!(!o.blocks(&Vec3::new(0.0, 0.0, 1.0), &Vec3::new(0.0, 0.0, 0.6)));
    }

    #[test]
    fn skew_parallelogram() {
        let o = Occluder::Rect {
            center: Vec3::zeros(),
            half_u: Vec3::new(1.0, 0.0, 0.0),
            half_v: Vec3::new(1.0, 1.0, 0.0),
        };
        let z = |x: f64, y: f64| (Vec3::new(x, y, 1.0), Vec3::new(x, y, -1.0));
        let (s, c) = z(1.9, 0.95);
        assert!(o.blocks(&s, &c));
        let (s, c) = z(-1.5, 0.9);
        assert!(!o.blocks(&s, &c));
    }

    #[test]
    fn sphere_cases() {
        let o = Occluder::Sphere {
            center: Vec3::zeros(),
            radius: 0.5,
        };
        assert!(o.blocks(&Vec3::new(-1.0, 0.0, 0.0), &Vec3::new(1.0, 0.0, 0.0)));
        assert!(o.blocks(&Vec3::new(-1.0, 0.5, 0.0), &Vec3::new(1.0, 0.5, 0.0)));
        assert!(!o.blocks(&Vec3::new(-1.0, 0.51, 0.0), &Vec3::new(1.0, 0.51, 0.0)));
        // Ends on the surface, pointing away: touches only at the end point.
        assert!(!o.blocks(&Vec3::new(0.5, 0.0, 0.0), &Vec3::new(1.0, 0.0, 0.0)));
        // Starts inside.
        assert!(o.blocks(&Vec3::new(0.2, 0.0, 0.0), &Vec3::new(1.0, 0.0, 0.0)));
    }

    /// The square of `square()` as two triangles split along a diagonal.
    fn two_triangles() -> Occluder {
        let q = |x: f64, y: f64| Vec3::new(x, y, 0.5);
        let (a, b, c, d) = (q(-0.1, -0.1), q(0.1, -0.1), q(0.1, 0.1), q(-0.1, 0.1));
        Occluder::Mesh(Arc::new(Mesh::new(
            vec![[a, b, c], [a, c, d]],
            MeshSource {
                path: "square.obj".into(),
                scale: None,
                offset: None,
            },
        )))
    }

    #[test]
    fn triangles_block_like_the_rect_they_tile_even_through_the_diagonal() {
        let (rect, mesh) = (square(), two_triangles());
        let down = |x: f64, y: f64| (Vec3::new(x, y, 1.0), Vec3::new(x, y, 0.0));
        // On the diagonal, on the edges and corners, just inside and outside.
        let mut xs: Vec<f64> = vec![-0.1, 0.1, 0.0, 0.05, -0.0999999999999, 0.1000000000001];
        xs.extend((0..41).map(|k| -0.12 + 0.006 * k as f64));
        for &x in &xs {
            for &y in &xs {
                let (s, c) = down(x, y);
                assert_eq!(rect.blocks(&s, &c), mesh.blocks(&s, &c), "({x}, {y})");
                // Oblique rays too.
                let o = Vec3::new(0.3, -0.2, 1.0);
                assert_eq!(
                    rect.blocks(&o, &c),
                    mesh.blocks(&o, &c),
                    "from o to ({x}, {y})"
                );
            }
        }
        let (s, c) = down(0.05, 0.05);
        assert!(mesh.blocks(&s, &c));
        assert!(!mesh.blocks(&Vec3::new(0.0, 0.0, 1.0), &Vec3::new(0.0, 0.0, 0.5)));
        assert!(!mesh.blocks(&Vec3::new(-1.0, 0.0, 0.5), &Vec3::new(1.0, 0.0, 0.5)));
        assert!(!mesh.blocks(&Vec3::new(0.3, 0.0, 1.0), &Vec3::new(0.3, 0.0, 0.0)));
    }
}
