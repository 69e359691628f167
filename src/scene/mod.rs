//! Scene files and the validated geometry they describe (MODEL.md "Scene files",
//! "Geometry of a scene file", "The crossed polarizer of a pose").
//!
//! A [`Scene`] is only ever built through validation, so every other room can
//! rely on unit normals, orthonormal plane axes, positive sizes and grids, a
//! camera and a hidden scene in front of the wall, and well-defined polarizer axes.

mod analyzer;
pub mod builtin;
mod colour;
mod error;
mod file;
pub(crate) mod footprint;
mod frame;
pub(crate) mod homography;
pub(crate) mod mesh;
pub(crate) mod occluder;
pub(crate) mod plane;

use std::path::Path;

#[cfg(any(feature = "daemon", feature = "report"))]
pub(crate) use analyzer::MOSAIC_DEGREES;
pub(crate) use analyzer::{crossed_axis, perpendicular};
pub(crate) use analyzer::{Analyzer, Mosaic, MosaicLayout};
pub use analyzer::{Channel, UnknownAnalyzer};
pub use colour::Colour;
pub use error::SceneError;
#[cfg(feature = "daemon")]
pub(crate) use footprint::wall_corners;
pub(crate) use footprint::{effective_pixels, Cells, FootprintError};
pub use footprint::{FrameGeometry, PixelMap};
pub use frame::Frame;
pub use homography::Homography;
pub use occluder::{Mesh, Occluder};
pub use plane::{Grid, Plane};

use crate::optics::{Brdf, PolarizerModel, Vec3};

/// How a hidden-scene element radiates towards the wall (MODEL.md `g_k`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Emitter {
    /// `g = max(0, n_s . (c - s)/|c - s|)`.
    Lambertian,
    /// `g = 1`.
    Isotropic,
}

/// How an occluder's shadow is computed from each hidden-scene sample
/// (`[scene] shadows`).
///
/// Why: point sources (MODEL.md) cast hard shadows that jump between wall
/// samples as an occluder moves, so a misfit over occluder positions is
/// rough; a sample's whole cell as an area source gives a penumbra that is
/// continuous in the occluder's position (docs/realphoto.md, "Area shadows").
#[derive(
    Debug,
    Clone,
    Copy,
    PartialEq,
    Eq,
    Default,
    serde::Serialize,
    serde::Deserialize,
    clap::ValueEnum,
)]
#[serde(rename_all = "lowercase")]
pub enum ShadowModel {
    /// Each sample is a point: visible or not (MODEL.md).
    Point,
    /// Each sample stands for its cell (the element's `m x m` sub-cell): the
    /// visible fraction of the cell, exact for rects and mesh triangles.
    Area,
    /// No `shadows` key: chosen from the scene, and from a photo where one
    /// is fitted ([`Scene::shadow_choice`], docs/realphoto.md "Which
    /// shadows").
    #[default]
    Auto,
}

impl ShadowModel {
    /// The value as a scene file writes it.
    pub fn name(self) -> &'static str {
        match self {
            ShadowModel::Point => "point",
            ShadowModel::Area => "area",
            ShadowModel::Auto => "auto",
        }
    }
}

/// A penumbra narrower than this many wall samples is negligible: point and
/// area shadows then differ at most in the one wall sample a shadow edge
/// crosses (docs/realphoto.md, "Which shadows").
pub const NEGLIGIBLE_PENUMBRA: f64 = 0.5;

/// The shadow model a `T` is built with and why.
///
/// Why: callers put it in their reports; `shadows` is a key few users know,
/// and on a photo the wrong one costs more than any other setting
/// (docs/realphoto.md, "Which shadows").
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct ShadowChoice {
    /// `Point` or `Area`, never `Auto`.
    pub model: ShadowModel,
    /// Why, in words.
    pub reason: String,
    /// The widest penumbra one scene cell casts on the wall through the
    /// occluders, in wall samples; `None` without occluders.
    pub penumbra: Option<f64>,
    /// Whether a photo should decide: the file left `shadows` out and the
    /// penumbra is not negligible, so point shadows are only the default.
    pub open: bool,
    /// The photo's misfits with point and with area shadows, when a photo
    /// decided (`solve::photo::photo_transport`).
    pub misfit: Option<[f64; 2]>,
}

/// The rough wall the camera sees.
#[derive(Debug, Clone, PartialEq)]
pub struct Wall {
    /// Geometry and discretization of the wall.
    pub plane: Plane,
    /// Its reflectance.
    pub brdf: Brdf,
    /// How the rows of a pose with a homography average over an element.
    pub sampling: WallSampling,
}

