//! Grey images: reading 8/16-bit PNG or TIFF into [0, 1], writing 16-bit PNG,
//! and area resampling onto a grid.

use std::path::Path;

use super::FileError;

/// A grey image with values in [0, 1], row-major, top row first.
#[derive(Debug, Clone, PartialEq)]
pub struct Gray {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Values in [0, 1].
    pub data: Vec<f64>,
}

/// Reads an image file (PNG or TIFF, any bit depth; colour is converted to luma).
pub fn read_gray(path: &Path) -> Result<Gray, FileError> {
    let img = image::ImageReader::open(path)
        .map_err(|e| FileError::read(path, e))?
        .with_guessed_format()
        .map_err(|e| FileError::read(path, e))?
        .decode()
        .map_err(|e| {
            FileError::format(
                path,
                format!("cannot decode image ({e}); use an 8- or 16-bit grey PNG"),
            )
        })?;
    let g = img.to_luma16();
    let (w, h) = (g.width() as usize, g.height() as usize);
    Ok(Gray {
        width: w,
        height: h,
        data: g
            .into_raw()
            .into_iter()
            .map(|v| f64::from(v) / 65535.0)
            .collect(),
    })
}

/// Encodes 16-bit grey pixels as PNG bytes.
pub fn encode_png16(width: usize, height: usize, pixels: &[u16]) -> Result<Vec<u8>, String> {
    let buf = image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_raw(
        width as u32,
        height as u32,
        pixels.to_vec(),
    )
    .ok_or_else(|| "pixel count does not match the image size".to_string())?;
    let mut out = std::io::Cursor::new(Vec::new());
    buf.write_to(&mut out, image::ImageFormat::Png)
        .map_err(|e| e.to_string())?;
    Ok(out.into_inner())
}

/// Writes 16-bit grey pixels as a PNG, atomically.
pub fn write_png16(
    path: &Path,
    width: usize,
    height: usize,
    pixels: &[u16],
) -> Result<(), FileError> {
    let bytes = encode_png16(width, height, pixels).map_err(|e| FileError::format(path, e))?;
    super::write_atomic(path, &bytes)
}

/// Maps [0, 1] to the full 16-bit range (values outside are clipped).
pub fn unit_to_u16(values: &[f64]) -> Vec<u16> {
    values
        .iter()
        .map(|v| (v.clamp(0.0, 1.0) * 65535.0).round() as u16)
        .collect()
}

/// Scales values by `1 / max` into 16 bits, for viewing a physical image.
pub fn normalized_u16(values: &[f64]) -> Vec<u16> {
    let max = values.iter().copied().fold(0.0f64, f64::max);
    if max <= 0.0 {
        return vec![0; values.len()];
    }
    values
        .iter()
        .map(|v| ((v / max).clamp(0.0, 1.0) * 65535.0).round() as u16)
        .collect()
}

/// Box-filter resampling with fractional pixel coverage: each destination
/// cell is the exact mean of the source area it covers (down- or up-sampling).
pub fn resample_area(src: &Gray, width: usize, height: usize) -> Vec<f64> {
    let sx = src.width as f64 / width as f64;
    let sy = src.height as f64 / height as f64;
    let spans = |i: usize, scale: f64, n: usize| -> Vec<(usize, f64)> {
        let (a, b) = (i as f64 * scale, (i + 1) as f64 * scale);
        let mut out = Vec::new();
        let mut p = a.floor() as usize;
        while (p as f64) < b && p < n {
            let w = (b.min(p as f64 + 1.0) - a.max(p as f64)).max(0.0);
            if w > 0.0 {
                out.push((p, w));
            }
            p += 1;
        }
        out
    };
    let mut out = Vec::with_capacity(width * height);
    for y in 0..height {
        let ys = spans(y, sy, src.height);
        for x in 0..width {
            let xs = spans(x, sx, src.width);
            let (mut acc, mut wsum) = (0.0, 0.0);
            for &(py, wy) in &ys {
                for &(px, wx) in &xs {
                    acc += src.data[py * src.width + px] * wx * wy;
                    wsum += wx * wy;
                }
            }
            out.push(if wsum > 0.0 { acc / wsum } else { 0.0 });
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn downsampling_averages_blocks() {
        let src = Gray {
            width: 4,
            height: 2,
            data: vec![0.0, 1.0, 0.5, 0.5, 1.0, 0.0, 0.5, 0.5],
        };
        assert_eq!(resample_area(&src, 2, 1), vec![0.5, 0.5]);
        // Fractional coverage: [0, 0.3, 0.9] onto 2 cells of 1.5 pixels each.
        let src = Gray {
            width: 3,
            height: 1,
            data: vec![0.0, 0.3, 0.9],
        };
        let r = resample_area(&src, 2, 1);
        assert!(
            (r[0] - 0.1).abs() < 1e-15 && (r[1] - 0.7).abs() < 1e-15,
            "{r:?}"
        );
    }

    #[test]
    fn png16_round_trip() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("x.png");
        write_png16(&p, 3, 2, &[0, 1000, 65535, 7, 8, 9]).unwrap();
        let g = read_gray(&p).unwrap();
        assert_eq!((g.width, g.height), (3, 2));
        assert!((g.data[1] - 1000.0 / 65535.0).abs() < 1e-12);
        assert_eq!(g.data[2], 1.0);
    }
}
