//! Area shadows: the fraction of a scene sample's cell that a wall sample
//! cannot see behind the occluders.
//!
//! Why: a point source's shadow edge jumps from one wall sample to the next
//! as an occluder moves; a cell's covered fraction moves continuously, so a
//! misfit over the occluder's position is smooth (docs/realphoto.md, "Area
//! shadows"). A segment from wall sample `p` to a point `s'` of the scene
//! plane meets a convex piece lying strictly between the two planes exactly
//! when `s'` is in the piece's central projection from `p` onto the scene
//! plane: a convex polygon. The covered part of the cell is the union of
//! those polygons clipped to the cell.

use crate::optics::Vec3;
use crate::scene::Plane;

/// Vertices a polygon here can have: a pentagon (a quadrilateral cut by the
/// scene plane, [`super::Shadows`]) clipped by the cell's four sides gains
/// at most one vertex per side.
const MAX: usize = 9;

/// A convex polygon in cell coordinates (metres along the scene plane's
/// `u` and `v` from the sample), at most [`MAX`] vertices, in order.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Polygon {
    n: usize,
    p: [[f64; 2]; MAX],
}

impl Polygon {
    fn new() -> Self {
        Polygon {
            n: 0,
            p: [[0.0; 2]; MAX],
        }
    }

    fn push(&mut self, q: [f64; 2]) {
        if self.n < MAX {
            self.p[self.n] = q;
            self.n += 1;
        }
    }

    fn points(&self) -> &[[f64; 2]] {
        &self.p[..self.n]
    }

    /// Its edges, each from a vertex to the next.
    fn edges(&self) -> impl Iterator<Item = ([f64; 2], [f64; 2])> + '_ {
        let p = self.points();
        (0..p.len()).map(move |i| (p[i], p[(i + 1) % p.len()]))
    }

    /// Unsigned area (the shoelace formula).
    pub(crate) fn area(&self) -> f64 {
        0.5 * self
            .edges()
            .map(|(a, b)| a[0] * b[1] - b[0] * a[1])
            .sum::<f64>()
            .abs()
    }

    /// The `y` range where the vertical line at `x` crosses it, when it
    /// does (`x` never at a vertex: the caller takes slab midpoints).
    fn span_at(&self, x: f64) -> Option<(f64, f64)> {
        let mut span: Option<(f64, f64)> = None;
        for (a, b) in self.edges() {
            if a[0] == b[0] || (a[0] - x) * (b[0] - x) > 0.0 {
                continue;
            }
            let y = a[1] + (x - a[0]) * (b[1] - a[1]) / (b[0] - a[0]);
            span = Some(span.map_or((y, y), |(lo, hi)| (lo.min(y), hi.max(y))));
        }
        span
    }

    /// The part of it where `k * q[axis] <= limit` (one Sutherland-Hodgman pass).
    fn clip_side(&self, axis: usize, k: f64, limit: f64) -> Self {
        let mut out = Polygon::new();
        let inside = |q: &[f64; 2]| k * q[axis] <= limit;
        for (a, b) in self.edges() {
            let (ia, ib) = (inside(&a), inside(&b));
            if ia {
                out.push(a);
            }
            if ia != ib {
                let t = (limit - k * a[axis]) / (k * (b[axis] - a[axis]));
                out.push([a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])]);
            }
        }
        out
    }
}

/// A scene sample's cell: the scene plane's frame and the cell's half sizes.
#[derive(Debug, Clone)]
pub(crate) struct Cell {
    n: Vec3,
    u: Vec3,
    v: Vec3,
    /// A point of the scene plane.
    origin: Vec3,
    half: [f64; 2],
}

impl Cell {
    /// The sub-sample cell of `plane`: an element divided `m x m`.
    pub(crate) fn of(plane: &Plane) -> Self {
        let m = plane.supersample.max(1) as f64;
        Cell {
            n: plane.normal,
            u: plane.u,
            v: plane.v,
            origin: plane.center,
            half: [
                plane.size[0] / (plane.grid.nu as f64 * m * 2.0),
                plane.size[1] / (plane.grid.nv as f64 * m * 2.0),
            ],
        }
    }

    /// The cell's area, square metres.
    pub(crate) fn area(&self) -> f64 {
        4.0 * self.half[0] * self.half[1]
    }

