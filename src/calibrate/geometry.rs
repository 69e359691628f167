//! Geometry calibration: a pose's camera→wall homography from an image of
//! a dot target on the wall.
//!
//! The dots are found as bright connected blobs (intensity-weighted
//! centroids); they are identified by the convex hull, which a homography
//! maps onto the detections' hull in the same cyclic order (every rotation
//! and both directions are tried, and the one whose homography explains all
//! dots best wins, so the target needs no symmetry); `H` comes from the
//! normalized DLT (Hartley) on every dot, refined by Levenberg-Marquardt on
//! the reprojection error in pixels, which is reported.

use nalgebra::{DMatrix, Matrix3, SVector};

use crate::scene::{Frame, Homography};

/// A dot target: dot centres in wall coordinates and their radius.
#[derive(Debug, Clone, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct Target {
    /// Dot radius, metres.
    pub radius_m: f64,
    /// Dot centres `[u, v]`, metres from the wall centre.
    pub dots: Vec<[f64; 2]>,
}

/// Why a calibration could not be made.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CalibrationError {
    /// The target file is wrong.
    #[error("target: {0}")]
    Target(String),
    /// Not as many dots in the image as the target has.
    #[error("found {found} dots in the image but the target has {expected}; check that the whole target is in view, lit, in focus, and not saturated, and that the target file is the one on the wall")]
    DotCount {
        /// Blobs found.
        found: usize,
        /// Dots in the target.
        expected: usize,
    },
    /// The dots could not be identified (the hulls differ, or no assignment fits).
    #[error("the dots could not be identified: {0}")]
    Identification(String),
}

/// Fewest pixels a blob needs to count as a dot.
const MIN_BLOB_PIXELS: usize = 4;
/// Hull vertices turning less than this (radians) are edge points, not corners.
const HULL_TURN: f64 = 0.1;

/// The shipped target (`config/targets/dots-5x5.toml`): what the demo bench
/// shows and what `POST /calibrations` assumes when none is given.
pub(crate) const DEFAULT_TARGET: &str = include_str!("../../config/targets/dots-5x5.toml");

/// The built-in targets by name, as scenes are: name and TOML text.
pub const BUILTIN_TARGETS: [(&str, &str); 1] = [("dots-5x5", DEFAULT_TARGET)];

impl Target {
    /// The TOML text of a built-in target by name (`dots-5x5`).
    pub fn builtin_text(name: &str) -> Option<&'static str> {
        BUILTIN_TARGETS
            .iter()
            .find(|(n, _)| *n == name)
            .map(|(_, t)| *t)
    }

    /// The shipped target, `DEFAULT_TARGET`.
    pub fn default_target() -> Self {
        match Self::from_toml_str(DEFAULT_TARGET) {
            Ok(t) => t,
            Err(e) => unreachable!("the shipped target parses (tested): {e}"),
        }
    }

    /// Parses a target file (TOML: `radius_m`, `dots`).
    pub fn from_toml_str(text: &str) -> Result<Self, CalibrationError> {
        let t: Target =
            toml::from_str(text).map_err(|e| CalibrationError::Target(e.to_string()))?;
        if !(t.radius_m > 0.0 && t.radius_m.is_finite()) {
            return Err(CalibrationError::Target(format!(
                "radius_m = {}: must be a positive length",
                t.radius_m
            )));
        }
        if t.dots.len() < 5 || t.dots.len() > 10_000 {
            return Err(CalibrationError::Target(format!(
                "{} dots: give 5 to 10000 (4 hull corners and at least one more)",
                t.dots.len()
            )));
        }
        if t.dots.iter().flatten().any(|x| !x.is_finite()) {
            return Err(CalibrationError::Target(
                "a dot coordinate is not a finite number".into(),
            ));
        }
        Ok(t)
    }
}

/// A bright blob: centroid in pixels (x right, y down; pixel centres at
/// integers) and its area.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Blob {
    /// Centroid x.
    pub x: f64,
    /// Centroid y.
    pub y: f64,
    /// Pixels above the threshold.
    pub pixels: usize,
    /// Variance of the centroid `(x, y)`, pixels squared, from the frame's
    /// variance: `sum (x_p - x)^2 var_p / (sum w)^2`; `None` without one.
    pub variance: Option<[f64; 2]>,
}

