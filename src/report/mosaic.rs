//! The question a buyer asks: one exposure of a polarization camera (a 2x2
//! micro-polarizer mosaic on the sensor, MODEL.md "On-chip polarizer
//! mosaic") against a crossed sheet (one exposure) and a rotating sheet
//! (four exposures), at equal total exposure time, with ideal and partial
//! micro-polarizers (extinction 300 and 100): `kappa(T)` and the PSNR of
//! the automatic-λ reconstruction.
//!
//! Each setup's data goes through camera frames (MODEL.md revision 3: each
//! pixel at its own wall point, each mosaic block measured over its own
//! angle's pixels) with per-pixel shot and read noise: polnlos's own
//! rendering of the setup's scene, and Mitsuba's camera frames of the
//! rotating bench (`tests/data/rendered/rotating/frames`, their Monte-Carlo
//! variance added to the camera's) composed into a mosaic pixel by pixel,
//! `I(theta) + I(theta + 90)/E` (exact for ideal
//! micro-polarizers; for partial ones it takes the 90-degree sheet's axis
//! for `t_perp`, which differs from `normalize(w_o x t)` only off the
//! optical axis).

use std::path::Path;

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

use super::charts::{numbered, panels, Chart, ChartError, Marker, Plot, Series};
use super::BenchError;
use crate::files::npy;
use crate::measure::{assemble, CaptureFrames};
use crate::scene::{Channel, Frame, FrameGeometry, Mosaic, MosaicLayout, Scene, WallSampling};
use crate::simulate::camera::expose;
use crate::simulate::unpolarized_peak;
use crate::solve::lambda::NoiseLevel;
use crate::solve::metrics::{compare, Metrics};
use crate::solve::reconstruct::Context;
use crate::solve::{condition, reconstruct, SolveRequest};
use crate::transport::{build, MemoryBudget};

/// Photo-electrons at the brightest unpolarized wall pixel for the whole
/// exposure time (a rotating sheet's four exposures share it).
pub const PHOTONS: f64 = 2e4;

/// Read noise per pixel and exposure, electrons RMS.
pub const READ_NOISE: f64 = 5.0;

/// Noise seeds averaged per setup.
pub(crate) const SEEDS: u64 = 32;

/// One setup of the comparison.
#[derive(Debug, Clone, Serialize)]
pub struct MosaicRow {
    /// What the camera looks through.
    pub setup: String,
    /// The same in a word (the chart's axis).
    pub short: String,
    /// The micro-polarizers' extinction ratio (mosaic setups; `None`: ideal).
    pub extinction: Option<f64>,
    /// Exposures the total exposure time is split into.
    pub exposures: usize,
    /// `kappa(T)` of the setup (`"pixels"` rows).
    pub kappa: f64,
    /// Reconstruction of polnlos's camera-frame simulation (mean over the seeds).
    pub simulated: Metrics,
    /// Reconstruction of Mitsuba's camera frames (mean over the seeds), when read.
    pub rendered: Option<Metrics>,
}

/// The comparison and what it was measured with.
#[derive(Debug, Clone, Serialize)]
pub struct MosaicReport {
    /// Electrons at the brightest unpolarized pixel for the whole exposure time.
    pub photons: f64,
    /// Read noise per exposure, electrons.
    pub read_noise: f64,
    /// Seeds averaged.
    pub seeds: u64,
    /// The folder of Mitsuba's frames.
    pub frames: String,
    /// Why the Mitsuba column is empty, when it is.
    pub rendered_skipped: Option<String>,
    /// One per setup.
    pub rows: Vec<MosaicRow>,
}

/// The setups, in the report's order: (label, short label, setup).
const SETUPS: [(&str, &str, Setup); 5] = [
    ("crossed sheet", "crossed", Setup::Crossed),
    ("rotating sheet (0/45/90/135)", "rotating", Setup::Rotating),
    ("mosaic, ideal", "mosaic", Setup::Mosaic(None)),
    (
        "mosaic, extinction 300",
        "E 300",
        Setup::Mosaic(Some(300.0)),
    ),
    (
        "mosaic, extinction 100",
        "E 100",
        Setup::Mosaic(Some(100.0)),
    ),
];

/// Steps [`mosaic_report`] reports.
pub const STEPS: usize = SETUPS.len();

#[derive(Debug, Clone, Copy)]
enum Setup {
    Crossed,
    Rotating,
    Mosaic(Option<f64>),
}