    /// The corners of the cell centred on sample `s`.
    pub(crate) fn corners(&self, s: &Vec3) -> [Vec3; 4] {
        let (du, dv) = (self.u * self.half[0], self.v * self.half[1]);
        [s - du - dv, s + du - dv, s + du + dv, s - du + dv]
    }

    /// The convex piece with vertices `verts` (in order around it) projected
    /// from wall sample `p` onto the scene plane, in coordinates about `s`;
    /// `None` unless every vertex lies strictly between `p` and the plane.
    pub(crate) fn project(&self, s: &Vec3, p: &Vec3, verts: &[Vec3]) -> Option<Polygon> {
        let height = self.n.dot(&(self.origin - p));
        let mut out = Polygon::new();
        for x in verts {
            let lambda = height / self.n.dot(&(x - p));
            if !(lambda.is_finite() && lambda > 1.0 + 1e-9) {
                return None;
            }
            let q = p + (x - p) * lambda - s;
            out.push([self.u.dot(&q), self.v.dot(&q)]);
        }
        Some(out)
    }

    /// `q` clipped to the cell; `None` when nothing of it is inside.
    pub(crate) fn clip(&self, q: &Polygon) -> Option<Polygon> {
        let [a, b] = self.half;
        let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
        for p in q.points() {
            for i in 0..2 {
                lo[i] = lo[i].min(p[i]);
                hi[i] = hi[i].max(p[i]);
            }
        }
        if hi[0] <= -a || lo[0] >= a || hi[1] <= -b || lo[1] >= b {
            return None;
        }
        let c = q
            .clip_side(0, 1.0, a)
            .clip_side(0, -1.0, a)
            .clip_side(1, 1.0, b)
            .clip_side(1, -1.0, b);
        (c.n >= 3).then_some(c)
    }
}

/// Where a piece certainly covers all of a cell or none of it, seen from a
/// wall sample: the piece's shadow on the wall cast from the cell's centre,
/// with `r`, how far its vertices move when cast from the cell's corners.
///
/// Why: every polygon cast from a point of the cell has its vertices within
/// `r` of these (the cell's image is the hull of its corners' images), so it
/// lies within `r` of this one; a wall sample deeper than `r` inside sees
/// none of the cell, one farther than `r` outside sees all of it, and only
/// the band between needs the exact area.
pub(crate) struct Band {
    /// Inward unit normal and offset of each edge: `n . q + c` is the
    /// distance of `q` inside the edge's line.
    edges: [[f64; 3]; 4],
    n: usize,
    r: f64,
}

/// What a [`Band`] says of a wall sample.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Cover {
    /// The piece hides the whole cell.
    All,
    /// The piece hides none of it.
    Nothing,
    /// Take the exact area.
    Part,
}

impl Band {
    /// From the piece's vertices (3 or 4, in order) cast onto the wall from
    /// the cell's centre, `centre`, and from its corners, `corners[c]`;
    /// `None` for a polygon of no area.
    pub(crate) fn new(centre: &[[f64; 2]], corners: &[Vec<[f64; 2]>; 4]) -> Option<Band> {
        let m = centre.len();
        if !(3..=4).contains(&m) || corners.iter().any(|c| c.len() != m) {
            return None;
        }
        let twice_area: f64 = (0..m)
            .map(|i| {
                let (a, b) = (centre[i], centre[(i + 1) % m]);
                a[0] * b[1] - b[0] * a[1]
            })
            .sum();
        if twice_area == 0.0 || twice_area.is_nan() {
            return None;
        }
        let sign = twice_area.signum();
        let mut band = Band {
            edges: [[0.0; 3]; 4],
            n: 0,
            r: 0.0,
        };
        for i in 0..m {
            let (a, b) = (centre[i], centre[(i + 1) % m]);
            let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
            let len = dx.hypot(dy);
            if len > 0.0 {
                let (nx, ny) = (-dy * sign / len, dx * sign / len);
                band.edges[band.n] = [nx, ny, -(nx * a[0] + ny * a[1])];
                band.n += 1;
            }
            for c in corners {
                band.r = band.r.max((c[i][0] - a[0]).hypot(c[i][1] - a[1]));
            }
        }
        // Far beyond rounding, against the exact test's tolerance.
        let size = centre
            .iter()
            .fold(0.0f64, |s, q| s.max(q[0].abs()).max(q[1].abs()));
        band.r = band.r * (1.0 + 1e-9) + 1e-12 * size.max(1.0);
        band.r.is_finite().then_some(band)
    }

