//! Scenes the daemon knows by name: the built-in bench scenes and the
//! config's `scene_files`, each with its transport matrix, its Gram `T^T T`
//! and its singular values computed once on first use (all depend on the
//! scene alone): a repeat or progressive reconstruction forms only `T^T i`.

use std::collections::BTreeMap;
use std::path::Path;
use std::sync::{Arc, Mutex};

use crate::scene::{Scene, SceneError};
use crate::solve::gram::Gram;
use crate::solve::{condition_with, Conditioning, SolveError};
use crate::stop::Stop;
use crate::transport::{build_with_progress, MemoryBudget, Transport, TransportError};

/// Why a scene's `T` or conditioning is not available.
#[derive(Debug, thiserror::Error)]
pub enum ScenesError {
    /// No scene by that name.
    #[error("unknown scene {name:?}; known: {}", known.join(", "))]
    Unknown {
        /// The name asked for.
        name: String,
        /// Every name the daemon knows.
        known: Vec<String>,
    },
    /// `T` could not be built (too large for the memory budget, ...).
    #[error("scene {name:?}: {source}")]
    Transport {
        /// The scene.
        name: String,
        /// Why.
        source: TransportError,
    },
    /// A variant of the scene (area shadows) does not validate.
    #[error("scene {name:?} with area shadows: {source}")]
    Edit {
        /// The scene.
        name: String,
        /// Why.
        source: crate::scene::SceneError,
    },
    /// The caller's stop flag was raised while `T` or its Gram was made (a
    /// cancelled job, a stopping daemon); nothing was cached.
    #[error("stopped on request while T or its Gram was made")]
    Stopped,
    /// The SVD of `T` failed.
    #[error("scene {name:?}: conditioning: {source}")]
    Conditioning {
        /// The scene.
        name: String,
        /// Why.
        source: SolveError,
    },
}

use super::wall_views::wall_views;
pub use super::wall_views::WallView;

/// Where a scene the daemon knows comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, utoipa::ToSchema)]
#[serde(rename_all = "kebab-case")]
pub enum SceneOrigin {
    /// Built into polnlos (the Brewster bench scenes).
    BuiltIn,
    /// A file of the config's `scene_files`.
    File,
    /// Sent over HTTP (`POST /scenes`, `PUT /scenes/{name}`), kept in the
    /// data directory's `scenes/`.
    Posted,
}

impl SceneOrigin {
    /// In words, for a message.
    pub fn words(self) -> &'static str {
        match self {
            SceneOrigin::BuiltIn => "built in",
            SceneOrigin::File => "a file of scene_files",
            SceneOrigin::Posted => "posted",
        }
    }
}

/// Which geometry a scene serves with: its file's, or a scene calibration's.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, utoipa::ToSchema)]
#[serde(rename_all = "kebab-case", tag = "geometry")]
pub(crate) enum Geometry {
    /// The scene file's geometry, as written.
    #[default]
    AsWritten,
    /// Placed by a scene calibration (`POST /calibrations/scene`).
    Fitted {
        /// The calibration's id.
        calibration: i64,
    },
}

impl Geometry {
    /// In words, as a reconstruction's report says it.
    pub(crate) fn words(self) -> String {
        match self {
            Geometry::AsWritten => "as written".into(),
            Geometry::Fitted { calibration } => {
                format!("fitted by scene calibration {calibration}")
            }
        }
    }

    /// A reconstruction's report with this geometry in `geometry`.
    pub(crate) fn stamped(
        self,
        report: &impl serde::Serialize,
    ) -> serde_json::Result<serde_json::Value> {
        let mut v = serde_json::to_value(report)?;
        if let Some(o) = v.as_object_mut() {
            o.insert("geometry".into(), self.words().into());
        }
        Ok(v)
    }
}

/// One scene as `GET /scenes` lists it: a scene that serves, or a file
/// that does not, with why.
#[derive(Debug, Clone, PartialEq, serde::Serialize, utoipa::ToSchema)]
pub struct SceneListing {
    /// The name requests use (a file's stem).
    pub name: String,
    /// Where it comes from.
    pub origin: SceneOrigin,
    /// Why its file does not load (null for a scene that serves); another
    /// scene of the name (a built-in one) may serve meanwhile.
    pub error: Option<String>,
    /// The scene calibration whose geometry it serves with (null: as written).
    pub fitted_by: Option<i64>,
}