/// A fitted homography and how well it explains the dots.
#[derive(Debug, Clone, PartialEq)]
pub struct Fit {
    /// Wall metres → pixels.
    pub homography: Homography,
    /// RMS reprojection error, pixels.
    pub rms_px: f64,
    /// Largest reprojection error, pixels.
    pub max_px: f64,
    /// Dots used.
    pub dots: usize,
    /// Whether the homography explains the dots to their centroid noise
    /// (chi-square over both coordinates of every dot, 8 numbers fitted).
    pub model_check: crate::solve::adequacy::Adequacy,
}

/// The image a camera at `h` sees of the target: 1 on the dots, 0 elsewhere,
/// each pixel the mean of 4x4 sub-samples (for the fake camera and tests).
///
/// Only the pixels near a dot are sub-sampled: a dot lies in its bounding
/// square, and a square wholly in front of the camera maps into the box of
/// its four corners' pixels, so every other pixel is 0 (the daemon renders
/// this image for each of its demo's blocks when it starts).
pub fn render(target: &Target, h: &Homography, width: usize, height: usize) -> Frame {
    let near = near_dots(target, h, width, height);
    let pixels = (0..width * height)
        .map(|k| {
            if near[k] {
                coverage(target, h, k % width, k / width)
            } else {
                0.0
            }
        })
        .collect();
    Frame {
        width,
        height,
        pixels,
    }
}

/// The share of pixel (x, y)'s 4x4 sub-samples that see a dot of `target`.
fn coverage(target: &Target, h: &Homography, x: usize, y: usize) -> f32 {
    const S: usize = 4;
    let r2 = target.radius_m * target.radius_m;
    let mut hits = 0;
    for sy in 0..S {
        for sx in 0..S {
            let xs = x as f64 - 0.5 + (sx as f64 + 0.5) / S as f64;
            let ys = y as f64 - 0.5 + (sy as f64 + 0.5) / S as f64;
            if let Some((u, v)) = h.invert(xs, ys) {
                let inside = target
                    .dots
                    .iter()
                    .any(|d| (d[0] - u).powi(2) + (d[1] - v).powi(2) <= r2);
                hits += usize::from(inside);
            }
        }
    }
    hits as f32 / (S * S) as f32
}

/// Which pixels a dot of `target` can reach through `h` (row-major): each
/// dot's box, with a pixel's margin, clipped to the image; the whole image
/// for a dot whose bounding square is not wholly in front of the camera
/// (its image is not bounded by its corners').
fn near_dots(target: &Target, h: &Homography, width: usize, height: usize) -> Vec<bool> {
    let r = target.radius_m;
    let mut near = vec![false; width * height];
    for d in &target.dots {
        let corners =
            [(-r, -r), (r, -r), (r, r), (-r, r)].map(|(du, dv)| h.apply(d[0] + du, d[1] + dv));
        let (x0, y0, x1, y1) = if corners.iter().all(Option::is_some) {
            let (mut xl, mut yl, mut xh, mut yh) = (
                f64::INFINITY,
                f64::INFINITY,
                f64::NEG_INFINITY,
                f64::NEG_INFINITY,
            );
            for (x, y) in corners.into_iter().flatten() {
                (xl, yl, xh, yh) = (xl.min(x), yl.min(y), xh.max(x), yh.max(y));
            }
            let lo = |v: f64| (v - 1.5).floor().max(0.0) as usize;
            let hi = |v: f64, n: usize| ((v + 2.5).ceil().max(0.0) as usize).min(n);
            (lo(xl), lo(yl), hi(xh, width), hi(yh, height))
        } else {
            (0, 0, width, height)
        };
        for y in y0..y1 {
            near[y * width + x0.min(x1)..y * width + x1].fill(true);
        }
    }
    near
}

