//! `T` kept on disk between command-line calls: `measure`, `reconstruct`
//! and `reconstruct --photo` of the same scene build it once (issue 37).
//!
//! Why: a real photo's scene takes seconds to build (the chair's `T` once
//! took 107 s per call, per colour channel) and every call of the same
//! scene builds the same matrix. An entry is keyed by everything that makes
//! `T`: the scene's whole content (meshes included) and this very binary
//! (its size and modification time), so a changed scene or a rebuilt
//! polnlos never reads an old matrix. The folder is bounded: the oldest
//! entries go first.

use std::hash::{Hash, Hasher};
use std::path::{Path, PathBuf};

use crate::scene::Scene;
use crate::transport::{MemoryBudget, Transport, TransportError};

/// The environment variable naming the cache folder, or `off`.
pub(crate) const ENV: &str = "POLNLOS_CACHE";
/// The most bytes the cache folder keeps; older entries are removed past it.
pub(crate) const MAX_BYTES: u64 = 4 << 30;
/// Matrices smaller than this build in well under a second: not worth a file.
pub(crate) const MIN_BYTES: u64 = 16 << 20;

/// Where `T`s are kept, and how much.
#[derive(Debug, Clone)]
pub struct TransportCache {
    dir: PathBuf,
    max_bytes: u64,
}

/// `T` and whether it came from the cache.
pub struct Cached {
    /// The matrix.
    pub t: Transport,
    /// `"hit"` (read from the cache), `"stored"` (built and kept) or
    /// `"built"` (built, not kept: under `MIN_BYTES`, over half the
    /// bound, or the folder could not be written).
    pub source: &'static str,
}

impl std::ops::Deref for Cached {
    type Target = Transport;

    fn deref(&self) -> &Transport {
        &self.t
    }
}

impl TransportCache {
    /// The cache `ENV` names, else `$XDG_CACHE_HOME/polnlos/transport`,
    /// else `$HOME/.cache/polnlos/transport`; `None` when `ENV` is `off`
    /// or no folder can be named.
    pub fn from_env() -> Option<Self> {
        let dir = match std::env::var_os(ENV) {
            Some(v) if v == "off" => return None,
            Some(v) if !v.is_empty() => PathBuf::from(v),
            _ => std::env::var_os("XDG_CACHE_HOME")
                .filter(|v| !v.is_empty())
                .map(PathBuf::from)
                .or_else(|| std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".cache")))?
                .join("polnlos")
                .join("transport"),
        };
        Some(Self::at(dir))
    }

    /// A cache in `dir`.
    pub fn at(dir: PathBuf) -> Self {
        Self {
            dir,
            max_bytes: MAX_BYTES,
        }
    }

    /// `scene`'s `T`: read from the cache when it holds it, else built
    /// (within `budget`, `progress` hearing the columns) and kept when it
    /// is large enough to be slow to build. A cache that cannot be read or written is
    /// passed by: the matrix is built as without one.
    pub fn build(
        &self,
        scene: &Scene,
        budget: MemoryBudget,
        progress: &(dyn Fn(usize) + Sync),
    ) -> Result<Cached, TransportError> {
        let path = self.dir.join(format!("{:016x}.npy", key(scene)));
        if let Some(t) = read(&path, scene) {
            // Touched, so the least recently used entry goes first.
            let _ = std::fs::File::open(&path)
                .and_then(|f| f.set_modified(std::time::SystemTime::now()));
            return Ok(Cached { t, source: "hit" });
        }
        let t = crate::transport::build_with_progress(scene, budget, progress, Default::default())?;
        let bytes = (t.rows() * t.cols() * 8) as u64;
        let worth = (MIN_BYTES..=self.max_bytes / 2).contains(&bytes);
        let source = match worth && self.store(&path, &t).is_ok() {
            true => "stored",
            false => "built",
        };
        Ok(Cached { t, source })
    }

    /// Writes `t` to `path` (atomically), then trims the folder to its bound.
    fn store(&self, path: &Path, t: &Transport) -> Result<(), crate::files::FileError> {
        std::fs::create_dir_all(&self.dir)
            .map_err(|e| crate::files::FileError::write(&self.dir, e))?;
        let data: Vec<f64> = (0..t.cols())
            .flat_map(|k| t.col(k).iter().copied())
            .collect();
        crate::files::npy::write_f64(path, &[t.cols(), t.rows()], &data)?;
        self.trim(path);
        Ok(())
    }

    /// Removes the oldest entries (not `keep`) until the folder fits its bound.
    fn trim(&self, keep: &Path) {
        let Ok(list) = std::fs::read_dir(&self.dir) else {
            return;
        };
        let mut entries: Vec<(std::time::SystemTime, u64, PathBuf)> = list
            .filter_map(Result::ok)
            .filter(|e| e.path().extension().is_some_and(|x| x == "npy"))
            .filter_map(|e| {
                let m = e.metadata().ok()?;
                Some((m.modified().ok()?, m.len(), e.path()))
            })
            .collect();
        entries.sort();
        let mut total: u64 = entries.iter().map(|e| e.1).sum();
        for (_, len, path) in entries {
            if total <= self.max_bytes {
                break;
            }
            if path != keep && std::fs::remove_file(&path).is_ok() {
                total -= len;
            }
        }
    }
}