/// A scene as the daemon holds it: parsed, its text and where it is read from.
#[derive(Clone)]
pub(crate) struct Entry {
    pub(crate) scene: Arc<Scene>,
    /// Its TOML text as loaded, for writing calibrated copies of it.
    pub(crate) source: String,
    /// The folder its file is in (its relative mesh paths are read from
    /// there); `""` for a built-in scene.
    pub(crate) folder: std::path::PathBuf,
    pub(crate) origin: SceneOrigin,
    /// Whose geometry `scene` has: the file's (`source`), or a scene calibration's.
    pub(crate) geometry: Geometry,
}

impl Entry {
    /// The scene file `path` (a `scene_files` entry or a posted file).
    pub(crate) fn read(path: &Path, origin: SceneOrigin) -> Result<Self, SceneError> {
        let source = std::fs::read_to_string(path).map_err(|source| SceneError::Read {
            path: path.to_path_buf(),
            source,
        })?;
        let folder = path.parent().unwrap_or(Path::new("")).to_path_buf();
        Self::parse(source, folder, origin).map_err(|e| e.in_file(path))
    }

    /// Scene text as a file in `folder`.
    pub(crate) fn parse(
        source: String,
        folder: std::path::PathBuf,
        origin: SceneOrigin,
    ) -> Result<Self, SceneError> {
        Ok(Self {
            scene: Arc::new(Scene::from_toml_str_in(&source, &folder)?),
            source,
            folder,
            origin,
            geometry: Geometry::AsWritten,
        })
    }

    /// This entry with the geometry of scene calibration `calibration`
    /// (`placed`, a file in the entry's folder placed from its `source`).
    pub(crate) fn fitted(&self, calibration: i64, placed: &str) -> Result<Self, SceneError> {
        Ok(Self {
            scene: Arc::new(Scene::from_toml_str_in(placed, &self.folder)?),
            geometry: Geometry::Fitted { calibration },
            ..self.clone()
        })
    }

    /// This entry with its file's geometry.
    pub(crate) fn as_written(&self) -> Result<Self, SceneError> {
        match self.geometry {
            Geometry::AsWritten => Ok(self.clone()),
            Geometry::Fitted { .. } => {
                Self::parse(self.source.clone(), self.folder.clone(), self.origin)
            }
        }
    }
}

/// The stem of scene file `path`: the name the daemon knows it by.
pub(crate) fn file_name(path: &Path) -> String {
    path.file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default()
}

/// Scenes by name, with a cache of their `T`, each built within one memory
/// budget: one snapshot of the daemon's scenes (`scene_registry`
/// makes a new one on each change; a job keeps the one it started with).
pub struct Scenes {
    budget: MemoryBudget,
    entries: BTreeMap<String, Entry>,
    /// Files that did not load, by name, with why.
    broken: BTreeMap<String, (SceneOrigin, String)>,
    transports: Cache<Transport>,
    grams: Cache<Gram>,
    conditioning: Cache<Conditioning>,
    /// Scenes sampled as a reconstruction chose from its noise, by key
    /// (`name#sampling,wall m,scene m`): each has its own cached `T`.
    variants: Mutex<BTreeMap<String, Arc<Scene>>>,
    /// Each scene's pixel maps (which pixels image which wall element, per
    /// pose and frame geometry), made on first use and kept: a measurement
    /// is then one pass over each frame.
    pixel_maps: Mutex<BTreeMap<String, Arc<crate::measure::PixelMaps>>>,
}

impl Scenes {
    /// Built-in scenes plus these files (a file replaces a built-in of the
    /// same name), whose `T` will be built within `budget`.
    pub fn load(files: &[impl AsRef<Path>], budget: MemoryBudget) -> Result<Self, SceneError> {
        let mut entries = Self::builtin()?;
        for f in files {
            let f = f.as_ref();
            entries.insert(file_name(f), Entry::read(f, SceneOrigin::File)?);
        }
        Ok(Self::of(entries, BTreeMap::new(), budget))
    }