/// The bright blobs of `frame`: pixels above the midpoint between the 1st
/// and 99.9th percentile, 8-connected, weighted by their height above it.
pub fn detect(frame: &Frame) -> Vec<Blob> {
    detect_with_variance(frame, None)
}

/// [`detect`], with each centroid's variance from the frame's per-pixel
/// `variance` (ignored unless it has the frame's size).
pub(crate) fn detect_with_variance(frame: &Frame, variance: Option<&Frame>) -> Vec<Blob> {
    let variance = variance.filter(|v| {
        v.width == frame.width && v.height == frame.height && v.pixels.len() == frame.pixels.len()
    });
    let (w, h) = (frame.width, frame.height);
    let n = (w * h).min(frame.pixels.len());
    if n == 0 {
        return Vec::new();
    }
    // Two order statistics, not a full sort.
    let mut values: Vec<f32> = frame.pixels[..n].to_vec();
    let lo = f64::from(*values.select_nth_unstable_by(n / 100, f32::total_cmp).1);
    let hi = f64::from(
        *values
            .select_nth_unstable_by((n - 1) - (n - 1) / 1000, f32::total_cmp)
            .1,
    );
    if hi <= lo {
        return Vec::new();
    }
    let threshold = 0.5 * (lo + hi);
    let mut seen = vec![false; n];
    let mut blobs = Vec::new();
    let mut stack = Vec::new();
    for start in 0..n {
        if seen[start] || f64::from(frame.pixels[start]) <= threshold {
            continue;
        }
        seen[start] = true;
        stack.push(start);
        let (mut sw, mut sx, mut sy, mut count) = (0.0, 0.0, 0.0, 0);
        let mut members = Vec::new();
        while let Some(k) = stack.pop() {
            let (x, y) = (k % w, k / w);
            let weight = f64::from(frame.pixels[k]) - threshold;
            sw += weight;
            sx += weight * x as f64;
            sy += weight * y as f64;
            count += 1;
            if variance.is_some() {
                members.push(k);
            }
            for dy in -1i64..=1 {
                for dx in -1i64..=1 {
                    let (nx, ny) = (x as i64 + dx, y as i64 + dy);
                    if nx < 0 || ny < 0 || nx >= w as i64 || ny >= h as i64 {
                        continue;
                    }
                    let j = ny as usize * w + nx as usize;
                    if !seen[j] && f64::from(frame.pixels[j]) > threshold {
                        seen[j] = true;
                        stack.push(j);
                    }
                }
            }
        }
        if count >= MIN_BLOB_PIXELS && sw > 0.0 {
            let (cx, cy) = (sx / sw, sy / sw);
            // Linear error propagation of the weighted centroid.
            let variance = variance.map(|v| {
                let (mut vx, mut vy) = (0.0, 0.0);
                for &k in &members {
                    let var = f64::from(v.pixels[k]).max(0.0);
                    vx += ((k % w) as f64 - cx).powi(2) * var;
                    vy += ((k / w) as f64 - cy).powi(2) * var;
                }
                [vx / (sw * sw), vy / (sw * sw)]
            });
            blobs.push(Blob {
                x: cx,
                y: cy,
                pixels: count,
                variance,
            });
        }
    }
    blobs
}

