//! Area shadows' pieces of a mesh with coincident faces: its triangles with
//! the copies dropped, the internal faces of a closed solid dropped, and
//! coplanar neighbours merged into convex quadrilaterals.
//!
//! Why: a voxel editor's export writes every cube's 12 triangles, so each
//! face two cubes share is there twice, inside the solid. Area shadows take
//! the union of every piece's projection (docs/realphoto.md, "Area
//! shadows"): exact whatever the pieces, but the many small pieces rarely
//! cover a whole cell alone, and each one adds to the union. The union of
//! the projections is the projection of the union of the pieces, so any
//! pieces with the same union give the same shadow:
//!
//! - a copy of a face adds nothing;
//! - a face inside a closed solid adds nothing: a segment between two points
//!   outside the solid that meets it passes through the solid, so it meets
//!   the solid's surface (the faces that remain) as well;
//! - two coplanar convex pieces sharing an edge whose union is convex are
//!   that union.
//!
//! A mesh without coincident faces keeps its triangles as they are, so its
//! `T` does not change; point shadows never use these pieces.

use std::collections::HashMap;

use crate::optics::Vec3;

/// Most triangles whose internal faces are looked for: each test casts a ray
/// against every face (the copies are dropped whatever the size).
const MAX_SEARCHED: usize = 20_000;

/// Relative tolerance of "coplanar" and "collinear": far above the rounding
/// of coordinates on one grid, far below anything that moves a shadow.
const FLAT: f64 = 1e-12;

/// The mesh's pieces for area shadows: convex planar polygons (3 or 4
/// vertices, in order) with the same union as `triangles` for any segment
/// between two points outside the mesh's solid; `None` when the mesh has no
/// coincident faces (then its triangles are its pieces).
pub(crate) fn area_pieces(triangles: &[[Vec3; 3]]) -> Option<Vec<Vec<Vec3>>> {
    let mut mesh = Indexed::new(triangles);
    mesh.pair_triangles();
    let mut groups: HashMap<Vec<u32>, Vec<usize>> = HashMap::new();
    for (f, face) in mesh.faces.iter().enumerate() {
        let mut key = face.clone();
        key.sort_unstable();
        groups.entry(key).or_default().push(f);
    }
    if groups.values().all(|g| g.len() == 1) {
        return None;
    }
    let closed = triangles.len() <= MAX_SEARCHED && mesh.closed_mod_2();
    // With a closed surface, the faces an odd number of times are the
    // solid's surface (mod 2 the copies cancel and it stays closed).
    let surface: Vec<usize> = if closed {
        groups
            .values()
            .filter(|g| g.len() % 2 == 1)
            .map(|g| g[0])
            .collect()
    } else {
        Vec::new()
    };
    let fans: Vec<[Vec3; 3]> = surface.iter().flat_map(|&f| mesh.fan(f)).collect();
    let mut keep: Vec<usize> = groups
        .values()
        .filter(|g| !(closed && g.len() % 2 == 0 && mesh.inside(g[0], &fans)))
        .map(|g| g[0])
        .collect();
    keep.sort_unstable();
    mesh.faces = keep.iter().map(|&f| mesh.faces[f].clone()).collect();
    mesh.merge_coplanar();
    Some(
        mesh.faces
            .iter()
            .map(|f| f.iter().map(|&i| mesh.points[i as usize]).collect())
            .collect(),
    )
}

/// A mesh as faces over shared vertices (equal when every coordinate is).
struct Indexed {
    points: Vec<Vec3>,
    /// Convex planar polygons, vertex indices in order.
    faces: Vec<Vec<u32>>,
}

impl Indexed {
    fn new(triangles: &[[Vec3; 3]]) -> Self {
        let mut index: HashMap<[u64; 3], u32> = HashMap::new();
        let mut points = Vec::new();
        let mut id = |p: &Vec3| -> u32 {
            // 0.0 and -0.0 are one point.
            let key = [p.x, p.y, p.z].map(|x| (x + 0.0).to_bits());
            *index.entry(key).or_insert_with(|| {
                points.push(*p);
                (points.len() - 1) as u32
            })
        };
        let faces = triangles
            .iter()
            .map(|t| t.iter().map(&mut id).collect())
            .collect();
        Indexed { points, faces }
    }

    fn at(&self, i: u32) -> Vec3 {
        self.points[i as usize]
    }

    /// Face `f`'s unit normal (Newell's), and its largest edge length.
    fn plane(&self, f: &[u32]) -> (Vec3, f64) {
        let mut n = Vec3::zeros();
        let mut size = 0.0f64;
        for k in 0..f.len() {
            let (a, b) = (self.at(f[k]), self.at(f[(k + 1) % f.len()]));
            n += a.cross(&b);
            size = size.max((b - a).norm());
        }
        (n.normalize(), size)
    }