/// How a row of `T` averages over its wall element (MODEL.md "Rows that
/// match the measurement", `[wall] sampling`); a pose without a homography
/// always samples uniformly.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum WallSampling {
    /// The element's `m x m` sub-samples (wall `supersample`).
    #[default]
    Uniform,
    /// The wall points `H^-1(p)` of the element's pixels, weighted by their
    /// footprints: the same pixels and weights as the measurement.
    Pixels,
}

impl WallSampling {
    /// Every value, default first.
    pub const ALL: [WallSampling; 2] = [WallSampling::Uniform, WallSampling::Pixels];

    /// The value as a scene file writes it.
    pub fn name(self) -> &'static str {
        match self {
            WallSampling::Uniform => "uniform",
            WallSampling::Pixels => "pixels",
        }
    }

    /// The value a scene file names, or `None` for an unknown name.
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|m| m.name() == name)
    }
}

/// Which of the keys that set how finely `T` is sampled a scene file left
/// out: a reconstruction, which knows the noise, may choose those itself
/// (MODEL.md "Rows that match the measurement").
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct LeftOut {
    /// `[wall] supersample`.
    pub wall_supersample: bool,
    /// `[scene] supersample`.
    pub scene_supersample: bool,
    /// `[wall] sampling`.
    pub sampling: bool,
}

/// The hidden scene: a plane of emitting elements.
#[derive(Debug, Clone, PartialEq)]
pub struct HiddenScene {
    /// Geometry and discretization of the emitting screen.
    pub plane: Plane,
    /// Angular emission lobe.
    pub emitter: Emitter,
    /// Extra falloff `cos^n_u(theta_u) cos^n_v(theta_v)` of a screen whose
    /// brightness drops off axis (a monitor), `[n_u, n_v]`; `None`: none.
    /// `theta_u` is the angle of the ray to the wall from the normal within
    /// the plane (normal, u), likewise `theta_v`: a monitor is often
    /// narrow vertically and wide horizontally (docs/realphoto.md).
    pub lobe: Option<[f64; 2]>,
    /// Field direction of a linearly polarized scene (unit), if any (MODEL.md Eq. 11).
    pub polarization: Option<Vec3>,
    /// Point or area shadows behind occluders.
    pub shadows: ShadowModel,
}

/// A camera pose: where the camera is and which polarizer angles it captures.
#[derive(Debug, Clone, PartialEq)]
pub struct Pose {
    /// Name used in captures and API requests.
    pub name: String,
    /// Centre of projection `o`.
    pub camera: Vec3,
    /// Polarizer settings in block order (a sheet's angles in file order, a
    /// mosaic's four micro-polarizers); empty means no polarizer.
    pub analyzers: Vec<Analyzer>,
    /// The on-chip polarizer mosaic, when the pose has one instead of a sheet.
    pub mosaic: Option<Mosaic>,
    /// Wall (u, v) metres to image pixels, when the pose has been calibrated.
    pub homography: Option<Homography>,
    /// The camera frame the homography was calibrated at, when the file says.
    pub frame: Option<CameraFrame>,
}

/// A camera frame geometry: region of interest `[x, y, width, height]`
/// (pixels, after binning) and binning `[x, y]`. A homography maps wall
/// coordinates to pixels of exactly this frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct CameraFrame {
    /// Offset and size, pixels.
    pub region: [u32; 4],
    /// Binning factors.
    pub binning: [u32; 2],
}

impl Pose {
    /// Number of row blocks this pose adds to `T` (one per angle, one without a polarizer).
    pub fn block_count(&self) -> usize {
        self.analyzers.len().max(1)
    }

    /// The analyzer of its block `channel`, when it has a polarizer.
    pub fn analyzer(&self, channel: Channel) -> Option<&Analyzer> {
        self.analyzers.iter().find(|a| a.channel.same(channel))
    }

    /// The channel of each of its blocks, in block order.
    pub fn channels(&self) -> Vec<Channel> {
        if self.analyzers.is_empty() {
            return vec![Channel::None];
        }
        self.analyzers.iter().map(|a| a.channel).collect()
    }
}

/// A validated scene: wall, hidden scene, poses and occluders.
///
/// Its fields are private so that it stays as validation left it: read them
/// through the accessors, change them through [`Scene::edit`], which runs the
/// loader's validation again.
#[derive(Debug, Clone, PartialEq)]
pub struct Scene {
    wall: Wall,
    hidden: HiddenScene,
    poses: Vec<Pose>,
    occluders: Vec<Occluder>,
    polarizer: PolarizerModel,
    left_out: LeftOut,
}

