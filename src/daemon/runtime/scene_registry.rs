//! The scenes the daemon serves now, changed without a restart: a scene
//! posted, replaced or deleted over HTTP, and every file read again on
//! SIGHUP. Each change makes a new [`Scenes`] snapshot; a job holds the one
//! it started with, so a change never touches a running job.
//!
//! The layers, lowest first: the built-in scenes, the config's
//! `scene_files`, the posted scenes in the data directory's `scenes/`
//! (`NAME.toml`); a name in a higher layer hides the lower ones.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, RwLock};

use super::scenes::{file_name, Entry, SceneListing, SceneOrigin, Scenes};
use crate::scene::SceneError;
use crate::transport::MemoryBudget;

/// The most bytes a posted scene file may have: a scene file is a page of
/// TOML (its meshes are files of their own).
pub(crate) const MAX_SCENE_BYTES: usize = 256 * 1024;

/// Why a scene could not be added, replaced or deleted.
#[derive(Debug, thiserror::Error)]
pub enum SceneChangeError {
    /// The name cannot name a scene (or a file).
    #[error("scene name {name:?}: {reason}")]
    Name {
        /// The name given.
        name: String,
        /// What a name must be.
        reason: &'static str,
    },
    /// `POST` of a name the daemon knows.
    #[error("scene {name:?} exists ({}); PUT /scenes/{name} replaces it", origin.words())]
    Exists {
        /// The name.
        name: String,
        /// Where the scene of that name comes from.
        origin: SceneOrigin,
    },
    /// `PUT` or `DELETE` of a name the daemon does not know.
    #[error("no scene {name:?}; POST /scenes?name={name} adds one")]
    Unknown {
        /// The name.
        name: String,
    },
    /// `DELETE` of a scene that was not posted.
    #[error("scene {name:?} is {}, not posted: only a posted scene can be deleted (remove a file from scene_files in the config)", origin.words())]
    NotPosted {
        /// The name.
        name: String,
        /// Where it comes from.
        origin: SceneOrigin,
    },
    /// The body is not a valid scene file.
    #[error("scene {name:?}: {source}")]
    Invalid {
        /// The name.
        name: String,
        /// Why (a TOML error names its line).
        #[source]
        source: SceneError,
    },
    /// A relative mesh path of the body cannot be written for the data directory.
    #[error("scene {name:?}: {source}")]
    MeshPath {
        /// The name.
        name: String,
        /// Why.
        #[source]
        source: crate::calibrate::scene_text::MeshPathError,
    },
    /// The body is not TOML that can be edited.
    #[error("scene {name:?}: the body is not TOML: {source}")]
    Toml {
        /// The name.
        name: String,
        /// Where it is not (line and column).
        #[source]
        source: toml_edit::TomlError,
    },
    /// The file could not be written.
    #[error("scene {name:?}: {source}")]
    Write {
        /// The name.
        name: String,
        /// Why.
        #[source]
        source: crate::files::FileError,
    },
    /// A folder could not be made or a file removed.
    #[error("scene {name:?}: {} in the data directory: {source}", what)]
    Store {
        /// The name.
        name: String,
        /// What was done (`writing scenes/NAME.toml`).
        what: String,
        /// Why.
        #[source]
        source: std::io::Error,
    },
}

/// The daemon's scenes now, and how to change them.
pub struct SceneRegistry {
    budget: MemoryBudget,
    /// The config's `scene_files`.
    files: Vec<PathBuf>,
    /// Where posted scenes are kept: the data directory's `scenes/`.
    posted: PathBuf,
    current: RwLock<Arc<Scenes>>,
    /// Held through a change, so two changes do not each start from the
    /// same snapshot and lose one.
    changing: Mutex<()>,
    /// Each scene's geometry in force from a scene calibration, by name.
    fitted: Mutex<BTreeMap<String, FittedGeometry>>,
}

/// A scene calibration's geometry: the file text it placed and the placed
/// file (in the same folder); a scene whose file reads otherwise now
/// serves as written.
#[derive(Debug, Clone)]
pub(crate) struct FittedGeometry {
    /// The scene calibration's id.
    pub calibration: i64,
    /// The scene file's text it placed.
    pub source: String,
    /// That text with the fitted geometry.
    pub placed: String,
}

