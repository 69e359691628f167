//! `POST /captures/import`: a measurement or a photo taken elsewhere made a
//! capture of one pose of a scene, stored like any capture with its
//! provenance.
//!
//! Why: a lab with an ordinary camera, or data from another bench, must
//! reach the daemon's one reconstruction (its gain and background fitted)
//! without converting files by hand; and a file that does not fit its
//! scene is refused before anything is stored.

use serde::Deserialize;
use sha2::{Digest, Sha256};

use super::admission::Admission;
use super::validate::RequestError;
use crate::daemon::SubmitError;
use crate::files::frames::{decode_frames, decode_png, FrameFile};
use crate::measure::colour::BayerPattern;
use crate::measure::given::GivenCapture;
use crate::measure::{assemble_colour, load, PixelMaps};
use crate::scene::{Channel, Scene};
use crate::store::{CaptureFiles, CaptureRecord, ImportInfo};
use crate::transport::{blocks_of, Block};

/// The query of `POST /captures/import`.
#[derive(Debug, Clone, Deserialize, utoipa::IntoParams)]
#[serde(deny_unknown_fields)]
pub struct ImportQuery {
    /// Scene name.
    pub scene: String,
    /// Pose name in the scene: the file holds this pose's blocks.
    pub pose: String,
    /// For a pose with several polarizer angles: the one block the file
    /// holds, degrees from crossed (absent: every block of the pose, in the
    /// scene's row order).
    pub polarizer_deg: Option<f64>,
    /// A raw colour frame's Bayer pattern (`RG`, `GR`, `GB` or `BG`, the
    /// colours of the sensor's first row) for a grey TIFF or PNG of raw
    /// pixels: red, green and blue are measured each from its own pixels.
    pub bayer: Option<String>,
    /// The file's name, kept with the capture (at most 200 characters).
    pub name: Option<String>,
}

/// The most colour channels an imported measurement may hold.
const MAX_COLOURS: usize = 4;
/// The longest file name kept.
const MAX_NAME: usize = 200;

/// What an upload turned into: the measurement of the pose's blocks and
/// what to record of it.
struct Imported {
    /// Shape `[n]` or `[n, C]`, `n` the blocks' rows.
    shape: Vec<usize>,
    /// Values in C order, NaN where not measured.
    data: Vec<f64>,
    format: &'static str,
    bayer: Option<BayerPattern>,
    /// What the user should know (a float mean with no full scale, ...).
    warnings: Vec<String>,
}

impl Admission {
    /// Checks an upload against its scene and pose, measures it (an image
    /// through the pose's homography), and stores it as a done capture: the
    /// file as received, its measurement and its provenance. Nothing is
    /// stored when any check fails.
    pub(crate) fn import_capture(
        &self,
        q: &ImportQuery,
        bytes: &[u8],
    ) -> Result<CaptureRecord, SubmitError> {
        let scene = self
            .scenes
            .now()
            .scene(&q.scene)
            .map_err(RequestError::from)?;
        let blocks = pose_blocks(&scene, q)?;
        if let Some(name) = &q.name {
            if name.chars().count() > MAX_NAME || name.chars().any(char::is_control) {
                return Err(invalid(format!(
                    "name: at most {MAX_NAME} characters and no control characters"
                )));
            }
        }
        let bayer = q
            .bayer
            .as_deref()
            .map(|b| {
                b.parse::<BayerPattern>()
                    .map_err(|e| invalid(format!("bayer: {e}")))
            })
            .transpose()?;
        let nw = scene.wall().plane.grid.count();
        let imported = decode(&scene, &q.pose, &blocks, nw, bytes, bayer)?;
        let need = 2 * bytes.len() as u64 + 8 * imported.data.len() as u64 + (1 << 20);
        let free = crate::files::space::free_disk_bytes(self.store.dir())
            .map_err(|e| SubmitError::Internal(self.store.describe_io(self.store.dir(), &e)))?;
        let keep = self.config.queue.reserve_free_mib << 20;
        if need.saturating_add(keep) > free {
            return Err(SubmitError::Disk {
                need,
                free,
                held: 0,
                keep,
            });
        }
        let colours = match imported.shape.as_slice() {
            [_, c] => *c,
            _ => 1,
        };
        let info = ImportInfo {
            format: imported.format.to_string(),
            name: q.name.clone(),
            bytes: bytes.len() as u64,
            sha256: hex(&Sha256::digest(bytes)),
            colours,
            bayer: imported.bayer.map(|b| format!("{b:?}")),
        };
        let channels: Vec<Channel> = blocks.iter().map(|b| b.channel).collect();
        let internal = |e: crate::store::StoreError| SubmitError::Internal(self.store.describe(&e));
        let id = self
            .store
            .insert_import(&q.scene, &q.pose, &channels, &info)
            .map_err(internal)?;
        if let Err(e) = self.write_import(id, &imported, bytes) {
            let reason = format!("the import could not be stored: {e}");
            let _ = self.store.capture_failed(id, &reason);
            let _ = std::fs::remove_dir_all(self.store.capture_dir(id));
            return Err(SubmitError::Internal(reason));
        }
        self.store.import_done(id).map_err(internal)?;
        for w in &imported.warnings {
            tracing::warn!("capture-{id} (import): {w}");
        }
        tracing::info!(
            "capture-{id} imported: {} pose {} ({}, {} bytes, {} value(s) x {colours} channel(s))",
            q.scene,
            q.pose,
            imported.format,
            bytes.len(),
            imported.shape[0]
        );
        self.events
            .job(format!("capture-{id}"), crate::store::JobState::Done, None);
        self.store.capture(id).map_err(internal)
    }

