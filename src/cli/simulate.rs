//! `polnlos simulate`: a noisy measurement of a truth image, with the wall
//! images (and optionally camera frames) it implies.

use std::path::PathBuf;

use polnlos::files::{frames::write_frames, image, json, load_grid_image, npy};
use polnlos::scene::{Frame, FrameGeometry};
use polnlos::simulate::camera;
use polnlos::simulate::{unpolarized_peak, NoiseModel, Simulation};
use polnlos::transport::MemoryBudget;
use polnlos::transport::Transport;

/// Simulate a measurement of a hidden scene.
#[derive(Debug, clap::Args)]
#[command(
    after_help = "Exposure is set so that the brightest element of the UNPOLARIZED wall image collects \
--photons electrons; polarized blocks collect what the polarizer passes at that same exposure.\n\
Writes measurement.npy, truth.npy, wall-<pose>-<angle>.png per block, simulate.json \
(with --frames, camera frames rendered pixel by pixel, each pixel at its own wall point, with \
per-pixel shot and read noise: frames-<pose>-<angle>.tiff, --frame-count pages of 16-bit DN that \
`polnlos measure` reads, dark-<pose>-<angle>.tiff with --dark-level, and a preview \
frame-<pose>-<angle>.png). Example:\n  \
polnlos simulate config/scenes/brewster-crossed.toml --truth disk.png --out sim/ --photons 20000 --seed 3"
)]
pub struct Args {
    /// Scene file (TOML).
    scene: PathBuf,
    /// Truth image of the hidden scene: 8/16-bit grey PNG (resampled to the scene grid) or .npy.
    #[arg(long, value_name = "IMG")]
    truth: PathBuf,
    /// Output folder.
    #[arg(long, value_name = "DIR")]
    out: PathBuf,
    /// Photo-electrons at the brightest element of the unpolarized wall image (also the full well).
    #[arg(long, default_value_t = NoiseModel::default().photons)]
    photons: f64,
    /// Read noise, electrons RMS.
    #[arg(long = "read-noise", value_name = "E", default_value_t = NoiseModel::default().read_noise)]
    read_noise: f64,
    /// Digitizer bit depth (1-16).
    #[arg(long, value_name = "B", default_value_t = NoiseModel::default().bits)]
    bits: u32,
    /// Random seed (same seed, same noise).
    #[arg(long, value_name = "S", default_value_t = NoiseModel::default().seed)]
    seed: u64,
    /// Also write the camera frame of each block through its pose's homography.
    #[arg(long)]
    frames: bool,
    /// Camera frame size for --frames, WIDTHxHEIGHT.
    #[arg(long, value_name = "WxH", default_value = "512x512")]
    frame_size: String,
    /// Frames (TIFF pages) per block with --frames, each with its own noise.
    #[arg(long, value_name = "N", default_value_t = 4)]
    frame_count: usize,
    /// Dark level the camera adds to every pixel, DN; with --frames and a
    /// level above 0, dark frames (the scene off) are written too.
    #[arg(long, value_name = "DN", default_value_t = 0.0)]
    dark_level: f64,
}

/// One block in `simulate.json`.
#[derive(serde::Serialize)]
struct BlockOut {
    pose: String,
    /// The block's analyzer: `{"analyzer": "sheet", "deg": 0}`, `none`, or a mosaic angle.
    channel: polnlos::scene::Channel,
    wall_png: String,
    frame_png: Option<String>,
    mean_electrons: f64,
    max_electrons: f64,
    /// Mean over elements of signal / sqrt(signal + read^2).
    mean_snr: f64,
}

/// `simulate.json`.
#[derive(serde::Serialize)]
struct Output {
    scene: String,
    truth: String,
    scene_grid: polnlos::scene::Grid,
    wall_grid: polnlos::scene::Grid,
    rows: usize,
    cols: usize,
    noise: NoiseModel,
    unpolarized_peak: f64,
    electrons_per_unit: f64,
    units_per_dn: f64,
    png_scale: f64,
    /// With --frames: the gain `polnlos measure --gain` takes for them at
    /// `--exposure-us 1` (fraction of full scale per unit of `T l`, the
    /// unpolarized peak at full scale), so the measurement is in units of `T l`.
    #[serde(skip_serializing_if = "Option::is_none")]
    frame_gain: Option<f64>,
    transport_seconds: f64,
    blocks: Vec<BlockOut>,
}

