//! Grey images: reading 8/16-bit PNG or TIFF into [0, 1] and 32-bit float
//! TIFF as it is, writing 16-bit PNG, and area resampling onto a grid.

use std::path::Path;

use super::FileError;

/// A grey image, row-major, top row first: values in [0, 1] from an integer
/// image, a float TIFF's own values (e.g. the daemon's `mean.tiff`, in DN).
#[derive(Debug, Clone, PartialEq)]
pub struct Gray {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Values.
    pub data: Vec<f64>,
}

/// Reads an image file (PNG or TIFF, any bit depth; colour is converted to luma).
pub fn read_gray(path: &Path) -> Result<Gray, FileError> {
    let img = image::ImageReader::open(path)
        .map_err(|e| FileError::read(path, e))?
        .with_guessed_format()
        .map_err(|e| FileError::read(path, e))?
        .decode();
    let img = match img {
        Ok(img) => img,
        Err(e) => {
            return read_float_tiff(path)?.ok_or_else(|| {
                FileError::format(
                    path,
                    format!("cannot decode image ({e}); use an 8- or 16-bit grey PNG or TIFF, or a 32-bit float TIFF"),
                )
            })
        }
    };
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

/// A single-page 32-bit float grey TIFF (the daemon's `mean.tiff` and
/// `variance.tiff`), values as they are; `None` when the file is not one.
///
/// Why: the `image` crate decodes no float TIFF ("color type Unknown(32)"),
/// and a user calibrating from a capture's mean frame has exactly that.
fn read_float_tiff(path: &Path) -> Result<Option<Gray>, FileError> {
    let f = std::fs::File::open(path).map_err(|e| FileError::read(path, e))?;
    let Ok(mut dec) = tiff::decoder::Decoder::new(std::io::BufReader::new(f)) else {
        return Ok(None);
    };
    let Ok((w, h)) = dec.dimensions() else {
        return Ok(None);
    };
    match dec.read_image() {
        Ok(tiff::decoder::DecodingResult::F32(v)) if v.len() == w as usize * h as usize => {
            Ok(Some(Gray {
                width: w as usize,
                height: h as usize,
                data: v.into_iter().map(f64::from).collect(),
            }))
        }
        _ => Ok(None),
    }
}

/// The largest side, pixels, of an image scaled by [`scale_png16`].
pub const MAX_SCALED_SIDE: u32 = 4096;

/// A 16-bit grey PNG enlarged `k` times, each pixel a `k` x `k` block
/// (nearest neighbour: no value is invented between the scene's elements).
///
/// Why: a reconstruction of an 8x8 scene is an 8x8 PNG, too small to look
/// at in an image viewer. `k` must be at least 1 and the result at most
/// [`MAX_SCALED_SIDE`] on a side; the error says what is allowed.
pub fn scale_png16(png: &[u8], k: u32) -> Result<Vec<u8>, PngError> {
    let img = image::load_from_memory(png).map_err(|e| PngError::Decode(e.to_string()))?;
    let (w, h) = (img.width(), img.height());
    let most = (MAX_SCALED_SIDE / w.max(h).max(1)).max(1);
    if k == 0 || k > most {
        return Err(PngError::Scale {
            k,
            most,
            size: (w, h),
        });
    }
    // A stored image is 16-bit grey or 16-bit RGB (a colour camera's): its
    // type is kept, each pixel repeated k x k.
    let scaled = img.resize_exact(w * k, h * k, image::imageops::FilterType::Nearest);
    png_bytes(&scaled)
}

/// Why PNG bytes could not be made or read: each variant names the input
/// that was wrong.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum PngError {
    /// Stored bytes that do not decode as an image (the decoder's reason).
    #[error("cannot decode the stored PNG: {0}")]
    Decode(String),
    /// A scale factor outside what the image may grow by.
    #[error("scale = {k}: give a whole number from 1 to {most} (the {}x{} image may grow to {MAX_SCALED_SIDE} pixels a side)", size.0, size.1)]
    Scale {
        /// The factor asked for.
        k: u32,
        /// The largest factor allowed for this image.
        most: u32,
        /// The image's width and height.
        size: (u32, u32),
    },
    /// Pixels that do not fill the image they are said to be.
    #[error("{values} pixel values do not match a {width}x{height} image")]
    PixelCount {
        /// Values given (channels interleaved).
        values: usize,
        /// Columns asked for.
        width: usize,
        /// Rows asked for.
        height: usize,
    },
    /// The encoder failed (its reason).
    #[error("cannot encode the PNG: {0}")]
    Encode(String),
}

/// PNG bytes of an image in its own pixel type.
fn png_bytes(img: &image::DynamicImage) -> Result<Vec<u8>, PngError> {
    let mut out = std::io::Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Png)
        .map_err(|e| PngError::Encode(e.to_string()))?;
    Ok(out.into_inner())
}

