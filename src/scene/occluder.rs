//! Occluders between the hidden scene and the wall (MODEL.md `V(s, c)`):
//! closed parallelograms and closed balls against the open segment s -> c.

use crate::optics::Vec3;

/// A blocker of light paths.
#[derive(Debug, Clone, Copy, PartialEq)]
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
}

impl Occluder {
    /// Whether the open segment from `s` to `c` meets the occluder.
    ///
    /// A segment that touches only at an end point, or that lies in a
    /// rectangle's plane, is not blocked (MODEL.md "Edge cases").
    pub fn blocks(&self, s: &Vec3, c: &Vec3) -> bool {
        let d = c - s;
        match *self {
            Occluder::Rect {
                center,
                half_u,
                half_v,
            } => {
                let m = half_u.cross(&half_v);
                let denom = m.dot(&d);
                if denom.abs() <= 1e-14 * m.norm() * d.norm() {
                    return false;
                }
                let t = m.dot(&(center - s)) / denom;
                if t <= 0.0 || t >= 1.0 {
                    return false;
                }
                // Solve p = a half_u + b half_v in the (possibly skew) edge basis.
                let p = s + d * t - center;
                let (uu, uv, vv) = (
                    half_u.dot(&half_u),
                    half_u.dot(&half_v),
                    half_v.dot(&half_v),
                );
                let (pu, pv) = (p.dot(&half_u), p.dot(&half_v));
                let det = uu * vv - uv * uv;
                let a = (pu * vv - pv * uv) / det;
                let b = (pv * uu - pu * uv) / det;
                let tol = 1e-12;
                a.abs() <= 1.0 + tol && b.abs() <= 1.0 + tol
            }
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
}