    /// The polygon `cycle` with its collinear vertices dropped, when it is
    /// strictly convex and flat (normal `n`, edges up to `size`) with at
    /// most 4 vertices.
    fn convex(&self, cycle: &[u32], n: &Vec3, size: f64) -> Option<Vec<u32>> {
        let m = cycle.len();
        let mut out = Vec::with_capacity(m);
        let mut sign = 0.0f64;
        for k in 0..m {
            let (a, b, c) = (
                self.at(cycle[(k + m - 1) % m]),
                self.at(cycle[k]),
                self.at(cycle[(k + 1) % m]),
            );
            let turn = (b - a).cross(&(c - b)).dot(n);
            if turn.abs() <= FLAT * size * size {
                continue;
            }
            if sign * turn < 0.0 {
                return None;
            }
            sign = turn.signum();
            out.push(cycle[k]);
        }
        (3..=4).contains(&out.len()).then_some(out)
    }

    /// Whether the points `extra` lie in face `f`'s plane.
    fn flat_with(&self, f: &[u32], extra: &[u32]) -> bool {
        let (n, size) = self.plane(f);
        let o = self.at(f[0]);
        extra
            .iter()
            .all(|&i| n.dot(&(self.at(i) - o)).abs() <= FLAT * size)
    }

    /// Faces `f` and `g` joined along their shared edge when they are
    /// coplanar and their union is a convex polygon of at most 4 vertices.
    fn join(&self, f: &[u32], g: &[u32]) -> Option<Vec<u32>> {
        let (nf, mf) = (f.len(), g.len());
        for i in 0..nf {
            let (a, b) = (f[i], f[(i + 1) % nf]);
            // The shared edge runs b -> a in g when both are oriented alike,
            // a -> b when not.
            let Some(j) = (0..mf).find(|&j| {
                let (c, d) = (g[j], g[(j + 1) % mf]);
                (c, d) == (b, a) || (c, d) == (a, b)
            }) else {
                continue;
            };
            // g's other vertices in the order that walks round g from a to b.
            let forward = g[j] == b;
            let rest: Vec<u32> = if forward {
                (2..mf).map(|k| g[(j + k) % mf]).collect()
            } else {
                (2..mf).map(|k| g[(j + mf + 1 - k) % mf]).collect()
            };
            if rest.iter().any(|v| f.contains(v)) || !self.flat_with(f, &rest) {
                return None;
            }
            let mut cycle: Vec<u32> = Vec::with_capacity(nf + rest.len());
            cycle.extend((0..=i).map(|k| f[k]));
            cycle.extend(&rest);
            cycle.extend((i + 1..nf).map(|k| f[k]));
            let (n, size) = self.plane(f);
            let size = size.max(self.plane(g).1);
            return self.convex(&cycle, &n, size);
        }
        None
    }

