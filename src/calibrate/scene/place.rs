//! A bench's geometry moved by a fit's offsets: in a scene (the `T` the fit
//! builds) and in its file (the placed scene a user keeps).
//!
//! Why one room: the fit and the file it writes must move the same parts by
//! the same rule, or the written scene would not be the one fitted.

use std::path::Path;

use super::SceneFitError;
use crate::optics::Vec3;
use crate::scene::{Mesh, Occluder, Scene, SceneError, SceneParts};

/// One number of the geometry that `calibrate scene` can fit.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Freedom {
    /// The selected occluders' common translation along world x, metres.
    OccluderX,
    /// ... along world y, metres.
    OccluderY,
    /// ... along world z, metres.
    OccluderZ,
    /// The hidden plane moved along its own u axis, metres.
    SceneU,
    /// The hidden plane moved along its own v axis, metres.
    SceneV,
    /// The wall (and every camera) moved away from the hidden scene along
    /// the wall's normal, metres: the wall-to-scene distance grows by it.
    Distance,
    /// The selected occluders turned about the hidden plane's v axis
    /// through their bounding box's centre, degrees (right-handed).
    OccluderYaw,
    /// The wall's field of view moved along the wall's u axis, metres.
    WallU,
    /// The wall's field of view moved along the wall's v axis, metres.
    WallV,
}

impl Freedom {
    /// Every freedom, in report order.
    pub const ALL: [Freedom; 9] = [
        Freedom::OccluderX,
        Freedom::OccluderY,
        Freedom::OccluderZ,
        Freedom::SceneU,
        Freedom::SceneV,
        Freedom::Distance,
        Freedom::OccluderYaw,
        Freedom::WallU,
        Freedom::WallV,
    ];

    /// What a fit frees when it is not told: what a tape measure gets
    /// wrong most (the occluders, the monitor in its plane, the distance).
    pub const DEFAULT: [Freedom; 6] = [
        Freedom::OccluderX,
        Freedom::OccluderY,
        Freedom::OccluderZ,
        Freedom::SceneU,
        Freedom::SceneV,
        Freedom::Distance,
    ];

    /// Its name on a command line and in a report.
    pub fn name(self) -> &'static str {
        match self {
            Freedom::OccluderX => "occluder-x",
            Freedom::OccluderY => "occluder-y",
            Freedom::OccluderZ => "occluder-z",
            Freedom::SceneU => "scene-u",
            Freedom::SceneV => "scene-v",
            Freedom::Distance => "distance",
            Freedom::OccluderYaw => "occluder-yaw",
            Freedom::WallU => "wall-u",
            Freedom::WallV => "wall-v",
        }
    }

    /// The freedom named `name` ([`Freedom::name`]).
    pub fn parse(name: &str) -> Option<Freedom> {
        Freedom::ALL.into_iter().find(|f| f.name() == name)
    }

    /// Whether it is an angle (degrees) rather than a length (metres).
    pub fn angular(self) -> bool {
        self == Freedom::OccluderYaw
    }

    /// Its unit in a report.
    pub fn unit(self) -> &'static str {
        if self.angular() {
            "°"
        } else {
            "mm"
        }
    }

    /// A value in its report unit (millimetres or degrees).
    pub fn shown(self, value: f64) -> f64 {
        if self.angular() {
            value
        } else {
            value * 1e3
        }
    }
}

/// Offsets of the geometry from the scene file's, one per [`Freedom`]
/// (zero: as written).
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct Placement(pub [f64; 9]);

impl Placement {
    /// The offset of `f`.
    pub fn get(&self, f: Freedom) -> f64 {
        self.0[f as usize]
    }

    /// Sets the offset of `f`.
    pub fn set(&mut self, f: Freedom, value: f64) {
        self.0[f as usize] = value;
    }

    /// `scene` moved by this placement, every occluder together (as a fit
    /// of all occluders places them): a bench that stands off its file, for
    /// a simulation or a fake camera to show.
    pub fn moved(&self, scene: &Scene) -> Result<Scene, crate::scene::SceneError> {
        let all: Vec<usize> = (0..scene.occluders().len()).collect();
        let centre = match all.is_empty() {
            true => Vec3::zeros(),
            false => pivot(scene, &all),
        };
        scene.clone().edit(|p| place(p, &all, centre, self))
    }
}

