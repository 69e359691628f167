//! The files of a capture: raw frames and dark frames as multi-page 16-bit
//! TIFF with JSON metadata in each page's ImageDescription (written page by
//! page as frames arrive), the mean (dark-subtracted) frame and the variance
//! of the mean as 32-bit float TIFF, and a PNG preview.

use std::io::Cursor;
use std::path::Path;

use serde::Serialize;
use tiff::encoder::{colortype, TiffEncoder};
use tiff::tags::Tag;

use super::{CaptureKind, StoreError};
use crate::camera::{Acquisition, RawFrame};
use crate::files::{image, write_atomic, FileError};
use crate::measure::FrameStack;
use crate::scene::Frame;

/// Metadata written into every page of a capture's TIFF files: everything
/// the camera was set to, so a file says how it was taken on its own.
#[derive(Debug, Clone, Serialize)]
pub struct FrameMeta {
    /// Capture id.
    pub capture: i64,
    /// `light` (scene on) or `dark` (scene off).
    pub kind: CaptureKind,
    /// Scene name.
    pub scene: String,
    /// Pose name.
    pub pose: String,
    /// The blocks the frames hold (one through a sheet or none, four from a mosaic sensor).
    pub channels: Vec<crate::scene::Channel>,
    /// Camera settings (flattened: the same keys as before it was one type).
    #[serde(flatten)]
    pub acquisition: Acquisition,
    /// The dark capture subtracted from this one, if any.
    pub dark_capture: Option<i64>,
    /// Camera id (GenICam vendor-model-serial).
    pub camera_id: String,
}

/// File names inside a capture folder.
pub(crate) struct CaptureFiles;

impl CaptureFiles {
    /// Raw frames, one page each.
    pub const FRAMES: &'static str = "frames.tiff";
    /// Raw dark frames, one page each.
    pub const DARK: &'static str = "dark.tiff";
    /// Mean frame minus mean dark, 32-bit float.
    pub const MEAN: &'static str = "mean.tiff";
    /// Per-pixel variance of the mean of the frames, 32-bit float (2+ frames).
    pub const VARIANCE: &'static str = "variance.tiff";
    /// 16-bit PNG preview of the mean, scaled to its maximum.
    pub const PREVIEW: &'static str = "preview.png";
    /// 32-bit float, 1 where a pixel was at full scale in any frame, else 0;
    /// written only when one was.
    pub const SATURATED: &'static str = "saturated.tiff";
    /// An imported capture's measurement: its pose's blocks in the scene's
    /// row order, `[n]` or `[n, C]`, NaN where not measured.
    pub const MEASUREMENT: &'static str = "measurement.npy";
    /// An imported capture's file as it was received, `source.` and its format.
    pub const SOURCE: &'static str = "source";
}

/// Reads an imported capture's measurement ([`CaptureFiles::MEASUREMENT`]).
pub(crate) fn read_imported(dir: &Path) -> Result<crate::files::npy::Array, StoreError> {
    Ok(crate::files::npy::read(
        &dir.join(CaptureFiles::MEASUREMENT),
    )?)
}

/// Removes the raw frame files (`frames.tiff`, `dark.tiff`) of a capture
/// that did not finish, and returns those it removed.
///
/// Why: a cancelled or interrupted capture keeps no data the user can use,
/// but its dark frames were complete before its light frames began and
/// would stay behind (up to hundreds of MB with many dark frames).
pub(crate) fn remove_raw(dir: &Path) -> Vec<std::path::PathBuf> {
    [CaptureFiles::DARK, CaptureFiles::FRAMES]
        .iter()
        .map(|f| dir.join(f))
        .filter(|p| std::fs::remove_file(p).is_ok())
        .collect()
}

/// Bytes the files of a capture take at most: raw pages, mean, variance and
/// preview, plus a little for headers and metadata.
pub(crate) fn capture_bytes(width: u32, height: u32, frames: usize, dark_frames: usize) -> u64 {
    let px = u64::from(width) * u64::from(height);
    let pages = (frames + dark_frames) as u64;
    px.saturating_mul(2)
        .saturating_mul(pages)
        .saturating_add(px.saturating_mul(4 + 4 + 2))
        .saturating_add(pages.saturating_mul(4096).saturating_add(1 << 20))
}