    /// Joins pairs of triangles into quadrilaterals, each triangle with the
    /// first neighbour it makes a convex one with: a square split either way
    /// becomes the same four vertices, so two copies of it are found equal.
    fn pair_triangles(&mut self) {
        let faces = std::mem::take(&mut self.faces);
        let mut by_edge: HashMap<(u32, u32), Vec<usize>> = HashMap::new();
        for (f, face) in faces.iter().enumerate() {
            for k in 0..3 {
                let (a, b) = (face[k], face[(k + 1) % 3]);
                by_edge.entry((a.min(b), a.max(b))).or_default().push(f);
            }
        }
        let mut used = vec![false; faces.len()];
        for f in 0..faces.len() {
            if used[f] {
                continue;
            }
            used[f] = true;
            let mut key = faces[f].clone();
            key.sort_unstable();
            let mut joined = None;
            'edges: for k in 0..3 {
                let (a, b) = (faces[f][k], faces[f][(k + 1) % 3]);
                for &g in &by_edge[&(a.min(b), a.max(b))] {
                    let mut other = faces[g].clone();
                    other.sort_unstable();
                    if used[g] || other == key {
                        continue;
                    }
                    if let Some(q) = self.join(&faces[f], &faces[g]) {
                        used[g] = true;
                        joined = Some(q);
                        break 'edges;
                    }
                }
            }
            self.faces.push(joined.unwrap_or_else(|| faces[f].clone()));
        }
    }

    /// Whether every edge is on an even number of faces: the faces are then
    /// the surface of a solid (mod 2: a point is inside when a ray from it
    /// crosses them an odd number of times).
    fn closed_mod_2(&self) -> bool {
        let mut count: HashMap<(u32, u32), usize> = HashMap::new();
        for face in &self.faces {
            for k in 0..face.len() {
                let (a, b) = (face[k], face[(k + 1) % face.len()]);
                *count.entry((a.min(b), a.max(b))).or_default() += 1;
            }
        }
        count.values().all(|c| c % 2 == 0)
    }

    /// Face `f` as triangles fanned from its first vertex.
    fn fan(&self, f: usize) -> Vec<[Vec3; 3]> {
        let face = &self.faces[f];
        (1..face.len() - 1)
            .map(|k| [self.at(face[0]), self.at(face[k]), self.at(face[k + 1])])
            .collect()
    }

    /// Whether face `f` lies inside the solid whose surface is `surface`:
    /// points just off both its sides, at its centroid and near each
    /// vertex, all inside. `false` when a ray cannot say.
    fn inside(&self, f: usize, surface: &[[Vec3; 3]]) -> bool {
        let face = &self.faces[f];
        let (n, size) = self.plane(face);
        let centroid = face.iter().map(|&i| self.at(i)).sum::<Vec3>() / face.len() as f64;
        let eps = 1e-6 * size;
        std::iter::once(centroid)
            .chain(
                face.iter()
                    .map(|&i| self.at(i) + (centroid - self.at(i)) * 0.01),
            )
            .flat_map(|p| [p + n * eps, p - n * eps])
            .all(|q| parity(&q, surface) == Some(true))
    }

    /// Merges coplanar faces that share an edge into convex polygons of at
    /// most 4 vertices, until none is left to merge.
    fn merge_coplanar(&mut self) {
        loop {
            let mut by_edge: HashMap<(u32, u32), Vec<usize>> = HashMap::new();
            for (f, face) in self.faces.iter().enumerate() {
                for k in 0..face.len() {
                    let (a, b) = (face[k], face[(k + 1) % face.len()]);
                    by_edge.entry((a.min(b), a.max(b))).or_default().push(f);
                }
            }
            let mut gone = vec![false; self.faces.len()];
            let mut merged = 0;
            for f in 0..self.faces.len() {
                if gone[f] {
                    continue;
                }
                let face = self.faces[f].clone();
                'edges: for k in 0..face.len() {
                    let (a, b) = (face[k], face[(k + 1) % face.len()]);
                    for &g in &by_edge[&(a.min(b), a.max(b))] {
                        if g == f || gone[g] {
                            continue;
                        }
                        if let Some(q) = self.join(&self.faces[f], &self.faces[g]) {
                            self.faces[f] = q;
                            gone[g] = true;
                            merged += 1;
                            break 'edges;
                        }
                    }
                }
            }
            if merged == 0 {
                return;
            }
            let mut k = 0;
            self.faces.retain(|_| {
                k += 1;
                !gone[k - 1]
            });
        }
    }
}

