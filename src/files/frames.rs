//! Camera frames from a user's own acquisition software: a multi-page 8- or
//! 16-bit grey TIFF (one frame per page) averaged into a [`FrameStack`], or
//! a single 32-bit float TIFF that is already a mean (such as the daemon's
//! `mean.tiff`).
//!
//! Why: `polnlos measure` must turn frames polnlos did not take into the same
//! measurement the daemon makes, so the reading is checked like a camera's:
//! every page the same size, sizes bounded before anything is allocated.

use std::path::Path;

use super::FileError;
use crate::measure::FrameStack;

/// The largest frame side accepted, pixels (GenICam sensors are below 16k).
pub(crate) const MAX_SIDE: u32 = 32_768;
/// The most pixels in one frame accepted (a 16k x 16k sensor).
pub const MAX_PIXELS: u64 = 1 << 28;

/// Frames read from one file.
#[derive(Debug, Clone)]
pub struct FrameFile {
    /// The frames' running mean and variance.
    pub stack: FrameStack,
    /// Bits per pixel of the integer pages (8 or 16, or the camera's depth
    /// a polnlos frame file states); `None` for a float mean.
    pub bits: Option<u32>,
    /// An RGB file's red, green and blue frames (`stack` then holds green).
    pub colours: Option<Vec<FrameStack>>,
}

impl FrameFile {
    /// Full scale of the pages' bit depth, DN; `None` for a float mean.
    pub fn full_scale(&self) -> Option<f64> {
        self.bits.map(|b| f64::from((1u32 << b) - 1))
    }
}

/// Reads every page of a grey TIFF: 8/16-bit pages are frames to average;
/// one 32-bit float page is a mean frame. Pages of another size or type
/// than the first are an error naming the page.
pub fn read_frames(path: &Path) -> Result<FrameFile, FileError> {
    let f = std::fs::File::open(path).map_err(|e| FileError::read(path, e))?;
    decode_from(std::io::BufReader::new(f), path)
}

/// [`read_frames`] on bytes in memory (an upload, a fuzz input); errors name `<bytes>`.
pub fn decode_frames(bytes: &[u8]) -> Result<FrameFile, FileError> {
    decode_from(std::io::Cursor::new(bytes), Path::new("<bytes>"))
}

/// A PNG in memory as one frame: grey or RGB (an alpha channel is
/// dropped), 8 or 16 bits. Its size is checked against `MAX_SIDE` and
/// [`MAX_PIXELS`] from the header, before any pixel is decoded.
pub(crate) fn decode_png(bytes: &[u8]) -> Result<FrameFile, FileError> {
    use super::image::DecodeError;
    let path = Path::new("<bytes>");
    let img = super::image::decode_png(bytes, MAX_SIDE, MAX_PIXELS).map_err(|e| match e {
        DecodeError::Size { .. } => FileError::format(path, e.to_string()),
        DecodeError::Png(e) => FileError::format(
            path,
            format!("cannot decode as PNG ({e}); give a grey or RGB PNG of 8 or 16 bits"),
        ),
    })?;
    let (w, h, bits) = (img.width, img.height, img.bits);
    if img.grey() {
        let mut stack = FrameStack::new(w, h);
        let grey: Vec<u16> = img.samples.iter().step_by(img.channels).copied().collect();
        stack.push_raw(&grey, bits);
        return Ok(FrameFile {
            stack,
            bits: Some(bits),
            colours: None,
        });
    }
    let like = FrameStack::new(w, h);
    let mut colours = None;
    push_rgb(&mut colours, &like, &img.rgb(), bits);
    let colours = colours.ok_or_else(|| FileError::format(path, "the PNG has no pixels"))?;
    Ok(FrameFile {
        stack: colours[1].clone(),
        bits: Some(bits),
        colours: Some(colours),
    })
}