impl Setup {
    /// The rotating bench `base` read through this setup, with `"pixels"` rows.
    fn scene(self, base: &Scene) -> Result<Scene, BenchError> {
        super::edit("mosaic bench", base.clone(), |s| {
            s.wall.sampling = WallSampling::Pixels;
            match self {
                Setup::Crossed => s.poses[0].analyzers.truncate(1),
                Setup::Rotating => {}
                Setup::Mosaic(extinction) => {
                    s.poses[0].analyzers.clear();
                    s.poses[0].mosaic = Some(Mosaic {
                        sensor_deg: 0.0,
                        extinction,
                        layout: MosaicLayout::Polarsens,
                    });
                }
            }
        })
    }

    fn exposures(self) -> usize {
        match self {
            Setup::Rotating => 4,
            _ => 1,
        }
    }
}

/// One capture of a setup: what it yields, its clean frame and the
/// variance its source already carries per pixel (a render's Monte-Carlo
/// noise), both in units of `T l`.
struct Shot {
    channels: Vec<Channel>,
    clean: Frame,
    carried: Option<Frame>,
}

/// A frame and, when it has one, its per-pixel variance.
type Source = (Frame, Option<Frame>);

/// The captures of `setup` from the four sheet frames at 0, 45, 90, 135
/// degrees (`sheet[k]`), or, for a mosaic, from its own blocks' frames
/// (`own`, in block order) when given.
fn shots(setup: Setup, sheet: &[Source], own: Option<&[Frame]>) -> Vec<Shot> {
    let shot = |channels: Vec<Channel>, (clean, carried): &Source| Shot {
        channels,
        clean: clean.clone(),
        carried: carried.clone(),
    };
    match setup {
        Setup::Crossed => vec![shot(vec![Channel::Sheet { deg: 0.0 }], &sheet[0])],
        Setup::Rotating => sheet
            .iter()
            .zip(crate::scene::MOSAIC_DEGREES)
            .map(|(f, deg)| shot(vec![Channel::Sheet { deg }], f))
            .collect(),
        Setup::Mosaic(extinction) => {
            let (w, h) = (sheet[0].0.width, sheet[0].0.height);
            let leak = extinction.map_or(0.0, |e| 1.0 / e) as f32;
            let mut clean = Frame::zeros(w, h);
            let mut carried = sheet[0].1.as_ref().map(|_| Frame::zeros(w, h));
            for p in 0..w * h {
                let k = MosaicLayout::Polarsens.block_at((p % w) as i64, (p / w) as i64);
                // I(theta) + I(theta + 90)/E, or the block's own frame.
                clean.pixels[p] = match own {
                    Some(blocks) => blocks[k].pixels[p],
                    None => sheet[k].0.pixels[p] + leak * sheet[(k + 2) % 4].0.pixels[p],
                };
                if let Some(c) = carried.as_mut() {
                    let var = |j: usize| sheet[j].1.as_ref().map_or(0.0, |v| v.pixels[p]);
                    c.pixels[p] = var(k) + leak * leak * var((k + 2) % 4);
                }
            }
            vec![Shot {
                channels: Channel::mosaic().to_vec(),
                clean,
                carried,
            }]
        }
    }
}

/// The reconstruction of `shots` taken with `setup` of `scene` (truth
/// `truth`), each exposure `1/exposures` of the total, with per-pixel shot
/// and read noise (seed `seed`), measured as a capture is.
fn reconstruct_shots(
    scene: &Scene,
    t: &crate::transport::Transport,
    cond: &crate::solve::Conditioning,
    shots: &[Shot],
    electrons_per_unit: f64,
    seed: u64,
    truth: &[f64],
) -> Result<Metrics, BenchError> {
    let fraction = 1.0 / shots.len() as f64;
    let scale = electrons_per_unit * fraction;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let pose = scene.poses()[0].name.clone();
    let captures: Vec<CaptureFrames> = shots
        .iter()
        .enumerate()
        .map(|(k, shot)| {
            let (mean, mut variance) = expose(&shot.clean, scale, READ_NOISE, &mut rng);
            // The source's own noise is in the data: the variance says so.
            if let Some(c) = &shot.carried {
                for (v, &c) in variance.pixels.iter_mut().zip(&c.pixels) {
                    *v = (f64::from(*v) + f64::from(c) * scale * scale) as f32;
                }
            }
            // Digital numbers are electrons: full scale `scale` puts i in units of T l.
            CaptureFrames::exposure(
                format!("shot {k}"),
                pose.clone(),
                shot.channels.clone(),
                (mean, variance),
                scale,
            )
        })
        .collect();
    let blocks = crate::transport::blocks_of(scene);
    let m = assemble(scene, &blocks, &captures).map_err(|e| BenchError::Rendered {
        case: "mosaic bench".into(),
        reason: e.to_string(),
    })?;
    let level = NoiseLevel::measured(m.variance.unwrap_or_default());
    let solved = reconstruct(
        t,
        &m.i,
        Some(level),
        cond,
        &SolveRequest::default(),
        Context::default(),
    )?;
    Ok(compare(t.scene_grid(), truth, &solved.image))
}