/// Writes `--frame-count` noisy frames of one block (and its dark frames
/// with `--dark-level`): each pixel's electrons drawn from its own clean
/// value, the dark level added in DN; returns the preview's file name.
fn write_frames_of(
    a: &Args,
    label: &str,
    b: usize,
    clean: &Frame,
    set: &FrameSet<'_>,
    png_scale: f64,
) -> anyhow::Result<String> {
    let values: Vec<f64> = clean.pixels.iter().map(|&v| f64::from(v)).collect();
    let dark_values = vec![0.0; values.len()];
    let page = |values: &[f64], k: usize| -> anyhow::Result<Vec<u16>> {
        // A seed per block and page: the same command gives the same frames.
        let model = NoiseModel {
            seed: set.model.seed ^ ((b as u64 + 1) << 32) ^ (k as u64 + 1),
            ..*set.model
        };
        Ok(model
            .apply_with_offset(values.to_vec(), set.peak, a.dark_level)?
            .dn)
    };
    // Pages `seeds` of `values` written as one file.
    let write = |file: String, values: &[f64], seeds: std::ops::Range<usize>| {
        let pages = seeds
            .map(|k| page(values, k))
            .collect::<anyhow::Result<Vec<_>>>()?;
        write_frames(&a.out.join(file), clean.width, clean.height, &pages, a.bits)?;
        anyhow::Ok(pages)
    };
    let n = a.frame_count;
    let pages = write(format!("frames-{label}.tiff"), &values, 0..n)?;
    if a.dark_level > 0.0 {
        write(format!("dark-{label}.tiff"), &dark_values, n..2 * n)?;
    }
    let preview: Vec<u16> = pages[0]
        .iter()
        .map(|&d| (f64::from(d) * png_scale).round().min(65535.0) as u16)
        .collect();
    let name = format!("frame-{label}.png");
    image::write_png16(&a.out.join(&name), clean.width, clean.height, &preview)?;
    Ok(name)
}

fn parse_size(s: &str) -> Result<(usize, usize), super::Usage> {
    let bad = || {
        super::Usage(format!(
            "--frame-size {s:?}: give WxH, each side 1 to 16384, e.g. 512x512"
        ))
    };
    let (w, h) = s.split_once('x').ok_or_else(bad)?;
    let (w, h): (usize, usize) = match (w.trim().parse(), h.trim().parse()) {
        (Ok(w), Ok(h)) => (w, h),
        _ => return Err(bad()),
    };
    if !((1..=16384).contains(&w) && (1..=16384).contains(&h)) {
        return Err(bad());
    }
    Ok((w, h))
}

