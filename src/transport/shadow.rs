//! Which wall samples an occluder can block from one scene point.
//!
//! A segment from the scene point `s` to a wall sample `p` that crosses an
//! occluder at `x` has `p` as the central projection of `x` from `s` onto the
//! wall plane. So only the samples inside the projection of the occluder's
//! convex hull can be blocked: per scene point, each convex piece (a rect, a
//! ball's box, one triangle of a mesh) is projected, bounded by a box on the
//! wall, and the exact [`Occluder::blocks`] test runs only on the samples in
//! that box (found through a bucket grid of the samples). It stays the only
//! decider, so `T` is the same as testing every pair.

use crate::optics::Vec3;
use crate::scene::occluder::triangle_blocks;
use crate::scene::{Occluder, Plane};

/// A convex piece of an occluder.
enum Piece {
    /// A rect or a ball, tested whole.
    Whole(Occluder),
    /// One triangle of a mesh.
    Triangle([Vec3; 3]),
}

impl Piece {
    /// Exactly what the occluder's own test says for this piece.
    #[inline]
    fn blocks(&self, s: &Vec3, p: &Vec3) -> bool {
        match self {
            Piece::Whole(o) => o.blocks(s, p),
            Piece::Triangle(t) => triangle_blocks(t, s, &(p - s)),
        }
    }
}

/// The wall samples sorted into a grid of cells on the wall plane, row-major,
/// so that one row of cells is one contiguous run of `order`.
struct Buckets {
    u0: f64,
    v0: f64,
    inv_u: f64,
    inv_v: f64,
    nu: usize,
    nv: usize,
    /// `order[start[c]..start[c + 1]]` are the samples in cell `c`.
    start: Vec<u32>,
    order: Vec<u32>,
}

impl Buckets {
    fn new(us: &[f64], vs: &[f64]) -> Self {
        let range = |x: &[f64]| {
            x.iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &v| {
                    (lo.min(v), hi.max(v))
                })
        };
        let ((u0, u1), (v0, v1)) = (range(us), range(vs));
        // About four samples per cell.
        let side = ((us.len() as f64 / 4.0).sqrt().ceil() as usize).clamp(1, 1024);
        let inv = |lo: f64, hi: f64| {
            if hi > lo {
                side as f64 / (hi - lo)
            } else {
                0.0
            }
        };
        let mut b = Buckets {
            u0,
            v0,
            inv_u: inv(u0, u1),
            inv_v: inv(v0, v1),
            nu: side,
            nv: side,
            start: vec![0; side * side + 1],
            order: vec![0; us.len()],
        };
        let cells: Vec<usize> = us
            .iter()
            .zip(vs)
            .map(|(&u, &v)| b.cell_v(v) * b.nu + b.cell_u(u))
            .collect();
        for &c in &cells {
            b.start[c + 1] += 1;
        }
        for c in 0..side * side {
            b.start[c + 1] += b.start[c];
        }
        let mut next = b.start.clone();
        for (j, &c) in cells.iter().enumerate() {
            b.order[next[c] as usize] = j as u32;
            next[c] += 1;
        }
        b
    }

    fn cell_u(&self, u: f64) -> usize {
        (((u - self.u0) * self.inv_u).floor().max(0.0) as usize).min(self.nu - 1)
    }

    fn cell_v(&self, v: f64) -> usize {
        (((v - self.v0) * self.inv_v).floor().max(0.0) as usize).min(self.nv - 1)
    }
}

/// A box `[u_min, u_max, v_min, v_max]` on the wall plane.
type Box2 = [f64; 4];

/// The occluders of a scene as convex pieces, with the wall samples' plane
/// coordinates: what [`Shadows::shade`] needs per scene point.
pub(super) struct Shadows {
    pieces: Vec<Piece>,
    /// Points whose convex hull holds each piece.
    hulls: Vec<Vec<Vec3>>,
    origin: Vec3,
    n: Vec3,
    u: Vec3,
    v: Vec3,
    us: Vec<f64>,
    vs: Vec<f64>,
    /// `None` when a sample is off the wall plane: then every pair is tested.
    buckets: Option<Buckets>,
}

