//! One daemon per data directory: an exclusive `flock` on `polnlos.lock`,
//! taken before the catalogue is opened and held for the life of the store.
//! The kernel drops it when the process ends, however it ends (SIGKILL too),
//! so a stale lock file never blocks a restart.

use std::io::{Read, Seek, Write};
use std::os::unix::io::AsRawFd;
use std::path::{Path, PathBuf};

use super::StoreError;

/// The held lock; released when dropped (or when the process ends).
#[derive(Debug)]
pub(crate) struct DirLock {
    _file: std::fs::File,
}

/// Name of the lock file inside the data directory.
pub(crate) const LOCK_FILE: &str = "polnlos.lock";

impl DirLock {
    /// Takes the lock on `dir` or says which process holds it.
    pub fn acquire(dir: &Path) -> Result<Self, StoreError> {
        let path = dir.join(LOCK_FILE);
        let io = |source| StoreError::DataDir {
            path: path.clone(),
            source,
        };
        let mut file = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .open(&path)
            .map_err(io)?;
        // SAFETY: `file` is open, so its descriptor is valid for this call;
        // flock only takes the descriptor and flags.
        let rc = unsafe { libc::flock(file.as_raw_fd(), libc::LOCK_EX | libc::LOCK_NB) };
        if rc != 0 {
            let err = std::io::Error::last_os_error();
            if err.raw_os_error() == Some(libc::EWOULDBLOCK) {
                let mut text = String::new();
                let _ = file.read_to_string(&mut text);
                return Err(StoreError::Locked {
                    dir: dir.to_path_buf(),
                    holder: text.trim().parse().ok(),
                });
            }
            return Err(io(err));
        }
        file.set_len(0).map_err(io)?;
        file.rewind().map_err(io)?;
        writeln!(file, "{}", std::process::id()).map_err(io)?;
        file.sync_all().map_err(io)?;
        Ok(Self { _file: file })
    }
}

/// Removes the temporary files (`.<name>.tmp-<pid>`) a killed daemon left in
/// the data directory and its job folders; returns the paths removed.
pub(crate) fn remove_orphans(dir: &Path) -> Vec<PathBuf> {
    let mut removed = Vec::new();
    let mut folders = vec![dir.to_path_buf()];
    for sub in ["captures", "reconstructions"] {
        if let Ok(entries) = std::fs::read_dir(dir.join(sub)) {
            folders.extend(entries.flatten().map(|e| e.path()).filter(|p| p.is_dir()));
        }
    }
    for folder in folders {
        let Ok(entries) = std::fs::read_dir(&folder) else {
            continue;
        };
        for e in entries.flatten() {
            let name = e.file_name();
            let name = name.to_string_lossy();
            let orphan =
                name.starts_with('.') && name.contains(super::TMP_MARK) && e.path().is_file();
            if orphan && std::fs::remove_file(e.path()).is_ok() {
                removed.push(e.path());
            }
        }
    }
    removed
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_second_lock_names_the_holder_and_a_dropped_one_is_free_again() {
        let dir = tempfile::tempdir().unwrap();
        let first = DirLock::acquire(dir.path()).unwrap();
        match DirLock::acquire(dir.path()) {
            Err(StoreError::Locked { holder, .. }) => assert_eq!(holder, Some(std::process::id())),
            other => panic!("{other:?}"),
        }
        drop(first);
        DirLock::acquire(dir.path()).unwrap();
    }

    #[test]
    fn orphaned_temporaries_are_removed_and_nothing_else() {
        let dir = tempfile::tempdir().unwrap();
        let cap = dir.path().join("captures").join("3");
        std::fs::create_dir_all(&cap).unwrap();
        for name in [".frames.tiff.tmp-123", "mean.tiff", ".mean.tiff.tmp-9"] {
            std::fs::write(cap.join(name), b"x").unwrap();
        }
        std::fs::write(dir.path().join(".catalogue.tmp-1"), b"x").unwrap();
        let removed = remove_orphans(dir.path());
        assert_eq!(removed.len(), 3, "{removed:?}");
        assert!(cap.join("mean.tiff").exists());
    }
}