/// The parts of a [`Scene`], open for change inside [`Scene::edit`].
///
/// Only the values a scene file gives are read back: the derived ones (a
/// plane's `v` axis, an analyzer's `axis` and `normal`) are recomputed from
/// them, as when the file is loaded, so a moved camera gets its own crossed sheet.
#[derive(Debug, Clone, PartialEq)]
pub struct SceneParts {
    /// The wall (file section `[wall]`).
    pub wall: Wall,
    /// The hidden scene (file section `[scene]`).
    pub hidden: HiddenScene,
    /// Camera poses, in file order (`[[pose]]`); an analyzer counts by its `angle_deg`.
    pub poses: Vec<Pose>,
    /// Occluders between scene and wall (`[[occluder]]`).
    pub occluders: Vec<Occluder>,
    /// How every pose's polarizer sheet acts on oblique rays (`[polarizer] model`).
    pub polarizer: PolarizerModel,
    /// The sampling keys the file left out; a key an edit sets away from its
    /// default counts as given from then on.
    pub left_out: LeftOut,
}

impl Scene {
    /// A built-in reference scene by name (e.g. `brewster-crossed-3x3`).
    pub fn builtin(name: &str) -> Option<Result<Self, SceneError>> {
        builtin::text(name).map(Self::from_toml_str)
    }

    /// Parses and validates a scene from TOML text.
    ///
    /// A relative `mesh` path is read from the current directory, as a
    /// relative path given on a command line is; [`Scene::from_toml_str_in`]
    /// names the folder instead.
    pub fn from_toml_str(text: &str) -> Result<Self, SceneError> {
        file::parse(text, Path::new(""))
    }

    /// Parses and validates scene text as if it were a file in `dir`: a
    /// relative `mesh` path is read from there (an absolute one as it is).
    pub fn from_toml_str_in(text: &str, dir: &Path) -> Result<Self, SceneError> {
        file::parse(text, dir)
    }

    /// A scene file, or the built-in scene of that name when no such file
    /// exists (`brewster-crossed-3x3`, as the daemon knows them): how every
    /// front end (the CLI, the Python bindings) names a scene.
    pub fn load_or_builtin(path: &Path) -> Result<Self, SceneError> {
        match (path.exists(), builtin::text(&path.to_string_lossy())) {
            (false, Some(text)) => Self::from_toml_str(text),
            _ => Self::load(path),
        }
    }

    /// Reads, parses and validates a scene file.
    pub fn load(path: &Path) -> Result<Self, SceneError> {
        let text = std::fs::read_to_string(path).map_err(|source| SceneError::Read {
            path: path.to_path_buf(),
            source,
        })?;
        let dir = path.parent().unwrap_or(Path::new(""));
        Self::from_toml_str_in(&text, dir).map_err(|e| e.in_file(path))
    }

    /// The same scene with area shadows: the other model a photo of a scene
    /// that left `shadows` out is compared with ([`Scene::shadow_choice`]).
    pub fn with_area_shadows(&self) -> Result<Scene, SceneError> {
        self.clone().edit(|p| p.hidden.shadows = ShadowModel::Area)
    }

    /// The same scene changed by `change`, validated again as a scene file is:
    /// how a bench or a fit varies one value of a loaded scene without ever
    /// holding one that the loader would refuse (the error names the key).
    pub fn edit(self, change: impl FnOnce(&mut SceneParts)) -> Result<Scene, SceneError> {
        let mut parts = SceneParts {
            wall: self.wall,
            hidden: self.hidden,
            poses: self.poses,
            occluders: self.occluders,
            polarizer: self.polarizer,
            left_out: self.left_out,
        };
        change(&mut parts);
        file::revalidate(parts)
    }

    /// The wall.
    pub fn wall(&self) -> &Wall {
        &self.wall
    }

    /// The hidden scene (the file's `[scene]` section).
    pub fn hidden(&self) -> &HiddenScene {
        &self.hidden
    }

    /// Camera poses, in file order (the row-block order of `T`).
    pub fn poses(&self) -> &[Pose] {
        &self.poses
    }

    /// The sampling keys the scene file left out.
    pub fn left_out(&self) -> LeftOut {
        self.left_out
    }

    /// Occluders between scene and wall.
    pub fn occluders(&self) -> &[Occluder] {
        &self.occluders
    }

    /// How every pose's polarizer sheet acts on oblique rays (MODEL.md `[polarizer] model`).
    pub fn polarizer(&self) -> PolarizerModel {
        self.polarizer
    }