fn tiff_err(path: &Path, e: tiff::TiffError) -> StoreError {
    StoreError::File(FileError::Format {
        path: path.to_path_buf(),
        reason: format!("cannot encode TIFF: {e}"),
    })
}

/// Writes `expected` frames from `frames` as pages of a 16-bit TIFF at `path`
/// while they arrive (temporary name, fsync, rename: a capture that stops
/// early leaves no file), calling `on_frame` with the running mean after each
/// page (so a caller can watch the mean converge); returns their
/// running mean and variance. Stops at the first frame of another size.
pub fn write_frames(
    path: &Path,
    kind: &str,
    meta: &FrameMeta,
    expected: usize,
    frames: impl IntoIterator<Item = RawFrame>,
    on_frame: &mut dyn FnMut(&FrameStack),
) -> Result<FrameStack, StoreError> {
    write_counted(path, kind, meta, (expected, expected), frames, on_frame)
}

/// As [`write_frames`], but the file is kept with any count from 1 to
/// `at_most` frames (those after it are not taken).
///
/// Why: a live session's recording that ends early keeps the frames it got.
pub(crate) fn write_frames_upto(
    path: &Path,
    kind: &str,
    meta: &FrameMeta,
    at_most: usize,
    frames: impl IntoIterator<Item = RawFrame>,
    on_frame: &mut dyn FnMut(&FrameStack),
) -> Result<FrameStack, StoreError> {
    let frames = frames.into_iter().take(at_most);
    write_counted(path, kind, meta, (1, at_most), frames, on_frame)
}

