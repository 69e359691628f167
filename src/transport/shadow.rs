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
//!
//! With area shadows (`[scene] shadows = "area"`) each scene sample stands
//! for its cell on the scene plane, and a wall sample keeps the fraction of
//! the cell it sees: the pieces are projected from the wall sample onto the
//! scene plane, clipped to the cell, and the area of their union is taken
//! (see [`area`]).

use crate::optics::Vec3;
use crate::scene::occluder::triangle_blocks;
use crate::scene::{Occluder, Plane};

pub(super) mod area;
mod faces;

use area::{Band, Cell, Cover, Polygon};

/// A convex piece of an occluder.
enum Piece {
    /// A rect or a ball, tested whole.
    Whole(Occluder),
    /// One triangle of a mesh.
    Triangle([Vec3; 3]),
    /// A convex planar polygon of a mesh's faces (area shadows only: see
    /// [`faces`]), its vertices in order.
    Polygon(Vec<Vec3>),
}

impl Piece {
    /// Exactly what the occluder's own test says for this piece.
    #[inline]
    fn blocks(&self, s: &Vec3, p: &Vec3) -> bool {
        match self {
            Piece::Whole(o) => o.blocks(s, p),
            Piece::Triangle(t) => triangle_blocks(t, s, &(p - s)),
            Piece::Polygon(v) => {
                (1..v.len() - 1).any(|k| triangle_blocks(&[v[0], v[k], v[k + 1]], s, &(p - s)))
            }
        }
    }
}

impl Piece {
    /// Its vertices in order when it is a polygon (a rect or a triangle).
    fn polygon(&self) -> Option<Vec<Vec3>> {
        match self {
            Piece::Whole(Occluder::Rect {
                center,
                half_u,
                half_v,
            }) => Some(
                [(1.0, 1.0), (-1.0, 1.0), (-1.0, -1.0), (1.0, -1.0)]
                    .map(|(a, b)| center + half_u * a + half_v * b)
                    .to_vec(),
            ),
            Piece::Triangle(t) => Some(t.to_vec()),
            Piece::Polygon(v) => Some(v.clone()),
            Piece::Whole(_) => None,
        }
    }

    /// Points whose convex hull holds it: a polygon's vertices, a ball's box.
    fn corners(&self) -> Vec<Vec3> {
        match self {
            Piece::Whole(Occluder::Sphere { center, radius }) => (0..8)
                .map(|k| {
                    let sign = |bit: usize| if k >> bit & 1 == 1 { *radius } else { -radius };
                    center + Vec3::new(sign(0), sign(1), sign(2))
                })
                .collect(),
            _ => self.polygon().unwrap_or_default(),
        }
    }
}

/// What [`cut_beyond`] leaves of a polygon.
enum Cut {
    /// Nothing of it lies beyond the scene plane: the piece as it is.
    Whole,
    /// The part at least `delta` on the wall's side, in order.
    Part(Vec<Vec3>),
    /// Nothing is left: it cannot block.
    Gone,
}