/// Fits the homography wall → pixels from the target and the blobs found.
pub fn fit(target: &Target, blobs: &[Blob]) -> Result<Fit, CalibrationError> {
    if blobs.len() != target.dots.len() {
        return Err(CalibrationError::DotCount {
            found: blobs.len(),
            expected: target.dots.len(),
        });
    }
    let image: Vec<[f64; 2]> = blobs.iter().map(|b| [b.x, b.y]).collect();
    let hull_t = hull_corners(&target.dots);
    let hull_i = hull_corners(&image);
    if hull_t.len() != hull_i.len() || hull_t.len() < 4 {
        return Err(CalibrationError::Identification(format!(
            "the target's outline has {} corners but the dots in the image outline {}; is a dot hidden, or an extra bright spot in view?",
            hull_t.len(),
            hull_i.len()
        )));
    }
    let k = hull_t.len();
    let mut best: Option<(f64, Vec<usize>)> = None;
    for reverse in [false, true] {
        for shift in 0..k {
            let pairs: Vec<([f64; 2], [f64; 2])> = (0..k)
                .map(|j| {
                    let i = if reverse {
                        (shift + k - j) % k
                    } else {
                        (shift + j) % k
                    };
                    (target.dots[hull_t[j]], image[hull_i[i]])
                })
                .collect();
            let Some(h) = dlt(&pairs) else { continue };
            let Some((cost, assignment)) = assign(&h, &target.dots, &image) else {
                continue;
            };
            if best.as_ref().is_none_or(|(c, _)| cost < *c) {
                best = Some((cost, assignment));
            }
        }
    }
    let (_, assignment) = best.ok_or_else(|| {
        CalibrationError::Identification(
            "no assignment of the outline corners gives a valid homography".into(),
        )
    })?;
    let pairs: Vec<([f64; 2], [f64; 2])> = target
        .dots
        .iter()
        .zip(&assignment)
        .map(|(d, &i)| (*d, image[i]))
        .collect();
    let h0 = dlt(&pairs).ok_or_else(|| {
        CalibrationError::Identification("the identified dots give a degenerate homography".into())
    })?;
    let h = refine(h0, &pairs);
    let homography = Homography::new(h).ok_or_else(|| {
        CalibrationError::Identification("the refined homography is singular".into())
    })?;
    let errors: Vec<f64> = pairs
        .iter()
        .map(|(w, p)| match project(&h, *w) {
            Some(q) => ((q[0] - p[0]).powi(2) + (q[1] - p[1]).powi(2)).sqrt(),
            None => f64::INFINITY,
        })
        .collect();
    let rms_px = (errors.iter().map(|e| e * e).sum::<f64>() / errors.len() as f64).sqrt();
    let max_px = errors.iter().copied().fold(0.0, f64::max);
    // Residuals and centroid variances, x and y of every dot.
    let residual: Vec<f64> = pairs
        .iter()
        .flat_map(|(w, p)| {
            let q = project(&h, *w).unwrap_or([f64::INFINITY; 2]);
            [q[0] - p[0], q[1] - p[1]]
        })
        .collect();
    let variance: Option<Vec<f64>> = assignment
        .iter()
        .map(|&i| blobs[i].variance)
        .collect::<Option<Vec<[f64; 2]>>>()
        .map(|v| v.concat());
    Ok(Fit {
        homography,
        rms_px,
        max_px,
        dots: pairs.len(),
        model_check: crate::solve::adequacy::Adequacy::of(&residual, variance.as_deref(), 8),
    })
}

/// The largest distance in pixels between where `a` and `b` put the wall
/// points `at` (e.g. a target's dots): how far apart two calibrations of a
/// pose are. Infinite when either maps a point to infinity.
pub fn max_distance(a: &Homography, b: &Homography, at: &[[f64; 2]]) -> f64 {
    at.iter()
        .map(|w| match (a.apply(w[0], w[1]), b.apply(w[0], w[1])) {
            (Some(p), Some(q)) => ((p.0 - q.0).powi(2) + (p.1 - q.1).powi(2)).sqrt(),
            _ => f64::INFINITY,
        })
        .fold(0.0, f64::max)
}