    /// The built-in scenes.
    pub(crate) fn builtin() -> Result<BTreeMap<String, Entry>, SceneError> {
        crate::scene::builtin::BUILT_IN
            .iter()
            .map(|(name, text)| {
                let entry =
                    Entry::parse(text.to_string(), Default::default(), SceneOrigin::BuiltIn)?;
                Ok((name.to_string(), entry))
            })
            .collect()
    }

    /// These scenes and broken files, with empty caches.
    pub(crate) fn of(
        entries: BTreeMap<String, Entry>,
        broken: BTreeMap<String, (SceneOrigin, String)>,
        budget: MemoryBudget,
    ) -> Self {
        Self {
            budget,
            entries,
            broken,
            transports: Mutex::new(BTreeMap::new()),
            grams: Mutex::new(BTreeMap::new()),
            conditioning: Mutex::new(BTreeMap::new()),
            variants: Mutex::new(BTreeMap::new()),
            pixel_maps: Mutex::new(BTreeMap::new()),
        }
    }

    /// These scenes with what was made for `old`'s scenes kept (their `T`,
    /// Gram, conditioning, variants and pixel maps) where a scene is the
    /// same text read from the same folder.
    pub(crate) fn keeping(self, old: &Scenes) -> Self {
        let same = |name: &str| {
            let base = name.split('#').next().unwrap_or(name);
            match (self.entries.get(base), old.entries.get(base)) {
                (Some(a), Some(b)) => {
                    a.source == b.source && a.folder == b.folder && a.geometry == b.geometry
                }
                _ => false,
            }
        };
        Self {
            transports: kept(&old.transports, same),
            grams: kept(&old.grams, same),
            conditioning: kept(&old.conditioning, same),
            variants: kept(&old.variants, same),
            pixel_maps: kept(&old.pixel_maps, same),
            ..self
        }
    }

    /// The entry of scene `name`, for a change of it.
    pub(crate) fn entry(&self, name: &str) -> Option<&Entry> {
        self.entries.get(name)
    }

    /// Every entry and broken file, for a new snapshot made from these.
    #[allow(clippy::type_complexity)]
    pub(crate) fn parts(
        &self,
    ) -> (
        BTreeMap<String, Entry>,
        BTreeMap<String, (SceneOrigin, String)>,
    ) {
        (self.entries.clone(), self.broken.clone())
    }

    /// Every scene that serves and every file that does not, by name.
    pub fn listing(&self) -> Vec<SceneListing> {
        let serving = self.entries.iter().map(|(name, e)| SceneListing {
            name: name.clone(),
            origin: e.origin,
            error: None,
            fitted_by: match e.geometry {
                Geometry::Fitted { calibration } => Some(calibration),
                Geometry::AsWritten => None,
            },
        });
        let broken = self
            .broken
            .iter()
            .map(|(name, (origin, why))| SceneListing {
                name: name.clone(),
                origin: *origin,
                error: Some(why.clone()),
                fitted_by: None,
            });
        let mut all: Vec<SceneListing> = serving.chain(broken).collect();
        all.sort_by(|a, b| {
            a.name
                .cmp(&b.name)
                .then(a.error.is_some().cmp(&b.error.is_some()))
        });
        all
    }

    /// The memory budget every `T` of these scenes is built within.
    ///
    /// Other models of a scene built for a request (the wall fit's point
    /// source, the demo's unpolarized image) are held to it too.
    pub fn budget(&self) -> MemoryBudget {
        self.budget
    }

    /// The scene with this name.
    pub fn get(&self, name: &str) -> Option<Arc<Scene>> {
        self.entries.get(name).map(|e| Arc::clone(&e.scene))
    }

    /// Which geometry scene `name` serves with (as written when unknown).
    pub(crate) fn geometry(&self, name: &str) -> Geometry {
        self.entries
            .get(name)
            .map(|e| e.geometry)
            .unwrap_or_default()
    }

    /// A scene's TOML text as loaded.
    pub fn source(&self, name: &str) -> Option<&str> {
        self.entries.get(name).map(|e| e.source.as_str())
    }

    /// The folder scene `name`'s file is in (`""` for a built-in scene):
    /// where its relative mesh paths are read from.
    pub fn folder(&self, name: &str) -> &Path {
        self.entries
            .get(name)
            .map_or(Path::new(""), |e| e.folder.as_path())
    }

    /// Every name.
    pub fn names(&self) -> Vec<String> {
        self.entries.keys().cloned().collect()
    }