impl SceneRegistry {
    /// The built-in scenes, `files` and the scenes posted to `data_dir`
    /// before; a file that does not load is listed with its error, not
    /// served (only a built-in scene that does not parse is an error).
    pub fn open(
        files: &[PathBuf],
        data_dir: &Path,
        budget: MemoryBudget,
    ) -> Result<Self, SceneError> {
        let posted = data_dir.join("scenes");
        let current = gather(files, &posted, budget)?;
        Ok(Self {
            budget,
            files: files.to_vec(),
            posted,
            current: RwLock::new(Arc::new(current)),
            changing: Mutex::new(()),
            fitted: Mutex::new(BTreeMap::new()),
        })
    }

    /// The scenes now: a snapshot a job keeps while it runs.
    pub fn now(&self) -> Arc<Scenes> {
        Arc::clone(&self.current.read().unwrap_or_else(|e| e.into_inner()))
    }

    /// Adds scene `name` from the text of its file, kept in the data directory.
    pub fn add(&self, name: &str, text: &str) -> Result<SceneListing, SceneChangeError> {
        check_name(name)?;
        let _g = self.changing.lock().unwrap_or_else(|e| e.into_inner());
        let now = self.now();
        if let Some(e) = now.entry(name) {
            return Err(SceneChangeError::Exists {
                name: name.into(),
                origin: e.origin,
            });
        }
        self.store(&now, name, text, &self.posted)
    }

    /// Replaces scene `name` with the text of a file beside the one it
    /// replaces (its relative mesh paths are read from that folder and
    /// rewritten for the data directory), kept in the data directory.
    pub fn replace(&self, name: &str, text: &str) -> Result<SceneListing, SceneChangeError> {
        check_name(name)?;
        let _g = self.changing.lock().unwrap_or_else(|e| e.into_inner());
        let now = self.now();
        let Some(old) = now.entry(name) else {
            return Err(SceneChangeError::Unknown { name: name.into() });
        };
        let from = match old.origin {
            SceneOrigin::BuiltIn => self.posted.clone(),
            _ => old.folder.clone(),
        };
        self.store(&now, name, text, &from)
    }

    /// Deletes posted scene `name` (its file in the data directory); a
    /// scene of the name in a lower layer (a built-in one, a file of
    /// `scene_files`, read now) serves again.
    pub fn delete(&self, name: &str) -> Result<(), SceneChangeError> {
        let _g = self.changing.lock().unwrap_or_else(|e| e.into_inner());
        let now = self.now();
        match now.entry(name) {
            None => return Err(SceneChangeError::Unknown { name: name.into() }),
            Some(e) if e.origin != SceneOrigin::Posted => {
                return Err(SceneChangeError::NotPosted {
                    name: name.into(),
                    origin: e.origin,
                })
            }
            Some(_) => {}
        }
        let path = self.posted.join(format!("{name}.toml"));
        std::fs::remove_file(&path).map_err(|source| SceneChangeError::Store {
            name: name.into(),
            what: format!("removing scenes/{name}.toml"),
            source,
        })?;
        let (mut entries, mut broken) = now.parts();
        entries.remove(name);
        broken.remove(name);
        if let Some(entry) = Scenes::builtin().ok().and_then(|mut b| b.remove(name)) {
            entries.insert(name.into(), entry);
        }
        if let Some(f) = self.files.iter().rev().find(|f| file_name(f) == name) {
            match Entry::read(f, SceneOrigin::File) {
                Ok(entry) => {
                    entries.insert(name.into(), entry);
                }
                Err(e) => {
                    broken.insert(name.into(), (SceneOrigin::File, e.to_string()));
                }
            }
        }
        self.publish(entries, broken, &now);
        Ok(())
    }

    /// Serves scene `name` with a scene calibration's geometry, or
    /// (`None`) with its file's; running jobs keep theirs.
    pub(crate) fn set_fitted(&self, name: &str, fitted: Option<FittedGeometry>) {
        let _g = self.changing.lock().unwrap_or_else(|e| e.into_inner());
        {
            let mut map = self.fitted.lock().unwrap_or_else(|e| e.into_inner());
            match fitted {
                Some(f) => map.insert(name.to_string(), f),
                None => map.remove(name),
            };
        }
        let now = self.now();
        let (entries, broken) = now.parts();
        self.publish(entries, broken, &now);
    }