/// `p` rotated by `angle` radians about the unit `axis` through `pivot`
/// (Rodrigues' formula).
fn rotate(p: Vec3, pivot: Vec3, axis: Vec3, angle: f64) -> Vec3 {
    let r = p - pivot;
    let (s, c) = angle.sin_cos();
    pivot + r * c + axis.cross(&r) * s + axis * (axis.dot(&r) * (1.0 - c))
}

/// A direction rotated as [`rotate`] rotates points.
fn turn(d: Vec3, axis: Vec3, angle: f64) -> Vec3 {
    rotate(d, Vec3::zeros(), axis, angle)
}

/// The scene's parts moved by `at`: the selected occluders turned about
/// `pivot` and translated, the hidden plane and the wall's field of view
/// moved in their planes, the wall and every camera moved along the
/// wall's normal.
pub(crate) fn place(p: &mut SceneParts, selected: &[usize], pivot: Vec3, at: &Placement) {
    let axis = p.hidden.plane.v;
    let yaw = at.get(Freedom::OccluderYaw).to_radians();
    let t = Vec3::new(
        at.get(Freedom::OccluderX),
        at.get(Freedom::OccluderY),
        at.get(Freedom::OccluderZ),
    );
    let moved = |q: Vec3| rotate(q, pivot, axis, yaw) + t;
    for &i in selected {
        match p.occluders.get_mut(i) {
            Some(Occluder::Rect {
                center,
                half_u,
                half_v,
            }) => {
                *center = moved(*center);
                *half_u = turn(*half_u, axis, yaw);
                *half_v = turn(*half_v, axis, yaw);
            }
            Some(Occluder::Sphere { center, .. }) => *center = moved(*center),
            Some(Occluder::Mesh(m)) => {
                let tri = m.triangles().iter().map(|t| t.map(moved)).collect();
                let mut source = m.source().clone();
                let o = source.offset.unwrap_or([0.0; 3]);
                source.offset = Some([o[0] + t.x, o[1] + t.y, o[2] + t.z]);
                *m = std::sync::Arc::new(Mesh::new(tri, source));
            }
            None => {}
        }
    }
    let hidden = &mut p.hidden.plane;
    hidden.center += hidden.u * at.get(Freedom::SceneU) + hidden.v * at.get(Freedom::SceneV);
    let away = -p.wall.plane.normal * at.get(Freedom::Distance);
    let wall = &mut p.wall.plane;
    wall.center += away + wall.u * at.get(Freedom::WallU) + wall.v * at.get(Freedom::WallV);
    for pose in &mut p.poses {
        pose.camera += away;
    }
}

/// The centre of the selected occluders' bounding box: the pivot of
/// [`Freedom::OccluderYaw`].
pub(crate) fn pivot(scene: &Scene, selected: &[usize]) -> Vec3 {
    let (lo, hi) = crate::calibrate::occluder::bounds(scene, selected);
    (Vec3::from(lo) + Vec3::from(hi)) * 0.5
}

/// Photos, each its channels, each one value per row of `T`.
pub(crate) type Photos = Vec<Vec<Vec<f64>>>;

/// A scene's wall resampled `factor` times coarser per axis (the elements
/// that do not fill a whole coarse one left out), with the rows of
/// `channels` averaged to match; `None` when the wall is too small.
///
/// Why: the coarse level of a coarse-to-fine fit solves a ninth of the
/// full wall's least squares (factor 3), and its misfit is smoother.
pub(crate) fn coarse_wall(
    scene: &Scene,
    factor: usize,
    photos: &[Vec<Vec<f64>>],
) -> Result<Option<(Scene, Photos)>, SceneError> {
    let plane = &scene.wall().plane;
    let g = plane.grid;
    let (nu, nv) = (g.nu / factor.max(1), g.nv / factor.max(1));
    if factor <= 1 || nu < 4 || nv < 4 {
        return Ok(None);
    }
    let pitch = [plane.size[0] / g.nu as f64, plane.size[1] / g.nv as f64];
    let size = [
        (nu * factor) as f64 * pitch[0],
        (nv * factor) as f64 * pitch[1],
    ];
    let shift =
        plane.u * ((size[0] - plane.size[0]) / 2.0) + plane.v * ((size[1] - plane.size[1]) / 2.0);
    let coarse = scene.clone().edit(|p| {
        p.wall.plane.grid = crate::scene::Grid { nu, nv };
        // Each coarse element averages the fine elements' own samples: the
        // coarse model is the block mean of the fine one, as its photo is.
        p.wall.plane.supersample *= factor;
        p.wall.plane.size = size;
        p.wall.plane.center += shift;
    })?;
    let blocks = scene.block_count();
    let average = |c: &Vec<f64>| -> Vec<f64> {
        let mut out = vec![0.0; blocks * nu * nv];
        let w = 1.0 / (factor * factor) as f64;
        for b in 0..blocks {
            for iv in 0..nv * factor {
                for iu in 0..nu * factor {
                    let from = b * g.count() + iv * g.nu + iu;
                    let to = b * nu * nv + (iv / factor) * nu + iu / factor;
                    out[to] += c.get(from).copied().unwrap_or(0.0) * w;
                }
            }
        }
        out
    };
    let photos = photos
        .iter()
        .map(|channels| channels.iter().map(average).collect())
        .collect();
    Ok(Some((coarse, photos)))
}

