//! The files of a capture: raw frames and dark frames as multi-page 16-bit
//! TIFF with JSON metadata in each page's ImageDescription, the mean
//! (dark-subtracted) frame as 32-bit float TIFF, and a PNG preview.

use std::io::Cursor;
use std::path::Path;

use serde::Serialize;
use tiff::encoder::{colortype, TiffEncoder};
use tiff::tags::Tag;

use super::StoreError;
use crate::camera::{Frame, RawFrame};
use crate::files::{image, write_atomic, FileError};

/// Metadata written into every page of a capture's TIFF files.
#[derive(Debug, Clone, Serialize)]
pub struct FrameMeta {
    /// Capture id.
    pub capture: i64,
    /// Scene name.
    pub scene: String,
    /// Pose name.
    pub pose: String,
    /// Polarizer angle (null: none).
    pub polarizer_deg: Option<f64>,
    /// Exposure, microseconds.
    pub exposure_us: f64,
    /// Gain.
    pub gain: f64,
    /// Camera id.
    pub camera_id: String,
    /// Camera counters after the capture.
    pub counters: crate::camera::Counters,
}

/// File names inside a capture folder.
pub struct CaptureFiles;

impl CaptureFiles {
    /// Raw frames, one page each.
    pub const FRAMES: &'static str = "frames.tiff";
    /// Raw dark frames, one page each.
    pub const DARK: &'static str = "dark.tiff";
    /// Mean frame minus mean dark, 32-bit float.
    pub const MEAN: &'static str = "mean.tiff";
    /// 16-bit PNG preview of the mean, scaled to its maximum.
    pub const PREVIEW: &'static str = "preview.png";
}

fn tiff_err(path: &Path, e: tiff::TiffError) -> StoreError {
    StoreError::File(FileError::Format {
        path: path.to_path_buf(),
        reason: format!("cannot encode TIFF: {e}"),
    })
}

fn encode_pages(
    path: &Path,
    frames: &[RawFrame],
    meta: &FrameMeta,
    kind: &str,
) -> Result<Vec<u8>, StoreError> {
    let mut buf = Cursor::new(Vec::new());
    {
        let mut enc = TiffEncoder::new(&mut buf).map_err(|e| tiff_err(path, e))?;
        for (i, f) in frames.iter().enumerate() {
            let desc = serde_json::json!({
                "polnlos": kind, "page": i, "frame_id": f.frame_id, "system_timestamp_ns": f.system_timestamp_ns,
                "bits": f.bits, "meta": meta,
            })
            .to_string();
            let mut img = enc
                .new_image::<colortype::Gray16>(f.width as u32, f.height as u32)
                .map_err(|e| tiff_err(path, e))?;
            img.encoder()
                .write_tag(Tag::ImageDescription, desc.as_str())
                .map_err(|e| tiff_err(path, e))?;
            img.encoder()
                .write_tag(Tag::Software, "polnlos")
                .map_err(|e| tiff_err(path, e))?;
            img.write_data(&f.pixels).map_err(|e| tiff_err(path, e))?;
        }
    }
    Ok(buf.into_inner())
}

/// Writes every file of a capture into `dir` (created if needed), each
/// atomically; returns the mean dark-subtracted frame.
pub fn write_capture_files(
    dir: &Path,
    frames: &[RawFrame],
    dark: &[RawFrame],
    meta: &FrameMeta,
) -> Result<Frame, StoreError> {
    std::fs::create_dir_all(dir).map_err(|source| StoreError::DataDir {
        path: dir.to_path_buf(),
        source,
    })?;
    let mean = mean_frame(frames, dark);
    let p = dir.join(CaptureFiles::FRAMES);
    write_atomic(&p, &encode_pages(&p, frames, meta, "frames")?)?;
    if !dark.is_empty() {
        let p = dir.join(CaptureFiles::DARK);
        write_atomic(&p, &encode_pages(&p, dark, meta, "dark")?)?;
    }
    let p = dir.join(CaptureFiles::MEAN);
    let mut buf = Cursor::new(Vec::new());
    {
        let mut enc = TiffEncoder::new(&mut buf).map_err(|e| tiff_err(&p, e))?;
        let mut img = enc
            .new_image::<colortype::Gray32Float>(mean.width as u32, mean.height as u32)
            .map_err(|e| tiff_err(&p, e))?;
        let desc = serde_json::json!({"polnlos": "mean", "frames": frames.len(), "dark_frames": dark.len(), "meta": meta}).to_string();
        img.encoder()
            .write_tag(Tag::ImageDescription, desc.as_str())
            .map_err(|e| tiff_err(&p, e))?;
        img.write_data(&mean.pixels).map_err(|e| tiff_err(&p, e))?;
    }
    write_atomic(&p, &buf.into_inner())?;
    let values: Vec<f64> = mean.pixels.iter().map(|&v| f64::from(v)).collect();
    image::write_png16(
        &dir.join(CaptureFiles::PREVIEW),
        mean.width,
        mean.height,
        &image::normalized_u16(&values),
    )?;
    Ok(mean)
}

