//! Where the occluders stand, fitted to a photo: the translation (common to
//! the selected occluders) that minimizes the photo's model misfit.
//!
//! Why: a passive reconstruction needs the occluder's position to a few
//! millimetres, and a tape measure gives it to a centimetre at best; the
//! photo itself says where the shadows fall (docs/realphoto.md, "Placing
//! the occluders"). The misfit is the least-squares misfit of the data term
//! of differences (blind to the photo's unknown gain and ambient light)
//! summed over the colour channels, with `T` built with area shadows: exact,
//! and continuous in the translation.

use std::collections::HashMap;
use std::path::Path;
use std::time::Instant;

use crate::optics::Vec3;
use crate::scene::{Mesh, Occluder, Scene, SceneError, ShadowModel};
use crate::solve::photo::{least_squares_misfit, DataTerm};
use crate::solve::SolveError;
use crate::transport::{build, MemoryBudget, TransportError};

/// Why the occluders could not be fitted.
#[derive(Debug, thiserror::Error)]
pub enum OccluderError {
    /// The scene has no occluder to move.
    #[error("the scene has no [[occluder]]: there is nothing to place")]
    NoOccluders,
    /// A selected occluder index is not in the scene.
    #[error("occluder {index} is not in the scene, which has {count} (0 to {})", count.saturating_sub(1))]
    Index {
        /// The index asked for.
        index: usize,
        /// Occluders in the scene.
        count: usize,
    },
    /// The selection names no occluder.
    #[error("the occluder selection is empty")]
    NoneSelected,
    /// No colour channel was given.
    #[error("the photo has no channel")]
    NoChannels,
    /// A channel does not have one value per row of the scene's `T`.
    #[error("photo channel {channel} has {got} values but the scene's T has {rows} rows (wall elements x blocks): was the photo taken of another scene?")]
    Rows {
        /// Channel index.
        channel: usize,
        /// Values given.
        got: usize,
        /// Rows of `T`.
        rows: usize,
    },
    /// A search option is out of range.
    #[error("{name} = {value}: {reason}")]
    Parameter {
        /// Option name, as on the command line.
        name: &'static str,
        /// Given value.
        value: f64,
        /// What it must be.
        reason: &'static str,
    },
    /// The scene with the occluders moved does not validate.
    #[error("the scene with its occluders moved: {0}")]
    Scene(#[from] SceneError),
    /// A scene file's text could not be edited.
    #[error("scene file: {0}")]
    SceneFile(String),
    /// `T` could not be built.
    #[error(transparent)]
    Transport(#[from] TransportError),
    /// The photo's fit failed.
    #[error(transparent)]
    Solve(#[from] SolveError),
}

/// How the search runs; `Default` gives the documented defaults.
#[derive(Debug, Clone)]
pub struct OccluderOptions {
    /// Indices of the occluders that move together; `None`: all.
    pub selected: Option<Vec<usize>>,
    /// Largest distance searched from the start along each axis, metres.
    pub range: f64,
    /// First step, metres; `None`: [`STEP_SHADOW_PITCHES`] shadow pitches.
    pub step: Option<f64>,
    /// Last step, metres; `None`: one shadow pitch ([`shadow_pitch`]).
    pub min_step: Option<f64>,
    /// Scene `supersample` of the `T` the objective builds; `None`: 1 with
    /// area shadows (a block's visibility is then exact, only its emission
    /// is taken at its centre), else the scene's own raised to [`SUPERSAMPLE`].
    pub supersample: Option<usize>,
    /// Shadows of the objective's `T`; area shadows by default, whatever
    /// the scene says, for a misfit continuous in the translation.
    pub shadows: ShadowModel,
    /// Memory budget of each `T`.
    pub budget: MemoryBudget,
}

/// Default search range per axis, metres: a first guess measured by hand.
pub const RANGE: f64 = 0.05;
/// Default first step in shadow pitches (then halved down to one pitch).
pub const STEP_SHADOW_PITCHES: f64 = 4.0;
/// Default scene supersample of the objective's `T` with point shadows: at
/// the chair's 2 the objective is rough by 5 % from one millimetre to the
/// next, at 6 by 1 % (docs/realphoto.md).
pub const SUPERSAMPLE: usize = 6;

impl Default for OccluderOptions {
    fn default() -> Self {
        Self {
            selected: None,
            range: RANGE,
            step: None,
            min_step: None,
            supersample: None,
            shadows: ShadowModel::Area,
            budget: MemoryBudget::DEFAULT,
        }
    }
}

/// One evaluation of the objective.
#[derive(Debug, Clone, Copy, serde::Serialize)]
pub struct Probe {
    /// Translation from the start, metres.
    pub translation: [f64; 3],
    /// Misfit summed over channels.
    pub objective: f64,
}

/// The fitted translation and what it rests on.
#[derive(Debug, Clone, serde::Serialize)]
pub struct OccluderFit {
    /// Indices of the occluders moved.
    pub selected: Vec<usize>,
    /// Translation from the scene's position, metres.
    pub translation: [f64; 3],
    /// Standard uncertainty of each component, metres (docs/realphoto.md).
    pub sd: [f64; 3],
    /// Curvature of the objective along each axis at the end, per m².
    pub curvature: [f64; 3],
    /// The selected occluders' bounding box, lowest corner, before the move.
    pub corner_start: [f64; 3],
    /// The same corner moved by the translation.
    pub corner_end: [f64; 3],
    /// Objective at the scene's own position.
    pub objective_start: f64,
    /// Lowest objective evaluated.
    pub objective_end: f64,
    /// Rows of the data term, all channels (for the misfit per degree of freedom).
    pub rows: usize,
    /// First and last step, metres.
    pub steps: [f64; 2],
    /// Scene supersample of the objective's `T`.
    pub supersample: usize,
    /// `T` builds (one per objective evaluation).
    pub builds: usize,
    /// Seconds, all builds and fits.
    pub seconds: f64,
    /// Every evaluation, in order.
    pub probes: Vec<Probe>,
}

/// The occluder indices `selected` names, checked against the scene.
fn selection(scene: &Scene, selected: Option<&[usize]>) -> Result<Vec<usize>, OccluderError> {
    let count = scene.occluders().len();
    if count == 0 {
        return Err(OccluderError::NoOccluders);
    }
    let Some(s) = selected else {
        return Ok((0..count).collect());
    };
    if s.is_empty() {
        return Err(OccluderError::NoneSelected);
    }
    if let Some(&index) = s.iter().find(|&&i| i >= count) {
        return Err(OccluderError::Index { index, count });
    }
    let mut v = s.to_vec();
    v.sort_unstable();
    v.dedup();
    Ok(v)
}

/// The occluder displacement that moves its shadow on the wall by one wall
/// element: the natural unit of the search (the shadow of a point at depth
/// `a` from the scene plane, seen from the scene, moves `D / a` as fast).
pub fn shadow_pitch(scene: &Scene, selected: &[usize]) -> f64 {
    let (wall, hidden) = (&scene.wall().plane, &scene.hidden().plane);
    let n = hidden.normal;
    let (lo, hi) = bounds(scene, selected);
    let centre = (Vec3::from(lo) + Vec3::from(hi)) * 0.5;
    let depth = n.dot(&(centre - hidden.center)).abs();
    let d = n.dot(&(wall.center - hidden.center)).abs();
    let pitch = wall.size[0] / wall.grid.nu as f64;
    if d > 0.0 && depth > 0.0 {
        pitch * (depth / d).min(1.0)
    } else {
        pitch
    }
}

/// The lowest and highest corner of the selected occluders' bounding box.
pub fn bounds(scene: &Scene, selected: &[usize]) -> ([f64; 3], [f64; 3]) {
    let mut lo = Vec3::repeat(f64::INFINITY);
    let mut hi = Vec3::repeat(f64::NEG_INFINITY);
    let mut add = |p: Vec3| {
        lo = lo.inf(&p);
        hi = hi.sup(&p);
    };
    for &i in selected {
        match scene.occluders().get(i) {
            Some(Occluder::Rect {
                center,
                half_u,
                half_v,
            }) => {
                let e = half_u.abs() + half_v.abs();
                add(center - e);
                add(center + e);
            }
            Some(Occluder::Sphere { center, radius }) => {
                add(center - Vec3::repeat(*radius));
                add(center + Vec3::repeat(*radius));
            }
            Some(Occluder::Mesh(m)) => m.triangles().iter().flatten().for_each(|p| add(*p)),
            None => {}
        }
    }
    (lo.into(), hi.into())
}

/// `scene` with the selected occluders moved by `d` and the hidden scene
/// sampled `supersample` times per side, its shadows as `shadows` says.
pub fn moved(
    scene: &Scene,
    selected: &[usize],
    d: [f64; 3],
    supersample: usize,
    shadows: ShadowModel,
) -> Result<Scene, SceneError> {
    let d = Vec3::from(d);
    scene.clone().edit(|p| {
        p.hidden.plane.supersample = supersample;
        p.hidden.shadows = shadows;
        for &i in selected {
            match p.occluders.get_mut(i) {
                Some(Occluder::Rect { center, .. } | Occluder::Sphere { center, .. }) => {
                    *center += d
                }
                Some(Occluder::Mesh(m)) => {
                    let tri = m.triangles().iter().map(|t| t.map(|p| p + d)).collect();
                    let mut source = m.source().clone();
                    let o = source.offset.unwrap_or([0.0; 3]);
                    source.offset = Some([o[0] + d.x, o[1] + d.y, o[2] + d.z]);
                    *m = std::sync::Arc::new(Mesh::new(tri, source));
                }
                None => {}
            }
        }
    })
}

/// The objective at one translation: `T` of the moved scene, then the
/// least-squares misfit of the data term of differences, summed over the
/// channels ([`least_squares_misfit`]).
fn objective(
    scene: &Scene,
    selected: &[usize],
    channels: &[Vec<f64>],
    d: [f64; 3],
    supersample: usize,
    options: &OccluderOptions,
) -> Result<f64, OccluderError> {
    let t = build(
        &moved(scene, selected, d, supersample, options.shadows)?,
        options.budget,
    )?;
    Ok(least_squares_misfit(&t, DataTerm::Differences, channels)?)
}

/// A positive, finite option or an error naming it.
fn positive(name: &'static str, value: f64) -> Result<f64, OccluderError> {
    if value.is_finite() && value > 0.0 {
        Ok(value)
    } else {
        Err(OccluderError::Parameter {
            name,
            value,
            reason: "must be a positive number of metres",
        })
    }
}

/// Checks the photo against the scene: at least one channel, each with one
/// value per row of `T`.
fn check_channels(scene: &Scene, channels: &[Vec<f64>]) -> Result<(), OccluderError> {
    if channels.is_empty() {
        return Err(OccluderError::NoChannels);
    }
    let rows = scene.rows();
    match channels.iter().position(|c| c.len() != rows) {
        Some(channel) => Err(OccluderError::Rows {
            channel,
            got: channels[channel].len(),
            rows,
        }),
        None => Ok(()),
    }
}

/// Fits the translation of the selected occluders that minimizes the
/// photo's misfit (the module's doc), by [`search`].
pub fn fit_occluder(
    scene: &Scene,
    channels: &[Vec<f64>],
    options: &OccluderOptions,
) -> Result<OccluderFit, OccluderError> {
    let start = Instant::now();
    let selected = selection(scene, options.selected.as_deref())?;
    check_channels(scene, channels)?;
    let range = positive("range", options.range)?;
    let pitch = shadow_pitch(scene, &selected);
    let min_step = positive("min-step", options.min_step.unwrap_or(pitch))?;
    let step = positive(
        "step",
        options.step.unwrap_or(STEP_SHADOW_PITCHES * min_step),
    )?;
    if step < min_step || step > range {
        return Err(OccluderError::Parameter {
            name: "step",
            value: step,
            reason: "must lie between min-step and range",
        });
    }
    let supersample = options.supersample.unwrap_or(match options.shadows {
        ShadowModel::Area => 1,
        ShadowModel::Point | ShadowModel::Auto => scene.hidden().plane.supersample.max(SUPERSAMPLE),
    });
    let mut probes = Vec::new();
    let mut f = |d: [f64; 3]| {
        let v = objective(scene, &selected, channels, d, supersample, options)?;
        probes.push(Probe {
            translation: d,
            objective: v,
        });
        Ok::<f64, OccluderError>(v)
    };
    let found = search(&mut f, step, min_step, range)?;
    let objective_start = probes.first().map_or(f64::NAN, |p| p.objective);
    // The misfit per degree of freedom: rows of differences less the unknowns, per channel.
    let g = scene.wall().plane.grid;
    let rows_per_channel =
        scene.block_count() * (g.nu.saturating_sub(1) * g.nv + g.nu * g.nv.saturating_sub(1));
    let rows = rows_per_channel * channels.len();
    let dof = rows.saturating_sub(scene.cols() * channels.len()).max(1);
    let s2 = found.value / dof as f64;
    let sd = found.curvature.map(|c| {
        if c > 0.0 {
            (2.0 * s2 / c).sqrt()
        } else {
            f64::INFINITY
        }
    });
    let (lo, _) = bounds(scene, &selected);
    Ok(OccluderFit {
        selected,
        translation: found.point,
        sd,
        curvature: found.curvature,
        corner_start: lo,
        corner_end: [0, 1, 2].map(|a| lo[a] + found.point[a]),
        objective_start,
        objective_end: found.value,
        rows,
        steps: [step, found.last_step],
        supersample,
        builds: probes.len(),
        seconds: start.elapsed().as_secs_f64(),
        probes,
    })
}

/// Where [`search`] ended.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Found {
    /// The best evaluated point moved to its per-axis parabola's vertex.
    pub point: [f64; 3],
    /// The lowest value evaluated.
    pub value: f64,
    /// Per axis, the parabola's curvature `f''` through the best point and
    /// its two neighbours at the last step (0 when not convex).
    pub curvature: [f64; 3],
    /// The last step.
    pub last_step: f64,
}

/// Minimizes `f` over translations within `range` of the origin along each
/// axis: a compass search (each axis in turn, stepping on while it
/// improves) whose step halves from `step` down to `min_step` whenever no
/// neighbour is lower, then a parabola per axis through the best point and
/// its two neighbours for the sub-step position and the curvature.
///
/// Why: `f` costs one `T` build per point, so the search moves on a lattice
/// (no point is evaluated twice) down to the shadow pitch and lets the
/// parabolas place the minimum between its points.
pub fn search<E>(
    f: &mut dyn FnMut([f64; 3]) -> Result<f64, E>,
    step: f64,
    min_step: f64,
    range: f64,
) -> Result<Found, E> {
    let unit = min_step / 4.0;
    let key = |p: [f64; 3]| p.map(|x| (x / unit).round() as i64);
    let mut seen: HashMap<[i64; 3], f64> = HashMap::new();
    let mut eval = |p: [f64; 3]| -> Result<f64, E> {
        if let Some(v) = seen.get(&key(p)) {
            return Ok(*v);
        }
        let v = f(p)?;
        seen.insert(key(p), v);
        Ok(v)
    };
    let (mut p, mut h) = ([0.0; 3], step);
    let mut fp = eval(p)?;
    loop {
        let mut moved = false;
        for a in 0..3 {
            moved |= line(&mut eval, &mut p, &mut fp, a, h, range)?;
        }
        if !moved {
            if h / 2.0 < min_step * (1.0 - 1e-9) {
                break;
            }
            h /= 2.0;
        }
    }
    let mut point = p;
    let mut curvature = [0.0; 3];
    for a in 0..3 {
        let (mut lo, mut hi) = (p, p);
        lo[a] -= h;
        hi[a] += h;
        let (fl, fh) = (eval(lo)?, eval(hi)?);
        let c = (fl + fh - 2.0 * fp) / (h * h);
        if c > 0.0 {
            curvature[a] = c;
            point[a] += (h * (fl - fh) / (2.0 * c * h * h)).clamp(-h, h);
        }
    }
    Ok(Found {
        point,
        value: fp,
        curvature,
        last_step: h,
    })
}

/// One axis of the compass search: tries `p ± h` along axis `a` and, while
/// the better side improves, steps on (within `range`). Whether it moved.
fn line<E>(
    eval: &mut dyn FnMut([f64; 3]) -> Result<f64, E>,
    p: &mut [f64; 3],
    fp: &mut f64,
    a: usize,
    h: f64,
    range: f64,
) -> Result<bool, E> {
    let inside = |q: &[f64; 3]| q[a].abs() <= range * (1.0 + 1e-9);
    let mut best: Option<(f64, f64)> = None;
    for dir in [1.0, -1.0] {
        let mut q = *p;
        q[a] += dir * h;
        if !inside(&q) {
            continue;
        }
        let v = eval(q)?;
        if v < *fp && best.is_none_or(|(_, b)| v < b) {
            best = Some((dir, v));
        }
    }
    let Some((dir, v)) = best else {
        return Ok(false);
    };
    p[a] += dir * h;
    *fp = v;
    loop {
        let mut q = *p;
        q[a] += dir * h;
        if !inside(&q) {
            return Ok(true);
        }
        let v = eval(q)?;
        if v >= *fp {
            return Ok(true);
        }
        *p = q;
        *fp = v;
    }
}

/// The scene file's text with the selected `[[occluder]]` entries moved by
/// `d` (a rect's or sphere's `center`, a mesh's `offset`), validated as a
/// file in `dir` (where a relative mesh path is read from).
pub fn scene_with_occluders_moved(
    scene_toml: &str,
    selected: &[usize],
    d: [f64; 3],
    dir: &Path,
) -> Result<String, OccluderError> {
    let bad = |m: String| OccluderError::SceneFile(m);
    let mut table: toml::Table = toml::from_str(scene_toml).map_err(|e| bad(e.to_string()))?;
    let entries = table
        .get_mut("occluder")
        .and_then(|o| o.as_array_mut())
        .ok_or(OccluderError::NoOccluders)?;
    let count = entries.len();
    for &i in selected {
        let entry = entries
            .get_mut(i)
            .and_then(|e| e.as_table_mut())
            .ok_or(OccluderError::Index { index: i, count })?;
        let (table, key) = if entry.contains_key("mesh") {
            (entry, "offset")
        } else {
            let shape = ["rect", "sphere"]
                .into_iter()
                .find(|k| entry.contains_key(*k))
                .ok_or_else(|| bad(format!("occluder[{i}] is neither rect, sphere nor mesh")))?;
            let t = entry
                .get_mut(shape)
                .and_then(|v| v.as_table_mut())
                .ok_or_else(|| bad(format!("occluder[{i}].{shape} is not a table")))?;
            (t, "center")
        };
        let old: Vec<f64> = match table.get(key) {
            None => vec![0.0; 3],
            Some(v) => v
                .as_array()
                .map(|a| a.iter().filter_map(number).collect())
                .unwrap_or_default(),
        };
        if old.len() != 3 {
            return Err(bad(format!("occluder[{i}].{key} is not three numbers")));
        }
        let new = (0..3).map(|a| toml::Value::Float(old[a] + d[a])).collect();
        table.insert(key.into(), toml::Value::Array(new));
    }
    let text = toml::to_string_pretty(&table).map_err(|e| bad(e.to_string()))?;
    Scene::from_toml_str_in(&text, dir)?;
    Ok(text)
}

/// A TOML number as f64.
fn number(v: &toml::Value) -> Option<f64> {
    v.as_float().or_else(|| v.as_integer().map(|i| i as f64))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A small scene with two rect occluders and one sphere.
    const SCENE: &str = r#"
[wall]
center = [0.0, 0.0, 0.0]
normal = [0.0, 0.0, 1.0]
u_axis = [1.0, 0.0, 0.0]
size = [0.4, 0.4]
grid = [4, 4]
roughness = 1.0
ior = 1.5
ks = 0.0
kd = 1.0
diffuse = "lambert"

[scene]
center = [0.0, 0.0, 1.0]
normal = [0.0, 0.0, -1.0]
u_axis = [1.0, 0.0, 0.0]
size = [0.2, 0.2]
grid = [2, 2]

[[pose]]
name = "A"
camera = [0.0, -0.3, 0.5]
polarizer_deg = []

[[occluder]]
rect = { center = [0.0, 0.0, 0.5], half_u = [0.02, 0, 0], half_v = [0, 0.03, 0] }
[[occluder]]
sphere = { center = [0.05, 0.0, 0.25], radius = 0.01 }
[[occluder]]
rect = { center = [-0.05, 0.0, 0.5], half_u = [0.01, 0, 0], half_v = [0, 0.01, 0] }
"#;

    #[test]
    fn the_search_finds_the_minimum_of_a_tilted_bowl_to_within_its_last_step() {
        // A bowl with a valley across x and y, its minimum off every lattice point.
        let m = [0.0137, -0.0071, 0.0029];
        let mut calls = 0;
        let mut f = |p: [f64; 3]| -> Result<f64, ()> {
            calls += 1;
            let d = [p[0] - m[0], p[1] - m[1], p[2] - m[2]];
            Ok(1.0 + d[0] * d[0] + 2.0 * d[1] * d[1] + 0.5 * d[2] * d[2] + 0.8 * d[0] * d[1])
        };
        let found = search(&mut f, 0.008, 0.002, 0.05).unwrap();
        for ((p, m), c) in found.point.iter().zip(m).zip(found.curvature) {
            assert!((p - m).abs() < 0.002 && c > 0.0, "{found:?}");
        }
        assert_eq!(found.last_step, 0.002);
        assert!(calls < 60, "{calls} evaluations");
    }

    #[test]
    fn the_search_stays_within_its_range() {
        let mut f = |p: [f64; 3]| -> Result<f64, ()> { Ok(-p[0] + p[1] * p[1] + p[2] * p[2]) };
        let found = search(&mut f, 0.01, 0.005, 0.03).unwrap();
        assert!((found.point[0] - 0.03).abs() < 1e-12, "{found:?}");
        // A failing objective ends the search with its error.
        let mut bad = |_: [f64; 3]| -> Result<f64, &str> { Err("no T") };
        assert_eq!(search(&mut bad, 0.01, 0.005, 0.03), Err("no T"));
    }

    #[test]
    fn bad_selections_photos_and_options_are_errors_naming_them() {
        let scene = Scene::from_toml_str(SCENE).unwrap();
        let photo = vec![vec![0.0; 16]];
        let fit = |sel: Option<Vec<usize>>, ch: &[Vec<f64>], range: f64| {
            let o = OccluderOptions {
                selected: sel,
                range,
                ..OccluderOptions::default()
            };
            fit_occluder(&scene, ch, &o).unwrap_err().to_string()
        };
        let e = fit(Some(vec![0, 3]), &photo, 0.05);
        assert!(e.contains("occluder 3") && e.contains("has 3"), "{e}");
        assert!(fit(Some(vec![]), &photo, 0.05).contains("empty"));
        let e = fit(None, &[vec![0.0; 15]], 0.05);
        assert!(
            e.contains("channel 0 has 15") && e.contains("16 rows"),
            "{e}"
        );
        assert!(fit(None, &[], 0.05).contains("no channel"));
        let e = fit(None, &photo, -0.01);
        assert!(e.starts_with("range = -0.01"), "{e}");
        assert!(fit(None, &photo, f64::NAN).starts_with("range = NaN"));
        let bare = scene.clone().edit(|p| p.occluders.clear()).unwrap();
        let e = fit_occluder(&bare, &photo, &OccluderOptions::default()).unwrap_err();
        assert!(e.to_string().contains("no [[occluder]]"), "{e}");
    }

    #[test]
    fn moving_occluders_moves_only_the_selected_in_the_scene_and_its_file() {
        let scene = Scene::from_toml_str(SCENE).unwrap();
        let d = [0.01, -0.02, 0.005];
        let m = moved(&scene, &[0, 1], d, 1, ShadowModel::Point).unwrap();
        let text = scene_with_occluders_moved(SCENE, &[0, 1], d, Path::new("")).unwrap();
        let written = Scene::from_toml_str(&text).unwrap();
        assert_eq!(written.occluders(), m.occluders());
        let (lo, hi) = bounds(&scene, &[0, 1]);
        let (lo2, hi2) = bounds(&m, &[0, 1]);
        for a in 0..3 {
            assert!((lo2[a] - lo[a] - d[a]).abs() < 1e-12);
            assert!((hi2[a] - hi[a] - d[a]).abs() < 1e-12);
        }
        assert_eq!(m.occluders()[2], scene.occluders()[2]);
        assert_eq!(lo, [-0.02, -0.03, 0.24]);
        let e = scene_with_occluders_moved(SCENE, &[5], d, Path::new("")).unwrap_err();
        assert!(e.to_string().contains("occluder 5"), "{e}");
        // The rect at depth 0.5 of a 1 m gap casts a shadow 2x its motion:
        // half a wall element (0.1 m) per shadow pitch.
        assert!((shadow_pitch(&scene, &[0]) - 0.05).abs() < 1e-12);
    }
}