/// Whether `q` is inside the surface `triangles` (mod 2), from a ray that
/// crosses no edge; `None` when none of a few rays is clear.
fn parity(q: &Vec3, triangles: &[[Vec3; 3]]) -> Option<bool> {
    const RAYS: [[f64; 3]; 4] = [
        [0.5773, 0.6284, 0.5213],
        [-0.3121, 0.8067, -0.5017],
        [0.7012, -0.2113, -0.6748],
        [-0.6199, -0.4387, 0.6507],
    ];
    'rays: for d in RAYS {
        let d = Vec3::from(d).normalize();
        let mut odd = false;
        for t in triangles {
            let (e1, e2) = (t[1] - t[0], t[2] - t[0]);
            let p = d.cross(&e2);
            let det = e1.dot(&p);
            let scale = e1.norm() * e2.norm();
            if det.abs() <= 1e-9 * scale {
                // Along the triangle's plane: clear only when off it.
                let off = (q - t[0]).dot(&e1.cross(&e2)) / scale.max(f64::MIN_POSITIVE);
                if off.abs() <= 1e-9 * e1.norm().max(e2.norm()) {
                    continue 'rays;
                }
                continue;
            }
            let s = q - t[0];
            let u = s.dot(&p) / det;
            let qv = s.cross(&e1);
            let v = d.dot(&qv) / det;
            let dist = e2.dot(&qv) / det;
            let edge = 1e-9;
            let near = |x: f64| x.abs() <= edge;
            if near(u) || near(v) || near(1.0 - u - v) {
                if u > -edge && v > -edge && u + v < 1.0 + edge && dist > 0.0 {
                    continue 'rays;
                }
                continue;
            }
            if u > 0.0 && v > 0.0 && u + v < 1.0 && dist > 0.0 {
                odd = !odd;
            }
        }
        return Some(odd);
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The 12 triangles of the box from `lo` to `hi`.
    fn cube(lo: [f64; 3], hi: [f64; 3]) -> Vec<[Vec3; 3]> {
        let v = |x: usize, y: usize, z: usize| {
            Vec3::new([lo[0], hi[0]][x], [lo[1], hi[1]][y], [lo[2], hi[2]][z])
        };
        let quads = [
            [v(0, 0, 0), v(0, 1, 0), v(1, 1, 0), v(1, 0, 0)],
            [v(0, 0, 1), v(1, 0, 1), v(1, 1, 1), v(0, 1, 1)],
            [v(0, 0, 0), v(1, 0, 0), v(1, 0, 1), v(0, 0, 1)],
            [v(0, 1, 0), v(0, 1, 1), v(1, 1, 1), v(1, 1, 0)],
            [v(0, 0, 0), v(0, 0, 1), v(0, 1, 1), v(0, 1, 0)],
            [v(1, 0, 0), v(1, 1, 0), v(1, 1, 1), v(1, 0, 1)],
        ];
        quads
            .iter()
            .flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]])
            .collect()
    }

    fn area(pieces: &[Vec<Vec3>]) -> f64 {
        pieces
            .iter()
            .map(|p| {
                (1..p.len() - 1)
                    .map(|k| 0.5 * (p[k] - p[0]).cross(&(p[k + 1] - p[0])).norm())
                    .sum::<f64>()
            })
            .sum()
    }

    #[test]
    fn a_mesh_without_coincident_faces_keeps_its_triangles() {
        assert!(area_pieces(&cube([0.0; 3], [1.0, 2.0, 3.0])).is_none());
        let mut two = cube([0.0; 3], [1.0; 3]);
        two.extend(cube([2.0, 0.0, 0.0], [3.0, 1.0, 1.0]));
        assert!(area_pieces(&two).is_none());
    }

    #[test]
    fn a_row_of_voxels_becomes_the_box_around_them() {
        // Three unit cubes along x, each with its 12 triangles: the two
        // shared faces are inside, each side a 3 x 1 rectangle.
        let mut row = Vec::new();
        for i in 0..3 {
            let x = i as f64;
            row.extend(cube([x, 0.0, 0.0], [x + 1.0, 1.0, 1.0]));
        }
        let pieces = area_pieces(&row).unwrap();
        assert_eq!(pieces.len(), 6, "{pieces:?}");
        assert!(pieces.iter().all(|p| p.len() == 4));
        assert!((area(&pieces) - 14.0).abs() < 1e-12);
    }

    #[test]
    fn a_shared_face_split_along_the_other_diagonal_is_found_inside() {
        let a = cube([0.0; 3], [1.0; 3]);
        // The second cube's face at x = 1 split along the other diagonal.
        let mut b = cube([1.0, 0.0, 0.0], [2.0, 1.0, 1.0]);
        let (p, q, r, s) = (
            Vec3::new(1.0, 0.0, 0.0),
            Vec3::new(1.0, 0.0, 1.0),
            Vec3::new(1.0, 1.0, 1.0),
            Vec3::new(1.0, 1.0, 0.0),
        );
        b.retain(|t| !t.iter().all(|v| v.x == 1.0));
        b.extend([[p, q, s], [q, r, s]]);
        let mut both = a;
        both.extend(b);
        let pieces = area_pieces(&both).unwrap();
        assert_eq!(pieces.len(), 6, "{pieces:?}");
        assert!((area(&pieces) - 10.0).abs() < 1e-12);
    }

    #[test]
    fn a_doubled_sheet_is_kept_once_and_an_open_mesh_only_loses_copies() {
        // A closed cube and, apart from it, a square sheet written twice:
        // the sheet is outside the cube, so one copy stays.
        let mut mesh = cube([0.0; 3], [1.0; 3]);
        let (a, b, c, d) = (
            Vec3::new(3.0, 0.0, 0.0),
            Vec3::new(4.0, 0.0, 0.0),
            Vec3::new(4.0, 1.0, 0.0),
            Vec3::new(3.0, 1.0, 0.0),
        );
        mesh.extend([[a, b, c], [a, c, d], [a, c, b], [a, d, c]]);
        let pieces = area_pieces(&mesh).unwrap();
        assert_eq!(pieces.len(), 7, "{pieces:?}");
        assert!((area(&pieces) - 7.0).abs() < 1e-12);
        // Two cubes sharing a face with one outer face missing: not closed,
        // so the shared face stays (once).
        let mut open = cube([0.0; 3], [1.0; 3]);
        open.extend(cube([1.0, 0.0, 0.0], [2.0, 1.0, 1.0]));
        open.truncate(open.len() - 2);
        let pieces = area_pieces(&open).unwrap();
        assert!((area(&pieces) - 10.0).abs() < 1e-12, "{}", area(&pieces));
    }

    #[test]
    fn rays_count_crossings_of_a_closed_surface() {
        let c = cube([0.0; 3], [1.0; 3]);
        assert_eq!(parity(&Vec3::new(0.5, 0.5, 0.5), &c), Some(true));
        assert_eq!(parity(&Vec3::new(1.5, 0.5, 0.5), &c), Some(false));
        assert_eq!(parity(&Vec3::new(0.3, 0.9, 0.1), &c), Some(true));
    }
}