/// Polygon `verts` cut to where `toward . (x - origin) >= delta` when some
/// vertex lies beyond the scene plane (`toward`: its unit normal towards
/// the wall, `origin` a point of it).
///
/// Why: area shadows project a piece from the wall sample onto the scene
/// plane, exact only for a piece wholly between the planes; a piece
/// reaching beyond would take the point test of the cell's centre for the
/// whole cell, which depends on how a solid is cut into pieces
/// (docs/realphoto.md, "Area shadows").
fn cut_beyond(verts: &[Vec3], toward: &Vec3, origin: &Vec3, delta: f64) -> Cut {
    let h: Vec<f64> = verts.iter().map(|x| toward.dot(&(x - origin))).collect();
    if h.iter().all(|&h| h >= 0.0) {
        return Cut::Whole;
    }
    let mut out = Vec::with_capacity(verts.len() + 1);
    for i in 0..verts.len() {
        let j = (i + 1) % verts.len();
        let (a, b) = (h[i] - delta, h[j] - delta);
        if a >= 0.0 {
            out.push(verts[i]);
        }
        if (a >= 0.0) != (b >= 0.0) {
            let t = a / (a - b);
            out.push(verts[i] + (verts[j] - verts[i]) * t);
        }
    }
    if out.len() >= 3 {
        Cut::Part(out)
    } else {
        Cut::Gone
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

    /// Calls `f` with each sample `j` (below `us.len()`) whose `(us[j],
    /// vs[j])` lies in box `b`, found through the cells the box covers.
    fn each_in(&self, b: &Box2, us: &[f64], vs: &[f64], mut f: impl FnMut(usize)) {
        let (iu0, iu1) = (self.cell_u(b[0]), self.cell_u(b[1]));
        for iv in self.cell_v(b[2])..=self.cell_v(b[3]) {
            let row = iv * self.nu;
            let run = self.start[row + iu0] as usize..self.start[row + iu1 + 1] as usize;
            for &j in &self.order[run] {
                let j = j as usize;
                if j < us.len() && (b[0]..=b[1]).contains(&us[j]) && (b[2]..=b[3]).contains(&vs[j])
                {
                    f(j);
                }
            }
        }
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
    /// Each piece's vertices in order when it is a polygon (a rect or a
    /// triangle), for area shadows.
    polygons: Vec<Option<Vec<Vec3>>>,
    origin: Vec3,
    n: Vec3,
    u: Vec3,
    v: Vec3,
    us: Vec<f64>,
    vs: Vec<f64>,
    /// `None` when a sample is off the wall plane: then every pair is tested.
    buckets: Option<Buckets>,
    /// The scene plane's sample cell, for area shadows; `None`: point shadows.
    cell: Option<Cell>,
}

impl Shadows {
    /// The pieces of `occluders` against the wall samples `points` of
    /// `plane`, with area shadows over the sample cells of `scene` when it
    /// is given; `None` without an occluder.
    pub fn new(
        occluders: &[Occluder],
        plane: &Plane,
        points: &[Vec3],
        scene: Option<&Plane>,
    ) -> Option<Self> {
        if occluders.is_empty() {
            return None;
        }
        // Area shadows take a mesh with coincident faces as fewer, larger
        // pieces of the same union; point shadows always test its triangles.
        let pieces: Vec<Piece> = occluders
            .iter()
            .flat_map(|o| match o {
                Occluder::Mesh(mesh) => {
                    match scene.and_then(|_| faces::area_pieces(mesh.triangles())) {
                        Some(polygons) => polygons.into_iter().map(Piece::Polygon).collect(),
                        None => mesh
                            .triangles()
                            .iter()
                            .map(|t| Piece::Triangle(*t))
                            .collect(),
                    }
                }
                o => vec![Piece::Whole(o.clone())],
            })
            .collect();
        // Area shadows: a polygon reaching beyond the scene plane is cut to
        // the part on the wall's side (a segment ending on the scene plane
        // never meets what lies beyond it), a sliver `delta` off the plane
        // so that every vertex stays strictly between the planes.
        let pieces: Vec<Piece> = match scene {
            Some(sp) => {
                let side = sp.normal.dot(&(plane.center - sp.center)).signum();
                let toward = sp.normal * side;
                let reach = points
                    .iter()
                    .fold(0.0f64, |m, p| m.max(toward.dot(&(p - sp.center))));
                pieces
                    .into_iter()
                    .filter_map(|piece| match piece.polygon() {
                        Some(v) => match cut_beyond(&v, &toward, &sp.center, 2e-9 * reach) {
                            Cut::Whole => Some(piece),
                            Cut::Part(v) => Some(Piece::Polygon(v)),
                            Cut::Gone => None,
                        },
                        None => Some(piece),
                    })
                    .collect()
            }
            None => pieces,
        };
        if pieces.is_empty() {
            return None;
        }
        let polygons: Vec<Option<Vec<Vec3>>> = pieces.iter().map(Piece::polygon).collect();
        let hulls = pieces
            .iter()
            .zip(&polygons)
            .map(|(piece, polygon)| polygon.clone().unwrap_or_else(|| piece.corners()))
            .collect();
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
            polygons,
            origin,
            n,
            u,
            v,
            us,
            vs,
            buckets,
            cell: scene.map(Cell::of),
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
    /// whose segment from `s` some occluder blocks; with area shadows,
    /// scales it by the fraction of `s`'s cell the sample sees.
    pub fn shade(&self, s: &Vec3, points: &[Vec3], base: &mut [f64]) {
        if let Some(cell) = &self.cell {
            return self.shade_area(cell, s, points, base);
        }
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
            grid.each_in(&b, us, vs, |j| {
                if base[j] != 0.0 && piece.blocks(s, &points[j]) {
                    base[j] = 0.0;
                }
            });
        }
    }

    /// Point `x` cast from `s` onto the wall plane, in its `(u, v)`; `None`
    /// unless `x` lies strictly between `s` and the wall.
    fn cast(&self, s: &Vec3, x: &Vec3) -> Option<[f64; 2]> {
        let hs = self.n.dot(&(s - self.origin));
        let gap = hs - self.n.dot(&(x - self.origin));
        if !(hs > 0.0 && gap > 1e-9 * hs) {
            return None;
        }
        let q = s + (x - s) * (hs / gap) - self.origin;
        Some([self.u.dot(&q), self.v.dot(&q)])
    }

    /// Piece `k`'s [`Band`] for the cell centred on `s`; `None` when the
    /// piece is not a polygon or does not lie between the cell and the wall.
    fn band(&self, s: &Vec3, corners: &[Vec3; 4], k: usize) -> Option<Band> {
        let verts = self.polygons[k].as_ref()?;
        let cast_all = |from: &Vec3| -> Option<Vec<[f64; 2]>> {
            verts.iter().map(|x| self.cast(from, x)).collect()
        };
        let centre = cast_all(s)?;
        let [a, b, c, d] = corners;
        let corners = [cast_all(a)?, cast_all(b)?, cast_all(c)?, cast_all(d)?];
        Band::new(&centre, &corners)
    }

    /// Area shadows ([`Shadows::shade`]): each wall sample in some piece's
    /// shadow box from the cell's corners keeps `1 - f` of its value, `f`
    /// the covered fraction of the cell.
    fn shade_area(&self, cell: &Cell, s: &Vec3, points: &[Vec3], base: &mut [f64]) {
        let len = base.len().min(points.len());
        let corners = cell.corners(s);
        let heights = corners.map(|c| self.n.dot(&(c - self.origin)));
        // Each piece's shadow box over the whole cell; `None`: unbounded.
        let boxes: Vec<Option<Box2>> = (0..self.pieces.len())
            .map(|k| {
                let mut b = [
                    f64::INFINITY,
                    f64::NEG_INFINITY,
                    f64::INFINITY,
                    f64::NEG_INFINITY,
                ];
                for (c, &h) in corners.iter().zip(&heights) {
                    let e = self.shadow_box(c, h, k)?;
                    b = [
                        b[0].min(e[0]),
                        b[1].max(e[1]),
                        b[2].min(e[2]),
                        b[3].max(e[3]),
                    ];
                }
                Some(b)
            })
            .collect();
        let bands: Vec<Option<Band>> = (0..self.pieces.len())
            .map(|k| self.band(s, &corners, k))
            .collect();
        let mut polygons: Vec<Polygon> = Vec::new();
        let mut shade_one = |j: usize, base: &mut [f64]| {
            let (p, (u, v)) = (&points[j], (self.us[j], self.vs[j]));
            polygons.clear();
            for (k, piece) in self.pieces.iter().enumerate() {
                if let Some(b) = &boxes[k] {
                    if !(b[0]..=b[1]).contains(&u) || !(b[2]..=b[3]).contains(&v) {
                        continue;
                    }
                }
                match bands[k].as_ref().map_or(Cover::Part, |b| b.cover(u, v)) {
                    Cover::All => {
                        base[j] = 0.0;
                        return;
                    }
                    Cover::Nothing => continue,
                    Cover::Part => {}
                }
                let projected = self.polygons[k]
                    .as_ref()
                    .and_then(|v| cell.project(s, p, v));
                match projected {
                    Some(q) => {
                        if let Some(q) = cell.clip(&q) {
                            polygons.push(q);
                        }
                    }
                    // A ball, or a piece not wholly between the two planes:
                    // the point test at the sample decides the whole cell.
                    None if piece.blocks(s, p) => {
                        base[j] = 0.0;
                        return;
                    }
                    None => {}
                }
            }
            let covered = area::union_area(&polygons) / cell.area();
            if covered >= 1.0 - 1e-12 {
                base[j] = 0.0;
            } else if covered > 0.0 {
                base[j] *= 1.0 - covered;
            }
        };
        let union = boxes.iter().try_fold(
            [
                f64::INFINITY,
                f64::NEG_INFINITY,
                f64::INFINITY,
                f64::NEG_INFINITY,
            ],
            |a, b| {
                b.map(|b| {
                    [
                        a[0].min(b[0]),
                        a[1].max(b[1]),
                        a[2].min(b[2]),
                        a[3].max(b[3]),
                    ]
                })
            },
        );
        let (Some(grid), Some(b)) = (&self.buckets, union) else {
            for j in 0..len {
                if base[j] != 0.0 {
                    shade_one(j, base);
                }
            }
            return;
        };
        if b[0] > b[1] || b[2] > b[3] {
            return;
        }
        grid.each_in(&b, &self.us[..len], &self.vs[..len], |j| {
            if base[j] != 0.0 {
                shade_one(j, base);
            }
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::occluder::MeshSource;
    use crate::scene::{Grid, Mesh};
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

    /// A mesh of two triangles, the second reaching below some scene points.
    fn two_triangles() -> Occluder {
        let tri = |a: [f64; 3], b: [f64; 3], c: [f64; 3]| [a, b, c].map(Vec3::from);
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
        )))
    }

    fn occluders() -> Vec<Occluder> {
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
            two_triangles(),
        ]
    }

    #[test]
    fn shading_through_the_boxes_blocks_exactly_what_testing_every_pair_blocks() {
        let plane = wall();
        let points = plane.sample_points();
        let occ = occluders();
        let shadows = Shadows::new(&occ, &plane, &points, None).unwrap();
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
        assert!(Shadows::new(&[], &plane, &points, None).is_none());
    }

    #[test]
    fn samples_off_the_wall_plane_are_all_tested() {
        let plane = wall();
        let mut points = plane.sample_points();
        points[3].z = 0.01;
        let occ = occluders();
        let shadows = Shadows::new(&occ, &plane, &points, None).unwrap();
        assert!(shadows.buckets.is_none());
        let s = Vec3::new(0.0, 0.0, 1.0);
        let mut fast = vec![1.0; points.len()];
        shadows.shade(&s, &points, &mut fast);
        for (j, p) in points.iter().enumerate() {
            assert_eq!(fast[j] == 0.0, occ.iter().any(|o| o.blocks(&s, p)));
        }
    }

    /// The scene plane of the area tests: 8 x 8 cells at z = 1 facing the wall.
    fn screen() -> Plane {
        Plane {
            center: Vec3::new(0.0, 0.0, 1.0),
            normal: -Vec3::z(),
            u: Vec3::x(),
            v: -Vec3::y(),
            size: [0.8, 0.8],
            grid: Grid { nu: 8, nv: 8 },
            supersample: 1,
        }
    }

    /// Polygons wholly between the screen and the wall: a slanted rect, an
    /// overlapping copy of it, and two mesh triangles.
    fn polygons() -> Vec<Occluder> {
        let rect = |x: f64| Occluder::Rect {
            center: Vec3::new(x, 0.05, 0.3),
            half_u: Vec3::new(0.05, 0.0, 0.02),
            half_v: Vec3::new(0.0, 0.08, 0.0),
        };
        vec![rect(0.0), rect(0.03), two_triangles()]
    }

    /// Each wall sample's visible fraction of each cell, area shadows.
    fn area_fractions(occ: &[Occluder]) -> Vec<Vec<f64>> {
        let (plane, screen) = (wall(), screen());
        let points = plane.sample_points();
        let shadows = Shadows::new(occ, &plane, &points, Some(&screen)).unwrap();
        screen
            .sample_points()
            .iter()
            .map(|s| {
                let mut f = vec![1.0; points.len()];
                shadows.shade(s, &points, &mut f);
                f
            })
            .collect()
    }

    #[test]
    fn area_shadows_are_the_mean_of_point_shadows_over_each_cell() {
        let occ = polygons();
        let (plane, screen) = (wall(), screen());
        let points = plane.sample_points();
        let area = area_fractions(&occ);
        let n = 16;
        let (mut partial, mut worst, mut total) = (0, 0.0f64, 0.0);
        for (c, s) in screen.sample_points().iter().enumerate() {
            for (j, p) in points.iter().enumerate().step_by(3) {
                let mut seen = 0;
                for a in 0..n {
                    for b in 0..n {
                        let du = ((a as f64 + 0.5) / n as f64 - 0.5) * 0.1;
                        let dv = ((b as f64 + 0.5) / n as f64 - 0.5) * 0.1;
                        let q = s + screen.u * du + screen.v * dv;
                        seen += !occ.iter().any(|o| o.blocks(&q, p)) as usize;
                    }
                }
                let counted = seen as f64 / (n * n) as f64;
                let d = (area[c][j] - counted).abs();
                worst = worst.max(d);
                total += d;
                partial += (area[c][j] > 0.0 && area[c][j] < 1.0) as usize;
            }
        }
        let mean = total / (points.len().div_ceil(3) * 64) as f64;
        assert!(partial > 700, "{partial} pairs in a penumbra");
        assert!(worst < 0.1 && mean < 2e-3, "worst {worst}, mean {mean}");
    }

    #[test]
    fn area_shadows_move_continuously_with_the_occluder_where_point_shadows_jump() {
        let (plane, screen) = (wall(), screen());
        let points = plane.sample_points();
        let shift = |d: f64| -> Vec<Occluder> {
            polygons()
                .into_iter()
                .map(|o| match o {
                    Occluder::Rect {
                        center,
                        half_u,
                        half_v,
                    } => Occluder::Rect {
                        center: center + Vec3::new(d, 0.0, 0.0),
                        half_u,
                        half_v,
                    },
                    o => o,
                })
                .collect()
        };
        let (a, b) = (area_fractions(&shift(0.0)), area_fractions(&shift(1e-4)));
        let step = a
            .iter()
            .flatten()
            .zip(b.iter().flatten())
            .fold(0.0f64, |m, (x, y)| m.max((x - y).abs()));
        assert!(step > 0.0 && step < 0.01, "{step}");
        let point = |occ: &[Occluder]| -> Vec<f64> {
            let shadows = Shadows::new(occ, &plane, &points, None).unwrap();
            screen
                .sample_points()
                .iter()
                .flat_map(|s| {
                    let mut f = vec![1.0; points.len()];
                    shadows.shade(s, &points, &mut f);
                    f
                })
                .collect()
        };
        let (p, q) = (point(&shift(0.0)), point(&shift(1e-4)));
        assert!(p.iter().zip(&q).any(|(x, y)| (x - y).abs() == 1.0));
    }

    #[test]
    fn a_piece_reaching_beyond_the_scene_plane_shades_by_its_part_before_it() {
        // A slanted rect through the screen (z = 1): the part beyond it
        // cannot block; the rest is between the planes.
        let occ = vec![Occluder::Rect {
            center: Vec3::new(0.02, 0.03, 0.98),
            half_u: Vec3::new(0.12, 0.0, 0.05),
            half_v: Vec3::new(0.0, 0.1, 0.0),
        }];
        let (plane, screen) = (wall(), screen());
        let points = plane.sample_points();
        let area = area_fractions(&occ);
        let n = 16;
        let (mut partial, mut total, mut count) = (0, 0.0, 0);
        for (c, s) in screen.sample_points().iter().enumerate() {
            for (j, p) in points.iter().enumerate().step_by(3) {
                let mut seen = 0;
                for a in 0..n {
                    for b in 0..n {
                        let du = ((a as f64 + 0.5) / n as f64 - 0.5) * 0.1;
                        let dv = ((b as f64 + 0.5) / n as f64 - 0.5) * 0.1;
                        let q = s + screen.u * du + screen.v * dv;
                        seen += !occ[0].blocks(&q, p) as usize;
                    }
                }
                total += (area[c][j] - seen as f64 / (n * n) as f64).abs();
                count += 1;
                partial += (area[c][j] > 0.0 && area[c][j] < 1.0) as usize;
            }
        }
        let mean = total / count as f64;
        assert!(partial > 100, "{partial} pairs in a penumbra");
        assert!(mean < 2e-3, "mean {mean}");
        // Wholly beyond the screen: no shadow at all.
        let behind = vec![Occluder::Rect {
            center: Vec3::new(0.0, 0.0, 1.1),
            half_u: Vec3::new(0.1, 0.0, 0.0),
            half_v: Vec3::new(0.0, 0.1, 0.0),
        }];
        let shadows = Shadows::new(&behind, &plane, &points, Some(&screen));
        assert!(shadows.is_none());
    }

    #[test]
    fn a_ball_or_a_piece_not_between_the_planes_shades_the_whole_cell_by_its_centre() {
        let (plane, screen) = (wall(), screen());
        let points = plane.sample_points();
        let occ = occluders();
        let shadows = Shadows::new(&occ[2..4], &plane, &points, Some(&screen)).unwrap();
        for s in screen.sample_points() {
            let mut f = vec![1.0; points.len()];
            shadows.shade(&s, &points, &mut f);
            for (j, p) in points.iter().enumerate() {
                let blocked = occ[2..4].iter().any(|o| o.blocks(&s, p));
                assert_eq!(f[j], if blocked { 0.0 } else { 1.0 });
            }
        }
    }
}