/// A TOML array of a point, rounded to 0.1 µm (far below any bench's
/// precision, so the file stays readable).
fn point(v: Vec3) -> toml_edit::Value {
    let r = |x: f64| (x * 1e7).round() / 1e7;
    toml_edit::Value::Array([r(v.x), r(v.y), r(v.z)].into_iter().collect())
}

/// The scene file `text` (a file in `from_dir`) with its geometry placed
/// at `at`, as a file in `to_dir`: only the moved values change (centres,
/// cameras, a turned rectangle's half vectors, a mesh's offset); comments,
/// order and every other value stay as written, relative mesh paths are
/// rewritten for `to_dir`, and the result is validated there.
pub(crate) fn placed_scene_file(
    text: &str,
    from_dir: &Path,
    selected: &[usize],
    at: &Placement,
    to_dir: &Path,
) -> Result<String, SceneFitError> {
    use crate::calibrate::scene_text::{entries, rebase_mesh_paths, set_value};
    let scene = Scene::from_toml_str_in(text, from_dir)?;
    let pivot = pivot(&scene, selected);
    let moved = scene.clone().edit(|p| place(p, selected, pivot, at))?;
    let mut doc: toml_edit::DocumentMut = text.parse().map_err(SceneFitError::Toml)?;
    set_center(&mut doc, "wall", moved.wall().plane.center)?;
    set_center(&mut doc, "scene", moved.hidden().plane.center)?;
    for (entry, pose) in entries(&mut doc, "pose").into_iter().zip(moved.poses()) {
        if entry.contains_key("camera") {
            set_value(entry, "camera", point(pose.camera));
        }
    }
    let yaw = at.get(Freedom::OccluderYaw) != 0.0;
    for (i, entry) in entries(&mut doc, "occluder").into_iter().enumerate() {
        if !selected.contains(&i) {
            continue;
        }
        match moved.occluders().get(i) {
            Some(Occluder::Rect {
                center,
                half_u,
                half_v,
            }) => {
                if let Some(rect) = entry.get_mut("rect").and_then(|r| r.as_table_like_mut()) {
                    set_value(rect, "center", point(*center));
                    if yaw {
                        set_value(rect, "half_u", point(*half_u));
                        set_value(rect, "half_v", point(*half_v));
                    }
                }
            }
            Some(Occluder::Sphere { center, .. }) => {
                if let Some(s) = entry.get_mut("sphere").and_then(|r| r.as_table_like_mut()) {
                    set_value(s, "center", point(*center));
                }
            }
            Some(Occluder::Mesh(m)) => {
                if yaw {
                    return Err(SceneFitError::TurnedMesh(i));
                }
                if let Some(o) = m.source().offset {
                    set_value(entry, "offset", point(Vec3::from(o)));
                }
            }
            None => {}
        }
    }
    rebase_mesh_paths(&mut doc, from_dir, to_dir)?;
    let out = doc.to_string();
    Scene::from_toml_str_in(&out, to_dir)?;
    Ok(out)
}

/// Sets `[key] center` of `doc` to `c`.
fn set_center(
    doc: &mut toml_edit::DocumentMut,
    key: &'static str,
    c: Vec3,
) -> Result<(), SceneFitError> {
    let t = doc
        .get_mut(key)
        .and_then(toml_edit::Item::as_table_like_mut)
        .ok_or(SceneFitError::Missing(key))?;
    crate::calibrate::scene_text::set_value(t, "center", point(c));
    Ok(())
}