/// The entry's key: the scene's whole content and this binary's identity.
fn key(scene: &Scene) -> u64 {
    let mut h = std::collections::hash_map::DefaultHasher::new();
    format!("{scene:?}").hash(&mut h);
    env!("CARGO_PKG_VERSION").hash(&mut h);
    if let Some(m) = std::env::current_exe().ok().and_then(|p| p.metadata().ok()) {
        m.len().hash(&mut h);
        if let Ok(t) = m.modified() {
            t.hash(&mut h);
        }
    }
    h.finish()
}

/// The cached `T` of `scene` at `path`, when there is one of its shape.
fn read(path: &Path, scene: &Scene) -> Option<Transport> {
    let a = crate::files::npy::read(path).ok()?;
    let (rows, cols) = (scene.rows(), scene.cols());
    (a.shape == [cols, rows] && a.data.len() == rows * cols).then(|| {
        Transport::from_col_major(
            rows,
            cols,
            a.data,
            crate::transport::blocks_of(scene),
            scene.wall().plane.grid,
            scene.hidden().plane.grid,
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_scene_is_built_once_and_read_back_the_same_and_a_changed_one_is_not() {
        let dir = tempfile::tempdir().unwrap();
        let mut cache = TransportCache::at(dir.path().to_path_buf());
        let scene = Scene::builtin("brewster-crossed").unwrap().unwrap();
        let direct = crate::transport::build(&scene, MemoryBudget::DEFAULT).unwrap();
        // The bench's T is under MIN_BYTES: stored here by hand.
        let path = dir.path().join(format!("{:016x}.npy", key(&scene)));
        cache.store(&path, &direct).unwrap();
        let hit = cache.build(&scene, MemoryBudget::DEFAULT, &|_| {}).unwrap();
        assert_eq!(hit.source, "hit");
        assert_eq!((hit.t.rows(), hit.t.cols()), (direct.rows(), direct.cols()));
        assert!((0..direct.cols()).all(|k| hit.t.col(k) == direct.col(k)));
        assert_eq!(hit.t.blocks(), direct.blocks());
        // Another scene has another key; a file of the wrong shape is not read.
        let other = Scene::builtin("brewster-crossed-3x3").unwrap().unwrap();
        assert_ne!(key(&other), key(&scene));
        crate::files::npy::write_f64(
            &dir.path().join(format!("{:016x}.npy", key(&other))),
            &[1, 2],
            &[0.0, 1.0],
        )
        .unwrap();
        assert!(read(
            &dir.path().join(format!("{:016x}.npy", key(&other))),
            &other
        )
        .is_none());
        // Past its bound the oldest entry goes, never the one just written.
        cache.max_bytes = 1;
        cache.trim(&path);
        let left: Vec<_> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().path())
            .collect();
        assert_eq!(left, vec![path]);
    }
}