pub fn run(a: Args, budget: MemoryBudget) -> anyhow::Result<()> {
    let scene = super::load_scene(&a.scene)?;
    let model = NoiseModel {
        photons: a.photons,
        read_noise: a.read_noise,
        bits: a.bits,
        seed: a.seed,
    };
    model.validate()?;
    let frame_size = a.frames.then(|| parse_size(&a.frame_size)).transpose()?;
    if a.frames && !(1..=1000).contains(&a.frame_count) {
        return Err(super::Usage(format!(
            "--frame-count {}: give 1 to 1000 frames per block",
            a.frame_count
        ))
        .into());
    }
    let full_dn = f64::from((1u32 << a.bits.clamp(1, 16)) - 1);
    if !(a.dark_level >= 0.0 && a.dark_level < full_dn) {
        return Err(super::Usage(format!(
            "--dark-level {}: give 0 to {full_dn} DN (below full scale)",
            a.dark_level
        ))
        .into());
    }
    if a.frames {
        if let Some(p) = scene.poses().iter().find(|p| p.homography.is_none()) {
            anyhow::bail!(
                "--frames needs a homography for every pose; pose {:?} has none",
                p.name
            );
        }
    }
    let sgrid = scene.hidden().plane.grid;
    let truth = load_grid_image(&a.truth, sgrid)?;
    super::out_dir(&a.out)?;

    let (t, transport_seconds) = super::progress::build_transport(&scene, budget)?;
    let clean = t.apply(&truth);
    let peak = unpolarized_peak(&scene, &t, &truth, budget)?;
    let sim = model.apply(clean, peak)?;

    npy::write_f64(
        &a.out.join("measurement.npy"),
        &[t.rows()],
        &sim.measurement,
    )?;
    npy::write_f64(
        &a.out.join("truth.npy"),
        &[sgrid.nv, sgrid.nu],
        &sgrid.to_top_first(&truth, 1),
    )?;
    let full = f64::from((1u32 << a.bits) - 1);
    let png_scale = 65535.0 / full;
    let wgrid = t.wall_grid();
    // Each pixel at its own wall point (MODEL.md revision 3), not one value per element.
    let clean_frames: Vec<Option<Frame>> = match frame_size {
        Some((w, h)) => camera::render(&scene, &truth, FrameGeometry::plain(w, h))
            .into_iter()
            .map(|(_, f)| f)
            .collect(),
        None => vec![None; t.blocks().len()],
    };
    let blocks = (0..t.blocks().len())
        .map(|b| {
            let frames = FrameSet {
                clean: clean_frames[b].as_ref(),
                model: &model,
                peak,
            };
            write_block(&a, &t, &sim, b, frames, png_scale)
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    let out = Output {
        scene: super::scene_name(&a.scene),
        truth: a.truth.display().to_string(),
        scene_grid: sgrid,
        wall_grid: wgrid,
        rows: t.rows(),
        cols: t.cols(),
        noise: model,
        unpolarized_peak: peak,
        electrons_per_unit: sim.electrons_per_unit,
        units_per_dn: sim.units_per_dn,
        png_scale,
        frame_gain: a.frames.then(|| 1.0 / peak),
        transport_seconds,
        blocks,
    };
    json::write(&a.out.join("simulate.json"), &out)?;
    eprintln!(
        "simulated {} blocks of {} wall elements into {}",
        t.blocks().len(),
        wgrid.count(),
        a.out.display()
    );
    Ok(())
}

/// What one block's camera frames are made from.
struct FrameSet<'a> {
    /// The clean frame (units of `T l` per pixel), with --frames.
    clean: Option<&'a Frame>,
    model: &'a NoiseModel,
    /// The unpolarized peak that sets the exposure.
    peak: f64,
}

/// Writes one block's wall image (and camera frames with `--frames`) and
/// returns what `simulate.json` says about it.
fn write_block(
    a: &Args,
    t: &Transport,
    sim: &Simulation,
    b: usize,
    frames: FrameSet<'_>,
    png_scale: f64,
) -> anyhow::Result<BlockOut> {
    let block = &t.blocks()[b];
    let rows = t.block_rows(b);
    let wgrid = t.wall_grid();
    let scaled: Vec<u16> = sim.dn[rows.clone()]
        .iter()
        .map(|&d| (f64::from(d) * png_scale).round() as u16)
        .collect();
    let wall_png = format!("wall-{}.png", block.label());
    image::write_png16(&a.out.join(&wall_png), wgrid.nu, wgrid.nv, &scaled)?;
    let frame_png = match frames.clean {
        Some(clean) => Some(write_frames_of(
            a,
            &block.label(),
            b,
            clean,
            &frames,
            png_scale,
        )?),
        None => None,
    };
    let electrons: Vec<f64> = sim.clean[rows]
        .iter()
        .map(|c| c * sim.electrons_per_unit)
        .collect();
    let n = electrons.len().max(1) as f64;
    let r2 = a.read_noise * a.read_noise;
    Ok(BlockOut {
        pose: block.pose.clone(),
        channel: block.channel,
        wall_png,
        frame_png,
        mean_electrons: electrons.iter().sum::<f64>() / n,
        max_electrons: electrons.iter().copied().fold(0.0, f64::max),
        mean_snr: electrons
            .iter()
            .map(|e| if *e > 0.0 { e / (e + r2).sqrt() } else { 0.0 })
            .sum::<f64>()
            / n,
    })
}