    /// Names of the poses of every scene, sorted, once each.
    pub fn pose_names(&self) -> Vec<String> {
        let mut names: Vec<String> = self
            .entries
            .values()
            .flat_map(|e| {
                e.scene
                    .poses()
                    .iter()
                    .map(|p| p.name.clone())
                    .collect::<Vec<_>>()
            })
            .collect();
        names.sort();
        names.dedup();
        names
    }

    /// The known truth of reconstruction `rec` on its scene grid as a 16-bit
    /// PNG, top row first (0..1 to black..white, the scale of its result;
    /// grey, or RGB for a colour image), when its request gave one;
    /// `Ok(None)` when it did not.
    pub(crate) fn truth_png(
        &self,
        rec: &crate::store::ReconstructionRecord,
    ) -> Result<Option<Vec<u8>>, TruthPngError> {
        let Some(truth) = &rec.params.truth else {
            return Ok(None);
        };
        let scene = self.scene(&rec.scene)?;
        let grid = scene.hidden().plane.grid;
        let colour = matches!(truth, crate::store::Truth::Image(i)
            if matches!(i.image.first().and_then(|r| r.first()), Some(crate::store::Pixel::Colour(_))));
        let c = 1 + 2 * usize::from(colour);
        let channels = truth.channels(grid, c, "truth")?;
        let scene_order: Vec<f64> = (0..grid.count())
            .flat_map(|k| channels.iter().map(move |ch| ch[k]))
            .collect();
        let pixels = crate::files::image::unit_to_u16(&grid.to_top_first(&scene_order, c));
        Ok(Some(match colour {
            true => crate::files::image::encode_png_rgb16(grid.nu, grid.nv, &pixels)?,
            false => crate::files::image::encode_png16(grid.nu, grid.nv, &pixels)?,
        }))
    }

    /// Where each pose of scene `name` sees its wall (the live view's aim).
    pub(crate) fn wall_views(&self, name: &str) -> Result<Vec<WallView>, ScenesError> {
        Ok(wall_views(&*self.scene(name)?))
    }

    /// The scene with this name (or a variant's key), or the error that lists the known ones.
    pub fn scene(&self, name: &str) -> Result<Arc<Scene>, ScenesError> {
        if let Some(v) = self
            .variants
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .get(name)
        {
            return Ok(Arc::clone(v));
        }
        self.get(name).ok_or_else(|| ScenesError::Unknown {
            name: name.to_string(),
            known: self.names(),
        })
    }

    /// The pixel maps of scene `name`'s poses, kept for every measurement of it.
    pub fn pixel_maps(&self, name: &str) -> Arc<crate::measure::PixelMaps> {
        let mut maps = self
            .pixel_maps
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        Arc::clone(maps.entry(name.to_string()).or_default())
    }

    /// The key under which scene `name`, sampled as a reconstruction with
    /// per-row `variance` chose (MODEL.md "Rows that match the measurement"),
    /// keeps its `T`, Gram and conditioning; `name` itself when the choice is
    /// the file's own, and what was chosen when the file left a key out.
    pub fn for_noise(
        &self,
        name: &str,
        variance: &[f64],
    ) -> Result<(String, Option<crate::transport::choose::ModelChoice>), ScenesError> {
        let scene = self.scene(name)?;
        if scene.left_out() == Default::default() {
            return Ok((name.to_string(), None));
        }
        let (chosen, choice) = crate::transport::choose::choose(&scene, variance, self.budget)
            .map_err(|source| ScenesError::Transport {
                name: name.to_string(),
                source,
            })?;
        if chosen == *scene {
            return Ok((name.to_string(), Some(choice)));
        }
        let key = format!(
            "{name}#{},{},{}",
            choice.sampling.name(),
            choice.wall_supersample,
            choice.scene_supersample
        );
        self.variants
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .entry(key.clone())
            .or_insert_with(|| Arc::new(chosen));
        Ok((key, Some(choice)))
    }

