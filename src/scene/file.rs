//! The TOML schema of a scene file and its validation into a [`Scene`].

use std::path::Path;
use std::sync::Arc;

use serde::{Deserialize, Serialize};

use super::mesh::{self, MeshError};
use super::occluder::{Mesh, MeshSource};
use super::{
    crossed_axis, Analyzer, CameraFrame, Emitter, Grid, HiddenScene, Homography, LeftOut, Mosaic,
    MosaicLayout, Occluder, Plane, Pose, Scene, SceneError, SceneParts, ShadowModel, Wall,
    WallSampling,
};
use crate::optics::{Brdf, DiffuseModel, PolarizerModel, Vec3};

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawFile {
    wall: RawWall,
    scene: RawScenePlane,
    #[serde(default)]
    pose: Vec<RawPose>,
    #[serde(default)]
    occluder: Vec<RawOccluder>,
    /// Read as a table so that an unknown key is an error naming it.
    polarizer: Option<toml::Table>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawWall {
    center: [f64; 3],
    normal: [f64; 3],
    u_axis: [f64; 3],
    size: [f64; 2],
    grid: [i64; 2],
    supersample: Option<i64>,
    roughness: f64,
    ior: f64,
    #[serde(default = "unit")]
    ks: f64,
    #[serde(default)]
    kd: f64,
    /// Read as a value so that a wrong one is an error naming the key.
    diffuse: Option<toml::Value>,
    /// Likewise.
    sampling: Option<toml::Value>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawScenePlane {
    center: [f64; 3],
    normal: [f64; 3],
    u_axis: [f64; 3],
    size: [f64; 2],
    grid: [i64; 2],
    supersample: Option<i64>,
    #[serde(default = "lambertian")]
    emitter: Emitter,
    lobe: Option<[f64; 2]>,
    polarization: Option<[f64; 3]>,
    shadows: Option<ShadowModel>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawPose {
    name: String,
    camera: [f64; 3],
    polarizer_deg: Option<Vec<f64>>,
    /// `"mosaic"`: an on-chip polarizer mosaic instead of a sheet.
    analyzer: Option<String>,
    sensor_deg: Option<f64>,
    extinction: Option<f64>,
    layout: Option<String>,
    homography: Option<[[f64; 3]; 3]>,
    region: Option<[i64; 4]>,
    binning: Option<[i64; 2]>,
}

#[derive(Deserialize, Serialize, Default)]
#[serde(deny_unknown_fields)]
struct RawOccluder {
    #[serde(skip_serializing_if = "Option::is_none")]
    rect: Option<RawRect>,
    #[serde(skip_serializing_if = "Option::is_none")]
    sphere: Option<RawSphere>,
    /// An OBJ or STL file, relative to the scene file's folder.
    #[serde(skip_serializing_if = "Option::is_none")]
    mesh: Option<String>,
    /// The mesh's unit in metres (`0.001` for millimetres); default 1.
    #[serde(skip_serializing_if = "Option::is_none")]
    scale: Option<f64>,
    /// Added to every mesh vertex after `scale`, metres.
    #[serde(skip_serializing_if = "Option::is_none")]
    offset: Option<[f64; 3]>,
    /// The mesh already read and checked: an edited scene keeps its
    /// triangles instead of reading the file again.
    #[serde(skip)]
    loaded: Option<Arc<Mesh>>,
}

#[derive(Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
struct RawRect {
    center: [f64; 3],
    half_u: [f64; 3],
    half_v: [f64; 3],
}

#[derive(Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
struct RawSphere {
    center: [f64; 3],
    radius: f64,
}

fn unit() -> f64 {
    1.0
}
fn lambertian() -> Emitter {
    Emitter::Lambertian
}

/// Largest exponent of a `lobe`: cos^1000 is already a 3-degree beam.
const MAX_LOBE: f64 = 1000.0;

/// Largest grid side accepted; a typo like `grid = [32000, 32000]` should be an
/// error, not an attempt to allocate a terabyte.
const MAX_GRID: i64 = 4096;
/// Largest supersampling per side. A partial occluder's shadow edge makes
/// the integrand discontinuous, so its error falls only as 1/m: against a
/// path tracer a 0.06 m occluder on the bench needs m = 32 to reach the
/// render's 0.3 % noise (validation/mitsuba/README.md). The memory this costs
/// on the wall is checked with `T` itself.
const MAX_SUPERSAMPLE: i64 = 32;

/// Parses and validates scene text whose relative paths (`mesh`) are in `dir`.
pub(super) fn parse(text: &str, dir: &Path) -> Result<Scene, SceneError> {
    let raw: RawFile = toml::from_str(text).map_err(|e| SceneError::Parse {
        path: None,
        message: e.to_string().trim_end().to_string(),
    })?;
    validate(raw, dir)
}

/// Validates the parts of an edited scene exactly as a file is validated: they
/// are written back in the file's terms (the values a file gives, not the
/// derived ones) and read again.
pub(super) fn revalidate(parts: SceneParts) -> Result<Scene, SceneError> {
    validate(RawFile::from(parts), Path::new(""))
}

/// A count in the file's integer type; one too large for it stays too large.
fn count(n: usize) -> i64 {
    i64::try_from(n).unwrap_or(i64::MAX)
}

fn array(v: Vec3) -> [f64; 3] {
    [v.x, v.y, v.z]
}

impl From<SceneParts> for RawFile {
    fn from(p: SceneParts) -> Self {
        let (w, s) = (p.wall.plane, p.hidden.plane);
        let (brdf, sampling, left_out) = (p.wall.brdf, p.wall.sampling, p.left_out);
        let mut polarizer = toml::Table::new();
        polarizer.insert("model".into(), p.polarizer.name().into());
        RawFile {
            wall: RawWall {
                center: array(w.center),
                normal: array(w.normal),
                u_axis: array(w.u),
                size: w.size,
                grid: [count(w.grid.nu), count(w.grid.nv)],
                supersample: (!left_out.wall_supersample || w.supersample != 1)
                    .then(|| count(w.supersample)),
                roughness: brdf.alpha,
                ior: brdf.eta,
                ks: brdf.ks,
                kd: brdf.kd,
                diffuse: Some(brdf.diffuse.name().into()),
                sampling: (!left_out.sampling || sampling != WallSampling::default())
                    .then(|| sampling.name().into()),
            },
            scene: RawScenePlane {
                center: array(s.center),
                normal: array(s.normal),
                u_axis: array(s.u),
                size: s.size,
                grid: [count(s.grid.nu), count(s.grid.nv)],
                supersample: (!left_out.scene_supersample || s.supersample != 1)
                    .then(|| count(s.supersample)),
                emitter: p.hidden.emitter,
                lobe: p.hidden.lobe,
                polarization: p.hidden.polarization.map(array),
                shadows: (p.hidden.shadows != ShadowModel::Auto).then_some(p.hidden.shadows),
            },
            pose: p
                .poses
                .into_iter()
                .map(|pose| RawPose {
                    name: pose.name,
                    camera: array(pose.camera),
                    polarizer_deg: pose
                        .mosaic
                        .is_none()
                        .then(|| pose.analyzers.iter().map(|a| a.angle_deg).collect()),
                    analyzer: pose.mosaic.map(|_| "mosaic".to_string()),
                    sensor_deg: pose.mosaic.map(|m| m.sensor_deg),
                    extinction: pose.mosaic.and_then(|m| m.extinction),
                    layout: pose.mosaic.map(|m| m.layout.name().to_string()),
                    homography: pose.homography.map(|h| h.matrix()),
                    region: pose.frame.map(|f| f.region.map(i64::from)),
                    binning: pose.frame.map(|f| f.binning.map(i64::from)),
                })
                .collect(),
            occluder: p.occluders.into_iter().map(raw_occluder).collect(),
            polarizer: Some(polarizer),
        }
    }
}

/// An occluder in the file's terms: a rect's or sphere's keys, a mesh's
/// keys as written (with its triangles kept).
fn raw_occluder(o: Occluder) -> RawOccluder {
    match o {
        Occluder::Rect {
            center,
            half_u,
            half_v,
        } => RawOccluder {
            rect: Some(RawRect {
                center: array(center),
                half_u: array(half_u),
                half_v: array(half_v),
            }),
            ..RawOccluder::default()
        },
        Occluder::Sphere { center, radius } => RawOccluder {
            sphere: Some(RawSphere {
                center: array(center),
                radius,
            }),
            ..RawOccluder::default()
        },
        Occluder::Mesh(mesh) => RawOccluder {
            mesh: Some(mesh.source().path.clone()),
            scale: mesh.source().scale,
            offset: mesh.source().offset,
            loaded: Some(mesh),
            ..RawOccluder::default()
        },
    }
}

impl Scene {
    /// The scene's `[[occluder]]` entries as a scene file writes them (a
    /// rect's or sphere's keys; a mesh's `mesh`, `scale` and `offset`), each
    /// mesh path replaced by what `path` makes of the path as written.
    ///
    /// Why: a tool that moves occluders (`calibrate occluder`) writes them
    /// in the file's own terms, and a relative mesh path must be rewritten
    /// for a file written to another folder.
    pub fn occluder_tables(
        &self,
        path: &mut dyn FnMut(usize, &str) -> Result<String, SceneError>,
    ) -> Result<Vec<toml::Table>, SceneError> {
        let mut out = Vec::with_capacity(self.occluders().len());
        for (i, o) in self.occluders().iter().enumerate() {
            let mut raw = raw_occluder(o.clone());
            if let Some(p) = raw.mesh.take() {
                raw.mesh = Some(path(i, &p)?);
            }
            let table = toml::Table::try_from(&raw).map_err(|e| {
                SceneError::invalid(
                    format!("occluder[{i}]"),
                    o,
                    format!("cannot be written: {e}"),
                )
            })?;
            out.push(table);
        }
        Ok(out)
    }
}

fn point(key: &str, v: [f64; 3]) -> Result<Vec3, SceneError> {
    if v.iter().any(|x| !x.is_finite()) {
        return Err(SceneError::invalid(key, v, "must be three finite numbers"));
    }
    Ok(Vec3::from(v))
}

fn direction(key: &str, v: [f64; 3]) -> Result<Vec3, SceneError> {
    let p = point(key, v)?;
    let n = p.norm();
    if n < 1e-12 {
        return Err(SceneError::invalid(key, v, "must be a non-zero direction"));
    }
    Ok(p / n)
}

fn plane(
    section: &str,
    c: [f64; 3],
    n: [f64; 3],
    u: [f64; 3],
    size: [f64; 2],
    grid: [i64; 2],
    m: i64,
) -> Result<Plane, SceneError> {
    let center = point(&format!("{section}.center"), c)?;
    let normal = direction(&format!("{section}.normal"), n)?;
    let u_raw = direction(&format!("{section}.u_axis"), u)?;
    // Gram-Schmidt: keep u in the plane even when the file is slightly off.
    let u_perp = u_raw - normal * normal.dot(&u_raw);
    if u_perp.norm() < 1e-6 {
        return Err(SceneError::invalid(
            format!("{section}.u_axis"),
            u,
            format!("is parallel to {section}.normal; it must lie in the plane"),
        ));
    }
    let u_axis = u_perp.normalize();
    if size.iter().any(|s| !s.is_finite() || *s <= 0.0) {
        return Err(SceneError::invalid(
            format!("{section}.size"),
            size,
            "both sides must be positive metres",
        ));
    }
    if grid.iter().any(|g| *g < 1 || *g > MAX_GRID) {
        return Err(SceneError::invalid(
            format!("{section}.grid"),
            grid,
            format!("both counts must be whole numbers from 1 to {MAX_GRID}"),
        ));
    }
    if !(1..=MAX_SUPERSAMPLE).contains(&m) {
        return Err(SceneError::invalid(
            format!("{section}.supersample"),
            m,
            format!("must be a whole number from 1 to {MAX_SUPERSAMPLE}"),
        ));
    }
    Ok(Plane {
        center,
        normal,
        u: u_axis,
        v: normal.cross(&u_axis),
        size,
        grid: Grid {
            nu: grid[0] as usize,
            nv: grid[1] as usize,
        },
        supersample: m as usize,
    })
}

/// A `mesh` occluder: the OBJ or STL file at `path` (relative to `dir`, the
/// scene file's folder), its vertices times `scale` plus `offset`; whatever
/// is wrong with the keys or the file is an error naming `occluder[i].mesh`
/// (or `.scale`, `.offset`).
fn mesh_occluder(
    key: &dyn Fn(&str) -> String,
    dir: &Path,
    path: String,
    scale: Option<f64>,
    offset: Option<[f64; 3]>,
) -> Result<Mesh, SceneError> {
    let factor = scale.unwrap_or(1.0);
    if !(factor.is_finite() && factor > 0.0) {
        return Err(SceneError::invalid(
            key("scale"),
            factor,
            "must be a finite number > 0 (metres per mesh unit, e.g. 0.001 for millimetres)",
        ));
    }
    let shift = point(&key("offset"), offset.unwrap_or([0.0; 3]))?;
    if path.trim().is_empty() {
        return Err(SceneError::invalid(
            key("mesh"),
            &path,
            "must name an .obj or .stl file",
        ));
    }
    let bad = |e: MeshError| SceneError::invalid(key("mesh"), &path, e.to_string());
    let raw = mesh::read(&dir.join(&path)).map_err(bad)?;
    let triangles = mesh::place(&raw, factor, shift).map_err(bad)?;
    Ok(Mesh::new(
        triangles,
        MeshSource {
            path,
            scale,
            offset,
        },
    ))
}

/// Largest refractive index accepted for the wall (germanium, the highest
/// common optical material, is about 4).
const MAX_IOR: f64 = 5.0;

/// Largest camera frame side accepted in a pose's region, pixels.
const MAX_FRAME_SIDE: i64 = 65_536;

/// Whether two linear-polarizer angles (degrees) are the same setting: equal modulo 180.
fn same_polarizer_setting(a: f64, b: f64) -> bool {
    let d = (a - b).rem_euclid(180.0);
    d < 1e-6 || 180.0 - d < 1e-6
}

/// A pose's on-chip polarizer mosaic (MODEL.md "On-chip polarizer mosaic"):
/// `analyzer = "mosaic"` with `sensor_deg`, `extinction` and `layout`; the
/// last three without it, or a mosaic with `polarizer_deg`, are errors naming the keys.
fn mosaic(key: &dyn Fn(&str) -> String, p: &RawPose) -> Result<Option<Mosaic>, SceneError> {
    match p.analyzer.as_deref() {
        None => {
            for (k, given) in [
                ("sensor_deg", p.sensor_deg.is_some()),
                ("extinction", p.extinction.is_some()),
                ("layout", p.layout.is_some()),
            ] {
                if given {
                    return Err(SceneError::invalid(
                        key(k),
                        &p.name,
                        "belongs to a pose with analyzer = \"mosaic\"; add that key or remove this one",
                    ));
                }
            }
            Ok(None)
        }
        Some("mosaic") => {
            if let Some(deg) = &p.polarizer_deg {
                return Err(SceneError::invalid(
                    format!("{} and {}", key("analyzer"), key("polarizer_deg")),
                    deg,
                    "a pose has either a polarizer sheet (polarizer_deg) or an on-chip mosaic (analyzer = \"mosaic\"), not both; remove one",
                ));
            }
            let sensor_deg = p.sensor_deg.unwrap_or(0.0);
            if !(-360.0..=360.0).contains(&sensor_deg) {
                return Err(SceneError::invalid(
                    key("sensor_deg"),
                    sensor_deg,
                    "must be degrees from -360 to 360",
                ));
            }
            if let Some(e) = p.extinction {
                if !(e > 1.0 && e.is_finite()) {
                    return Err(SceneError::invalid(
                        key("extinction"),
                        e,
                        "must be a finite ratio above 1 (e.g. 300); leave it out for ideal micro-polarizers",
                    ));
                }
            }
            let layout = match p.layout.as_deref() {
                None => MosaicLayout::default(),
                Some(name) => MosaicLayout::from_name(name).ok_or_else(|| {
                    SceneError::invalid(
                        key("layout"),
                        name,
                        format!(
                            "is not a known mosaic layout; known: {}",
                            MosaicLayout::ALL.map(MosaicLayout::name).join(", ")
                        ),
                    )
                })?,
            };
            Ok(Some(Mosaic {
                sensor_deg,
                extinction: p.extinction,
                layout,
            }))
        }
        Some(other) => Err(SceneError::invalid(
            key("analyzer"),
            other,
            "must be \"mosaic\" (an on-chip polarizer mosaic); leave it out for a polarizer sheet (polarizer_deg) or none",
        )),
    }
}

/// The camera frame a pose's homography was calibrated at: `region` (and
/// `binning`, default 1 x 1); both absent means the pose does not say.
fn camera_frame(
    key: &dyn Fn(&str) -> String,
    region: Option<[i64; 4]>,
    binning: Option<[i64; 2]>,
) -> Result<Option<CameraFrame>, SceneError> {
    let Some(r) = region else {
        if binning.is_some() {
            return Err(SceneError::invalid(
                key("binning"),
                binning,
                "needs region = [x, y, width, height] too: the frame the homography was calibrated at",
            ));
        }
        return Ok(None);
    };
    let [x, y, w, h] = r;
    if x < 0
        || y < 0
        || !(1..=MAX_FRAME_SIDE).contains(&w)
        || !(1..=MAX_FRAME_SIDE).contains(&h)
        || x + w > MAX_FRAME_SIDE
        || y + h > MAX_FRAME_SIDE
    {
        return Err(SceneError::invalid(
            key("region"),
            r,
            format!("must be [x, y, width, height] in pixels: offsets >= 0, sizes from 1 and everything within {MAX_FRAME_SIDE}"),
        ));
    }
    let b = binning.unwrap_or([1, 1]);
    if !b.iter().all(|v| (1..=64).contains(v)) {
        return Err(SceneError::invalid(
            key("binning"),
            b,
            "must be [x, y] factors from 1 to 64",
        ));
    }
    // The bounds above make every value fit u32.
    let u = |v: i64| v as u32;
    Ok(Some(CameraFrame {
        region: [u(x), u(y), u(w), u(h)],
        binning: [u(b[0]), u(b[1])],
    }))
}

/// `[wall] diffuse`: `"fresnel"` (default) or `"lambert"`.
fn diffuse_model(v: Option<toml::Value>) -> Result<DiffuseModel, SceneError> {
    let Some(v) = v else {
        return Ok(DiffuseModel::default());
    };
    v.as_str()
        .and_then(DiffuseModel::from_name)
        .ok_or_else(|| {
            SceneError::invalid(
                "wall.diffuse",
                v.to_string(),
                "must be \"fresnel\" (both interfaces of the wall, the default) or \"lambert\" (ideal depolarized Lambertian)",
            )
        })
}

/// `[wall] sampling`: `"uniform"` (default) or `"pixels"`.
fn wall_sampling(v: Option<toml::Value>) -> Result<WallSampling, SceneError> {
    let Some(v) = v else {
        return Ok(WallSampling::default());
    };
    v.as_str().and_then(WallSampling::from_name).ok_or_else(|| {
        SceneError::invalid(
            "wall.sampling",
            v.to_string(),
            "must be \"uniform\" (the element's supersample points, the default) or \"pixels\" (the wall points of the element's pixels, as the measurement weighs them)",
        )
    })
}

/// `[polarizer]`: only `model = "absorbing"` (default) or `"transmitting"`.
fn polarizer_model(t: Option<toml::Table>) -> Result<PolarizerModel, SceneError> {
    let Some(t) = t else {
        return Ok(PolarizerModel::default());
    };
    if let Some((key, v)) = t.iter().find(|(k, _)| k.as_str() != "model") {
        return Err(SceneError::invalid(
            format!("polarizer.{key}"),
            v.to_string(),
            "is not a key of [polarizer]; it takes only model = \"absorbing\" or \"transmitting\"",
        ));
    }
    let Some(v) = t.get("model") else {
        return Ok(PolarizerModel::default());
    };
    v.as_str()
        .and_then(PolarizerModel::from_name)
        .ok_or_else(|| {
            SceneError::invalid(
                "polarizer.model",
                v.to_string(),
                "must be \"absorbing\" (the tilted sheet as measured, the default) or \"transmitting\"",
            )
        })
}

fn validate(raw: RawFile, dir: &Path) -> Result<Scene, SceneError> {
    let polarizer = polarizer_model(raw.polarizer)?;
    let left_out = LeftOut {
        wall_supersample: raw.wall.supersample.is_none(),
        scene_supersample: raw.scene.supersample.is_none(),
        sampling: raw.wall.sampling.is_none(),
    };
    let wall = validate_wall(raw.wall)?;
    let hidden = validate_hidden(raw.scene, &wall.plane)?;
    let poses = validate_poses(raw.pose, &wall.plane, &hidden.plane)?;
    let occluders = validate_occluders(raw.occluder, dir)?;
    check_pixel_sampling(wall.sampling, &poses)?;
    Ok(Scene {
        wall,
        hidden,
        poses,
        occluders,
        polarizer,
        left_out,
    })
}

/// `[wall]`: its plane, its BRDF (roughness, index, weights, diffuse model) and its sampling.
/// The first section checked, so its errors come before any of `[scene]`'s, as they always have.
fn validate_wall(w: RawWall) -> Result<Wall, SceneError> {
    let sampling = wall_sampling(w.sampling)?;
    let wall_plane = plane(
        "wall",
        w.center,
        w.normal,
        w.u_axis,
        w.size,
        w.grid,
        w.supersample.unwrap_or(1),
    )?;
    if !(w.roughness > 0.0 && w.roughness <= 1.0) {
        return Err(SceneError::invalid(
            "wall.roughness",
            w.roughness,
            "must be in (0, 1]",
        ));
    }
    if !(w.ior > 1.0 && w.ior <= MAX_IOR) {
        return Err(SceneError::invalid(
            "wall.ior",
            w.ior,
            format!("must be a refractive index in (1, {MAX_IOR}] (paint and plaster about 1.5)"),
        ));
    }
    for (key, k) in [("wall.ks", w.ks), ("wall.kd", w.kd)] {
        if !(k >= 0.0 && k.is_finite()) {
            return Err(SceneError::invalid(key, k, "must be a finite weight >= 0"));
        }
    }
    let brdf = Brdf {
        alpha: w.roughness,
        eta: w.ior,
        ks: w.ks,
        kd: w.kd,
        diffuse: diffuse_model(w.diffuse)?,
    };
    Ok(Wall {
        plane: wall_plane,
        brdf,
        sampling,
    })
}

/// `[scene]`: the emitting plane, which must be in front of `wall`, with its lobe and polarization.
/// The side checks need the wall's plane, so this runs after [`validate_wall`].
fn validate_hidden(s: RawScenePlane, wall: &Plane) -> Result<HiddenScene, SceneError> {
    let scene_plane = plane(
        "scene",
        s.center,
        s.normal,
        s.u_axis,
        s.size,
        s.grid,
        s.supersample.unwrap_or(1),
    )?;
    let n = wall.normal;
    let c0 = wall.center;
    let s0 = scene_plane.center;
    if n.dot(&(s0 - c0)) <= 0.0 {
        return Err(SceneError::invalid(
            "scene.center",
            s.center,
            "is on or behind the wall; it must be on the side wall.normal points to",
        ));
    }
    if s.emitter == Emitter::Lambertian && scene_plane.normal.dot(&(c0 - s0)) <= 0.0 {
        return Err(SceneError::invalid(
            "scene.normal",
            s.normal,
            "faces away from the wall centre; a lambertian screen must face the wall (flip its sign or use emitter = \"isotropic\")",
        ));
    }
    let polarization = s
        .polarization
        .map(|p| direction("scene.polarization", p))
        .transpose()?;
    if let Some(l) = s.lobe {
        if !l
            .iter()
            .all(|n| n.is_finite() && (0.0..=MAX_LOBE).contains(n))
        {
            return Err(SceneError::invalid(
                "scene.lobe",
                l,
                "must be two exponents [n_u, n_v], each from 0 to 1000 (a monitor: about [1, 18])",
            ));
        }
    }
    let lobe = s.lobe.filter(|l| l.iter().any(|n| *n != 0.0));
    Ok(HiddenScene {
        plane: scene_plane,
        emitter: s.emitter,
        lobe,
        polarization,
        shadows: s.shadows.unwrap_or_default(),
    })
}

/// `[[pose]]`: at least one, each checked in file order against the earlier ones.
/// Names must be unique, so each pose is validated knowing the poses before it.
fn validate_poses(raw: Vec<RawPose>, wall: &Plane, scene: &Plane) -> Result<Vec<Pose>, SceneError> {
    if raw.is_empty() {
        return Err(SceneError::invalid(
            "pose",
            "[]",
            "at least one [[pose]] is required",
        ));
    }
    let mut poses = Vec::with_capacity(raw.len());
    for (i, p) in raw.into_iter().enumerate() {
        let pose = validate_pose(i, p, &poses, wall, scene)?;
        poses.push(pose);
    }
    Ok(poses)
}

/// `pose[i]`: its name, camera (in front of the wall), analyzers, homography and frame.
/// One pose's keys together, so every error names `pose[i].key` as before.
fn validate_pose(
    i: usize,
    p: RawPose,
    earlier: &[Pose],
    wall: &Plane,
    scene: &Plane,
) -> Result<Pose, SceneError> {
    let key = |k: &str| format!("pose[{i}].{k}");
    let name = pose_name(&key, &p.name, earlier)?;
    let camera = point(&key("camera"), p.camera)?;
    if wall.normal.dot(&(camera - wall.center)) <= 0.0 {
        return Err(SceneError::invalid(
            key("camera"),
            p.camera,
            format!("pose {name:?}: the camera is on or behind the wall"),
        ));
    }
    let mosaic = mosaic(&key, &p)?;
    let analyzers = pose_analyzers(
        &key,
        &p,
        &name,
        mosaic.as_ref(),
        &wall.center,
        &scene.center,
        &camera,
    )?;
    let homography = match p.homography {
        None => None,
        Some(h) => Some(Homography::new(h).ok_or_else(|| {
            SceneError::invalid(
                key("homography"),
                h,
                "must be a finite, invertible 3x3 matrix",
            )
        })?),
    };
    let frame = camera_frame(&key, p.region, p.binning)?;
    if let (Some(_), Some(f)) = (&mosaic, &frame) {
        if f.binning != [1, 1] {
            return Err(SceneError::invalid(
                key("binning"),
                f.binning,
                "must be [1, 1] on a pose with analyzer = \"mosaic\": a binned pixel mixes the micro-polarizers of a 2x2 cell",
            ));
        }
    }
    Ok(Pose {
        name,
        camera,
        analyzers,
        mosaic,
        homography,
        frame,
    })
}

/// A pose's name, trimmed: 1-64 letters, digits, '-', '_' or '.', unused by `earlier`.
/// Captures and API requests name poses, so a name must be safe and unambiguous.
fn pose_name(
    key: &dyn Fn(&str) -> String,
    raw: &str,
    earlier: &[Pose],
) -> Result<String, SceneError> {
    let name = raw.trim().to_string();
    if name.is_empty()
        || name.len() > 64
        || !name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || "-_.".contains(c))
    {
        return Err(SceneError::invalid(
            key("name"),
            raw,
            "must be 1-64 letters, digits, '-', '_' or '.'",
        ));
    }
    if earlier.iter().any(|q| q.name == name) {
        return Err(SceneError::invalid(
            key("name"),
            &name,
            "is used by an earlier pose; names must be unique",
        ));
    }
    Ok(name)
}

/// A pose's analyzers in block order: the mosaic's micro-polarizers, then the sheet's angles.
/// Both need the crossed axis of camera `o`, wall centre `c0` and scene centre `s0`, checked first.
fn pose_analyzers(
    key: &dyn Fn(&str) -> String,
    p: &RawPose,
    name: &str,
    mosaic: Option<&Mosaic>,
    c0: &Vec3,
    s0: &Vec3,
    camera: &Vec3,
) -> Result<Vec<Analyzer>, SceneError> {
    let polarizer_deg = p.polarizer_deg.clone().unwrap_or_default();
    let mut analyzers = Vec::with_capacity(polarizer_deg.len());
    if (!polarizer_deg.is_empty() || mosaic.is_some()) && crossed_axis(c0, s0, camera).is_none() {
        let k = if mosaic.is_some() {
            "analyzer"
        } else {
            "polarizer_deg"
        };
        return Err(SceneError::invalid(
            key(k),
            &p.polarizer_deg,
            format!("pose {name:?}: the crossed axis is undefined because the camera, the wall centre and the scene centre are collinear"),
        ));
    }
    if let Some(m) = mosaic {
        // The crossed axis exists (checked above), so every angle has a micro-polarizer.
        analyzers.extend(Analyzer::mosaic(c0, s0, camera, m).into_iter().flatten());
    }
    for (k, &deg) in polarizer_deg.iter().enumerate() {
        if !(-360.0..=360.0).contains(&deg) {
            return Err(SceneError::invalid(
                key("polarizer_deg"),
                &polarizer_deg,
                "angles must be degrees from -360 to 360",
            ));
        }
        // A linear polarizer at a and at a + 180 degrees is the same setting.
        if let Some(&earlier) = polarizer_deg[..k]
            .iter()
            .find(|&&e| same_polarizer_setting(e, deg))
        {
            return Err(SceneError::invalid(
                key("polarizer_deg"),
                &polarizer_deg,
                format!("{deg} and {earlier} degrees are the same polarizer setting (angles repeat every 180 degrees); list each setting once"),
            ));
        }
        // The crossed axis exists (checked above), so every angle has a sheet.
        if let Some(a) = Analyzer::at(c0, s0, camera, deg) {
            analyzers.push(a);
        }
    }
    Ok(analyzers)
}

/// `[[occluder]]`: each checked in file order, meshes read from `dir` unless already loaded.
/// Kept apart from the poses: occluders need nothing from the other sections.
fn validate_occluders(raw: Vec<RawOccluder>, dir: &Path) -> Result<Vec<Occluder>, SceneError> {
    let mut occluders = Vec::with_capacity(raw.len());
    for (i, o) in raw.into_iter().enumerate() {
        occluders.push(validate_occluder(i, o, dir)?);
    }
    Ok(occluders)
}

/// `occluder[i]`: exactly one of a rect, a sphere or a mesh (with its `scale` and `offset`).
/// One occluder's keys together, so every error names `occluder[i].key` as before.
fn validate_occluder(i: usize, o: RawOccluder, dir: &Path) -> Result<Occluder, SceneError> {
    let key = |k: &str| format!("occluder[{i}].{k}");
    if o.mesh.is_none() {
        let only = "belongs to a mesh occluder (mesh = \"file.obj\"); remove it or add mesh";
        if let Some(v) = o.scale {
            return Err(SceneError::invalid(key("scale"), v, only));
        }
        if let Some(v) = o.offset {
            return Err(SceneError::invalid(key("offset"), v, only));
        }
    }
    match (o.rect, o.sphere, o.mesh) {
        (None, None, Some(path)) => {
            let mesh = match o.loaded {
                Some(mesh) => mesh,
                None => Arc::new(mesh_occluder(&key, dir, path, o.scale, o.offset)?),
            };
            Ok(Occluder::Mesh(mesh))
        }
        (Some(r), None, None) => rect_occluder(&key, r),
        (None, Some(sp), None) => {
            let center = point(&key("sphere.center"), sp.center)?;
            if !(sp.radius > 0.0 && sp.radius.is_finite()) {
                return Err(SceneError::invalid(
                    key("sphere.radius"),
                    sp.radius,
                    "must be positive metres",
                ));
            }
            Ok(Occluder::Sphere {
                center,
                radius: sp.radius,
            })
        }
        _ => Err(SceneError::invalid(
            key(""),
            "",
            "give exactly one of rect = {...}, sphere = {...} or mesh = \"file.obj\"",
        )),
    }
}

/// A `rect` occluder: finite centre and half-axes, non-zero and not parallel.
/// Parallel or zero half-axes span no area, so the rectangle would cast no shadow.
fn rect_occluder(key: &dyn Fn(&str) -> String, r: RawRect) -> Result<Occluder, SceneError> {
    let center = point(&key("rect.center"), r.center)?;
    let half_u = point(&key("rect.half_u"), r.half_u)?;
    let half_v = point(&key("rect.half_v"), r.half_v)?;
    if half_u.cross(&half_v).norm() <= 1e-12 * half_u.norm().max(1e-300) * half_v.norm().max(1e-300)
        || half_u.norm() == 0.0
        || half_v.norm() == 0.0
    {
        return Err(SceneError::invalid(
            key("rect"),
            (r.half_u, r.half_v),
            "half_u and half_v must be non-zero and not parallel",
        ));
    }
    Ok(Occluder::Rect {
        center,
        half_u,
        half_v,
    })
}

/// `sampling = "pixels"` needs every pose's homography.
/// Rows over an element's pixels map the wall to the image through it (MODEL.md "Rows that match the measurement").
fn check_pixel_sampling(sampling: WallSampling, poses: &[Pose]) -> Result<(), SceneError> {
    if sampling == WallSampling::Pixels {
        if let Some(i) = poses.iter().position(|p| p.homography.is_none()) {
            return Err(SceneError::invalid(
                format!("pose[{i}].homography"),
                "absent",
                "is required by wall.sampling = \"pixels\" (rows over the element's pixels need the pose's homography); add it, or use sampling = \"uniform\"",
            ));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::Channel;

    /// A scene from text, relative paths in the current directory.
    fn parse(text: &str) -> Result<Scene, SceneError> {
        super::parse(text, Path::new(""))
    }

    const BASE: &str = r#"
[wall]
center = [0.0, 0.0, 0.0]
normal = [0.0, 0.0, 2.0]
u_axis = [1.0, 0.0, 0.1]
size = [0.3, 0.3]
grid = [4, 3]
roughness = 0.3
ior = 1.5

[scene]
center = [-0.374, 0.0, 0.25]
normal = [0.831365691684, 0.0, -0.555725729736]
u_axis = [0.0, 1.0, 0.0]
size = [0.2, 0.2]
grid = [2, 2]

[[pose]]
name = "A"
camera = [0.416, 0.0, 0.277]
polarizer_deg = [0.0, 90.0]
"#;

    fn with(from: &str, to: &str) -> Result<Scene, SceneError> {
        assert!(BASE.contains(from), "{from}");
        parse(&BASE.replacen(from, to, 1))
    }

    #[test]
    fn wall_sampling_is_read_checked_and_what_was_left_out_is_kept() {
        let s = parse(BASE).unwrap();
        assert_eq!(s.wall.sampling, WallSampling::Uniform);
        let all = LeftOut {
            wall_supersample: true,
            scene_supersample: true,
            sampling: true,
        };
        assert_eq!(s.left_out, all);
        // An edit keeps what the file left out left out.
        assert_eq!(s.clone().edit(|_| {}).unwrap().left_out, all);
        let h = "polarizer_deg = [0.0, 90.0]\nhomography = [[-425.5, 1220.5, 255.5], [250.9, 0, 255.5], [-1.665, 0, 1]]";
        let text = BASE
            .replace(
                "ior = 1.5",
                "ior = 1.5\nsampling = \"pixels\"\nsupersample = 2",
            )
            .replace("polarizer_deg = [0.0, 90.0]", h);
        let p = parse(&text).unwrap();
        assert_eq!(p.wall.sampling, WallSampling::Pixels);
        assert!(
            !p.left_out.sampling && !p.left_out.wall_supersample && p.left_out.scene_supersample
        );
        // "pixels" needs every pose's homography; an unknown value is named.
        let e = with("ior = 1.5", "ior = 1.5\nsampling = \"pixels\"").unwrap_err();
        assert_eq!(e.key(), Some("pose[0].homography"), "{e}");
        assert!(e.to_string().contains("wall.sampling = \"pixels\""), "{e}");
        let e = with("ior = 1.5", "ior = 1.5\nsampling = \"centre\"").unwrap_err();
        assert_eq!(e.key(), Some("wall.sampling"), "{e}");
    }

    #[test]
    fn defaults_and_normalization() {
        let s = parse(BASE).unwrap();
        assert_eq!(s.wall.plane.normal, Vec3::z());
        // u_axis made orthogonal to the normal.
        assert_eq!(s.wall.plane.u, Vec3::x());
        assert_eq!(s.wall.plane.v, Vec3::y());
        assert_eq!(s.wall.brdf.ks, 1.0);
        assert_eq!(s.wall.brdf.kd, 0.0);
        assert_eq!(s.wall.brdf.diffuse, DiffuseModel::Fresnel);
        assert_eq!(s.polarizer, PolarizerModel::Absorbing);
        assert_eq!(s.wall.plane.supersample, 1);
        assert_eq!(s.hidden.emitter, Emitter::Lambertian);
        assert!(s.occluders.is_empty());
        assert_eq!(s.rows(), 24);
        assert_eq!(s.cols(), 4);
    }

    #[test]
    fn a_mosaic_pose_has_four_micro_polarizers_and_survives_an_edit() {
        let s = with(
            "polarizer_deg = [0.0, 90.0]",
            "analyzer = \"mosaic\"\nsensor_deg = 10.0\nextinction = 300.0",
        )
        .unwrap();
        let p = &s.poses[0];
        let m = p.mosaic.expect("a mosaic");
        assert_eq!((m.sensor_deg, m.extinction), (10.0, Some(300.0)));
        assert_eq!(p.channels(), Channel::mosaic().to_vec());
        let psi: Vec<f64> = p.analyzers.iter().map(|a| a.angle_deg).collect();
        assert_eq!(psi, [10.0, 55.0, 100.0, 145.0]);
        assert_eq!(p.analyzers[0].cell, Some([1, 1]));
        let again = s.clone().edit(|_| {}).unwrap();
        assert_eq!(again.poses, s.poses);
    }

    #[test]
    fn crossed_axis_is_normal_to_the_s_direction_and_rotates() {
        let s = parse(BASE).unwrap();
        let p = &s.poses[0];
        let q0 = p.analyzers[0].axis;
        let q90 = p.analyzers[1].axis;
        // The bench's plane of incidence is x-z, so e_s0 is +-y and q(0) has no y part.
        assert!(q0.y.abs() < 1e-12);
        assert!((q90.y.abs() - 1.0).abs() < 1e-12);
        assert!(q0.dot(&q90).abs() < 1e-12);
    }

    #[test]
    fn errors_name_the_key() {
        let cases = [
            ("roughness = 0.3", "roughness = 0", "wall.roughness"),
            ("roughness = 0.3", "roughness = 1.5", "wall.roughness"),
            ("ior = 1.5", "ior = 1.0", "wall.ior"),
            ("ior = 1.5", "ior = 1e308", "wall.ior"),
            (
                "polarizer_deg = [0.0, 90.0]",
                "polarizer_deg = [1e308]",
                "pose[0].polarizer_deg",
            ),
            (
                "polarizer_deg = [0.0, 90.0]",
                "polarizer_deg = [0, 0, 360]",
                "pose[0].polarizer_deg",
            ),
            (
                "polarizer_deg = [0.0, 90.0]",
                "polarizer_deg = [45, 225]",
                "pose[0].polarizer_deg",
            ),
            (
                "polarizer_deg = [0.0, 90.0]",
                "polarizer_deg = [0.0]\nregion = [-1, 0, 10, 10]",
                "pose[0].region",
            ),
            (
                "polarizer_deg = [0.0, 90.0]",
                "polarizer_deg = [0.0]\nregion = [0, 0, 0, 10]",
                "pose[0].region",
            ),
            (
                "polarizer_deg = [0.0, 90.0]",
                "polarizer_deg = [0.0]\nbinning = [2, 2]",
                "pose[0].binning",
            ),
            (
                "polarizer_deg = [0.0, 90.0]",
                "polarizer_deg = [0.0]\nregion = [0, 0, 512, 512]\nbinning = [0, 1]",
                "pose[0].binning",
            ),
            (
                "polarizer_deg = [0.0, 90.0]",
                "polarizer_deg = [0.0]\nanalyzer = \"mosaic\"",
                "pose[0].analyzer and pose[0].polarizer_deg",
            ),
            (
                "polarizer_deg = [0.0, 90.0]",
                "analyzer = \"mosaic\"\nlayout = \"bayer\"",
                "pose[0].layout",
            ),
            (
                "polarizer_deg = [0.0, 90.0]",
                "analyzer = \"mosaic\"\nextinction = 1.0",
                "pose[0].extinction",
            ),
            (
                "polarizer_deg = [0.0, 90.0]",
                "analyzer = \"mosaic\"\nsensor_deg = 400.0",
                "pose[0].sensor_deg",
            ),
            (
                "polarizer_deg = [0.0, 90.0]",
                "analyzer = \"sheet\"",
                "pose[0].analyzer",
            ),
            (
                "polarizer_deg = [0.0, 90.0]",
                "polarizer_deg = [0.0]\nextinction = 300.0",
                "pose[0].extinction",
            ),
            (
                "polarizer_deg = [0.0, 90.0]",
                "analyzer = \"mosaic\"\nregion = [0, 0, 512, 512]\nbinning = [2, 2]",
                "pose[0].binning",
            ),
            ("grid = [4, 3]", "grid = [0, 3]", "wall.grid"),
            ("grid = [2, 2]", "grid = [2, -1]", "scene.grid"),
            (
                "normal = [0.0, 0.0, 2.0]",
                "normal = [0.0, 0.0, 0.0]",
                "wall.normal",
            ),
            (
                "u_axis = [1.0, 0.0, 0.1]",
                "u_axis = [0.0, 0.0, 1.0]",
                "wall.u_axis",
            ),
            (
                "camera = [0.416, 0.0, 0.277]",
                "camera = [0.416, 0.0, -0.1]",
                "pose[0].camera",
            ),
            (
                "center = [-0.374, 0.0, 0.25]",
                "center = [-0.374, 0.0, 0.0]",
                "scene.center",
            ),
            (
                "normal = [0.831365691684, 0.0, -0.555725729736]",
                "normal = [-0.83, 0.0, 0.55]",
                "scene.normal",
            ),
            ("size = [0.2, 0.2]", "size = [0.2, 0.0]", "scene.size"),
            (
                "camera = [0.416, 0.0, 0.277]",
                "camera = [-0.748, 0.0, 0.5]",
                "pose[0].polarizer_deg",
            ),
        ];
        for (from, to, key) in cases {
            let e = with(from, to).unwrap_err();
            assert_eq!(e.key(), Some(key), "{to}: {e}");
        }
        let e = with("roughness = 0.3", "roughness = 0").unwrap_err();
        assert_eq!(e.to_string(), "wall.roughness = 0.0: must be in (0, 1]");
    }

    #[test]
    fn revision_2_keys_are_read_and_wrong_ones_named() {
        let s = parse(&format!(
            "{}\n[polarizer]\nmodel = \"transmitting\"\n",
            BASE.replace("ior = 1.5", "ior = 1.5\ndiffuse = \"lambert\"")
        ))
        .unwrap();
        assert_eq!(s.polarizer, PolarizerModel::Transmitting);
        assert_eq!(s.wall.brdf.diffuse, DiffuseModel::Lambert);
        let cases = [
            ("[polarizer]\nmodel = \"absorbant\"", "polarizer.model"),
            ("[polarizer]\nmodel = 1", "polarizer.model"),
            ("[polarizer]\nmodle = \"absorbing\"", "polarizer.modle"),
            (
                "[polarizer]\nmodel = \"absorbing\"\nextinction = 1e4",
                "polarizer.extinction",
            ),
        ];
        for (extra, key) in cases {
            let e = parse(&format!("{BASE}\n{extra}\n")).unwrap_err();
            assert_eq!(e.key(), Some(key), "{extra}: {e}");
        }
        for bad in ["\"lambertian\"", "0.5", "\"Fresnel\""] {
            let e = with("ior = 1.5", &format!("ior = 1.5\ndiffuse = {bad}")).unwrap_err();
            assert_eq!(e.key(), Some("wall.diffuse"), "{bad}: {e}");
            assert!(e.to_string().contains("lambert"), "{e}");
        }
        // An empty [polarizer] table is the default.
        let s = parse(&format!("{BASE}\n[polarizer]\n")).unwrap();
        assert_eq!(s.polarizer, PolarizerModel::Absorbing);
    }

    #[test]
    fn scene_shadows_are_auto_unless_the_file_says_and_survive_an_edit() {
        let bare = parse(BASE).unwrap();
        assert_eq!(bare.hidden.shadows, ShadowModel::Auto);
        assert_eq!(bare.shadow_choice().model, ShadowModel::Point);
        let edited = bare
            .clone()
            .edit(|p| p.hidden.plane.supersample = 2)
            .unwrap();
        assert_eq!(edited.hidden().shadows, ShadowModel::Auto);
        let auto = with("grid = [2, 2]", "grid = [2, 2]\nshadows = \"auto\"").unwrap();
        assert_eq!(auto.hidden.shadows, ShadowModel::Auto);
        let area = "grid = [2, 2]\nshadows = \"area\"";
        let s = with("grid = [2, 2]", area).unwrap();
        assert_eq!(s.hidden.shadows, ShadowModel::Area);
        let scene = Scene::from_toml_str(&BASE.replace("grid = [2, 2]", area)).unwrap();
        let edited = scene.edit(|p| p.hidden.plane.supersample = 2).unwrap();
        assert_eq!(edited.hidden().shadows, ShadowModel::Area);
        let e = with("grid = [2, 2]", "grid = [2, 2]\nshadows = \"soft\"").unwrap_err();
        assert!(
            e.to_string().contains("shadows") && e.to_string().contains("area"),
            "{e}"
        );
    }

    /// A wall at z = 0 and a screen of one 0.2 m element at z = 1 facing
    /// it, a 0.3 m wall of 4 x 3 elements, a rect at z = 0.25.
    const PARALLEL: &str = r#"
[wall]
center = [0.0, 0.0, 0.0]
normal = [0.0, 0.0, 1.0]
u_axis = [1.0, 0.0, 0.0]
size = [0.3, 0.3]
grid = [4, 3]
roughness = 0.3
ior = 1.5

[scene]
center = [0.0, 0.0, 1.0]
normal = [0.0, 0.0, -1.0]
u_axis = [1.0, 0.0, 0.0]
size = [0.2, 0.2]
grid = [1, 1]

[[pose]]
name = "A"
camera = [0.0, 0.3, 0.5]
polarizer_deg = []

[[occluder]]
rect = { center = [0.0, 0.0, 0.25], half_u = [0.01, 0.0, 0.0], half_v = [0.0, 0.01, 0.0] }
"#;

    #[test]
    fn the_penumbra_is_the_cell_over_the_wall_pitch_through_the_occluder() {
        // 0.2 m x 0.25 / 0.75 over the wall's finer pitch, 0.3 / 4 m.
        let s = parse(PARALLEL).unwrap();
        let w = 0.2 * 0.25 / 0.75 / 0.075;
        assert!(
            (s.penumbra().unwrap() - w).abs() < 1e-12,
            "{:?}",
            s.penumbra()
        );
        let c = s.shadow_choice();
        assert_eq!((c.model, c.open), (ShadowModel::Point, true));
        assert!(c.reason.contains("0.89 wall samples"), "{}", c.reason);
        // Four samples a side: a quarter of it, negligible.
        let fine = s.edit(|p| p.hidden.plane.supersample = 4).unwrap();
        let c = fine.shadow_choice();
        assert_eq!((c.model, c.open), (ShadowModel::Point, false));
        // An isotropic screen facing away casts the same penumbra.
        let away = PARALLEL.replace(
            "normal = [0.0, 0.0, -1.0]",
            "normal = [0.0, 0.0, 1.0]\nemitter = \"isotropic\"",
        );
        let a = parse(&away).unwrap();
        assert!((a.penumbra().unwrap() - w).abs() < 1e-12);
        // The file's word stands; no occluder, nothing to choose.
        let area =
            parse(&PARALLEL.replace("grid = [1, 1]", "grid = [1, 1]\nshadows = \"area\"")).unwrap();
        let c = area.shadow_choice();
        assert_eq!((c.model, c.open), (ShadowModel::Area, false));
        assert!(c.reason.contains("says shadows = \"area\""), "{}", c.reason);
        let open = parse(PARALLEL.split("[[occluder]]").next().unwrap()).unwrap();
        assert_eq!(open.penumbra(), None);
        assert_eq!(open.shadow_choice().model, ShadowModel::Point);
    }

    #[test]
    fn missing_and_unknown_keys_are_parse_errors() {
        let e = with("ior = 1.5\n", "").unwrap_err();
        assert!(e.to_string().contains("ior"), "{e}");
        let e = with("ior = 1.5", "ior = 1.5\nroughnes = 0.2").unwrap_err();
        assert!(e.to_string().contains("roughnes"), "{e}");
        let e = with(
            "[[pose]]\nname = \"A\"\ncamera = [0.416, 0.0, 0.277]\npolarizer_deg = [0.0, 90.0]\n",
            "",
        )
        .unwrap_err();
        assert_eq!(e.key(), Some("pose"));
    }

    #[test]
    fn a_pose_records_the_frame_its_homography_maps_to() {
        let s = with(
            "polarizer_deg = [0.0, 90.0]",
            "polarizer_deg = [0.0, 90.0]\nregion = [8, 0, 512, 256]\nbinning = [2, 2]",
        )
        .unwrap();
        let f = s.poses[0].frame.unwrap();
        assert_eq!(f.region, [8, 0, 512, 256]);
        assert_eq!(f.binning, [2, 2]);
        assert_eq!(parse(BASE).unwrap().poses[0].frame, None);
        let e = with("polarizer_deg = [0.0, 90.0]", "polarizer_deg = [0, 180]").unwrap_err();
        assert!(e.to_string().contains("same polarizer setting"), "{e}");
    }

    #[test]
    fn duplicate_pose_names_are_rejected() {
        let twice = format!("{BASE}\n[[pose]]\nname = \"A\"\ncamera = [0.4, 0.1, 0.3]\n");
        assert_eq!(parse(&twice).unwrap_err().key(), Some("pose[1].name"));
    }

    #[test]
    fn an_edit_is_validated_again_and_recomputes_what_follows() {
        let s = parse(BASE).unwrap();
        let same = s.clone().edit(|_| {}).unwrap();
        assert_eq!(same.rows(), s.rows());
        assert!((same.poses[0].analyzers[1].axis - s.poses[0].analyzers[1].axis).norm() < 1e-12);

        let finer = s
            .clone()
            .edit(|p| p.hidden.plane.grid = Grid { nu: 5, nv: 6 })
            .unwrap();
        assert_eq!(finer.cols(), 30);

        // A moved camera gets its own crossed sheet, as in a file.
        let camera = Vec3::new(0.3, 0.2, 0.3);
        let moved = s.clone().edit(|p| p.poses[0].camera = camera).unwrap();
        let from_file = with("camera = [0.416, 0.0, 0.277]", "camera = [0.3, 0.2, 0.3]").unwrap();
        assert!(
            (moved.poses[0].analyzers[0].axis - from_file.poses[0].analyzers[0].axis).norm()
                < 1e-12
        );

        type Change = Box<dyn FnOnce(&mut SceneParts)>;
        let cases: [(&str, Change); 4] = [
            ("scene.grid", Box::new(|p| p.hidden.plane.grid.nu = 0)),
            ("wall.roughness", Box::new(|p| p.wall.brdf.alpha = 2.0)),
            ("pose[0].camera", Box::new(|p| p.poses[0].camera.z = -1.0)),
            ("pose", Box::new(|p| p.poses.clear())),
        ];
        for (key, change) in cases {
            let e = s.clone().edit(change).unwrap_err();
            assert_eq!(e.key(), Some(key), "{e}");
        }
    }

    /// BASE with one mesh occluder line `occluder` in a scene file written
    /// to a temporary folder beside `files` (name, content).
    fn with_mesh(occluder: &str, files: Files) -> Result<Scene, SceneError> {
        let dir = tempfile::tempdir().unwrap();
        for (name, bytes) in files {
            std::fs::write(dir.path().join(name), bytes).unwrap();
        }
        let path = dir.path().join("scene.toml");
        std::fs::write(&path, format!("{BASE}\n[[occluder]]\n{occluder}\n")).unwrap();
        Scene::load(&path)
    }

    /// Files (name, content) written beside a scene file.
    type Files<'a> = &'a [(&'a str, &'a [u8])];

    const TRIANGLE: &[u8] = b"v -0.2 -0.05 0.1\nv -0.2 0.05 0.1\nv -0.15 0.0 0.12\nf 1 2 3\n";

    #[test]
    fn a_mesh_is_read_beside_the_scene_file_and_survives_an_edit() {
        let s = with_mesh(
            "mesh = \"sub/tri.obj\"\nscale = 2.0\noffset = [0.1, 0.0, 0.0]",
            &[],
        );
        let e = s.unwrap_err();
        assert_eq!(e.key(), Some("occluder[0].mesh"), "{e}");
        assert!(e.to_string().contains("sub/tri.obj"), "{e}");

        let s = with_mesh(
            "mesh = \"tri.obj\"\nscale = 2.0\noffset = [0.1, 0.0, 0.0]",
            &[("tri.obj", TRIANGLE)],
        )
        .unwrap();
        let Occluder::Mesh(m) = &s.occluders()[0] else {
            panic!("a mesh")
        };
        assert_eq!(m.triangles().len(), 1);
        assert!((m.triangles()[0][0] - Vec3::new(-0.3, -0.1, 0.2)).norm() < 1e-15);
        assert_eq!(m.source().path, "tri.obj");
        // An edit keeps the triangles without the file (the folder is gone).
        let again = s.clone().edit(|_| {}).unwrap();
        assert_eq!(again.occluders(), s.occluders());
    }

    #[test]
    fn what_a_mesh_gets_wrong_is_named() {
        let binary_short = {
            let mut b = vec![0u8; 80];
            b.extend(3u32.to_le_bytes());
            b.extend([0u8; 60]);
            b
        };
        let far = b"v 1e5 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\n";
        // (occluder keys, files beside the scene, key named, words in the message)
        let cases: [(&str, Files, &str, &str); 11] = [
            ("mesh = \"none.obj\"", &[], "occluder[0].mesh", "none.obj"),
            (
                "mesh = \"e.obj\"",
                &[("e.obj", b"v 0 0 0\n")],
                "occluder[0].mesh",
                "no triangles",
            ),
            (
                "mesh = \"i.obj\"",
                &[("i.obj", b"v 0 0 0\nf 1 2 3\n")],
                "occluder[0].mesh",
                "out of range",
            ),
            (
                "mesh = \"n.obj\"",
                &[("n.obj", b"v nan 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\n")],
                "occluder[0].mesh",
                "finite",
            ),
            (
                "mesh = \"f.obj\"",
                &[("f.obj", far)],
                "occluder[0].mesh",
                "within",
            ),
            (
                "mesh = \"s.stl\"",
                &[("s.stl", &binary_short)],
                "occluder[0].mesh",
                "binary STL",
            ),
            (
                "mesh = \"t.ply\"",
                &[("t.ply", TRIANGLE)],
                "occluder[0].mesh",
                ".obj",
            ),
            (
                "mesh = \"t.obj\"\nscale = 0.0",
                &[("t.obj", TRIANGLE)],
                "occluder[0].scale",
                "> 0",
            ),
            (
                "mesh = \"t.obj\"\noffset = [0.0, 1e400, 0.0]",
                &[("t.obj", TRIANGLE)],
                "",
                "offset",
            ),
            (
                "sphere = { center = [0.0, 0.0, 0.1], radius = 0.01 }\nscale = 2.0",
                &[],
                "occluder[0].scale",
                "mesh",
            ),
            (
                "sphere = { center = [0.0, 0.0, 0.1], radius = 0.01 }\nmesh = \"t.obj\"",
                &[("t.obj", TRIANGLE)],
                "occluder[0].",
                "exactly one",
            ),
        ];
        for (occluder, files, key, says) in cases {
            let e = with_mesh(occluder, files).unwrap_err();
            if !key.is_empty() {
                assert_eq!(e.key(), Some(key), "{occluder}: {e}");
            }
            assert!(e.to_string().contains(says), "{occluder}: {e}");
        }
        // A directory is no mesh.
        let dir = tempfile::tempdir().unwrap();
        std::fs::create_dir(dir.path().join("d.obj")).unwrap();
        let text = format!("{BASE}\n[[occluder]]\nmesh = \"d.obj\"\n");
        let e = Scene::from_toml_str_in(&text, dir.path()).unwrap_err();
        assert_eq!(e.key(), Some("occluder[0].mesh"), "{e}");
    }

    proptest::proptest! {
        #[test]
        fn arbitrary_text_never_panics(s in "\\PC{0,400}") {
            let _ = parse(&s);
        }

        #[test]
        fn arbitrary_values_in_a_valid_frame_never_panic(
            key in proptest::sample::select(vec!["roughness", "ior", "ks", "kd", "supersample", "grid", "size", "normal", "u_axis", "camera", "polarizer_deg", "homography", "region", "binning", "diffuse", "model"]),
            value in proptest::sample::select(vec!["0", "-1", "1e308", "nan", "inf", "[]", "[0,0]", "[1e-300, 0, 0]", "\"x\"", "[[1,2,3],[4,5,6],[7,8,9]]", "[0, 0, 0]", "{ a = 1 }", "9999999999999"]),
        ) {
            let base = format!(
                "{}region = [0, 0, 64, 64]\nbinning = [1, 1]\n[polarizer]\nmodel = \"absorbing\"\n",
                BASE.replace("ior = 1.5", "ior = 1.5\ndiffuse = \"fresnel\"")
            );
            let text = base
                .lines()
                .map(|l| if l.starts_with(&format!("{key} =")) { format!("{key} = {value}") } else { l.to_string() })
                .collect::<Vec<_>>()
                .join("\n");
            let _ = parse(&text);
        }

        #[test]
        fn arbitrary_mosaic_values_never_panic_and_what_is_accepted_builds(
            key in proptest::sample::select(vec!["analyzer", "sensor_deg", "extinction", "layout", "polarizer_deg", "region", "binning"]),
            value in proptest::sample::select(vec!["0", "-1", "1", "1.0000001", "1e308", "nan", "inf", "-inf", "[]", "[0.0]", "[1, 0, 64, 64]", "[2, 2]", "\"mosaic\"", "\"polarsens\"", "\"x\"", "{ a = 1 }", "360", "-360.5"]),
        ) {
            let base = format!(
                "{}region = [0, 0, 64, 64]\nbinning = [1, 1]\npolarizer_deg = []\n",
                BASE.replace(
                    "polarizer_deg = [0.0, 90.0]",
                    "analyzer = \"mosaic\"\nsensor_deg = 10.0\nextinction = 300.0\nlayout = \"polarsens\"",
                )
            );
            let valid: Vec<&str> = base.lines().filter(|l| !l.starts_with("polarizer_deg =")).collect();
            proptest::prop_assert!(parse(&valid.join("\n")).is_ok(), "the unmutated mosaic pose parses");
            let text = base
                .lines()
                .filter(|l| key == "polarizer_deg" || !l.starts_with("polarizer_deg ="))
                .map(|l| if l.starts_with(&format!("{key} =")) { format!("{key} = {value}") } else { l.to_string() })
                .collect::<Vec<_>>()
                .join("\n");
            if let Ok(scene) = parse(&text) {
                let t = crate::transport::build(&scene, crate::transport::MemoryBudget::DEFAULT);
                let t = t.expect("an accepted scene builds");
                proptest::prop_assert!(t.col_major().iter().all(|v| v.is_finite()));
            }
        }
    }
}