/// The scene file `scene_toml` (a file in `folders.from`) with pose
/// `pose`'s `homography` replaced by `h` and its camera frame set to
/// `region` (binning 1), as a file in `folders.to`, for the user to review.
///
/// Why: the user's file as written (comments, order, every other value)
/// with only the fitted values changed, its relative mesh paths rewritten
/// for `folders.to`; checked to parse as a scene there.
pub fn scene_with_homography(
    scene_toml: &str,
    pose: &str,
    h: &Homography,
    region: [u32; 4],
    folders: SceneFolders<'_>,
) -> Result<String, CalibrationError> {
    use toml_edit::{Array, Value};
    let bad = |m: String| CalibrationError::Target(m);
    let mut doc: toml_edit::DocumentMut = scene_toml
        .parse()
        .map_err(|e| bad(format!("scene file: {e}")))?;
    let entry = crate::calibrate::scene_text::entries(&mut doc, "pose")
        .into_iter()
        .find(|p| p.get("name").and_then(|n| n.as_str()) == Some(pose))
        .ok_or_else(|| bad(format!("scene file has no pose {pose:?}")))?;
    let rows: Array = h
        .matrix()
        .iter()
        .map(|r| Value::Array(r.iter().copied().collect()))
        .collect();
    let ints = |v: &[u32]| -> Array { v.iter().map(|&x| i64::from(x)).collect() };
    let set = crate::calibrate::scene_text::set_value;
    set(entry, "homography", Value::Array(rows));
    set(entry, "region", Value::Array(ints(&region)));
    set(entry, "binning", Value::Array(ints(&[1, 1])));
    if folders.from != folders.to {
        crate::calibrate::scene_text::rebase_mesh_paths(&mut doc, folders.from, folders.to)
            .map_err(|e| bad(e.to_string()))?;
    }
    let text = doc.to_string();
    crate::scene::Scene::from_toml_str_in(&text, folders.to)
        .map_err(|e| bad(format!("the calibrated scene does not validate: {e}")))?;
    Ok(text)
}

/// Where a scene file that is edited was read from and where the edited
/// copy goes: its relative mesh paths are read from `from` and rewritten
/// for `to`.
#[derive(Debug, Clone, Copy)]
pub struct SceneFolders<'a> {
    /// The folder of the file the text was read from (`""`: the current one).
    pub from: &'a std::path::Path,
    /// The folder the edited file is written to.
    pub to: &'a std::path::Path,
}

impl<'a> SceneFolders<'a> {
    /// Read and written in one folder.
    pub fn same(dir: &'a std::path::Path) -> Self {
        Self { from: dir, to: dir }
    }
}

/// `H [u, v, 1]`, dehomogenized; None at infinity.
fn project(h: &[[f64; 3]; 3], w: [f64; 2]) -> Option<[f64; 2]> {
    let z = h[2][0] * w[0] + h[2][1] * w[1] + h[2][2];
    if z.abs() < 1e-12 {
        return None;
    }
    Some([
        (h[0][0] * w[0] + h[0][1] * w[1] + h[0][2]) / z,
        (h[1][0] * w[0] + h[1][1] * w[1] + h[1][2]) / z,
    ])
}

/// Matches every target dot to a distinct detection under `h` (nearest
/// first); the sum of squared distances, or None when a match is ambiguous.
fn assign(h: &[[f64; 3]; 3], dots: &[[f64; 2]], image: &[[f64; 2]]) -> Option<(f64, Vec<usize>)> {
    let projected: Vec<[f64; 2]> = dots.iter().map(|d| project(h, *d)).collect::<Option<_>>()?;
    let mut candidates: Vec<(f64, usize, usize)> = Vec::with_capacity(dots.len() * image.len());
    for (a, p) in projected.iter().enumerate() {
        for (b, q) in image.iter().enumerate() {
            candidates.push(((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2), a, b));
        }
    }
    candidates.sort_by(|x, y| x.0.total_cmp(&y.0));
    let mut of_dot = vec![usize::MAX; dots.len()];
    let mut taken = vec![false; image.len()];
    let mut cost = 0.0;
    for (d2, a, b) in candidates {
        if of_dot[a] == usize::MAX && !taken[b] {
            of_dot[a] = b;
            taken[b] = true;
            cost += d2;
        }
    }
    of_dot
        .iter()
        .all(|&b| b != usize::MAX)
        .then_some((cost, of_dot))
}