    /// The key of scene `name` with area shadows (`name#area`), registered
    /// on first use: a photo of a scene that left `shadows` out compares
    /// it with the scene's own, and its `T` is then cached as the scene's is.
    pub fn with_area_shadows(&self, name: &str) -> Result<String, ScenesError> {
        let scene = self.scene(name)?;
        let key = format!("{name}#area");
        let mut variants = self
            .variants
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        if !variants.contains_key(&key) {
            let area = scene
                .with_area_shadows()
                .map_err(|source| ScenesError::Edit {
                    name: name.to_string(),
                    source,
                })?;
            variants.insert(key.clone(), Arc::new(area));
        }
        Ok(key)
    }

    /// `T` of a scene, built on first use (CPU-heavy: call from a blocking task).
    pub fn transport(&self, name: &str) -> Result<Arc<Transport>, ScenesError> {
        self.transport_until(name, Stop::default())
    }

    /// [`Scenes::transport`], its build (when this call makes it) ended
    /// early with `ScenesError::Stopped` once `stop` is raised; nothing is
    /// cached then, so the next caller builds it.
    pub fn transport_until(
        &self,
        name: &str,
        stop: Stop<'_>,
    ) -> Result<Arc<Transport>, ScenesError> {
        let scene = self.scene(name)?;
        cached(&self.transports, name, || {
            build_with_progress(&scene, self.budget, &|_| {}, stop).map_err(|source| match source {
                TransportError::Stopped { .. } => ScenesError::Stopped,
                source => ScenesError::Transport {
                    name: name.to_string(),
                    source,
                },
            })
        })
    }

    /// `T^T T` of a scene's `T`, with its low-rank form for a large `T`,
    /// formed on first use (CPU-heavy: call from a blocking task).
    pub fn gram(&self, name: &str) -> Result<Arc<Gram>, ScenesError> {
        self.gram_until(name, Stop::default())
    }

    /// [`Scenes::gram`] (and the `T` it needs) ended early with
    /// `ScenesError::Stopped` once `stop` is raised.
    pub fn gram_until(&self, name: &str, stop: Stop<'_>) -> Result<Arc<Gram>, ScenesError> {
        cached(&self.grams, name, || {
            let t = self.transport_until(name, stop)?;
            Gram::of_until(&t, stop).ok_or(ScenesError::Stopped)
        })
    }

    /// Singular values and kappa of a scene's `T`, computed on first use:
    /// from the low-rank form of its Gram when `T` has one (as `polnlos
    /// reconstruct` does without `--full-spectrum`), else by an SVD (call
    /// from a blocking task).
    pub fn conditioning(&self, name: &str) -> Result<Arc<Conditioning>, ScenesError> {
        self.conditioning_until(name, Stop::default())
    }

    /// [`Scenes::conditioning`] (and the `T` and Gram it needs) ended early
    /// with `ScenesError::Stopped` once `stop` is raised; an SVD the
    /// caller stops goes on to its end beside it and is cached.
    pub fn conditioning_until(
        &self,
        name: &str,
        stop: Stop<'_>,
    ) -> Result<Arc<Conditioning>, ScenesError> {
        // Below this no Gram has a low-rank form: none is formed here.
        let t = self.transport_until(name, stop)?;
        let gram = if t.cols() >= crate::solve::lowrank::LOW_RANK_MIN_COLS {
            Some(self.gram_until(name, stop)?)
        } else {
            None
        };
        let made = |t: &Transport, gram: Option<&Gram>| {
            condition_with(t, gram).map_err(|source| ScenesError::Conditioning {
                name: name.to_string(),
                source,
            })
        };
        match gram.as_ref().is_some_and(|g| g.low_rank.is_some()) {
            true => cached(&self.conditioning, name, || made(&t, gram.as_deref())),
            // An SVD of `T` runs on its own thread, so that a stop ends the
            // wait (it cannot end the SVD).
            false => self.conditioning_svd(name, t, stop),
        }
    }

    /// The SVD branch of [`Scenes::conditioning_until`]: the SVD on a
    /// thread of its own that caches its result, waited for until `stop`.
    fn conditioning_svd(
        &self,
        name: &str,
        t: Arc<Transport>,
        stop: Stop<'_>,
    ) -> Result<Arc<Conditioning>, ScenesError> {
        let slot = slot(&self.conditioning, name);
        if let Some(c) = slot.lock().unwrap_or_else(|e| e.into_inner()).as_ref() {
            return Ok(c.clone());
        }
        let owned = name.to_string();
        let work = move || {
            let mut value = slot.lock().unwrap_or_else(|e| e.into_inner());
            if let Some(c) = value.as_ref() {
                return Ok(c.clone());
            }
            let c =
                Arc::new(
                    condition_with(&t, None).map_err(|source| ScenesError::Conditioning {
                        name: owned,
                        source,
                    })?,
                );
            *value = Some(c.clone());
            Ok(c)
        };
        crate::stop::finish_unless(stop, work).unwrap_or(Err(ScenesError::Stopped))
    }
}

