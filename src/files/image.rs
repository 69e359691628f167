//! Images: reading 8/16-bit PNG or TIFF into [0, 1] and 32-bit float TIFF
//! as it is, PNG bytes in and out (grey or RGB, 8 or 16 bits), and area
//! resampling onto a grid.
//!
//! Why the `png` and `tiff` crates and not `image`: every image polnlos
//! reads or writes is one of these two formats, and `image` brings colour
//! management (moxcms, pxfm) that polnlos never uses: 44 s of a fresh
//! build's unit time (docs/test-times.md).

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

/// Decoded integer pixels: `channels` samples a pixel (1 grey, 2 grey and
/// alpha, 3 RGB, 4 RGB and alpha), row-major, top row first.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) struct Pixels {
    /// Columns.
    pub(crate) width: usize,
    /// Rows.
    pub(crate) height: usize,
    /// Samples a pixel.
    pub(crate) channels: usize,
    /// Bits a sample: 8 or 16.
    pub(crate) bits: u32,
    /// The samples, at their own bit depth.
    pub(crate) samples: Vec<u16>,
}

impl Pixels {
    /// Grey samples at 16 bits: colour as luma with the weights and integer
    /// rounding the `image` crate used (ITU-R BT.709, in the source's depth),
    /// alpha dropped. Why: `read_gray` reads the same numbers it always did.
    fn luma16(&self) -> Vec<u16> {
        let up = |v: u32| if self.bits == 8 { v * 257 } else { v };
        self.samples
            .chunks_exact(self.channels.max(1))
            .map(|p| match p {
                [r, g, b, ..] => {
                    let l = (2126 * u32::from(*r) + 7152 * u32::from(*g) + 722 * u32::from(*b))
                        / 10_000;
                    up(l) as u16
                }
                [v, ..] => up(u32::from(*v)) as u16,
                [] => 0,
            })
            .collect()
    }

    /// RGB samples (grey repeated, alpha dropped), at their own depth.
    pub(crate) fn rgb(&self) -> Vec<u16> {
        self.samples
            .chunks_exact(self.channels.max(1))
            .flat_map(|p| match p {
                [r, g, b, ..] => [*r, *g, *b],
                [v, ..] => [*v; 3],
                [] => [0; 3],
            })
            .collect()
    }

    /// Whether the pixels are grey (with or without alpha).
    pub(crate) fn grey(&self) -> bool {
        self.channels <= 2
    }
}

/// Why a PNG did not decode within `max_side` and `max_pixels`: the
/// decoder's reason or the size it refused.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub(crate) enum DecodeError {
    /// Not a PNG the decoder can read.
    #[error("{0}")]
    Png(String),
    /// A header whose size is outside the limits.
    #[error("the PNG is {width}x{height}; frames must be 1 to {max_side} pixels a side and at most {max_pixels} pixels")]
    Size {
        /// Columns in the header.
        width: u32,
        /// Rows in the header.
        height: u32,
        /// Largest side allowed.
        max_side: u32,
        /// Most pixels allowed.
        max_pixels: u64,
    },
}

/// Decodes PNG bytes to 8- or 16-bit samples (palettes and lower depths
/// expanded), refusing from the header alone an image larger than
/// `max_side` a side or `max_pixels` in all, before any pixel is decoded.
pub(crate) fn decode_png(
    bytes: &[u8],
    max_side: u32,
    max_pixels: u64,
) -> Result<Pixels, DecodeError> {
    let bad = |e: png::DecodingError| DecodeError::Png(e.to_string());
    // Decoded as 16-bit RGBA at most: 8 bytes a pixel.
    let limit = usize::try_from(max_pixels.saturating_mul(8)).unwrap_or(usize::MAX);
    let mut decoder =
        png::Decoder::new_with_limits(std::io::Cursor::new(bytes), png::Limits { bytes: limit });
    decoder.set_transformations(png::Transformations::EXPAND);
    let mut reader = decoder.read_info().map_err(bad)?;
    let (width, height) = (reader.info().width, reader.info().height);
    if width == 0
        || height == 0
        || width > max_side
        || height > max_side
        || u64::from(width) * u64::from(height) > max_pixels
    {
        return Err(DecodeError::Size {
            width,
            height,
            max_side,
            max_pixels,
        });
    }
    let size = reader
        .output_buffer_size()
        .ok_or_else(|| DecodeError::Png("the image's size overflows memory".into()))?;
    let mut buf = vec![0u8; size];
    let info = reader.next_frame(&mut buf).map_err(bad)?;
    buf.truncate(info.buffer_size());
    let channels = info.color_type.samples();
    let (bits, samples) = match info.bit_depth {
        png::BitDepth::Sixteen => (
            16,
            buf.chunks_exact(2)
                .map(|b| u16::from_be_bytes([b[0], b[1]]))
                .collect(),
        ),
        png::BitDepth::Eight => (8, buf.iter().map(|&b| u16::from(b)).collect()),
        d => {
            return Err(DecodeError::Png(format!(
                "{d:?}-bit samples after expansion"
            )))
        }
    };
    Ok(Pixels {
        width: width as usize,
        height: height as usize,
        channels,
        bits,
        samples,
    })
}