impl Shadows {
    /// The pieces of `occluders` against the wall samples `points` of
    /// `plane`; `None` without an occluder.
    pub fn new(occluders: &[Occluder], plane: &Plane, points: &[Vec3]) -> Option<Self> {
        if occluders.is_empty() {
            return None;
        }
        let mut pieces = Vec::new();
        let mut hulls = Vec::new();
        for o in occluders {
            match o {
                Occluder::Rect {
                    center,
                    half_u,
                    half_v,
                } => {
                    hulls.push(
                        [(1.0, 1.0), (1.0, -1.0), (-1.0, 1.0), (-1.0, -1.0)]
                            .map(|(a, b)| center + half_u * a + half_v * b)
                            .to_vec(),
                    );
                    pieces.push(Piece::Whole(o.clone()));
                }
                Occluder::Sphere { center, radius } => {
                    let mut corners = Vec::with_capacity(8);
                    for k in 0..8 {
                        let sign = |bit: usize| if k >> bit & 1 == 1 { *radius } else { -radius };
                        corners.push(center + Vec3::new(sign(0), sign(1), sign(2)));
                    }
                    hulls.push(corners);
                    pieces.push(Piece::Whole(o.clone()));
                }
                Occluder::Mesh(mesh) => {
                    for t in mesh.triangles() {
                        hulls.push(t.to_vec());
                        pieces.push(Piece::Triangle(*t));
                    }
                }
            }
        }
        let (origin, n, u, v) = (plane.center, plane.normal, plane.u, plane.v);
        let us: Vec<f64> = points.iter().map(|p| u.dot(&(p - origin))).collect();
        let vs: Vec<f64> = points.iter().map(|p| v.dot(&(p - origin))).collect();
        let extent = us.iter().chain(&vs).fold(1.0f64, |m, x| m.max(x.abs()));
        let on_plane = points
            .iter()
            .all(|p| n.dot(&(p - origin)).abs() <= 1e-12 * extent);
        let buckets = (on_plane && !points.is_empty()).then(|| Buckets::new(&us, &vs));
        Some(Shadows {
            pieces,
            hulls,
            origin,
            n,
            u,
            v,
            us,
            vs,
            buckets,
        })
    }

    /// A box on the wall plane holding the projection from `s` of hull `k`,
    /// widened far beyond rounding and the occluders' own 1e-12 tolerance;
    /// `None` when the projection is unbounded (a hull point at or above
    /// `s`'s height over the wall).
    fn shadow_box(&self, s: &Vec3, hs: f64, k: usize) -> Option<Box2> {
        if hs.is_nan() || hs <= 0.0 {
            return None;
        }
        let mut b = [
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
        ];
        // The largest stretch `|dq/dx|` of the projection at a hull point.
        let mut stretch = 0.0f64;
        let hull = &self.hulls[k];
        let mid = hull.iter().sum::<Vec3>() / hull.len() as f64;
        let radius = hull.iter().fold(0.0f64, |r, x| r.max((x - mid).norm()));
        for x in hull {
            let hx = self.n.dot(&(x - self.origin));
            let gap = hs - hx;
            if gap.is_nan() || gap <= 1e-9 * hs {
                return None;
            }
            let lambda = hs / gap;
            let q = s + (x - s) * lambda - self.origin;
            let (qu, qv) = (self.u.dot(&q), self.v.dot(&q));
            b = [b[0].min(qu), b[1].max(qu), b[2].min(qv), b[3].max(qv)];
            stretch = stretch.max(lambda * (1.0 + (x - s).norm() / gap));
        }
        let size = b.iter().fold(1.0f64, |m, x| m.max(x.abs()));
        let margin = 1e-7 * (b[1] - b[0] + b[3] - b[2]) + 1e-9 * size + 1e-9 * radius * stretch;
        if !margin.is_finite() {
            return None;
        }
        Some([b[0] - margin, b[1] + margin, b[2] - margin, b[3] + margin])
    }

