//! What can be wrong with a scene file, naming the key and the reason.

use std::path::{Path, PathBuf};

/// A scene file that cannot be read, parsed or accepted.
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    /// The file could not be read.
    #[error("cannot read scene file {path}: {source}")]
    Read {
        /// File that was asked for.
        path: PathBuf,
        /// Underlying I/O error.
        source: std::io::Error,
    },
    /// The text is not valid TOML or does not have the scene schema.
    #[error("{}scene file is not valid: {message}", at(.path))]
    Parse {
        /// File, when known.
        path: Option<PathBuf>,
        /// Parser message, with the key and line.
        message: String,
    },
    /// A value has the right type but is not acceptable.
    #[error("{}{key} = {value}: {reason}", at(.path))]
    Invalid {
        /// File, when known.
        path: Option<PathBuf>,
        /// Dotted key, e.g. `wall.roughness` or `pose[1].camera`.
        key: String,
        /// The offending value as written.
        value: String,
        /// What it must be instead.
        reason: String,
    },
}

fn at(path: &Option<PathBuf>) -> String {
    path.as_ref()
        .map(|p| format!("{}: ", p.display()))
        .unwrap_or_default()
}

impl SceneError {
    pub(crate) fn invalid(
        key: impl Into<String>,
        value: impl std::fmt::Debug,
        reason: impl Into<String>,
    ) -> Self {
        SceneError::Invalid {
            path: None,
            key: key.into(),
            value: format!("{value:?}"),
            reason: reason.into(),
        }
    }

    /// Attaches the file the error came from.
    pub fn in_file(self, file: &Path) -> Self {
        match self {
            SceneError::Parse { message, .. } => SceneError::Parse {
                path: Some(file.to_path_buf()),
                message,
            },
            SceneError::Invalid {
                key, value, reason, ..
            } => SceneError::Invalid {
                path: Some(file.to_path_buf()),
                key,
                value,
                reason,
            },
            e => e,
        }
    }

    /// The offending key, when the error is about one value.
    pub fn key(&self) -> Option<&str> {
        match self {
            SceneError::Invalid { key, .. } => Some(key),
            _ => None,
        }
    }
}