/// Reads an image file (PNG or TIFF, any bit depth; colour is converted to luma).
pub fn read_gray(path: &Path) -> Result<Gray, FileError> {
    let bytes = std::fs::read(path).map_err(|e| FileError::read(path, e))?;
    let unreadable = |e: &dyn std::fmt::Display| {
        FileError::format(
            path,
            format!("cannot decode image ({e}); use an 8- or 16-bit grey PNG or TIFF, or a 32-bit float TIFF"),
        )
    };
    let pixels = if bytes.starts_with(b"\x89PNG") {
        decode_png(&bytes, u32::MAX, u64::MAX >> 4).map_err(|e| unreadable(&e))?
    } else {
        match read_tiff(&bytes) {
            Ok(Tiff::Float(g)) => return Ok(g),
            Ok(Tiff::Integer(p)) => p,
            Err(e) => return Err(unreadable(&e)),
        }
    };
    Ok(Gray {
        width: pixels.width,
        height: pixels.height,
        data: pixels
            .luma16()
            .into_iter()
            .map(|v| f64::from(v) / 65535.0)
            .collect(),
    })
}

/// A TIFF's first page: integer samples, or a 32-bit float grey image's values.
enum Tiff {
    Integer(Pixels),
    Float(Gray),
}

/// Decodes the first page of a TIFF in memory: 8/16-bit grey or RGB(A), or
/// 32-bit float grey (the daemon's `mean.tiff` and `variance.tiff`).
fn read_tiff(bytes: &[u8]) -> Result<Tiff, tiff::TiffError> {
    use tiff::decoder::{Decoder, DecodingResult};
    use tiff::ColorType;
    let mut dec = Decoder::new(std::io::Cursor::new(bytes))?;
    let (w, h) = dec.dimensions()?;
    let (width, height) = (w as usize, h as usize);
    let channels = match dec.colortype()? {
        ColorType::Gray(_) => 1,
        ColorType::GrayA(_) => 2,
        ColorType::RGB(_) => 3,
        ColorType::RGBA(_) => 4,
        c => {
            return Err(tiff::TiffError::UnsupportedError(
                tiff::TiffUnsupportedError::UnsupportedColorType(c),
            ))
        }
    };
    let integer = |bits: u32, samples: Vec<u16>| {
        Tiff::Integer(Pixels {
            width,
            height,
            channels,
            bits,
            samples,
        })
    };
    let image = match dec.read_image()? {
        DecodingResult::F32(v) if channels == 1 && v.len() == width * height => Tiff::Float(Gray {
            width,
            height,
            data: v.into_iter().map(f64::from).collect(),
        }),
        DecodingResult::U8(v) => integer(8, v.into_iter().map(u16::from).collect()),
        DecodingResult::U16(v) => integer(16, v),
        _ => {
            return Err(tiff::TiffError::UnsupportedError(
                tiff::TiffUnsupportedError::UnknownInterpretation,
            ))
        }
    };
    if let Tiff::Integer(p) = &image {
        if p.samples.len() != width * height * channels {
            return Err(tiff::TiffError::FormatError(
                tiff::TiffFormatError::InconsistentSizesEncountered,
            ));
        }
    }
    Ok(image)
}

/// The largest side, pixels, of an image scaled by [`scale_png16`].
pub(crate) const MAX_SCALED_SIDE: u32 = 4096;