    /// Reads every scene file again (SIGHUP): the scenes whose text is
    /// unchanged keep their `T`; the listing of what serves now.
    pub fn reload(&self) -> Vec<SceneListing> {
        let _g = self.changing.lock().unwrap_or_else(|e| e.into_inner());
        let now = self.now();
        self.reread(&now);
        self.now().listing()
    }

    /// Every layer read again, keeping what `now` made for unchanged scenes.
    fn reread(&self, now: &Scenes) {
        match gather(&self.files, &self.posted, self.budget) {
            Ok(scenes) => {
                let (entries, broken) = scenes.parts();
                self.publish(entries, broken, now)
            }
            Err(e) => tracing::error!("the built-in scenes do not parse: {e}"),
        }
    }

    /// Validates `text` as a file in `from`, writes it as
    /// `scenes/NAME.toml` (relative mesh paths rewritten for there) and
    /// serves it.
    fn store(
        &self,
        now: &Scenes,
        name: &str,
        text: &str,
        from: &Path,
    ) -> Result<SceneListing, SceneChangeError> {
        let invalid = |source| SceneChangeError::Invalid {
            name: name.into(),
            source,
        };
        crate::scene::Scene::from_toml_str_in(text, from).map_err(invalid)?;
        let written = self.rebased(name, text, from)?;
        let store = |what: String| {
            move |source| SceneChangeError::Store {
                name: name.into(),
                what,
                source,
            }
        };
        std::fs::create_dir_all(&self.posted).map_err(store("making scenes/".into()))?;
        let path = self.posted.join(format!("{name}.toml"));
        crate::files::write_atomic(&path, written.as_bytes()).map_err(|source| {
            SceneChangeError::Write {
                name: name.into(),
                source,
            }
        })?;
        let entry = Entry::read(&path, SceneOrigin::Posted).map_err(invalid)?;
        let (mut entries, mut broken) = now.parts();
        entries.insert(name.into(), entry);
        broken.remove(name);
        self.publish(entries, broken, now);
        Ok(self
            .now()
            .listing()
            .into_iter()
            .find(|l| l.name == name && l.error.is_none())
            .unwrap_or(SceneListing {
                name: name.into(),
                origin: SceneOrigin::Posted,
                error: None,
                fitted_by: None,
            }))
    }

    /// `text`, a file in `from`, as a file in the data directory's `scenes/`.
    fn rebased(&self, name: &str, text: &str, from: &Path) -> Result<String, SceneChangeError> {
        if from == self.posted {
            return Ok(text.to_string());
        }
        let mut doc: toml_edit::DocumentMut =
            text.parse().map_err(|source| SceneChangeError::Toml {
                name: name.into(),
                source,
            })?;
        std::fs::create_dir_all(&self.posted).map_err(|source| SceneChangeError::Store {
            name: name.into(),
            what: "making scenes/".into(),
            source,
        })?;
        crate::calibrate::scene_text::rebase_mesh_paths(&mut doc, from, &self.posted).map_err(
            |source| SceneChangeError::MeshPath {
                name: name.into(),
                source,
            },
        )?;
        Ok(doc.to_string())
    }

    /// Serves `entries` (each with the fitted geometry in force where it
    /// placed the entry's text as it reads now, else as written) and
    /// `broken`, keeping what `now` made for scenes that did not change.
    fn publish(
        &self,
        entries: BTreeMap<String, Entry>,
        broken: BTreeMap<String, (SceneOrigin, String)>,
        now: &Scenes,
    ) {
        let fitted = self
            .fitted
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .clone();
        let entries = entries
            .into_iter()
            .map(|(name, e)| {
                let placed = fitted
                    .get(&name)
                    .filter(|f| f.source == e.source)
                    .map(|f| (f.calibration, e.fitted(f.calibration, &f.placed)));
                let entry = match placed {
                    Some((_, Ok(placed))) => Ok(placed),
                    Some((id, Err(err))) => {
                        tracing::error!("scene {name:?}: scene calibration {id} does not load ({err}); it serves as written");
                        e.as_written()
                    }
                    None => e.as_written(),
                };
                match entry {
                    Ok(entry) => (name, entry),
                    // Its text loaded before: it loads again.
                    Err(_) => (name, e),
                }
            })
            .collect();
        self.set(Scenes::of(entries, broken, self.budget).keeping(now));
    }

