//! Truth images as people store them, top row first (+v up), read onto a
//! scene grid's element order ([`Grid::from_top_first`]).
//!
//! Why one reader: `reconstruct --truth`, `reconstruct --photo --truth` and
//! the daemon's `"truth": {"image": ...}` score against an image the same way.

use std::path::Path;

use super::{image, npy, FileError};
use crate::scene::Grid;

/// An image with its top row first: `height` rows of `width` pixels,
/// `channels` values a pixel, interleaved.
#[derive(Debug, Clone, PartialEq)]
pub struct TopFirst {
    /// Rows.
    pub height: usize,
    /// Columns.
    pub width: usize,
    /// Values a pixel: 1 (grey) or one a colour.
    pub channels: usize,
    /// The values, row-major, top row first.
    pub data: Vec<f64>,
}

/// Why a truth image cannot be scored against: each variant names the image
/// (`what`: its path, or the request's field) and what was wrong.
#[derive(Debug, thiserror::Error)]
pub enum TruthError {
    /// The file could not be read or decoded.
    #[error(transparent)]
    File(#[from] FileError),
    /// An image whose size is not the scene grid's.
    #[error("{what} is {height} x {width} (rows x columns); the scene grid is {nv} x {nu}: give the truth on the scene's grid, top row first")]
    Size {
        /// The image.
        what: String,
        /// Its rows.
        height: usize,
        /// Its columns.
        width: usize,
        /// The grid's rows.
        nv: usize,
        /// The grid's columns.
        nu: usize,
    },
    /// Values a pixel that are neither grey nor one a colour.
    #[error("{what} has {channels} values a pixel; give 1 (grey) or {wanted} (one a colour of the reconstruction)")]
    Channels {
        /// The image.
        what: String,
        /// Values a pixel it has.
        channels: usize,
        /// Colours of the reconstruction.
        wanted: usize,
    },
    /// Not the shape of an image.
    #[error("{what} has shape {shape:?}: give [rows, columns] or [rows, columns, colours], top row first")]
    Shape {
        /// The image.
        what: String,
        /// Its shape.
        shape: Vec<usize>,
    },
    /// A row of another length than the first.
    #[error("{what}: row {row} has {len} pixels, row 0 has {width}; every row needs as many")]
    Ragged {
        /// The image.
        what: String,
        /// The row, from the top.
        row: usize,
        /// Its pixels.
        len: usize,
        /// Row 0's pixels.
        width: usize,
    },
    /// A pixel unlike the first (grey among colours, or another count).
    #[error("{what}: the pixel at row {row}, column {col} is not like the first; give every pixel as a grey value, or every pixel as [red, green, blue]")]
    Mixed {
        /// The image.
        what: String,
        /// Its row, from the top.
        row: usize,
        /// Its column.
        col: usize,
    },
    /// A name that is no test pattern.
    #[error("{what} = {name:?}: must be a test pattern name (disk, bars, letter, flat) or {{\"image\": [[...], ...]}}")]
    Pattern {
        /// The field.
        what: String,
        /// The name given.
        name: String,
    },
    /// A value that is not a finite number.
    #[error("{what} holds the non-finite value {value} at row {row}, column {col}")]
    NotFinite {
        /// The image.
        what: String,
        /// The value.
        value: f64,
        /// Its row, from the top.
        row: usize,
        /// Its column.
        col: usize,
    },
}

impl TopFirst {
    /// Reads a truth image: a `.npy` of `[rows, columns]` or `[rows,
    /// columns, colours]` (unsigned integers scaled to [0, 1] by their full
    /// scale, floats as they are), a PNG (grey or RGB, scaled to [0, 1]) or
    /// a TIFF (as grey).
    pub fn read(path: &Path) -> Result<Self, TruthError> {
        let what = path.display().to_string();
        let is_npy = path
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("npy"));
        if is_npy {
            let a = npy::read(path)?;
            let (height, width, channels) = match a.shape[..] {
                [h, w] => (h, w, 1),
                [h, w, c] => (h, w, c),
                _ => {
                    return Err(TruthError::Shape {
                        what,
                        shape: a.shape,
                    })
                }
            };
            let full = a.unsigned_bits.map_or(1.0, |b| f64::from((1u32 << b) - 1));
            return Ok(Self {
                height,
                width,
                channels,
                data: a.data.iter().map(|v| v / full).collect(),
            });
        }
        let bytes = std::fs::read(path).map_err(|e| FileError::read(path, e))?;
        if !bytes.starts_with(b"\x89PNG") {
            let g = image::read_gray(path)?;
            return Ok(Self {
                height: g.height,
                width: g.width,
                channels: 1,
                data: g.data,
            });
        }
        let p = image::decode_png(&bytes, u32::MAX, u64::MAX >> 4)
            .map_err(|e| FileError::format(path, format!("cannot decode the PNG ({e})")))?;
        let full = f64::from((1u32 << p.bits) - 1);
        let (channels, samples) = match p.grey() {
            true => (1, p.samples.iter().step_by(p.channels).copied().collect()),
            false => (3, p.rgb()),
        };
        Ok(Self {
            height: p.height,
            width: p.width,
            channels,
            data: samples
                .into_iter()
                .map(|v: u16| f64::from(v) / full)
                .collect(),
        })
    }