/// A 16-bit grey PNG enlarged `k` times, each pixel a `k` x `k` block
/// (nearest neighbour: no value is invented between the scene's elements).
///
/// Why: a reconstruction of an 8x8 scene is an 8x8 PNG, too small to look
/// at in an image viewer. `k` must be at least 1 and the result at most
/// `MAX_SCALED_SIDE` on a side; the error says what is allowed.
#[cfg(feature = "daemon")]
pub(crate) fn scale_png16(png: &[u8], k: u32) -> Result<Vec<u8>, PngError> {
    let img = decode_png(png, MAX_SCALED_SIDE, u64::from(MAX_SCALED_SIDE).pow(2))
        .map_err(|e| PngError::Decode(e.to_string()))?;
    let (w, h) = (img.width as u32, img.height as u32);
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
    let (c, k) = (img.channels, k as usize);
    let mut out = Vec::with_capacity(img.samples.len() * k * k);
    for row in img.samples.chunks_exact(img.width * c) {
        let wide: Vec<u16> = row
            .chunks_exact(c)
            .flat_map(|p| std::iter::repeat_n(p, k).flatten().copied())
            .collect();
        for _ in 0..k {
            out.extend_from_slice(&wide);
        }
    }
    let colour = colour_type(c).ok_or_else(|| PngError::Decode(format!("{c} samples a pixel")))?;
    encode(img.width * k, img.height * k, colour, img.bits, &out)
}