/// Mean of the frames minus the mean of the dark frames (DN, f32).
pub fn mean_frame(frames: &[RawFrame], dark: &[RawFrame]) -> Frame {
    let avg = |fs: &[RawFrame]| -> Option<Vec<f64>> {
        let first = fs.first()?;
        let mut acc = vec![0.0f64; first.pixels.len()];
        for f in fs {
            for (a, &p) in acc.iter_mut().zip(&f.pixels) {
                *a += f64::from(p);
            }
        }
        acc.iter_mut().for_each(|a| *a /= fs.len() as f64);
        Some(acc)
    };
    let (w, h) = frames
        .first()
        .map(|f| (f.width, f.height))
        .unwrap_or((0, 0));
    let mut m = avg(frames).unwrap_or_default();
    if let Some(d) = avg(dark).filter(|d| d.len() == m.len()) {
        m.iter_mut().zip(d).for_each(|(a, b)| *a -= b);
    }
    Frame {
        width: w,
        height: h,
        pixels: m.into_iter().map(|v| v as f32).collect(),
    }
}

type TiffReader = tiff::decoder::Decoder<std::io::BufReader<std::fs::File>>;

fn decode_error(path: &Path, e: tiff::TiffError) -> StoreError {
    StoreError::File(FileError::Format {
        path: path.to_path_buf(),
        reason: format!("cannot decode TIFF: {e}"),
    })
}

/// Opens one of a capture's TIFF files for decoding.
fn open_tiff(path: &Path) -> Result<TiffReader, StoreError> {
    let f = std::fs::File::open(path).map_err(|e| StoreError::File(FileError::read(path, e)))?;
    tiff::decoder::Decoder::new(std::io::BufReader::new(f)).map_err(|e| decode_error(path, e))
}

/// Per-pixel variance of the mean of a capture's raw frames (DN^2): the
/// sample variance across frames divided by their number. `None` with fewer
/// than two frames. Used to estimate the noise of a measurement.
pub fn read_mean_variance(dir: &Path) -> Result<Option<Frame>, StoreError> {
    let p = dir.join(CaptureFiles::FRAMES);
    let bad = |e: tiff::TiffError| decode_error(&p, e);
    let mut dec = open_tiff(&p)?;
    let (w, h) = dec.dimensions().map_err(bad)?;
    let n_px = (w as usize) * (h as usize);
    let (mut sum, mut sum2, mut n) = (vec![0.0f64; n_px], vec![0.0f64; n_px], 0usize);
    loop {
        if let tiff::decoder::DecodingResult::U16(v) = dec.read_image().map_err(bad)? {
            for ((s, s2), &x) in sum.iter_mut().zip(sum2.iter_mut()).zip(&v) {
                let x = f64::from(x);
                *s += x;
                *s2 += x * x;
            }
            n += 1;
        }
        if !dec.more_images() {
            break;
        }
        dec.next_image().map_err(bad)?;
    }
    if n < 2 {
        return Ok(None);
    }
    let nf = n as f64;
    let pixels = sum
        .iter()
        .zip(&sum2)
        .map(|(s, s2)| (((s2 - s * s / nf) / (nf - 1.0)).max(0.0) / nf) as f32)
        .collect();
    Ok(Some(Frame {
        width: w as usize,
        height: h as usize,
        pixels,
    }))
}

/// Reads a capture's mean frame back.
pub fn read_mean(dir: &Path) -> Result<Frame, StoreError> {
    let p = dir.join(CaptureFiles::MEAN);
    let bad = |e: tiff::TiffError| decode_error(&p, e);
    let mut dec = open_tiff(&p)?;
    let (w, h) = dec.dimensions().map_err(bad)?;
    match dec.read_image().map_err(bad)? {
        tiff::decoder::DecodingResult::F32(v) => Ok(Frame {
            width: w as usize,
            height: h as usize,
            pixels: v,
        }),
        _ => Err(StoreError::File(FileError::Format {
            path: p.clone(),
            reason: "mean frame is not 32-bit float".into(),
        })),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn raw(v: u16) -> RawFrame {
        RawFrame {
            width: 3,
            height: 2,
            bits: 16,
            pixels: vec![v; 6],
            frame_id: 1,
            system_timestamp_ns: 0,
        }
    }

    #[test]
    fn mean_subtracts_dark_and_round_trips_through_tiff() {
        let dir = tempfile::tempdir().unwrap();
        let meta = FrameMeta {
            capture: 1,
            scene: "s".into(),
            pose: "A".into(),
            polarizer_deg: Some(0.0),
            exposure_us: 1000.0,
            gain: 0.0,
            camera_id: "cam".into(),
            counters: Default::default(),
        };
        let m = write_capture_files(dir.path(), &[raw(100), raw(110)], &[raw(5), raw(7)], &meta)
            .unwrap();
        assert_eq!(m.pixels, vec![99.0; 6]);
        assert_eq!(read_mean(dir.path()).unwrap(), m);
        for f in [
            CaptureFiles::FRAMES,
            CaptureFiles::DARK,
            CaptureFiles::PREVIEW,
        ] {
            assert!(dir.path().join(f).exists(), "{f}");
        }
        let mut dec = tiff::decoder::Decoder::new(
            std::fs::File::open(dir.path().join(CaptureFiles::FRAMES)).unwrap(),
        )
        .unwrap();
        let desc = dec.get_tag_ascii_string(Tag::ImageDescription).unwrap();
        assert!(desc.contains("\"pose\":\"A\""), "{desc}");
        assert!(dec.more_images());
    }
}