/// Indices of the corners of the convex hull, counter-clockwise in the
/// points' own axes (Andrew's monotone chain), without edge points.
fn hull_corners(points: &[[f64; 2]]) -> Vec<usize> {
    let mut idx: Vec<usize> = (0..points.len()).collect();
    idx.sort_by(|&a, &b| {
        points[a][0]
            .total_cmp(&points[b][0])
            .then(points[a][1].total_cmp(&points[b][1]))
    });
    let cross = |o: usize, a: usize, b: usize| {
        (points[a][0] - points[o][0]) * (points[b][1] - points[o][1])
            - (points[a][1] - points[o][1]) * (points[b][0] - points[o][0])
    };
    let mut hull: Vec<usize> = Vec::new();
    for pass in 0..2 {
        let start = hull.len();
        let order: Vec<usize> = if pass == 0 {
            idx.clone()
        } else {
            idx.iter().rev().copied().collect()
        };
        for &p in &order {
            while hull.len() >= start + 2
                && cross(hull[hull.len() - 2], hull[hull.len() - 1], p) <= 0.0
            {
                hull.pop();
            }
            hull.push(p);
        }
        hull.pop();
    }
    // Drop vertices where the outline barely turns (points along an edge).
    let n = hull.len();
    if n < 3 {
        return hull;
    }
    (0..n)
        .filter(|&k| {
            let (a, b, c) = (
                points[hull[(k + n - 1) % n]],
                points[hull[k]],
                points[hull[(k + 1) % n]],
            );
            let (d1, d2) = ([b[0] - a[0], b[1] - a[1]], [c[0] - b[0], c[1] - b[1]]);
            let turn = (d1[0] * d2[1] - d1[1] * d2[0]).atan2(d1[0] * d2[0] + d1[1] * d2[1]);
            turn.abs() > HULL_TURN
        })
        .map(|k| hull[k])
        .collect()
}

/// Similarity that moves points to their centroid and mean distance sqrt(2).
fn normalization(points: impl Iterator<Item = [f64; 2]> + Clone) -> Matrix3<f64> {
    let n = points.clone().count().max(1) as f64;
    let (cx, cy) = points
        .clone()
        .fold((0.0, 0.0), |(x, y), p| (x + p[0] / n, y + p[1] / n));
    let mean = points
        .map(|p| ((p[0] - cx).powi(2) + (p[1] - cy).powi(2)).sqrt())
        .sum::<f64>()
        / n;
    let s = if mean > 0.0 { 2f64.sqrt() / mean } else { 1.0 };
    Matrix3::new(s, 0.0, -s * cx, 0.0, s, -s * cy, 0.0, 0.0, 1.0)
}

/// Normalized DLT (Hartley & Zisserman, Alg. 4.2) from (wall, pixel) pairs.
fn dlt(pairs: &[([f64; 2], [f64; 2])]) -> Option<[[f64; 3]; 3]> {
    if pairs.len() < 4 {
        return None;
    }
    let tw = normalization(pairs.iter().map(|p| p.0));
    let ti = normalization(pairs.iter().map(|p| p.1));
    let mut a = DMatrix::<f64>::zeros(2 * pairs.len(), 9);
    for (k, (w, p)) in pairs.iter().enumerate() {
        let w = tw * nalgebra::Vector3::new(w[0], w[1], 1.0);
        let p = ti * nalgebra::Vector3::new(p[0], p[1], 1.0);
        let (x, y) = (p[0] / p[2], p[1] / p[2]);
        let row = [w[0], w[1], w[2]];
        for c in 0..3 {
            a[(2 * k, 3 + c)] = -row[c];
            a[(2 * k, 6 + c)] = y * row[c];
            a[(2 * k + 1, c)] = row[c];
            a[(2 * k + 1, 6 + c)] = -x * row[c];
        }
    }
    // The null vector of A: the eigenvector of A^T A with the least eigenvalue.
    let ata = a.transpose() * &a;
    let eig = ata.symmetric_eigen();
    let (k, _) = eig
        .eigenvalues
        .iter()
        .enumerate()
        .min_by(|a, b| a.1.total_cmp(b.1))?;
    let v = eig.eigenvectors.column(k);
    let hn = Matrix3::from_fn(|r, c| v[3 * r + c]);
    let h = ti.try_inverse()? * hn * tw;
    let scale = h[(2, 2)];
    if !scale.is_finite() || scale.abs() < 1e-300 {
        return None;
    }
    let h = h / scale;
    Some(std::array::from_fn(|r| std::array::from_fn(|c| h[(r, c)])))
}