    fn set(&self, scenes: Scenes) {
        *self.current.write().unwrap_or_else(|e| e.into_inner()) = Arc::new(scenes);
    }
}

/// A name a scene (and its file `NAME.toml`) can have: 1 to 64 letters,
/// digits, `-`, `_` or `.`, not starting with `.`.
fn check_name(name: &str) -> Result<(), SceneChangeError> {
    let fail = |reason| {
        Err(SceneChangeError::Name {
            name: name.into(),
            reason,
        })
    };
    if name.is_empty() || name.len() > 64 {
        return fail("give 1 to 64 characters");
    }
    if name.starts_with('.') {
        return fail("a name cannot start with '.'");
    }
    if !name
        .chars()
        .all(|c| c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.'))
    {
        return fail("use letters, digits, '-', '_' and '.' only");
    }
    Ok(())
}

/// The built-in scenes, then `files`, then the `*.toml` files in `posted`;
/// a file that does not load is listed as broken.
fn gather(files: &[PathBuf], posted: &Path, budget: MemoryBudget) -> Result<Scenes, SceneError> {
    let mut entries = Scenes::builtin()?;
    let mut broken = BTreeMap::new();
    let mut posted_files: Vec<PathBuf> = std::fs::read_dir(posted)
        .map(|dir| {
            dir.filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|p| p.extension().is_some_and(|x| x == "toml"))
                .collect()
        })
        .unwrap_or_default();
    posted_files.sort();
    let layers = files
        .iter()
        .map(|f| (f, SceneOrigin::File))
        .chain(posted_files.iter().map(|f| (f, SceneOrigin::Posted)));
    for (f, origin) in layers {
        let name = file_name(f);
        match Entry::read(f, origin) {
            Ok(e) => {
                broken.remove(&name);
                entries.insert(name, e);
            }
            Err(e) => {
                tracing::error!("scene {name:?} not served: {e}");
                broken.insert(name, (origin, e.to_string()));
            }
        }
    }
    Ok(Scenes::of(entries, broken, budget))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_change_makes_a_new_snapshot_and_keeps_the_old_one_whole() {
        let dir = tempfile::tempdir().expect("tempdir");
        let bad = dir.path().join("bad.toml");
        std::fs::write(&bad, "[wall]\nsize = \n").expect("write");
        let r = SceneRegistry::open(&[bad], dir.path(), MemoryBudget::DEFAULT).expect("open");
        let listed = r.now().listing();
        let broken = listed.iter().find(|l| l.name == "bad").expect("listed");
        assert!(
            broken
                .error
                .as_deref()
                .is_some_and(|e| e.contains("line 2")),
            "{broken:?}"
        );
        assert!(r.now().get("bad").is_none());
        let text = crate::scene::builtin::text("brewster-crossed").expect("built in");
        let before = r.now();
        let t = before.transport("brewster-crossed").expect("T");
        r.add("copy", text).expect("added");
        assert!(before.get("copy").is_none());
        let after = r.now();
        assert!(after.get("copy").is_some());
        // An unchanged scene keeps its T in the new snapshot.
        assert!(Arc::ptr_eq(
            &t,
            &after.transport("brewster-crossed").expect("T")
        ));
        assert!(matches!(
            r.add("copy", text),
            Err(SceneChangeError::Exists { .. })
        ));
        assert!(matches!(
            r.add("a/b", text),
            Err(SceneChangeError::Name { .. })
        ));
        assert!(matches!(
            r.delete("brewster-crossed"),
            Err(SceneChangeError::NotPosted { .. })
        ));
        r.delete("copy").expect("deleted");
        assert!(r.now().get("copy").is_none() && after.get("copy").is_some());
        assert!(!dir.path().join("scenes/copy.toml").exists());
    }
}