/// The values of `cache` under the names `keep` keeps (their slots shared).
fn kept<V: Clone>(
    cache: &Mutex<BTreeMap<String, V>>,
    keep: impl Fn(&str) -> bool,
) -> Mutex<BTreeMap<String, V>> {
    let map = cache
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner);
    Mutex::new(
        map.iter()
            .filter(|(k, _)| keep(k))
            .map(|(k, v)| (k.clone(), v.clone()))
            .collect(),
    )
}

/// One value per scene name, each made at most once.
type Cache<T> = Mutex<BTreeMap<String, Arc<Mutex<Option<Arc<T>>>>>>;

/// The value cached under `name`, or `make`'s, cached. The map's lock is held
/// only to find the name's slot; the slot's lock is held while `make` runs,
/// so two jobs asking for the same scene's `T` or Gram at once wait for one
/// build instead of making two (a poisoned lock keeps its value). A failed
/// `make` caches nothing: the next call tries again.
fn cached<T>(
    cache: &Cache<T>,
    name: &str,
    make: impl FnOnce() -> Result<T, ScenesError>,
) -> Result<Arc<T>, ScenesError> {
    let slot = slot(cache, name);
    let mut value = slot.lock().unwrap_or_else(|e| e.into_inner());
    if let Some(v) = value.as_ref() {
        return Ok(v.clone());
    }
    let made = Arc::new(make()?);
    *value = Some(made.clone());
    Ok(made)
}

/// The slot of `name` in `cache`, made empty on first use.
fn slot<T>(cache: &Cache<T>, name: &str) -> Arc<Mutex<Option<Arc<T>>>> {
    cache
        .lock()
        .unwrap_or_else(|e| e.into_inner())
        .entry(name.to_string())
        .or_default()
        .clone()
}