    /// Whether the piece hides all, none or part of the cell from the wall
    /// sample at `(u, v)`.
    pub(crate) fn cover(&self, u: f64, v: f64) -> Cover {
        let inside = self.edges[..self.n]
            .iter()
            .map(|e| e[0] * u + e[1] * v + e[2])
            .fold(f64::INFINITY, f64::min);
        if inside > self.r {
            Cover::All
        } else if inside < -self.r {
            Cover::Nothing
        } else {
            Cover::Part
        }
    }
}

/// Where segments `a0 a1` and `b0 b1` cross, its `x`; `None` when they do
/// not (or are parallel: their end points are vertices already).
fn crossing_x(a0: [f64; 2], a1: [f64; 2], b0: [f64; 2], b1: [f64; 2]) -> Option<f64> {
    let r = [a1[0] - a0[0], a1[1] - a0[1]];
    let s = [b1[0] - b0[0], b1[1] - b0[1]];
    let den = r[0] * s[1] - r[1] * s[0];
    if den == 0.0 {
        return None;
    }
    let w = [b0[0] - a0[0], b0[1] - a0[1]];
    let t = (w[0] * s[1] - w[1] * s[0]) / den;
    let u = (w[0] * r[1] - w[1] * r[0]) / den;
    ((0.0..=1.0).contains(&t) && (0.0..=1.0).contains(&u)).then(|| a0[0] + t * r[0])
}