/// [`write_frames`] with the least and the most frames a whole file holds.
fn write_counted(
    path: &Path,
    kind: &str,
    meta: &FrameMeta,
    (least, expected): (usize, usize),
    frames: impl IntoIterator<Item = RawFrame>,
    on_frame: &mut dyn FnMut(&FrameStack),
) -> Result<FrameStack, StoreError> {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let tmp = path.with_file_name(format!(".{name}{TMP_MARK}{}", std::process::id()));
    let counts = (least, expected);
    let result = write_pages(&tmp, kind, meta, counts, frames, on_frame).and_then(|stack| {
        std::fs::rename(&tmp, path).map_err(|e| StoreError::File(FileError::write(path, e)))?;
        if let Some(dir) = path.parent() {
            if let Ok(d) = std::fs::File::open(dir) {
                let _ = d.sync_all();
            }
        }
        Ok(stack)
    });
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

/// The marker in the names of files being written (`.<name>.tmp-<pid>`),
/// which a restart may remove.
pub(crate) const TMP_MARK: &str = ".tmp-";

fn write_pages(
    tmp: &Path,
    kind: &str,
    meta: &FrameMeta,
    (least, expected): (usize, usize),
    frames: impl IntoIterator<Item = RawFrame>,
    on_frame: &mut dyn FnMut(&FrameStack),
) -> Result<FrameStack, StoreError> {
    let file =
        std::fs::File::create(tmp).map_err(|e| StoreError::File(FileError::write(tmp, e)))?;
    let mut out = std::io::BufWriter::new(file);
    let [_, _, w, h] = meta.acquisition.region;
    // Classic TIFF addresses 4 GiB; longer captures are written as BigTIFF.
    let big = capture_bytes(w, h, expected, 0) > (3u64 << 30);
    let stack = if big {
        let enc = TiffEncoder::new_big(&mut out).map_err(|e| tiff_err(tmp, e))?;
        encode_stream(enc, tmp, kind, meta, (least, expected), frames, on_frame)?
    } else {
        let enc = TiffEncoder::new(&mut out).map_err(|e| tiff_err(tmp, e))?;
        encode_stream(enc, tmp, kind, meta, (least, expected), frames, on_frame)?
    };
    let file = out
        .into_inner()
        .map_err(|e| StoreError::File(FileError::write(tmp, e.into_error())))?;
    file.sync_all()
        .map_err(|e| StoreError::File(FileError::write(tmp, e)))?;
    Ok(stack)
}

fn encode_stream<W: std::io::Write + std::io::Seek, K: tiff::encoder::TiffKind>(
    mut enc: TiffEncoder<W, K>,
    path: &Path,
    kind: &str,
    meta: &FrameMeta,
    (least, expected): (usize, usize),
    frames: impl IntoIterator<Item = RawFrame>,
    on_frame: &mut dyn FnMut(&FrameStack),
) -> Result<FrameStack, StoreError> {
    let mut stack: Option<FrameStack> = None;
    for (i, f) in frames.into_iter().enumerate() {
        let st = stack.get_or_insert_with(|| FrameStack::new(f.width, f.height));
        if (f.width, f.height) != (st.width, st.height) || f.pixels.len() != f.width * f.height {
            return Err(StoreError::File(FileError::format(
                path,
                format!(
                    "frame {i} is {}x{} ({} values), the capture's first was {}x{}",
                    f.width,
                    f.height,
                    f.pixels.len(),
                    st.width,
                    st.height
                ),
            )));
        }
        let desc = serde_json::json!({
            "polnlos": kind, "page": i, "frame_id": f.frame_id, "system_timestamp_ns": f.system_timestamp_ns,
            "bits": f.bits, "meta": meta,
        })
        .to_string();
        let (w, h) = (
            u32::try_from(f.width).unwrap_or(u32::MAX),
            u32::try_from(f.height).unwrap_or(u32::MAX),
        );
        let mut img = enc
            .new_image::<colortype::Gray16>(w, h)
            .map_err(|e| tiff_err(path, e))?;
        img.encoder()
            .write_tag(Tag::ImageDescription, desc.as_str())
            .map_err(|e| tiff_err(path, e))?;
        img.encoder()
            .write_tag(Tag::Software, "polnlos")
            .map_err(|e| tiff_err(path, e))?;
        img.write_data(&f.pixels).map_err(|e| tiff_err(path, e))?;
        st.push_raw(&f.pixels, f.bits);
        on_frame(st);
    }
    match stack {
        Some(st) if (least..=expected).contains(&st.count) => Ok(st),
        other => Err(StoreError::Incomplete {
            path: path.to_path_buf(),
            got: other.map_or(0, |s| s.count),
            wanted: expected,
        }),
    }
}

/// Writes a capture's mean (minus `dark`, the mean dark frame, when given),
/// the variance of that mean (the frames' plus `dark_variance`, the dark
/// mean's, when known: MODEL.md `var_p`) and the preview, each atomically;
/// returns the mean. `frames` is the stack of the capture's frames.
pub(crate) fn write_summary(
    dir: &Path,
    frames: &FrameStack,
    dark: Option<&Frame>,
    dark_variance: Option<&Frame>,
    meta: &FrameMeta,
) -> Result<Frame, StoreError> {
    let mean = frames.mean_minus(dark).map_err(|e| {
        StoreError::File(FileError::format(
            &dir.join(CaptureFiles::MEAN),
            e.to_string(),
        ))
    })?;
    let desc =
        serde_json::json!({"polnlos": "mean", "frames": frames.count, "meta": meta}).to_string();
    write_float_tiff(&dir.join(CaptureFiles::MEAN), &mean, &desc)?;
    if let Some(mut var) = frames.variance_frame() {
        if let Some(d) = dark_variance.filter(|d| (d.width, d.height) == (var.width, var.height)) {
            var.pixels
                .iter_mut()
                .zip(&d.pixels)
                .for_each(|(v, d)| *v += d);
        }
        let desc = serde_json::json!({"polnlos": "variance of the mean", "frames": frames.count, "meta": meta}).to_string();
        write_float_tiff(&dir.join(CaptureFiles::VARIANCE), &var, &desc)?;
    }
    if let Some(sat) = frames.saturated_pixels() {
        let mask = Frame {
            width: frames.width,
            height: frames.height,
            pixels: sat.iter().map(|&s| if s { 1.0 } else { 0.0 }).collect(),
        };
        let desc = serde_json::json!({"polnlos": "saturated in any frame", "frames": frames.count, "meta": meta}).to_string();
        write_float_tiff(&dir.join(CaptureFiles::SATURATED), &mask, &desc)?;
    }
    let values: Vec<f64> = mean.pixels.iter().map(|&v| f64::from(v)).collect();
    let grey = image::normalized_u16(&values);
    let preview = dir.join(CaptureFiles::PREVIEW);
    match meta.acquisition.pixel_format.bayer() {
        // A colour camera's mean in colour: one RGB pixel per 2x2 cell, as
        // the live view shows it, on one stretch for every colour.
        Some(pattern) => {
            let region = meta.acquisition.region;
            let (w, h, rgb) = crate::measure::colour::cells_rgb(
                &grey,
                (mean.width, mean.height),
                pattern,
                [region[0], region[1]],
            );
            image::write_png_rgb16(&preview, w, h, &rgb)?
        }
        None => image::write_png16(&preview, mean.width, mean.height, &grey)?,
    }
    Ok(mean)
}

fn write_float_tiff(path: &Path, frame: &Frame, desc: &str) -> Result<(), StoreError> {
    let mut buf = Cursor::new(Vec::new());
    {
        let mut enc = TiffEncoder::new(&mut buf).map_err(|e| tiff_err(path, e))?;
        let mut img = enc
            .new_image::<colortype::Gray32Float>(frame.width as u32, frame.height as u32)
            .map_err(|e| tiff_err(path, e))?;
        img.encoder()
            .write_tag(Tag::ImageDescription, desc)
            .map_err(|e| tiff_err(path, e))?;
        img.write_data(&frame.pixels)
            .map_err(|e| tiff_err(path, e))?;
    }
    Ok(write_atomic(path, &buf.into_inner())?)
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
pub(crate) fn read_mean_variance(dir: &Path) -> Result<Option<Frame>, StoreError> {
    let v = dir.join(CaptureFiles::VARIANCE);
    if v.exists() {
        return read_float_tiff(&v).map(Some);
    }
    if !dir.join(CaptureFiles::MEAN).exists() || dir.join(CaptureFiles::FRAMES).exists() {
        return variance_from_pages(dir);
    }
    Ok(None)
}

/// The variance of the mean from the raw pages (captures written before
/// `variance.tiff` existed).
fn variance_from_pages(dir: &Path) -> Result<Option<Frame>, StoreError> {
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
    read_float_tiff(&dir.join(CaptureFiles::MEAN))
}

/// Reads a capture's mean with the pixels that were at full scale in any
/// frame set to NaN (not measured), when it recorded any.
///
/// Why: a saturated pixel's mean is a lower bound, and an element's mean
/// over it is biased low; the measurement leaves it out.
pub(crate) fn read_mean_in_range(dir: &Path) -> Result<Frame, StoreError> {
    let mut mean = read_mean(dir)?;
    let path = dir.join(CaptureFiles::SATURATED);
    if path.exists() {
        let mask = read_float_tiff(&path)?;
        if mask.pixels.len() != mean.pixels.len() {
            return Err(StoreError::File(FileError::format(
                &path,
                format!(
                    "{}x{} pixels, but the mean is {}x{}",
                    mask.width, mask.height, mean.width, mean.height
                ),
            )));
        }
        for (m, &s) in mean.pixels.iter_mut().zip(&mask.pixels) {
            if s != 0.0 {
                *m = f32::NAN;
            }
        }
    }
    Ok(mean)
}

/// Reads a single-page 32-bit float TIFF.
fn read_float_tiff(path: &Path) -> Result<Frame, StoreError> {
    let p = path.to_path_buf();
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
            reason: "not a 32-bit float image".into(),
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

    fn meta() -> FrameMeta {
        FrameMeta {
            capture: 1,
            kind: CaptureKind::Light,
            scene: "s".into(),
            pose: "A".into(),
            channels: vec![crate::scene::Channel::Sheet { deg: 0.0 }],
            acquisition: Acquisition {
                exposure_us: 1000.0,
                ..Acquisition::defaults_at([0, 0, 3, 2], [1, 1])
            },
            dark_capture: None,
            camera_id: "cam".into(),
        }
    }

    #[test]
    fn streamed_frames_give_mean_variance_and_subtract_the_dark() {
        let dir = tempfile::tempdir().unwrap();
        let mut seen = Vec::new();
        let stack = write_frames(
            &dir.path().join(CaptureFiles::FRAMES),
            "frames",
            &meta(),
            2,
            [raw(100), raw(110)],
            &mut |st: &FrameStack| seen.push((st.count, st.mean[0])),
        )
        .unwrap();
        assert_eq!(seen, vec![(1, 100.0), (2, 105.0)]);
        assert_eq!(stack.mean, vec![105.0; 6]);
        // Sample variance 50, of the mean 25.
        assert_eq!(stack.variance_of_mean().unwrap(), vec![25.0; 6]);
        let dark = Frame {
            width: 3,
            height: 2,
            pixels: vec![6.0; 6],
        };
        let m = write_summary(dir.path(), &stack, Some(&dark), None, &meta()).unwrap();
        assert_eq!(m.pixels, vec![99.0; 6]);
        assert_eq!(read_mean(dir.path()).unwrap(), m);
        assert_eq!(
            read_mean_variance(dir.path()).unwrap().unwrap().pixels,
            vec![25.0; 6]
        );
        // With the dark mean's variance, the dark-subtracted mean carries both.
        let dark_var = Frame {
            width: 3,
            height: 2,
            pixels: vec![2.0; 6],
        };
        write_summary(dir.path(), &stack, Some(&dark), Some(&dark_var), &meta()).unwrap();
        assert_eq!(
            read_mean_variance(dir.path()).unwrap().unwrap().pixels,
            vec![27.0; 6]
        );
        assert_eq!(
            variance_from_pages(dir.path()).unwrap().unwrap().pixels,
            vec![25.0; 6]
        );
        let mut dec = tiff::decoder::Decoder::new(
            std::fs::File::open(dir.path().join(CaptureFiles::FRAMES)).unwrap(),
        )
        .unwrap();
        let desc = dec.get_tag_ascii_string(Tag::ImageDescription).unwrap();
        for key in [
            "\"pose\":\"A\"",
            "\"region\":[0,0,3,2]",
            "\"binning\":[1,1]",
            "\"trigger\":\"free\"",
        ] {
            assert!(desc.contains(key), "{key}: {desc}");
        }
        assert!(dec.more_images());
    }

    #[test]
    fn a_recording_keeps_the_frames_it_got_up_to_its_count_and_none_is_no_file() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join(CaptureFiles::FRAMES);
        let write = |frames: Vec<RawFrame>| {
            write_frames_upto(&p, "frames", &meta(), 3, frames, &mut |_: &FrameStack| {})
        };
        // Ended early: the two frames it got, a whole file.
        let st = write(vec![raw(10), raw(20)]).unwrap();
        assert_eq!((st.count, st.mean[0]), (2, 15.0));
        let mut dec = tiff::decoder::Decoder::new(std::fs::File::open(&p).unwrap()).unwrap();
        assert!(dec.more_images());
        dec.next_image().unwrap();
        assert!(!dec.more_images(), "two pages");
        // More than asked: the first three, no more.
        let st = write(vec![raw(1), raw(2), raw(3), raw(100)]).unwrap();
        assert_eq!((st.count, st.mean[0]), (3, 2.0));
        // None: no file (the one before is replaced only by a whole one).
        std::fs::remove_file(&p).unwrap();
        let e = write(Vec::new()).unwrap_err();
        assert!(e.to_string().contains("only 0 of 3"), "{e}");
        assert!(!p.exists());
    }

    #[test]
    fn a_capture_that_stops_early_or_changes_size_leaves_no_file() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join(CaptureFiles::FRAMES);
        let e = write_frames(
            &p,
            "frames",
            &meta(),
            3,
            [raw(1), raw(2)],
            &mut |_: &FrameStack| {},
        )
        .unwrap_err();
        assert!(e.to_string().contains("2 of 3"), "{e}");
        let mut odd = raw(3);
        odd.width = 2;
        odd.pixels.truncate(4);
        let e = write_frames(
            &p,
            "frames",
            &meta(),
            2,
            [raw(1), odd],
            &mut |_: &FrameStack| {},
        )
        .unwrap_err();
        assert!(e.to_string().contains("2x2"), "{e}");
        assert_eq!(
            std::fs::read_dir(dir.path()).unwrap().count(),
            0,
            "no file, no temporary"
        );
    }

    #[test]
    fn capture_bytes_counts_pages_and_summaries() {
        assert_eq!(
            capture_bytes(512, 512, 4, 2),
            512 * 512 * (2 * 6 + 10) + 6 * 4096 + (1 << 20)
        );
        assert_eq!(
            capture_bytes(u32::MAX, u32::MAX, usize::MAX / 2, 0),
            u64::MAX
        );
    }
}