fn decode_from<R: std::io::Read + std::io::Seek>(
    reader: R,
    path: &Path,
) -> Result<FrameFile, FileError> {
    let bad = |e: tiff::TiffError| {
        FileError::format(
            path,
            format!("cannot decode as TIFF ({e}); give the frames as a grey multi-page 8/16-bit TIFF, or a 32-bit float mean"),
        )
    };
    let mut dec = tiff::decoder::Decoder::new(reader).map_err(bad)?;
    let described = described_bits(&mut dec);
    let mut stack: Option<FrameStack> = None;
    let mut colours: Option<Vec<FrameStack>> = None;
    let mut bits = None;
    for page in 0usize.. {
        let (w, h) = dec.dimensions().map_err(bad)?;
        if w == 0
            || h == 0
            || w > MAX_SIDE
            || h > MAX_SIDE
            || u64::from(w) * u64::from(h) > MAX_PIXELS
        {
            return Err(FileError::format(
                path,
                format!("page {page} is {w}x{h}; frames must be 1 to {MAX_SIDE} pixels a side and at most {MAX_PIXELS} pixels"),
            ));
        }
        let st = stack.get_or_insert_with(|| FrameStack::new(w as usize, h as usize));
        if (st.width, st.height) != (w as usize, h as usize) {
            return Err(FileError::format(
                path,
                format!(
                    "page {page} is {w}x{h}, page 0 was {}x{}; every frame must have the same size",
                    st.width, st.height
                ),
            ));
        }
        let n = st.width * st.height;
        let not_grey = || {
            FileError::format(
                path,
                format!("page {page} is not a frame of page 0's type; use one grey channel or RGB, 8 or 16 bits per pixel (or a single 32-bit float grey page)"),
            )
        };
        let rgb = matches!(dec.colortype().map_err(bad)?, tiff::ColorType::RGB(_));
        if rgb != colours.is_some() && page > 0 {
            return Err(not_grey());
        }
        // The camera's depth (a polnlos frame file states it), else the
        // page's: the level at which a pixel saturated.
        let depth = |page_bits: u32| {
            described
                .filter(|d| (1..=page_bits).contains(d))
                .unwrap_or(page_bits)
        };
        let value_bits = match dec.read_image().map_err(bad)? {
            tiff::decoder::DecodingResult::U8(v) if rgb && v.len() == 3 * n => {
                let v: Vec<u16> = v.into_iter().map(u16::from).collect();
                push_rgb(&mut colours, st, &v, depth(8));
                Some(8)
            }
            tiff::decoder::DecodingResult::U16(v) if rgb && v.len() == 3 * n => {
                push_rgb(&mut colours, st, &v, depth(16));
                Some(16)
            }
            tiff::decoder::DecodingResult::U8(v) if v.len() == n => {
                let v: Vec<u16> = v.into_iter().map(u16::from).collect();
                st.push_raw(&v, depth(8));
                Some(8)
            }
            tiff::decoder::DecodingResult::U16(v) if v.len() == n => {
                st.push_raw(&v, depth(16));
                Some(16)
            }
            tiff::decoder::DecodingResult::F32(v) if v.len() == n && page == 0 => {
                st.push(&v);
                None
            }
            _ => return Err(not_grey()),
        };
        if page > 0 && value_bits != bits {
            return Err(not_grey());
        }
        bits = value_bits;
        if !dec.more_images() {
            break;
        }
        if bits.is_none() {
            return Err(FileError::format(
                path,
                "a 32-bit float TIFF is read as one mean frame; it has more than one page",
            ));
        }
        dec.next_image().map_err(bad)?;
    }
    let stack = stack.ok_or_else(|| FileError::format(path, "the TIFF has no page"))?;
    // 8- to 16-bit camera data in 16-bit pages (the daemon's frame.tiff):
    // the page's own description says the camera's bit depth.
    let bits = bits.map(|b| described.filter(|d| (1..=b).contains(d)).unwrap_or(b));
    let stack = match &colours {
        Some(c) => c[1].clone(),
        None => stack,
    };
    Ok(FrameFile {
        stack,
        bits,
        colours,
    })
}

/// Adds an RGB page (interleaved, `bits` deep) to the red, green and blue
/// stacks, made at `like`'s size on the first page.
fn push_rgb(colours: &mut Option<Vec<FrameStack>>, like: &FrameStack, v: &[u16], bits: u32) {
    let c = colours.get_or_insert_with(|| {
        (0..3)
            .map(|_| FrameStack::new(like.width, like.height))
            .collect()
    });
    for (k, s) in c.iter_mut().enumerate() {
        let plane: Vec<u16> = v.iter().skip(k).step_by(3).copied().collect();
        s.push_raw(&plane, bits);
    }
}

