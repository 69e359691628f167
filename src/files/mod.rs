//! Reading and writing the files polnlos exchanges with people and other
//! tools: `.npy` arrays, 8/16-bit grey PNGs, TIFF frames, JSON reports; and
//! how much of them the machine can hold ([`space`]).

pub mod frames;
pub mod image;
pub mod json;
pub mod npy;
pub mod space;
pub mod transport_cache;
pub mod truth;

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
        FileError::Io {
            action: "cannot read",
            path: path.to_path_buf(),
            source,
        }
    }
    pub(crate) fn write(path: &std::path::Path, source: std::io::Error) -> Self {
        FileError::Io {
            action: "cannot write",
            path: path.to_path_buf(),
            source,
        }
    }
    /// A file whose content is wrong: its path and what is wrong with it.
    pub fn format(path: &std::path::Path, reason: impl Into<String>) -> Self {
        FileError::Format {
            path: path.to_path_buf(),
            reason: reason.into(),
        }
    }
}

/// Writes `bytes` to `path` atomically: a temporary file in the same folder,
/// fsynced, then renamed over the target, so a crash never leaves half a file.
pub fn write_atomic(path: &std::path::Path, bytes: &[u8]) -> Result<(), FileError> {
    use std::io::Write;
    let dir = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(std::path::Path::new("."));
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
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

/// Loads a scene image onto a grid, in the grid's element order: a PNG/TIFF
/// (8/16-bit grey, resampled by area averaging) or a `.npy` of `[rows,
/// columns]` (values used as given; resampled when its shape is not the
/// grid's), either top row first (the image's last row is the grid's row
/// `iv` = 0, [`crate::scene::Grid::from_top_first`]); a `.npy` of `[nu nv]`
/// values is taken in the element order itself.
pub fn load_grid_image(
    path: &std::path::Path,
    grid: crate::scene::Grid,
) -> Result<Vec<f64>, FileError> {
    let is_npy = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("npy"));
    let gray = if is_npy {
        let a = npy::read(path)?;
        let (h, w) = match a.shape.as_slice() {
            [n] if *n == grid.count() => return Ok(a.data),
            [h, w] => (*h, *w),
            s => {
                return Err(FileError::format(
                    path,
                    format!(
                        "shape {s:?} is neither the scene grid ({} x {}) nor a 2-D image",
                        grid.nv, grid.nu
                    ),
                ))
            }
        };
        if (h, w) == (grid.nv, grid.nu) {
            return Ok(grid.from_top_first(&a.data, 1));
        }
        image::Gray {
            width: w,
            height: h,
            data: a.data,
        }
    } else {
        image::read_gray(path)?
    };
    if gray.width == 0 || gray.height == 0 {
        return Err(FileError::format(path, "the image is empty"));
    }
    if let Some(v) = gray.data.iter().find(|v| !v.is_finite()) {
        return Err(FileError::format(
            path,
            format!("holds the non-finite value {v}"),
        ));
    }
    Ok(grid.from_top_first(&image::resample_area(&gray, grid.nu, grid.nv), 1))
}