    /// Zeroes `base[j]` for every wall sample `j` (with `base[j] != 0`)
    /// whose segment from `s` some occluder blocks.
    pub fn shade(&self, s: &Vec3, points: &[Vec3], base: &mut [f64]) {
        let hs = self.n.dot(&(s - self.origin));
        let len = base.len().min(points.len());
        let (us, vs) = (&self.us[..len], &self.vs[..len]);
        for (k, piece) in self.pieces.iter().enumerate() {
            let (Some(grid), Some(b)) = (&self.buckets, self.shadow_box(s, hs, k)) else {
                for j in 0..len {
                    if base[j] != 0.0 && piece.blocks(s, &points[j]) {
                        base[j] = 0.0;
                    }
                }
                continue;
            };
            let (iu0, iu1) = (grid.cell_u(b[0]), grid.cell_u(b[1]));
            for iv in grid.cell_v(b[2])..=grid.cell_v(b[3]) {
                let row = iv * grid.nu;
                let run = grid.start[row + iu0] as usize..grid.start[row + iu1 + 1] as usize;
                for &j in &grid.order[run] {
                    let j = j as usize;
                    if j < len
                        && base[j] != 0.0
                        && (b[0]..=b[1]).contains(&us[j])
                        && (b[2]..=b[3]).contains(&vs[j])
                        && piece.blocks(s, &points[j])
                    {
                        base[j] = 0.0;
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::{Grid, Mesh, MeshSource};
    use std::sync::Arc;

    fn wall() -> Plane {
        Plane {
            center: Vec3::new(0.1, 0.0, 0.0),
            normal: Vec3::z(),
            u: Vec3::x(),
            v: Vec3::y(),
            size: [0.6, 0.5],
            grid: Grid { nu: 37, nv: 29 },
            supersample: 2,
        }
    }

    fn occluders() -> Vec<Occluder> {
        let tri = |a: [f64; 3], b: [f64; 3], c: [f64; 3]| [a, b, c].map(Vec3::from);
        vec![
            Occluder::Rect {
                center: Vec3::new(0.0, 0.05, 0.3),
                half_u: Vec3::new(0.05, 0.0, 0.02),
                half_v: Vec3::new(0.0, 0.08, 0.0),
            },
            // Standing on the wall, and reaching above some scene points.
            Occluder::Rect {
                center: Vec3::new(0.2, -0.1, 0.4),
                half_u: Vec3::new(0.0, 0.0, 0.4),
                half_v: Vec3::new(0.0, 0.03, 0.0),
            },
            Occluder::Sphere {
                center: Vec3::new(-0.1, -0.1, 0.2),
                radius: 0.04,
            },
            // A ball through the wall.
            Occluder::Sphere {
                center: Vec3::new(0.3, 0.2, 0.0),
                radius: 0.05,
            },
            Occluder::Mesh(Arc::new(Mesh::new(
                vec![
                    tri([0.1, 0.1, 0.5], [0.2, 0.1, 0.5], [0.1, 0.2, 0.45]),
                    tri([-0.2, 0.0, 0.1], [-0.1, 0.0, 0.6], [-0.15, 0.05, 0.3]),
                ],
                MeshSource {
                    path: "t.obj".into(),
                    scale: None,
                    offset: None,
                },
            ))),
        ]
    }

    #[test]
    fn shading_through_the_boxes_blocks_exactly_what_testing_every_pair_blocks() {
        let plane = wall();
        let points = plane.sample_points();
        let occ = occluders();
        let shadows = Shadows::new(&occ, &plane, &points).unwrap();
        assert!(shadows.buckets.is_some());
        let mut blocked = 0;
        for s in [
            Vec3::new(0.0, 0.0, 1.0),
            Vec3::new(-0.3, 0.2, 0.6),
            Vec3::new(0.4, -0.3, 0.35),
            Vec3::new(0.15, 0.12, 0.52),
            Vec3::new(0.0, 0.0, -0.2),
        ] {
            let mut fast = vec![1.0; points.len()];
            shadows.shade(&s, &points, &mut fast);
            for (j, p) in points.iter().enumerate() {
                let slow = occ.iter().any(|o| o.blocks(&s, p));
                assert_eq!(fast[j] == 0.0, slow, "s = {s:?}, p = {p:?}");
                blocked += slow as usize;
            }
        }
        assert!(blocked > 500, "{blocked}");
        assert!(Shadows::new(&[], &plane, &points).is_none());
    }

    #[test]
    fn samples_off_the_wall_plane_are_all_tested() {
        let plane = wall();
        let mut points = plane.sample_points();
        points[3].z = 0.01;
        let occ = occluders();
        let shadows = Shadows::new(&occ, &plane, &points).unwrap();
        assert!(shadows.buckets.is_none());
        let s = Vec3::new(0.0, 0.0, 1.0);
        let mut fast = vec![1.0; points.len()];
        shadows.shade(&s, &points, &mut fast);
        for (j, p) in points.iter().enumerate() {
            assert_eq!(fast[j] == 0.0, occ.iter().any(|o| o.blocks(&s, p)));
        }
    }
}