    /// Writes an import's files: the bytes as received and the measurement.
    fn write_import(&self, id: i64, m: &Imported, bytes: &[u8]) -> Result<(), ImportWriteError> {
        let dir = self.store.capture_dir(id);
        std::fs::create_dir_all(&dir)
            .map_err(|e| ImportWriteError::Folder(self.store.describe_io(&dir, &e)))?;
        let file = |name: &'static str| {
            move |e: crate::files::FileError| ImportWriteError::File {
                file: name,
                reason: self.store.redact_paths(&e.to_string()),
            }
        };
        let source = dir.join(format!("{}.{}", CaptureFiles::SOURCE, m.format));
        crate::files::write_atomic(&source, bytes).map_err(file("the file as received"))?;
        crate::files::npy::write_f64(&dir.join(CaptureFiles::MEASUREMENT), &m.shape, &m.data)
            .map_err(file(CaptureFiles::MEASUREMENT))
    }
}

/// Why an import's files were not written; paths inside the data
/// directory are redacted as the store's own errors are.
#[derive(Debug, thiserror::Error)]
enum ImportWriteError {
    /// The capture's folder could not be made (the store's description).
    #[error("{0}")]
    Folder(String),
    /// One of its files could not be written: which, and why.
    #[error("{file}: {reason}")]
    File {
        /// The file: the bytes as received, or the measurement.
        file: &'static str,
        /// The writer's error, paths redacted.
        reason: String,
    },
}

fn invalid(m: impl Into<String>) -> SubmitError {
    SubmitError::Request(RequestError::Invalid(m.into()))
}

/// The blocks of the scene an import of `q.pose` holds: every block of the
/// pose, or the one at `q.polarizer_deg`.
fn pose_blocks(scene: &Scene, q: &ImportQuery) -> Result<Vec<Block>, SubmitError> {
    if scene.pose(&q.pose).is_none() {
        let poses: Vec<&str> = scene.poses().iter().map(|p| p.name.as_str()).collect();
        return Err(invalid(format!(
            "scene {:?} has no pose {:?}; its poses: {}",
            q.scene,
            q.pose,
            poses.join(", ")
        )));
    }
    let of_pose: Vec<Block> = blocks_of(scene)
        .into_iter()
        .filter(|b| b.pose == q.pose)
        .collect();
    let Some(deg) = q.polarizer_deg else {
        return Ok(of_pose);
    };
    if !deg.is_finite() {
        return Err(invalid("polarizer_deg: must be a finite number"));
    }
    let picked: Vec<Block> = of_pose
        .iter()
        .filter(|b| {
            b.channel
                .sheet_deg()
                .is_some_and(|d| (d - deg).abs() < 1e-6)
        })
        .cloned()
        .collect();
    if picked.is_empty() {
        let labels: Vec<String> = of_pose.iter().map(Block::label).collect();
        return Err(invalid(format!(
            "pose {:?} of scene {:?} has no block at polarizer_deg {deg}; its blocks: {}",
            q.pose,
            q.scene,
            labels.join(", ")
        )));
    }
    Ok(picked)
}

/// The upload as the measurement of `blocks` (`nw` rows each): a `.npy`
/// checked against their rows, or a TIFF or PNG sampled through the pose's
/// homography as a capture's mean frame is.
fn decode(
    scene: &Scene,
    pose: &str,
    blocks: &[Block],
    nw: usize,
    bytes: &[u8],
    bayer: Option<BayerPattern>,
) -> Result<Imported, SubmitError> {
    let n = nw * blocks.len();
    if bytes.starts_with(b"\x93NUMPY") {
        if bayer.is_some() {
            return Err(invalid(
                "bayer is for a raw colour frame (TIFF or PNG); a .npy is a measurement already",
            ));
        }
        return measurement(bytes, n);
    }
    let (frames, format) = if bytes.starts_with(b"II*\0") || bytes.starts_with(b"MM\0*") {
        (decode_frames(bytes), "tiff")
    } else if bytes.starts_with(b"\x89PNG\r\n\x1a\n") {
        (decode_png(bytes), "png")
    } else {
        return Err(invalid(
            "the body is neither a .npy measurement nor a TIFF or PNG image (by its first bytes); send the file itself as the body",
        ));
    };
    let frames = frames.map_err(|e| invalid(e.to_string()))?;
    image(scene, pose, blocks, frames, format, bayer)
}