    /// The image as `colours` channels in `grid`'s element order: grey is
    /// every colour's, a colour image against one channel is its luma
    /// (ITU-R BT.709); its size must be the grid's.
    pub fn on_grid(
        &self,
        grid: Grid,
        colours: usize,
        what: &str,
    ) -> Result<Vec<Vec<f64>>, TruthError> {
        if (self.height, self.width) != (grid.nv, grid.nu) {
            return Err(TruthError::Size {
                what: what.into(),
                height: self.height,
                width: self.width,
                nv: grid.nv,
                nu: grid.nu,
            });
        }
        let c = self.channels;
        if c == 0 || (c != 1 && c != colours && !(colours == 1 && c == 3)) {
            return Err(TruthError::Channels {
                what: what.into(),
                channels: c,
                wanted: colours,
            });
        }
        if let Some(k) = self.data.iter().position(|v| !v.is_finite()) {
            return Err(TruthError::NotFinite {
                what: what.into(),
                value: self.data[k],
                row: k / c / grid.nu,
                col: k / c % grid.nu,
            });
        }
        let scene = grid.from_top_first(&self.data, c);
        let pixels = scene.chunks_exact(c);
        Ok(match (c, colours) {
            (1, _) => vec![scene.clone(); colours],
            (3, 1) => vec![pixels
                .map(|p| 0.2126 * p[0] + 0.7152 * p[1] + 0.0722 * p[2])
                .collect()],
            _ => (0..c)
                .map(|ch| scene.iter().skip(ch).step_by(c).copied().collect())
                .collect(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn image(height: usize, width: usize, channels: usize) -> TopFirst {
        TopFirst {
            height,
            width,
            channels,
            data: (0..height * width * channels).map(|v| v as f64).collect(),
        }
    }

    #[test]
    fn a_truth_image_lands_on_the_grid_bottom_row_first() {
        let grid = Grid { nu: 2, nv: 3 };
        // Grey: the image's last row is the scene's row 0, for every colour.
        let grey = image(3, 2, 1).on_grid(grid, 2, "t").unwrap();
        assert_eq!(grey, vec![vec![4.0, 5.0, 2.0, 3.0, 0.0, 1.0]; 2]);
        // Colour: each channel of its own, rows reversed.
        let rgb = image(3, 2, 3).on_grid(grid, 3, "t").unwrap();
        assert_eq!(rgb[0], vec![12.0, 15.0, 6.0, 9.0, 0.0, 3.0]);
        assert_eq!(rgb[2], vec![14.0, 17.0, 8.0, 11.0, 2.0, 5.0]);
        // Colour against one channel: its luma.
        let luma = image(3, 2, 3).on_grid(grid, 1, "t").unwrap();
        assert!((luma[0][5] - (0.2126 * 3.0 + 0.7152 * 4.0 + 0.0722 * 5.0)).abs() < 1e-12);
    }

    #[test]
    fn a_truth_of_another_size_names_both_sizes() {
        let grid = Grid { nu: 36, nv: 29 };
        let e = image(36, 29, 1).on_grid(grid, 3, "truth.npy").unwrap_err();
        assert_eq!(
            e.to_string(),
            "truth.npy is 36 x 29 (rows x columns); the scene grid is 29 x 36: give the truth on the scene's grid, top row first"
        );
        let e = image(29, 36, 2).on_grid(grid, 3, "t").unwrap_err();
        assert!(
            matches!(
                e,
                TruthError::Channels {
                    channels: 2,
                    wanted: 3,
                    ..
                }
            ),
            "{e}"
        );
        let mut nan = image(29, 36, 1);
        nan.data[40] = f64::NAN;
        let e = nan.on_grid(grid, 1, "t").unwrap_err();
        assert!(
            matches!(e, TruthError::NotFinite { row: 1, col: 4, .. }),
            "{e}"
        );
    }
}