/// Why a reconstruction's truth image could not be made.
#[derive(Debug, thiserror::Error)]
pub(crate) enum TruthPngError {
    /// Its scene is not one the daemon knows now (the scenes' reason).
    #[error(transparent)]
    Scene(#[from] ScenesError),
    /// The image did not encode.
    #[error(transparent)]
    Png(#[from] crate::files::image::PngError),
    /// The stored truth does not fit the scene now (its reason).
    #[error(transparent)]
    Truth(#[from] crate::files::truth::TruthError),
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The built-in crossed bench scene with a 24x24 scene grid (576
    /// columns, past the low-rank threshold), as a file.
    fn large_scene(dir: &Path) -> std::path::PathBuf {
        let text = crate::scene::builtin::BUILT_IN
            .iter()
            .find(|(n, _)| *n == "brewster-crossed")
            .map(|(_, t)| *t)
            .expect("built-in scene")
            .replacen("grid = [8, 8]", "grid = [24, 24]", 1);
        let path = dir.join("large.toml");
        std::fs::write(&path, text).expect("write scene");
        path
    }

    #[test]
    fn each_pose_sees_its_wall_where_its_homography_puts_it() {
        let text = crate::scene::builtin::text("brewster-crossed").expect("built in");
        let scene = Scene::from_toml_str(text).expect("scene");
        let [v] = wall_views(&scene).try_into().expect("one pose");
        assert_eq!(v.centre, Some([255.5, 255.5]));
        let c = v.corners.expect("corners");
        // The wall (0.3 m) fills part of the 512 px frame, nearer edge wider.
        assert!(
            c.iter().flatten().all(|x| (0.0..512.0).contains(x)),
            "{c:?}"
        );
        assert!(c[0] != c[2] && (c[0][1] - c[1][1]).abs() > 10.0, "{c:?}");
        // Shifted by 100 px: the centre follows; no homography: no aim, a reason.
        let shifted = text.replacen(
            "[[-425.517945, 1220.52494, 255.5], [250.943812, 0, 255.5], [-1.66543227, 0, 1]]",
            "[[-592.061172, 1220.52494, 355.5], [250.943812, 0, 255.5], [-1.66543227, 0, 1]]",
            1,
        );
        let scene = Scene::from_toml_str(&shifted).expect("scene");
        let centre = wall_views(&scene)[0].centre.expect("centre");
        assert!((centre[0] - 355.5).abs() < 1e-9 && (centre[1] - 255.5).abs() < 1e-9);
        let bare = text.replacen("homography = ", "# homography = ", 1);
        let v = &wall_views(&Scene::from_toml_str(&bare).expect("scene"))[0];
        assert!(
            v.centre.is_none()
                && v.why.as_deref().is_some_and(|w| w.contains("no homography")
                    && w.contains("POST /calibrations,")
                    && !w.contains("/calibrations/wall"))
        );
    }

    #[test]
    fn a_scene_keeps_its_pixel_maps_and_a_noise_gets_its_own_model() {
        let none: [&Path; 0] = [];
        let scenes = Scenes::load(&none, MemoryBudget::DEFAULT).expect("scenes");
        let (a, b) = (
            scenes.pixel_maps("brewster-crossed"),
            scenes.pixel_maps("brewster-crossed"),
        );
        assert!(Arc::ptr_eq(&a, &b));
        assert!(!Arc::ptr_eq(&a, &scenes.pixel_maps("brewster-multi")));
        // A quiet measurement asks for the pixel rows the file leaves out: a
        // variant with its own key, T and scene; a loud one keeps the file's.
        let t = scenes.transport("brewster-crossed").expect("T");
        let level = t.apply(&vec![1.0; t.cols()]);
        let quiet: Vec<f64> = level.iter().map(|v| (1e-4 * v).powi(2)).collect();
        let (key, choice) = scenes
            .for_noise("brewster-crossed", &quiet)
            .expect("choice");
        assert_eq!(key, "brewster-crossed#pixels,1,1");
        assert_eq!(choice.expect("chosen").chosen, vec!["wall.sampling"]);
        let variant = scenes.scene(&key).expect("the variant is a scene");
        assert_eq!(variant.wall().sampling, crate::scene::WallSampling::Pixels);
        assert_eq!(scenes.transport(&key).expect("its T").rows(), t.rows());
        let loud: Vec<f64> = level.iter().map(|v| (0.05 * v).powi(2)).collect();
        let (key, _) = scenes.for_noise("brewster-crossed", &loud).expect("choice");
        assert_eq!(key, "brewster-crossed");
    }

    #[test]
    fn two_jobs_asking_at_once_share_one_build() {
        let dir = tempfile::tempdir().expect("tempdir");
        let scenes =
            Scenes::load(&[large_scene(dir.path())], MemoryBudget::DEFAULT).expect("scenes");
        let (a, b) = std::thread::scope(|s| {
            let a = s.spawn(|| scenes.gram("large").expect("gram"));
            let b = s.spawn(|| scenes.gram("large").expect("gram"));
            (a.join().expect("thread"), b.join().expect("thread"))
        });
        assert!(Arc::ptr_eq(&a, &b));
    }

    #[test]
    fn gram_is_formed_once_and_conditioning_comes_from_it() {
        let dir = tempfile::tempdir().expect("tempdir");
        let scenes =
            Scenes::load(&[large_scene(dir.path())], MemoryBudget::DEFAULT).expect("scenes");
        let first = scenes.gram("large").expect("gram");
        let again = scenes.gram("large").expect("gram");
        assert!(Arc::ptr_eq(&first, &again));
        let t = scenes.transport("large").expect("T");
        assert_eq!(first.lower.nrows(), t.cols());
        let lr = first
            .low_rank
            .as_ref()
            .expect("a 576-column bench T is low rank");
        let cond = scenes.conditioning("large").expect("conditioning");
        assert!(cond.from_gram);
        assert_eq!(
            cond.rank,
            Conditioning::from_low_rank(t.rows(), t.cols(), lr)
                .expect("cond")
                .rank
        );
        // A small scene keeps the SVD.
        let small = scenes
            .conditioning("brewster-crossed")
            .expect("conditioning");
        assert!(!small.from_gram);
    }
}