/// The area of the union of convex polygons.
///
/// Exact: between consecutive `x` of the vertices and edge crossings no two
/// edges cross, so the union's height is linear in `x` across each slab and
/// its value at the slab's middle times the slab's width is the slab's area.
pub(crate) fn union_area(polygons: &[Polygon]) -> f64 {
    match polygons {
        [] => 0.0,
        [one] => one.area(),
        _ => {
            let mut xs: Vec<f64> = Vec::new();
            for (i, a) in polygons.iter().enumerate() {
                xs.extend(a.points().iter().map(|p| p[0]));
                for b in &polygons[i + 1..] {
                    for (a0, a1) in a.edges() {
                        for (b0, b1) in b.edges() {
                            xs.extend(crossing_x(a0, a1, b0, b1));
                        }
                    }
                }
            }
            xs.sort_unstable_by(f64::total_cmp);
            xs.dedup();
            let mut spans: Vec<(f64, f64)> = Vec::with_capacity(polygons.len());
            let mut area = 0.0;
            for w in xs.windows(2) {
                let width = w[1] - w[0];
                if width <= 0.0 {
                    continue;
                }
                let x = 0.5 * (w[0] + w[1]);
                spans.clear();
                spans.extend(polygons.iter().filter_map(|p| p.span_at(x)));
                spans.sort_unstable_by(|a, b| a.0.total_cmp(&b.0));
                let (mut length, mut reach) = (0.0, f64::NEG_INFINITY);
                for &(lo, hi) in &spans {
                    let lo = lo.max(reach);
                    if hi > lo {
                        length += hi - lo;
                    }
                    reach = reach.max(hi);
                }
                area += width * length;
            }
            area
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn poly(p: &[[f64; 2]]) -> Polygon {
        let mut out = Polygon::new();
        p.iter().for_each(|q| out.push(*q));
        out
    }

    fn rect(x0: f64, y0: f64, x1: f64, y1: f64) -> Polygon {
        poly(&[[x0, y0], [x1, y0], [x1, y1], [x0, y1]])
    }

    /// The covered fraction of `[x0, x1] x [y0, y1]` by counting the
    /// centres of an `n x n` grid inside any polygon (convex: every edge
    /// on the same side).
    fn counted(polygons: &[Polygon], n: usize, x0: f64, x1: f64, y0: f64, y1: f64) -> f64 {
        let inside = |p: &Polygon, q: [f64; 2]| {
            let sides: Vec<f64> = p
                .edges()
                .map(|(a, b)| (b[0] - a[0]) * (q[1] - a[1]) - (b[1] - a[1]) * (q[0] - a[0]))
                .collect();
            sides.iter().all(|&s| s >= 0.0) || sides.iter().all(|&s| s <= 0.0)
        };
        let mut hits = 0;
        for i in 0..n {
            for k in 0..n {
                let q = [
                    x0 + (x1 - x0) * (i as f64 + 0.5) / n as f64,
                    y0 + (y1 - y0) * (k as f64 + 0.5) / n as f64,
                ];
                hits += polygons.iter().any(|p| inside(p, q)) as usize;
            }
        }
        hits as f64 / (n * n) as f64
    }

    #[test]
    fn the_union_counts_an_overlap_once_and_abutting_pieces_as_one() {
        let a = rect(0.0, 0.0, 2.0, 1.0);
        assert!((union_area(&[a, a]) - 2.0).abs() < 1e-12);
        let (l, r) = (rect(0.0, 0.0, 1.0, 1.0), rect(1.0, 0.0, 3.0, 1.0));
        assert!((union_area(&[l, r]) - 3.0).abs() < 1e-12);
        // Two squares crossing as a plus sign: 2 + 2 - 1.
        let (h, v) = (rect(-1.0, -0.5, 1.0, 0.5), rect(-0.5, -1.0, 0.5, 1.0));
        assert!((union_area(&[h, v]) - 3.0).abs() < 1e-12);
        // A triangle over a square's corner: 1 + 0.5 - 0.25.
        let t = poly(&[[0.5, 0.5], [1.5, 0.5], [0.5, 1.5]]);
        let sq = rect(0.0, 0.0, 1.0, 1.0);
        assert!((union_area(&[sq, t]) - 1.25).abs() < 1e-12);
    }

    #[test]
    fn clipping_keeps_the_part_inside_the_cell() {
        let cell = Cell {
            n: Vec3::z(),
            u: Vec3::x(),
            v: Vec3::y(),
            origin: Vec3::zeros(),
            half: [0.5, 0.25],
        };
        let big = rect(-3.0, -3.0, 3.0, 3.0);
        assert!((cell.clip(&big).unwrap().area() - cell.area()).abs() < 1e-15);
        assert!(cell.clip(&rect(0.5, -1.0, 2.0, 1.0)).is_none());
        // A diamond through the cell's centre: its part inside is a hexagon.
        let d = poly(&[[0.0, -0.5], [0.5, 0.0], [0.0, 0.5], [-0.5, 0.0]]);
        let c = cell.clip(&d).unwrap();
        assert!(
            (c.area() - (0.5 - 2.0 * 0.25 * 0.25)).abs() < 1e-15,
            "{}",
            c.area()
        );
        // A piece straddling the scene plane is not projected.
        let p = Vec3::new(0.0, 0.0, 1.0);
        let under = [
            Vec3::new(0.0, 0.0, 0.5),
            Vec3::new(0.1, 0.0, -0.1),
            Vec3::new(0.0, 0.1, 0.5),
        ];
        assert!(cell.project(&Vec3::zeros(), &p, &under).is_none());
        // Half-way up, a piece projects at twice its size.
        let mid = [
            Vec3::new(0.1, 0.0, 0.5),
            Vec3::new(0.2, 0.0, 0.5),
            Vec3::new(0.1, 0.1, 0.5),
        ];
        let q = cell.project(&Vec3::zeros(), &p, &mid).unwrap();
        assert!((q.area() - 4.0 * 0.005).abs() < 1e-15);
    }

    fn convex() -> impl Strategy<Value = Polygon> {
        // Points on an ellipse at sorted angles: a convex polygon.
        (
            -1.0..1.0f64,
            -1.0..1.0f64,
            0.05..1.5f64,
            0.05..1.5f64,
            proptest::collection::vec(0.0..std::f64::consts::TAU, 3..=6),
        )
            .prop_map(|(cx, cy, rx, ry, mut t)| {
                t.sort_by(f64::total_cmp);
                poly(
                    &t.iter()
                        .map(|a| [cx + rx * a.cos(), cy + ry * a.sin()])
                        .collect::<Vec<_>>(),
                )
            })
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]
        /// The slab union against counting a fine grid of points.
        #[test]
        fn the_union_area_agrees_with_counting_points(ps in proptest::collection::vec(convex(), 1..=4)) {
            let exact = union_area(&ps);
            let grid = counted(&ps, 200, -2.5, 2.5, -2.5, 2.5) * 25.0;
            prop_assert!((exact - grid).abs() < 0.06, "exact {exact}, counted {grid}");
        }
    }
}