/// The image `width` x `height` of `pixels` (interleaved channels of type
/// `P`), or why not.
fn buffer<P: image::Pixel>(
    width: usize,
    height: usize,
    pixels: &[P::Subpixel],
) -> Result<image::ImageBuffer<P, Vec<P::Subpixel>>, PngError> {
    let (w, h) = (u32::try_from(width), u32::try_from(height));
    let count = || PngError::PixelCount {
        values: pixels.len(),
        width,
        height,
    };
    let (Ok(w), Ok(h)) = (w, h) else {
        return Err(count());
    };
    image::ImageBuffer::from_raw(w, h, pixels.to_vec()).ok_or_else(count)
}

/// Encodes 16-bit RGB pixels (interleaved) as PNG bytes.
pub fn encode_png_rgb16(width: usize, height: usize, pixels: &[u16]) -> Result<Vec<u8>, PngError> {
    png_bytes(&buffer::<image::Rgb<u16>>(width, height, pixels)?.into())
}

/// Encodes 16-bit grey pixels as PNG bytes.
pub fn encode_png16(width: usize, height: usize, pixels: &[u16]) -> Result<Vec<u8>, PngError> {
    png_bytes(&buffer::<image::Luma<u16>>(width, height, pixels)?.into())
}

/// Writes 16-bit grey pixels as a PNG, atomically.
pub fn write_png16(
    path: &Path,
    width: usize,
    height: usize,
    pixels: &[u16],
) -> Result<(), FileError> {
    let bytes =
        encode_png16(width, height, pixels).map_err(|e| FileError::format(path, e.to_string()))?;
    super::write_atomic(path, &bytes)
}

/// Writes 8-bit RGB pixels (interleaved, rows top first) as a PNG, atomically.
pub fn write_png_rgb8(
    path: &Path,
    width: usize,
    height: usize,
    pixels: &[u8],
) -> Result<(), FileError> {
    let png = buffer::<image::Rgb<u8>>(width, height, pixels)
        .and_then(|b| png_bytes(&b.into()))
        .map_err(|e| FileError::format(path, e.to_string()))?;
    super::write_atomic(path, &png)
}

/// Writes 16-bit RGB pixels (interleaved) as a PNG, atomically: a colour
/// camera's reconstruction.
pub fn write_png_rgb16(
    path: &Path,
    width: usize,
    height: usize,
    pixels: &[u16],
) -> Result<(), FileError> {
    let png = encode_png_rgb16(width, height, pixels)
        .map_err(|e| FileError::format(path, e.to_string()))?;
    super::write_atomic(path, &png)
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
pub(crate) fn resample_area(src: &Gray, width: usize, height: usize) -> Vec<f64> {
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

    #[test]
    fn a_float_tiff_reads_as_its_values() {
        // The daemon's mean.tiff: 32-bit float, one page (the image crate
        // cannot decode it).
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("mean.tiff");
        let f = std::fs::File::create(&p).unwrap();
        let mut enc = tiff::encoder::TiffEncoder::new(std::io::BufWriter::new(f)).unwrap();
        enc.write_image::<tiff::encoder::colortype::Gray32Float>(
            3,
            2,
            &[0.0, 1.5, 4000.25, -2.0, 7.0, 8.0],
        )
        .unwrap();
        drop(enc);
        let g = read_gray(&p).unwrap();
        assert_eq!((g.width, g.height), (3, 2));
        assert_eq!(g.data, vec![0.0, 1.5, 4000.25, -2.0, 7.0, 8.0]);
        // Not an image at all: the error says what is read.
        std::fs::write(dir.path().join("x.tiff"), b"not a tiff").unwrap();
        let e = read_gray(&dir.path().join("x.tiff"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("32-bit float TIFF"), "{e}");
    }

    #[test]
    fn a_scaled_png_repeats_each_pixel_in_a_block_and_refuses_a_bad_scale() {
        let png = encode_png16(2, 1, &[100, 60000]).unwrap();
        let big = scale_png16(&png, 3).unwrap();
        let img = image::load_from_memory(&big).unwrap().to_luma16();
        assert_eq!(img.dimensions(), (6, 3));
        for y in 0..3 {
            for x in 0..6 {
                let want = if x < 3 { 100 } else { 60000 };
                assert_eq!(img.get_pixel(x, y).0[0], want, "({x}, {y})");
            }
        }
        assert!(scale_png16(&png, 0)
            .unwrap_err()
            .to_string()
            .contains("from 1 to 2048"));
        assert!(scale_png16(&png, 2049).is_err());
        assert!(scale_png16(b"not a png", 2)
            .unwrap_err()
            .to_string()
            .contains("cannot decode"));
    }
}