    /// The widest penumbra one scene sample's cell casts on the wall through
    /// an occluder, in wall samples; `None` without occluders (or none
    /// between the planes).
    ///
    /// A cell of side `c` seen past an occluder point at height `h_w` over
    /// the wall and `h_s` over the scene plane blurs a shadow edge over
    /// `c h_w / h_s` on the wall (similar triangles); over the wall's sample
    /// pitch this says how many wall samples a point source's hard edge
    /// would have to stand for (docs/realphoto.md, "Which shadows").
    pub fn penumbra(&self) -> Option<f64> {
        let (wall, scene) = (&self.wall.plane, &self.hidden.plane);
        let m = scene.supersample.max(1) as f64;
        let cell =
            (scene.size[0] / scene.grid.nu as f64).max(scene.size[1] / scene.grid.nv as f64) / m;
        let mw = wall.supersample.max(1) as f64;
        let pitch =
            (wall.size[0] / wall.grid.nu as f64).min(wall.size[1] / wall.grid.nv as f64) / mw;
        // Heights over the scene plane on the wall's side of it (an
        // isotropic screen's normal may face away).
        let side = scene.normal.dot(&(wall.center - scene.center)).signum();
        let mut widest: Option<f64> = None;
        let mut see = |x: Vec3| {
            let hw = wall.normal.dot(&(x - wall.center));
            let hs = side * scene.normal.dot(&(x - scene.center));
            if hw > 0.0 && hs > 0.0 && hw.is_finite() && hs.is_finite() {
                let w = cell * hw / hs / pitch;
                widest = Some(widest.map_or(w, |v: f64| v.max(w)));
            }
        };
        for o in &self.occluders {
            match o {
                Occluder::Rect {
                    center,
                    half_u,
                    half_v,
                } => {
                    for (a, b) in [(1.0, 1.0), (-1.0, 1.0), (-1.0, -1.0), (1.0, -1.0)] {
                        see(center + half_u * a + half_v * b);
                    }
                }
                Occluder::Sphere { center, .. } => see(*center),
                Occluder::Mesh(mesh) => mesh.triangles().iter().flatten().for_each(|p| see(*p)),
            }
        }
        widest
    }

    /// Which shadows `T` is built with: the file's `shadows` when it gives
    /// one; else point shadows where the [`Scene::penumbra`] is below
    /// [`NEGLIGIBLE_PENUMBRA`] wall samples (MODEL.md's point sources), and
    /// point shadows left `open` for a photo to decide where it is wider.
    ///
    /// Why: MODEL.md's point sources are exact where a cell's penumbra is
    /// negligible and the reference benches are defined by them; a photo of
    /// an extended screen behind a near occluder is not (docs/realphoto.md,
    /// "Which shadows": ZNCC 0.60 against 0.84 on a held-out photo).
    pub fn shadow_choice(&self) -> ShadowChoice {
        let penumbra = self.penumbra();
        let words = penumbra.map_or(String::new(), |w| {
            format!("a scene cell's penumbra spans {w:.2} wall samples")
        });
        let (model, reason, open) = match (self.hidden.shadows, penumbra) {
            (_, None) if self.occluders.is_empty() => {
                (ShadowModel::Point, "no occluders".to_string(), false)
            }
            (ShadowModel::Auto, None) => (
                ShadowModel::Point,
                "no occluder lies between the scene and the wall".to_string(),
                false,
            ),
            (ShadowModel::Auto, Some(w)) if w < NEGLIGIBLE_PENUMBRA => (
                ShadowModel::Point,
                format!(
                    "{words}, under {NEGLIGIBLE_PENUMBRA}: negligible, point sources (MODEL.md)"
                ),
                false,
            ),
            (ShadowModel::Auto, Some(_)) => (
                ShadowModel::Point,
                format!("{words}; point sources (MODEL.md) until a photo says otherwise"),
                true,
            ),
            (given, _) => (
                given,
                format!(
                    "the scene file says shadows = \"{}\"{}{words}",
                    given.name(),
                    if words.is_empty() { "" } else { "; " }
                ),
                false,
            ),
        };
        ShadowChoice {
            model,
            reason,
            penumbra,
            open,
            misfit: None,
        }
    }

    /// Number of rows of the stacked `T`: wall elements times row blocks.
    pub fn rows(&self) -> usize {
        self.wall.plane.grid.count() * self.block_count()
    }

    /// Number of columns of `T`: scene elements.
    pub fn cols(&self) -> usize {
        self.hidden.plane.grid.count()
    }

    /// Number of (pose, angle) row blocks.
    pub fn block_count(&self) -> usize {
        self.poses.iter().map(Pose::block_count).sum()
    }

    /// The pose with this name.
    pub fn pose(&self, name: &str) -> Option<&Pose> {
        self.poses.iter().find(|p| p.name == name)
    }

    /// The same scene read under another polarizer model: how a fit tells
    /// which reading of the sheet its captures support.
    pub fn with_polarizer_model(&self, model: PolarizerModel) -> Scene {
        Scene {
            polarizer: model,
            ..self.clone()
        }
    }

    /// The same scene with every polarizer removed: the reference for exposure
    /// (the unpolarized image sets full scale) and the "no polarizer" baseline.
    pub fn without_polarizers(&self) -> Scene {
        let mut s = self.clone();
        for p in &mut s.poses {
            p.analyzers.clear();
            p.mosaic = None;
        }
        s
    }
}