/// The camera's bits per pixel as a polnlos frame file's page description
/// states it (`{"polnlos": "frames", "bits": 12, ...}`), if it does.
/// Writes `pages` (each `width x height` DN, row-major) as a multi-page
/// 16-bit grey TIFF that states its bit depth, so that [`read_frames`] (and
/// `polnlos measure`) reads the right full scale back.
pub fn write_frames(
    path: &Path,
    width: usize,
    height: usize,
    pages: &[Vec<u16>],
    bits: u32,
) -> Result<(), FileError> {
    use tiff::encoder::{colortype, TiffEncoder};
    let fail = |e: tiff::TiffError| FileError::format(path, format!("cannot encode TIFF: {e}"));
    let (w, h) = match (u32::try_from(width), u32::try_from(height)) {
        (Ok(w), Ok(h)) if w <= MAX_SIDE && h <= MAX_SIDE => (w, h),
        _ => {
            return Err(FileError::format(
                path,
                format!(
                    "{width}x{height} is larger than the {MAX_SIDE}-pixel sides frames may have"
                ),
            ))
        }
    };
    let mut buf = std::io::Cursor::new(Vec::new());
    {
        let mut enc = TiffEncoder::new(&mut buf).map_err(fail)?;
        let desc = serde_json::json!({"polnlos": "frames", "bits": bits}).to_string();
        for px in pages {
            let mut image = enc.new_image::<colortype::Gray16>(w, h).map_err(fail)?;
            image
                .encoder()
                .write_tag(tiff::tags::Tag::ImageDescription, desc.as_str())
                .map_err(fail)?;
            image.write_data(px).map_err(fail)?;
        }
    }
    super::write_atomic(path, &buf.into_inner())
}

fn described_bits<R: std::io::Read + std::io::Seek>(
    dec: &mut tiff::decoder::Decoder<R>,
) -> Option<u32> {
    let text = dec
        .get_tag_ascii_string(tiff::tags::Tag::ImageDescription)
        .ok()?;
    let v: serde_json::Value = serde_json::from_str(&text).ok()?;
    v.get("polnlos")?;
    v.get("bits")?.as_u64().and_then(|b| u32::try_from(b).ok())
}

#[cfg(test)]
mod tests {
    use super::*;
    use tiff::encoder::{colortype, TiffEncoder};

    fn write_pages(path: &Path, pages: &[(u32, u32, Vec<u16>)]) {
        let mut f = std::fs::File::create(path).unwrap();
        let mut enc = TiffEncoder::new(&mut f).unwrap();
        for (w, h, px) in pages {
            enc.write_image::<colortype::Gray16>(*w, *h, px).unwrap();
        }
    }

    #[test]
    fn written_frames_read_back_with_their_bit_depth() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("f.tiff");
        write_frames(&p, 2, 1, &[vec![100, 7], vec![110, 7]], 12).unwrap();
        let f = read_frames(&p).unwrap();
        assert_eq!((f.stack.count, f.full_scale()), (2, Some(4095.0)));
        assert_eq!(f.stack.mean, vec![105.0, 7.0]);
    }

    #[test]
    fn pages_average_into_mean_and_variance() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("f.tiff");
        write_pages(&p, &[(2, 1, vec![100, 7]), (2, 1, vec![110, 7])]);
        let f = read_frames(&p).unwrap();
        assert_eq!(
            (f.stack.count, f.bits, f.full_scale()),
            (2, Some(16), Some(65535.0))
        );
        assert_eq!(f.stack.mean, vec![105.0, 7.0]);
        assert_eq!(f.stack.variance_of_mean(), Some(vec![25.0, 0.0]));
    }

    #[test]
    fn a_page_of_another_size_or_a_png_is_refused_with_a_reason() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("f.tiff");
        write_pages(&p, &[(2, 1, vec![1, 2]), (1, 2, vec![1, 2])]);
        let e = read_frames(&p).unwrap_err().to_string();
        assert!(e.contains("page 1 is 1x2, page 0 was 2x1"), "{e}");
        let png = dir.path().join("f.png");
        std::fs::write(&png, b"\x89PNG\r\n\x1a\n not really").unwrap();
        let e = read_frames(&png).unwrap_err().to_string();
        assert!(e.contains("multi-page 8/16-bit TIFF"), "{e}");
    }
}