/// The PNG colour type of `channels` samples a pixel.
#[cfg(feature = "daemon")]
fn colour_type(channels: usize) -> Option<png::ColorType> {
    match channels {
        1 => Some(png::ColorType::Grayscale),
        2 => Some(png::ColorType::GrayscaleAlpha),
        3 => Some(png::ColorType::Rgb),
        4 => Some(png::ColorType::Rgba),
        _ => None,
    }
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

/// PNG bytes of `width` x `height` pixels of `colour`, `bits` (8 or 16) a
/// sample, interleaved, rows top first; the counts are checked first.
fn encode(
    width: usize,
    height: usize,
    colour: png::ColorType,
    bits: u32,
    samples: &[u16],
) -> Result<Vec<u8>, PngError> {
    let count = || PngError::PixelCount {
        values: samples.len(),
        width,
        height,
    };
    let (Ok(w), Ok(h)) = (u32::try_from(width), u32::try_from(height)) else {
        return Err(count());
    };
    if width
        .checked_mul(height)
        .and_then(|n| n.checked_mul(colour.samples()))
        != Some(samples.len())
    {
        return Err(count());
    }
    let bytes: Vec<u8> = match bits {
        8 => samples.iter().map(|&v| v.min(255) as u8).collect(),
        _ => samples.iter().flat_map(|v| v.to_be_bytes()).collect(),
    };
    let mut out = Vec::new();
    let fail = |e: png::EncodingError| PngError::Encode(e.to_string());
    let mut enc = png::Encoder::new(&mut out, w, h);
    // Fast deflate with adaptive filters, as `image` wrote them: the page's
    // live frame is a 512 x 512 16-bit PNG several times a second, and png's
    // own default (zlib level 6) takes several times longer for files a
    // few per cent smaller.
    enc.set_compression(png::Compression::Fast);
    enc.set_filter(png::Filter::Adaptive);
    enc.set_color(colour);
    enc.set_depth(match bits {
        8 => png::BitDepth::Eight,
        _ => png::BitDepth::Sixteen,
    });
    let mut writer = enc.write_header().map_err(fail)?;
    writer.write_image_data(&bytes).map_err(fail)?;
    writer.finish().map_err(fail)?;
    Ok(out)
}

/// Encodes 16-bit RGB pixels (interleaved) as PNG bytes.
#[cfg(feature = "daemon")]
pub(crate) fn encode_png_rgb16(
    width: usize,
    height: usize,
    pixels: &[u16],
) -> Result<Vec<u8>, PngError> {
    encode(width, height, png::ColorType::Rgb, 16, pixels)
}

/// Encodes 16-bit grey pixels as PNG bytes.
pub fn encode_png16(width: usize, height: usize, pixels: &[u16]) -> Result<Vec<u8>, PngError> {
    encode(width, height, png::ColorType::Grayscale, 16, pixels)
}

/// Encodes 8-bit RGB pixels (interleaved, rows top first) as PNG bytes.
pub(crate) fn encode_png_rgb8(
    width: usize,
    height: usize,
    pixels: &[u8],
) -> Result<Vec<u8>, PngError> {
    let wide: Vec<u16> = pixels.iter().map(|&v| u16::from(v)).collect();
    encode(width, height, png::ColorType::Rgb, 8, &wide)
}

/// Writes 16-bit grey pixels as a PNG, atomically.
pub fn write_png16(
    path: &Path,
    width: usize,
    height: usize,
    pixels: &[u16],
) -> Result<(), FileError> {
    write(path, encode_png16(width, height, pixels))
}

/// Writes encoded PNG bytes to `path` atomically, or says why they could not be made.
fn write(path: &Path, png: Result<Vec<u8>, PngError>) -> Result<(), FileError> {
    let bytes = png.map_err(|e| FileError::format(path, e.to_string()))?;
    super::write_atomic(path, &bytes)
}

/// Writes 8-bit RGB pixels (interleaved, rows top first) as a PNG, atomically.
pub fn write_png_rgb8(
    path: &Path,
    width: usize,
    height: usize,
    pixels: &[u8],
) -> Result<(), FileError> {
    write(path, encode_png_rgb8(width, height, pixels))
}

/// Writes 16-bit RGB pixels (interleaved) as a PNG, atomically: a colour
/// camera's reconstruction.
#[cfg(feature = "daemon")]
pub(crate) fn write_png_rgb16(
    path: &Path,
    width: usize,
    height: usize,
    pixels: &[u16],
) -> Result<(), FileError> {
    write(path, encode_png_rgb16(width, height, pixels))
}

/// Maps [0, 1] to the full 16-bit range (values outside are clipped).
pub fn unit_to_u16(values: &[f64]) -> Vec<u16> {
    values
        .iter()
        .map(|v| (v.clamp(0.0, 1.0) * 65535.0).round() as u16)
        .collect()
}

/// Scales values by `1 / max` into 16 bits, for viewing a physical image.
#[cfg(feature = "daemon")]
pub(crate) fn normalized_u16(values: &[f64]) -> Vec<u16> {
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
    fn colour_and_8_bit_images_read_as_16_bit_luma() {
        let dir = tempfile::tempdir().unwrap();
        // RGB 8-bit PNG: luma (2126 r + 7152 g + 722 b) / 10000 in 8 bits,
        // then x 257 to 16 bits.
        let p = dir.path().join("rgb.png");
        write_png_rgb8(&p, 2, 1, &[255, 0, 0, 10, 200, 30]).unwrap();
        let g = read_gray(&p).unwrap();
        let want = [54.0 * 257.0, 147.0 * 257.0].map(|v: f64| v / 65535.0);
        assert_eq!(g.data, want.to_vec());
        // 16-bit RGB TIFF and 8-bit grey TIFF.
        let p = dir.path().join("rgb.tiff");
        let f = std::fs::File::create(&p).unwrap();
        let mut enc = tiff::encoder::TiffEncoder::new(std::io::BufWriter::new(f)).unwrap();
        enc.write_image::<tiff::encoder::colortype::RGB16>(1, 1, &[60000, 30000, 1000])
            .unwrap();
        drop(enc);
        let l = (2126u32 * 60000 + 7152 * 30000 + 722 * 1000) / 10_000;
        assert_eq!(read_gray(&p).unwrap().data, vec![f64::from(l) / 65535.0]);
        let p = dir.path().join("grey8.tiff");
        let f = std::fs::File::create(&p).unwrap();
        let mut enc = tiff::encoder::TiffEncoder::new(std::io::BufWriter::new(f)).unwrap();
        enc.write_image::<tiff::encoder::colortype::Gray8>(2, 1, &[0, 128])
            .unwrap();
        drop(enc);
        assert_eq!(
            read_gray(&p).unwrap().data,
            vec![0.0, 128.0 * 257.0 / 65535.0]
        );
    }

    #[test]
    fn a_png_larger_than_the_limits_is_refused_from_its_header() {
        let png = encode_png16(3, 2, &[0; 6]).unwrap();
        assert_eq!(
            decode_png(&png, 2, 100),
            Err(DecodeError::Size {
                width: 3,
                height: 2,
                max_side: 2,
                max_pixels: 100
            })
        );
        assert!(matches!(
            decode_png(&png, 8, 5),
            Err(DecodeError::Size { .. })
        ));
        assert!(matches!(
            decode_png(&png[..20], 8, 100),
            Err(DecodeError::Png(_))
        ));
        assert_eq!(
            encode_png16(3, 2, &[0; 5]),
            Err(PngError::PixelCount {
                values: 5,
                width: 3,
                height: 2
            })
        );
    }

    #[test]
    fn a_float_tiff_reads_as_its_values() {
        // The daemon's mean.tiff: 32-bit float, one page.
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

    #[cfg(feature = "daemon")]
    #[test]
    fn a_scaled_png_repeats_each_pixel_in_a_block_and_refuses_a_bad_scale() {
        let png = encode_png16(2, 1, &[100, 60000]).unwrap();
        let big = scale_png16(&png, 3).unwrap();
        let img = decode_png(&big, 64, 4096).unwrap();
        assert_eq!(
            (img.width, img.height, img.channels, img.bits),
            (6, 3, 1, 16)
        );
        for y in 0..3 {
            for x in 0..6 {
                let want = if x < 3 { 100 } else { 60000 };
                assert_eq!(img.samples[y * 6 + x], want, "({x}, {y})");
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