/// Levenberg-Marquardt ([`super::levenberg`]) on the reprojection error in
/// pixels over the 8 free entries of `H` (`h33 = 1`), from the DLT estimate.
fn refine(h: [[f64; 3]; 3], pairs: &[([f64; 2], [f64; 2])]) -> [[f64; 3]; 3] {
    let to_h = |p: &SVector<f64, 8>| -> [[f64; 3]; 3] {
        [[p[0], p[1], p[2]], [p[3], p[4], p[5]], [p[6], p[7], 1.0]]
    };
    // Each target dot where `H` puts it (none for a dot it sends to infinity).
    let model = |p: &SVector<f64, 8>| -> Result<Option<Vec<f64>>, std::convert::Infallible> {
        let h = to_h(p);
        let mut x = Vec::with_capacity(2 * pairs.len());
        for (w, _) in pairs {
            let Some(at) = project(&h, *w) else {
                return Ok(None);
            };
            x.extend(at);
        }
        Ok(Some(x))
    };
    let seen: Vec<f64> = pairs.iter().flat_map(|(_, q)| *q).collect();
    let start = SVector::<f64, 8>::from_fn(|k, _| h[k / 3][k % 3]);
    let Ok(Some(first)) = model(&start) else {
        return h;
    };
    let settings = super::levenberg::Settings {
        max_iter: 50,
        tries: 10,
        step: 1e-7,
        min_gain: 0.0,
        exact: 1e-20,
    };
    let Ok(fit) = super::levenberg::minimize(model, &seen, start, &first, |p| p, settings);
    to_h(&fit.p)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn target() -> Target {
        Target::from_toml_str(include_str!("../../config/targets/dots-5x5.toml")).expect("target")
    }

    fn shipped(scene: &str, pose: usize) -> Homography {
        match crate::scene::Scene::builtin(scene) {
            Some(Ok(s)) => s.poses()[pose].homography.expect("homography"),
            _ => panic!("scene"),
        }
    }

    /// [`render`] sub-sampling every pixel, as it did before it skipped the
    /// pixels no dot reaches.
    fn render_every_pixel(
        target: &Target,
        h: &Homography,
        width: usize,
        height: usize,
    ) -> Vec<f32> {
        (0..width * height)
            .map(|k| coverage(target, h, k % width, k / width))
            .collect()
    }

    #[test]
    fn render_skips_only_pixels_no_dot_reaches() {
        let t = target();
        // The demo bench's three poses, on their 512 x 512 sensor.
        let mut cases = vec![
            (shipped("brewster-crossed", 0), 512, 512),
            (shipped("brewster-multi", 0), 512, 512),
            (shipped("brewster-multi", 1), 512, 512),
        ];
        // Seen square on, large (dots spanning many pixels, overlapping the
        // image's edges), and with the horizon crossing the image (the
        // dots near it are not wholly in front of the camera).
        cases.extend(
            [
                [[2000.0, 0.0, 32.0], [0.0, 2000.0, 32.0], [0.0, 0.0, 1.0]],
                [[9000.0, 0.0, 64.0], [0.0, 9000.0, 60.0], [0.0, 0.0, 1.0]],
                [[800.0, 0.0, 32.0], [0.0, 800.0, 32.0], [-12.0, 0.0, 1.0]],
            ]
            .into_iter()
            .filter_map(Homography::new)
            .map(|h| (h, 64, 48)),
        );
        assert_eq!(cases.len(), 6);
        for (h, w, ht) in &cases {
            let fast = render(&t, h, *w, *ht);
            assert_eq!(fast.pixels, render_every_pixel(&t, h, *w, *ht), "{h:?}");
            assert!(fast.pixels.iter().any(|&p| p > 0.0), "{h:?}");
        }
    }

    fn disagreement(a: &Homography, b: &Homography, t: &Target) -> f64 {
        max_distance(a, b, &t.dots)
    }

    #[test]
    fn dlt_recovers_an_exact_homography_from_its_own_points() {
        let h = shipped("brewster-crossed", 0);
        let t = target();
        let pairs: Vec<_> = t
            .dots
            .iter()
            .map(|d| {
                let (x, y) = h.apply(d[0], d[1]).expect("in front");
                (*d, [x, y])
            })
            .collect();
        let m = dlt(&pairs).expect("dlt");
        let fitted = Homography::new(m).expect("regular");
        assert!(disagreement(&fitted, &h, &t) < 1e-6);
    }

    #[test]
    fn every_shipped_pose_is_recovered_from_an_image_of_the_target() {
        let t = target();
        for (scene, pose) in [
            ("brewster-crossed", 0),
            ("brewster-multi", 0),
            ("brewster-multi", 1),
        ] {
            let h = shipped(scene, pose);
            let frame = render(&t, &h, 512, 512);
            let blobs = detect(&frame);
            let f = fit(&t, &blobs).expect("fit");
            let err = disagreement(&f.homography, &h, &t);
            println!(
                "{scene} pose {pose}: rms {:.3} px, max {:.3} px, vs shipped {err:.3} px",
                f.rms_px, f.max_px
            );
            assert!(f.rms_px < 0.2, "{scene}/{pose}: {f:?}");
            assert!(err < 0.3, "{scene}/{pose}: {err}");
        }
    }

    #[test]
    fn a_hidden_dot_or_a_stray_spot_is_a_clear_error() {
        let t = target();
        let h = shipped("brewster-crossed", 0);
        let mut frame = render(&t, &h, 512, 512);
        let blobs = detect(&frame);
        let e = fit(&t, &blobs[1..]).expect_err("one dot short");
        assert!(
            matches!(
                e,
                CalibrationError::DotCount {
                    found: 25,
                    expected: 26
                }
            ),
            "{e}"
        );
        // A bright spot far from the target: one blob too many.
        for y in 5..10 {
            for x in 5..10 {
                frame.pixels[y * 512 + x] = 1.0;
            }
        }
        let e = fit(&t, &detect(&frame)).expect_err("a stray spot");
        assert!(e.to_string().contains("found 27 dots"), "{e}");
    }

    #[test]
    fn a_noisy_offset_image_still_gives_the_pose_within_a_third_of_a_pixel() {
        let t = target();
        let h = shipped("brewster-multi", 1);
        let mut frame = render(&t, &h, 512, 512);
        let mut seed = 0x2545_F491_4F6C_DD1Du64;
        for p in frame.pixels.iter_mut() {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            let noise = (seed >> 40) as f32 / (1u64 << 24) as f32 - 0.5;
            *p = 0.2 + 0.6 * *p + 0.1 * noise;
        }
        let f = fit(&t, &detect(&frame)).expect("fit");
        let err = disagreement(&f.homography, &h, &t);
        println!("noisy: rms {:.3} px, vs shipped {err:.3} px", f.rms_px);
        assert!(err < 0.3, "{err}");
    }

    #[test]
    fn the_calibrated_scene_file_parses_and_carries_the_fit() {
        let text = include_str!("../../config/scenes/brewster-multi.toml");
        let h = shipped("brewster-crossed", 0);
        let here = SceneFolders::same(std::path::Path::new(""));
        let out = scene_with_homography(text, "C", &h, [0, 0, 512, 512], here).expect("scene");
        let s = crate::scene::Scene::from_toml_str(&out).expect("parses");
        assert_eq!(s.pose("C").and_then(|p| p.homography), Some(h));
        assert_ne!(s.pose("B").and_then(|p| p.homography), Some(h));
        let e =
            scene_with_homography(text, "Z", &h, [0, 0, 512, 512], here).expect_err("no pose Z");
        assert!(e.to_string().contains("no pose \"Z\""), "{e}");
    }

    #[test]
    fn a_symmetric_target_file_is_refused_only_when_malformed() {
        assert!(Target::from_toml_str("radius_m = 0.0\ndots = []").is_err());
        assert!(Target::from_toml_str("radius_m = 0.01\ndots = [[0, 0]]").is_err());
        assert!(Target::from_toml_str("radius_m = 0.01\nextra = 1\ndots = []").is_err());
    }
}