/// Mean of metrics over seeds.
fn mean(all: &[Metrics]) -> Metrics {
    let n = all.len().max(1) as f64;
    Metrics {
        psnr_db: all.iter().map(|m| m.psnr_db).sum::<f64>() / n,
        zncc: all.iter().map(|m| m.zncc).sum::<f64>() / n,
        ssim: all.iter().map(|m| m.ssim).sum::<f64>() / n,
    }
}

/// Why Mitsuba's frames could not be compared (the report says so, and
/// compares the rest).
#[derive(Debug, thiserror::Error)]
enum RenderedError {
    /// Their scene file.
    #[error(transparent)]
    Scene(#[from] crate::scene::SceneError),
    /// Their truth or a frame could not be read.
    #[error(transparent)]
    File(#[from] crate::files::FileError),
    /// A frame's array is not 2-D.
    #[error("{0} is not a 2-D frame")]
    NotFrame(String),
    /// A frame's noise is not the frame's size.
    #[error("frame-sigma-{0}.npy is not the size of frame-{0}.npy")]
    SigmaSize(usize),
    /// Their scene is not the rotating bench.
    #[error("the frames' scene is not the rotating bench (one pose, four angles)")]
    NotRotating,
}

/// Mitsuba's four sheet frames of the rotating bench in `dir`, its scene
/// and truth; an error says what is missing.
fn mitsuba(dir: &Path) -> Result<(Scene, Vec<f64>, Vec<Source>), RenderedError> {
    let scene = Scene::load(&dir.join("scene.toml"))?;
    let truth = npy::read(&dir.join("truth.npy"))?;
    let read = |name: String, square: bool| -> Result<Frame, RenderedError> {
        let a = npy::read(&dir.join(&name))?;
        match a.shape[..] {
            [h, w] => Ok(Frame {
                width: w,
                height: h,
                pixels: a
                    .data
                    .iter()
                    .map(|&v| if square { v * v } else { v } as f32)
                    .collect(),
            }),
            _ => Err(RenderedError::NotFrame(name)),
        }
    };
    let frames = (0..4)
        .map(|k| {
            let frame = read(format!("frame-{k}.npy"), false)?;
            let var = read(format!("frame-sigma-{k}.npy"), true)?;
            if (var.width, var.height) != (frame.width, frame.height) {
                return Err(RenderedError::SigmaSize(k));
            }
            Ok((frame, Some(var)))
        })
        .collect::<Result<Vec<_>, RenderedError>>()?;
    if scene.poses().len() != 1 || scene.poses()[0].analyzers.len() != 4 {
        return Err(RenderedError::NotRotating);
    }
    Ok((scene, truth.data, frames))
}

/// The comparison on the rotating bench of `frames_dir` (Mitsuba's frames
/// and their scene; the built-in `brewster-rotating` when they cannot be
/// read), calling `step()` once per setup.
pub fn mosaic_report(
    frames_dir: &Path,
    budget: MemoryBudget,
    step: &mut dyn FnMut(),
) -> Result<MosaicReport, BenchError> {
    let rendered = mitsuba(frames_dir);
    let (base, truth) = match &rendered {
        Ok((scene, truth, _)) => (scene.clone(), truth.clone()),
        Err(_) => {
            let s = super::builtin("brewster-rotating")?;
            let truth = crate::simulate::patterns::Pattern::Letter.render(s.hidden().plane.grid);
            (s, truth)
        }
    };
    let geometry = FrameGeometry::plain(512, 512);
    let rotating = Setup::Rotating.scene(&base)?;
    let t_rotating = build(&rotating, budget)?;
    let peak = unpolarized_peak(&rotating, &t_rotating, &truth, budget)?;
    let electrons_per_unit = PHOTONS / peak.max(1e-300);
    let sheet: Vec<Source> = crate::simulate::camera::render(&rotating, &truth, geometry)
        .into_iter()
        .filter_map(|(_, f)| f.map(|f| (f, None)))
        .collect();
    let mut rows = Vec::with_capacity(SETUPS.len());
    for (label, short, setup) in SETUPS {
        let scene = setup.scene(&base)?;
        let t = build(&scene, budget)?;
        let cond = condition(&t)?;
        let own: Option<Vec<Frame>> = matches!(setup, Setup::Mosaic(_)).then(|| {
            crate::simulate::camera::render(&scene, &truth, geometry)
                .into_iter()
                .filter_map(|(_, f)| f)
                .collect()
        });
        let simulated_shots = shots(setup, &sheet, own.as_deref());
        let run = |shots: &[Shot]| -> Result<Metrics, BenchError> {
            let all = (0..SEEDS)
                .map(|seed| {
                    reconstruct_shots(&scene, &t, &cond, shots, electrons_per_unit, seed, &truth)
                })
                .collect::<Result<Vec<_>, _>>()?;
            Ok(mean(&all))
        };
        let simulated = run(&simulated_shots)?;
        let rendered = match &rendered {
            Ok((_, _, frames)) => Some(run(&shots(setup, frames, None))?),
            Err(_) => None,
        };
        rows.push(MosaicRow {
            setup: label.into(),
            short: short.into(),
            extinction: match setup {
                Setup::Mosaic(e) => e,
                _ => None,
            },
            exposures: setup.exposures(),
            kappa: cond.kappa,
            simulated,
            rendered,
        });
        step();
    }
    Ok(MosaicReport {
        photons: PHOTONS,
        read_noise: READ_NOISE,
        seeds: SEEDS,
        frames: frames_dir.display().to_string(),
        rendered_skipped: rendered.err().map(|e| e.to_string()),
        rows,
    })
}

/// PSNR per setup, polnlos's simulation and Mitsuba's frames.
pub fn chart(r: &MosaicReport) -> Result<Chart, ChartError> {
    let pts = |f: &dyn Fn(&MosaicRow) -> Option<f64>| -> Vec<(f64, f64)> {
        r.rows
            .iter()
            .enumerate()
            .filter_map(|(k, row)| f(row).map(|v| ((k + 1) as f64, v)))
            .collect()
    };
    let mut series = vec![Series::line(
        "polnlos camera-frame simulation",
        0,
        pts(&|row| Some(row.simulated.psnr_db)),
    )];
    if r.rows.iter().any(|row| row.rendered.is_some()) {
        series.push(Series {
            marker: Marker::Cross,
            thin: true,
            ..Series::line(
                "Mitsuba camera frames",
                1,
                pts(&|row| row.rendered.map(|m| m.psnr_db)),
            )
        });
    }
    panels(&[Plot {
        title: format!(
            "equal total exposure ({:.0e} e- at the unpolarized peak)",
            r.photons
        ),
        x_label: numbered("setup", r.rows.iter().map(|row| row.short.as_str())),
        y_label: "PSNR (dB)".into(),
        x_log: false,
        y_log: false,
        x_integer: true,
        series,
    }])
}

impl super::Report for MosaicReport {
    fn json(&self) -> serde_json::Map<String, serde_json::Value> {
        super::shape::fields(vec![("mosaic", serde_json::to_value(self))])
    }

    fn charts(&self) -> Result<Vec<(String, Chart)>, ChartError> {
        Ok(vec![("mosaic".into(), chart(self)?)])
    }

    fn markdown(&self) -> String {
        use std::fmt::Write as _;
        let mut md =
            String::from("## A polarization camera against a polarizer sheet (issue 27)\n\n");
        let _ = writeln!(
            md,
            "The rotating bench (letter on an 8x8 scene, 32x32 wall, pose A) seen through a crossed sheet (one exposure), a rotating sheet (four exposures of a quarter of the time each) and a Sony Polarsens mosaic (one exposure: 0/45/90/135 in a 2x2 pattern, its 0-degree micro-polarizers at crossed), at equal total exposure time: {:.0e} e- at the brightest unpolarized pixel in all, read noise {} e- per exposure, per-pixel noise, each block measured over its pixels (a mosaic block over its own angle's) and reconstructed with `\"pixels\"` rows and the automatic λ; PSNR and SSIM averaged over {} noise seeds. Mitsuba: the rendered camera frames of `{}` composed into a mosaic pixel by pixel (`I(theta) + I(theta + 90)/E`), their own Monte-Carlo noise (about 0.2 % per wall element over all its pixels) in the data and in the variance: a mosaic block keeps a quarter of a render's pixels, so it carries four times the render's variance, which a camera would not.{}\n\n![mosaic](mosaic.png)\n",
            self.photons,
            self.read_noise,
            self.seeds,
            self.frames,
            self.rendered_skipped
                .as_ref()
                .map_or(String::new(), |why| format!(" Mitsuba column skipped: {why}."))
        );
        md.push_str("| setup | exposures | kappa(T) | PSNR simulation | SSIM simulation | PSNR Mitsuba frames | SSIM Mitsuba frames |\n|---|---|---|---|---|---|---|\n");
        for r in &self.rows {
            let (p, s) = r.rendered.map_or(("-".to_string(), "-".to_string()), |m| {
                (format!("{:.2} dB", m.psnr_db), format!("{:.3}", m.ssim))
            });
            let _ = writeln!(
                md,
                "| {} | {} | {:.3e} | {:.2} dB | {:.3} | {p} | {s} |",
                r.setup, r.exposures, r.kappa, r.simulated.psnr_db, r.simulated.ssim
            );
        }
        md.push('\n');
        md
    }
}