/// A `.npy` measurement of `n` rows: `[n]` or `[n, C]`, C from 1 to
/// [`MAX_COLOURS`], finite or NaN (not measured).
fn measurement(bytes: &[u8], n: usize) -> Result<Imported, SubmitError> {
    let a = crate::files::npy::decode(bytes).map_err(|e| invalid(format!("the .npy: {e}")))?;
    match a.shape.as_slice() {
        [m] if *m == n => {}
        [m, c] if *m == n && (1..=MAX_COLOURS).contains(c) => {}
        s => {
            return Err(invalid(format!(
                "the .npy has shape {s:?}; this pose's blocks need [{n}] or [{n}, C] with C from 1 to {MAX_COLOURS} (one row per wall element of each block, in the scene's row order; one column per colour channel)"
            )))
        }
    }
    if let Some(v) = a.data.iter().find(|v| v.is_infinite()) {
        return Err(invalid(format!(
            "the .npy holds {v}; give finite values (NaN marks an element that was not measured)"
        )));
    }
    if a.data.iter().all(|v| v.is_nan()) {
        return Err(invalid("the .npy holds no measured value (all NaN)"));
    }
    Ok(Imported {
        shape: a.shape,
        data: a.data,
        format: "npy",
        bayer: None,
        warnings: Vec::new(),
    })
}

/// An image as the measurement of the pose's `blocks`: each colour plane
/// (or a raw Bayer frame's three colours) sampled through the pose's
/// homography over every pixel of each wall element, as the daemon measures
/// a capture.
fn image(
    scene: &Scene,
    pose: &str,
    blocks: &[Block],
    frames: FrameFile,
    format: &'static str,
    bayer: Option<BayerPattern>,
) -> Result<Imported, SubmitError> {
    if scene
        .pose(pose)
        .and_then(|p| p.homography.as_ref())
        .is_none()
    {
        return Err(invalid(format!(
            "pose {pose:?} has no homography, so an image cannot be sampled at its wall elements: calibrate the pose (POST /calibrations with a capture of the dot target) or give its homography in the scene file, or import a measurement (.npy) in the scene's row order"
        )));
    }
    let mut warnings = Vec::new();
    let full_scale = match frames.full_scale() {
        Some(f) => f,
        None => {
            warnings.push(
                "a float image has no bit depth: its values are taken as they are (full scale 1)"
                    .to_string(),
            );
            1.0
        }
    };
    let planes = match (frames.colours, bayer) {
        (Some(_), Some(_)) => return Err(invalid(
            "the image is RGB, already demosaiced: leave out bayer (it is for a raw colour frame)",
        )),
        (Some(c), None) => c,
        (None, _) => vec![frames.stack],
    };
    let channels: Vec<Channel> = blocks.iter().map(|b| b.channel).collect();
    let maps = PixelMaps::default();
    let mut measured = Vec::new();
    for plane in planes {
        let given = GivenCapture::new(
            "the import".into(),
            pose.to_string(),
            channels.clone(),
            plane,
            None,
            full_scale,
            1.0,
            "",
        )
        .with_bayer(bayer);
        // No dark is expected of an import: its background is fitted.
        let mut ignored = Vec::new();
        let loaded = load(scene, &given, &mut ignored).map_err(|e| invalid(e.to_string()))?;
        warnings.extend(ignored.into_iter().filter(|w| !w.contains("dark")));
        let colours: Vec<Option<crate::measure::colour::Colour>> = match loaded.bayer {
            Some(_) => crate::measure::colour::Colour::ALL.map(Some).to_vec(),
            None => vec![None],
        };
        for c in colours {
            let m = assemble_colour(scene, blocks, std::slice::from_ref(&loaded), &maps, c)
                .map_err(|e| invalid(e.to_string()))?;
            measured.push(m.i);
        }
    }
    let n = measured[0].len();
    let c = measured.len();
    let data: Vec<f64> = (0..n)
        .flat_map(|j| measured.iter().map(move |m| m[j]))
        .collect();
    if data.iter().all(|v| v.is_nan()) {
        return Err(invalid(
            "no wall element could be measured from the image (every one saturated or outside it)",
        ));
    }
    Ok(Imported {
        shape: if c == 1 { vec![n] } else { vec![n, c] },
        data,
        format,
        bayer,
        warnings,
    })
}

/// Bytes as lower-case hex.
fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}
