//! Scenes the daemon knows by name: the built-in bench scenes and the
//! config's `scene_files`, each with its transport matrix and its singular
//! values computed once on first use (both depend on the scene alone).

use std::collections::BTreeMap;
use std::path::Path;
use std::sync::{Arc, Mutex};

use crate::scene::{Scene, SceneError};
use crate::solve::{condition, Conditioning, SolveError};
use crate::transport::{build, Transport, TransportError};

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
    /// The SVD of `T` failed.
    #[error("scene {name:?}: conditioning: {source}")]
    Conditioning {
        /// The scene.
        name: String,
        /// Why.
        source: SolveError,
    },
}

/// Scenes by name, with a cache of their `T`.
pub struct Scenes {
    scenes: BTreeMap<String, Arc<Scene>>,
    /// Each scene's TOML text, for writing calibrated copies of it.
    sources: BTreeMap<String, String>,
    transports: Mutex<BTreeMap<String, Arc<Transport>>>,
    conditioning: Mutex<BTreeMap<String, Arc<Conditioning>>>,
}

impl Scenes {
    /// Built-in scenes plus these files (a file replaces a built-in of the same name).
    pub fn load(files: &[impl AsRef<Path>]) -> Result<Self, SceneError> {
        let mut scenes = BTreeMap::new();
        let mut sources = BTreeMap::new();
        for (name, text) in crate::scene::builtin::BUILT_IN {
            scenes.insert(name.to_string(), Arc::new(Scene::from_toml_str(text)?));
            sources.insert(name.to_string(), text.to_string());
        }
        for f in files {
            let f = f.as_ref();
            let name = f
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_default();
            let scene = Scene::load(f)?;
            if let Ok(text) = std::fs::read_to_string(f) {
                sources.insert(name.clone(), text);
            }
            scenes.insert(name, Arc::new(scene));
        }
        Ok(Self {
            scenes,
            sources,
            transports: Mutex::new(BTreeMap::new()),
            conditioning: Mutex::new(BTreeMap::new()),
        })
    }

    /// The scene with this name.
    pub fn get(&self, name: &str) -> Option<Arc<Scene>> {
        self.scenes.get(name).cloned()
    }

    /// A scene's TOML text as loaded.
    pub fn source(&self, name: &str) -> Option<&str> {
        self.sources.get(name).map(String::as_str)
    }

    /// Every name.
    pub fn names(&self) -> Vec<String> {
        self.scenes.keys().cloned().collect()
    }

    /// The scene with this name, or the error that lists the known ones.
    pub fn scene(&self, name: &str) -> Result<Arc<Scene>, ScenesError> {
        self.get(name).ok_or_else(|| ScenesError::Unknown {
            name: name.to_string(),
            known: self.names(),
        })
    }

    /// `T` of a scene, built on first use (CPU-heavy: call from a blocking task).
    pub fn transport(&self, name: &str) -> Result<Arc<Transport>, ScenesError> {
        let scene = self.scene(name)?;
        cached(&self.transports, name, || {
            build(&scene).map_err(|source| ScenesError::Transport {
                name: name.to_string(),
                source,
            })
        })
    }

    /// Singular values and kappa of a scene's `T`, computed on first use
    /// (an SVD: call from a blocking task).
    pub fn conditioning(&self, name: &str) -> Result<Arc<Conditioning>, ScenesError> {
        cached(&self.conditioning, name, || {
            let t = self.transport(name)?;
            condition(&t).map_err(|source| ScenesError::Conditioning {
                name: name.to_string(),
                source,
            })
        })
    }
}

/// The value cached under `name`, or `make`'s, cached (a poisoned lock only
/// loses the cache, never the value).
fn cached<T>(
    cache: &Mutex<BTreeMap<String, Arc<T>>>,
    name: &str,
    make: impl FnOnce() -> Result<T, ScenesError>,
) -> Result<Arc<T>, ScenesError> {
    if let Some(v) = cache.lock().ok().and_then(|m| m.get(name).cloned()) {
        return Ok(v);
    }
    let v = Arc::new(make()?);
    if let Ok(mut m) = cache.lock() {
        m.insert(name.to_string(), v.clone());
    }
    Ok(v)
}
