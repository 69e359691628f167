//! Reading and writing the files polnlos exchanges with people and other
//! tools: `.npy` arrays, 8/16-bit grey PNGs, TIFF frames, JSON reports.

pub mod image;
pub mod json;
pub mod npy;

use std::path::PathBuf;

/// A file that could not be read or written.
#[derive(Debug, thiserror::Error)]
pub enum FileError {
    /// Operating-system error on a path.
    #[error("{action} {path}: {source}")]
    Io {
        /// What was being done ("cannot read", "cannot write").
        action: &'static str,
        /// The path.
        path: PathBuf,
        /// Underlying error.
        source: std::io::Error,
    },
    /// The content is not what was expected.
    #[error("{path}: {reason}")]
    Format {
        /// The path.
        path: PathBuf,
        /// What is wrong with it.
        reason: String,
    },
}

impl FileError {
    pub(crate) fn read(path: &std::path::Path, source: std::io::Error) -> Self {
        FileError::Io { action: "cannot read", path: path.to_path_buf(), source }
    }
    pub(crate) fn write(path: &std::path::Path, source: std::io::Error) -> Self {
        FileError::Io { action: "cannot write", path: path.to_path_buf(), source }
    }
    pub(crate) fn format(path: &std::path::Path, reason: impl Into<String>) -> Self {
        FileError::Format { path: path.to_path_buf(), reason: reason.into() }
    }
}

/// Writes `bytes` to `path` atomically: a temporary file in the same folder,
/// fsynced, then renamed over the target, so a crash never leaves half a file.
pub fn write_atomic(path: &std::path::Path, bytes: &[u8]) -> Result<(), FileError> {
    use std::io::Write;
    let dir = path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(std::path::Path::new("."));
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let tmp = dir.join(format!(".{name}.tmp-{}", std::process::id()));
    let result = (|| {
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
        std::fs::rename(&tmp, path)?;
        if let Ok(d) = std::fs::File::open(dir) {
            let _ = d.sync_all();
        }
        Ok(())
    })();
    result.map_err(|e| {
        let _ = std::fs::remove_file(&tmp);
        FileError::write(path, e)
    })
}
