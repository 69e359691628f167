//! Scenes the daemon knows by name: the built-in bench scenes and the
//! config's `scene_files`, each with its transport matrix and its singular
//! values computed once on first use (both depend on the scene alone).

use std::collections::BTreeMap;
use std::path::Path;
use std::sync::{Arc, Mutex};

use crate::scene::{Scene, SceneError};
use crate::solve::{condition, Conditioning};
use crate::transport::{build, Transport, TransportError};

/// Scenes by name, with a cache of their `T`.
pub struct Scenes {
    scenes: BTreeMap<String, Arc<Scene>>,
    transports: Mutex<BTreeMap<String, Arc<Transport>>>,
    conditioning: Mutex<BTreeMap<String, Arc<Conditioning>>>,
}

impl Scenes {
    /// Built-in scenes plus these files (a file replaces a built-in of the same name).
    pub fn load(files: &[impl AsRef<Path>]) -> Result<Self, SceneError> {
        let mut scenes = BTreeMap::new();
        for (name, text) in crate::scene::builtin::BUILT_IN {
            scenes.insert(name.to_string(), Arc::new(Scene::from_toml_str(text)?));
        }
        for f in files {
            let f = f.as_ref();
            let name = f
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_default();
            scenes.insert(name, Arc::new(Scene::load(f)?));
        }
        Ok(Self {
            scenes,
            transports: Mutex::new(BTreeMap::new()),
            conditioning: Mutex::new(BTreeMap::new()),
        })
    }

    /// The scene with this name.
    pub fn get(&self, name: &str) -> Option<Arc<Scene>> {
        self.scenes.get(name).cloned()
    }

    /// Every name.
    pub fn names(&self) -> Vec<String> {
        self.scenes.keys().cloned().collect()
    }

    /// `T` of a scene, built on first use (CPU-heavy: call from a blocking task).
    pub fn transport(&self, name: &str) -> Option<Result<Arc<Transport>, TransportError>> {
        let scene = self.get(name)?;
        if let Some(t) = self
            .transports
            .lock()
            .ok()
            .and_then(|m| m.get(name).cloned())
        {
            return Some(Ok(t));
        }
        Some(build(&scene).map(|t| {
            let t = Arc::new(t);
            if let Ok(mut m) = self.transports.lock() {
                m.insert(name.to_string(), t.clone());
            }
            t
        }))
    }

    /// Singular values and kappa of a scene's `T`, computed on first use
    /// (an SVD: call from a blocking task). Errors are returned as text.
    pub fn conditioning(&self, name: &str) -> Option<Result<Arc<Conditioning>, String>> {
        if let Some(c) = self
            .conditioning
            .lock()
            .ok()
            .and_then(|m| m.get(name).cloned())
        {
            return Some(Ok(c));
        }
        let t = match self.transport(name)? {
            Ok(t) => t,
            Err(e) => return Some(Err(e.to_string())),
        };
        Some(condition(&t).map_err(|e| e.to_string()).map(|c| {
            let c = Arc::new(c);
            if let Ok(mut m) = self.conditioning.lock() {
                m.insert(name.to_string(), c.clone());
            }
            c
        }))
    }
}
