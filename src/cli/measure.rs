//! `polnlos measure`: camera frames from any acquisition software to the
//! measurement vector `i` (and its variance), through the same
//! [`polnlos::measure::load`] and [`polnlos::measure::assemble`] the daemon uses.

use std::path::{Path, PathBuf};

use polnlos::files::frames::{read_frames, FrameFile};
use polnlos::files::npy;
use polnlos::measure::colour::BayerPattern;
use polnlos::measure::given::{measure_given_sets, GivenCapture, Measured, UnitsWanted};
use polnlos::measure::{FrameStack, Measurement, Units};
use polnlos::scene::{Channel, Scene};
use polnlos::transport::{Block, MemoryBudget};

/// Turn camera frames into a measurement for `polnlos reconstruct`.
#[derive(Debug, clap::Args)]
#[command(
    after_help = "One capture per --frames (one block, or a mosaic pose's four with --angle mosaic); --pose, --angle, --dark and --exposure-us are given \
once for all blocks or once per --frames, in the same order. Blocks may come in any order; they are \
stacked in the scene's block order (MODEL.md). Writes the measurement (.npy) and, when every block \
has 2 frames or more, its variance beside it (<out>.variance.npy). Example:\n  \
polnlos measure brewster-crossed-3x3 --frames A.tiff --dark dark-A.tiff --pose A --angle 0 \
--exposure-us 200000 --gain 0.84 --out i.npy\n  \
polnlos reconstruct brewster-crossed-3x3 --measurement i.npy --variance i.variance.npy --out rec/"
)]
pub struct Args {
    /// Scene file (TOML) or built-in scene name the frames were taken with.
    scene: PathBuf,
    /// Frames of one block: a grey multi-page 8/16-bit TIFF (one frame per
    /// page, averaged) or one 32-bit float TIFF that is a mean already.
    #[arg(long, value_name = "TIFF", required = true)]
    frames: Vec<PathBuf>,
    /// Dark frames (scene off, same exposure and region), subtracted from
    /// the mean: one file for all blocks or one per --frames.
    #[arg(long, value_name = "TIFF")]
    dark: Vec<PathBuf>,
    /// Pose name of each block, as in the scene file.
    #[arg(long, value_name = "NAME", required = true)]
    pose: Vec<String>,
    /// Polarizer angle of each block in degrees from crossed, `none` for a
    /// pose without polarizer, or `mosaic` for a polarizer-mosaic camera's
    /// raw frame (analyzer = "mosaic"): its four blocks 0, 45, 90, 135.
    #[arg(
        long,
        value_name = "DEG|none|mosaic",
        required = true,
        allow_negative_numbers = true
    )]
    angle: Vec<AngleArg>,
    /// Exposure per frame, microseconds.
    #[arg(long = "exposure-us", value_name = "US", required = true)]
    exposure_us: Vec<f64>,
    /// Full scale in DN (default: from the TIFF bit depth, 255 or 65535;
    /// required for a float mean). Use 4095 for 12-bit data in 16-bit pages.
    #[arg(long = "full-scale", value_name = "DN")]
    full_scale: Option<f64>,
    /// Radiometric gain of the bench (the daemon's [calibration], `calibrate
    /// wall`'s gain): the measurement is divided by it into units of T l.
    #[arg(long, value_name = "G", conflicts_with = "raw")]
    gain: Option<f64>,
    /// Keep fractions of full scale per microsecond (for `calibrate wall`)
    /// instead of units of T l.
    #[arg(long)]
    raw: bool,
    /// The frames are a colour camera's raw Bayer frames with this pattern
    /// (the first row's colours: RG for RGGB, GR, GB, BG, as the camera's
    /// pixel format names it): red, green and blue are measured each from
    /// its own pixels into a [rows, 3] measurement.
    #[arg(long, value_name = "RG|GR|GB|BG", value_parser = parse_bayer)]
    bayer: Option<BayerPattern>,
    /// Output measurement (.npy).
    #[arg(long, value_name = "FILE")]
    out: PathBuf,
}

/// `--bayer`: a Bayer pattern by its first row's colours.
fn parse_bayer(s: &str) -> Result<BayerPattern, polnlos::measure::colour::UnknownBayerPattern> {
    s.parse()
}

/// `--angle`: degrees, `none` or `mosaic`: the blocks the frames hold.
#[derive(Debug, Clone)]
struct AngleArg(Vec<Channel>);

impl std::str::FromStr for AngleArg {
    type Err = polnlos::scene::UnknownAnalyzer;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Channel::of_capture(s).map(AngleArg)
    }
}

/// The value of a per-block option for block `k`: the one value for all, or the k-th.
fn per_block<'a, T>(values: &'a [T], k: usize, name: &str, n: usize) -> anyhow::Result<&'a T> {
    match values.len() {
        1 => Ok(&values[0]),
        m if m == n => Ok(&values[k]),
        m => Err(super::Usage(format!(
            "{m} values of {name} for {n} --frames; give one for all or one per --frames"
        ))
        .into()),
    }
}

/// The variance file written beside `out`: `i.npy` → `i.variance.npy`.
fn variance_path(out: &Path) -> PathBuf {
    let stem = out
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "measurement".into());
    out.with_file_name(format!("{stem}.variance.npy"))
}

/// Runs `polnlos measure`: reads the frames, measures them against the
/// scene's `T` and writes the measurement (and its variance).
pub fn run(a: Args, budget: MemoryBudget) -> anyhow::Result<()> {
    let scene = super::load_scene(&a.scene)?;
    let sets = read_captures(&a)?;
    let wanted = units_wanted(a.raw, a.gain)?;
    let measured = measure_sets(&scene, &sets, wanted, budget)?;
    if let Some(parent) = a.out.parent().filter(|p| !p.as_os_str().is_empty()) {
        super::out_dir(&parent.to_path_buf())?;
    }
    let blocks = measured[0].blocks.clone();
    // One channel per set (RGB planes) or three of one set (raw Bayer frames).
    let mut channels: Vec<_> = measured.into_iter().flat_map(|m| m.channels).collect();
    if channels.len() > 1 {
        return write_colours(&a.out, &channels, scene.wall().plane.grid.count());
    }
    let (m, units) = channels.swap_remove(0);
    write_grey(&a.out, &m, units, &blocks, scene.wall().plane.grid.count())
}

/// Reads every --frames (and its --dark) into captures, one set per colour
/// plane: one set for grey (or raw Bayer) frames, three for RGB frames.
/// Every per-block option is checked as its frames are read, so a wrong
/// command line is refused before `T` is built.
fn read_captures(a: &Args) -> anyhow::Result<Vec<Vec<GivenCapture>>> {
    let n = a.frames.len();
    let mut sets: Vec<Vec<GivenCapture>> = Vec::new();
    for (k, path) in a.frames.iter().enumerate() {
        let pose = per_block(&a.pose, k, "--pose", n)?.clone();
        let AngleArg(channels) = per_block(&a.angle, k, "--angle", n)?.clone();
        let exposure_us = *per_block(&a.exposure_us, k, "--exposure-us", n)?;
        if !(exposure_us.is_finite() && exposure_us > 0.0) {
            return Err(
                super::Usage(format!("--exposure-us {exposure_us}: must be positive")).into(),
            );
        }
        let frames = read_frames(path)?;
        let full_scale = full_scale_of(a.full_scale, &frames, path)?;
        let dark = if a.dark.is_empty() {
            None
        } else {
            Some(read_frames(per_block(&a.dark, k, "--dark", n)?)?)
        };
        let planes = colour_planes(frames, a.bayer, path)?;
        if !sets.is_empty() && sets.len() != planes.len() {
            return Err(super::Usage(format!(
                "{} has {} colour plane(s) but the frames before it {}: give every --frames as RGB or every one grey",
                path.display(),
                planes.len(),
                sets.len()
            ))
            .into());
        }
        sets.resize_with(planes.len(), Vec::new);
        for (c, plane) in planes.into_iter().enumerate() {
            // An RGB dark subtracts per colour; a grey one from every colour.
            let dark = dark.as_ref().map(|d| match &d.colours {
                Some(dc) => dc.get(c).cloned().unwrap_or_else(|| d.stack.clone()),
                None => d.stack.clone(),
            });
            sets[c].push(
                GivenCapture::new(
                    path.display().to_string(),
                    pose.clone(),
                    channels.clone(),
                    plane,
                    dark,
                    full_scale,
                    exposure_us,
                    "give dark frames (scene off, same exposure and region) with --dark",
                )
                .with_bayer(a.bayer),
            );
        }
    }
    Ok(sets)
}

/// The full scale of the frames in `path`: --full-scale when given, else
/// their bit depth's.
/// A float mean has no bit depth, so it needs --full-scale said.
fn full_scale_of(given: Option<f64>, frames: &FrameFile, path: &Path) -> anyhow::Result<f64> {
    match (given, frames.full_scale()) {
        (Some(f), _) if f.is_finite() && f > 0.0 => Ok(f),
        (Some(f), _) => Err(super::Usage(format!("--full-scale {f}: must be positive")).into()),
        (None, Some(f)) => Ok(f),
        (None, None) => Err(super::Usage(format!(
            "{} is a float mean: say its full scale with --full-scale (e.g. 65535)",
            path.display()
        ))
        .into()),
    }
}

/// The colour planes of the frames in `path`: red, green and blue of an RGB
/// file, or its one grey (or raw Bayer) stack.
/// --bayer is for raw grey frames; an RGB file was demosaiced already.
fn colour_planes(
    frames: FrameFile,
    bayer: Option<BayerPattern>,
    path: &Path,
) -> anyhow::Result<Vec<FrameStack>> {
    match (frames.colours, bayer) {
        (Some(_), Some(_)) => Err(super::Usage(format!(
            "{} is an RGB image, already demosaiced: leave out --bayer (it is for a colour camera's raw grey frames)",
            path.display()
        ))
        .into()),
        (Some(c), None) => Ok(c),
        (None, _) => Ok(vec![frames.stack]),
    }
}

/// The units --raw and --gain ask for: raw, divided by the gain, or estimated.
/// A gain that is not positive is refused here, as a usage error.
fn units_wanted(raw: bool, gain: Option<f64>) -> anyhow::Result<UnitsWanted> {
    match (raw, gain) {
        (true, _) => Ok(UnitsWanted::Raw),
        (false, Some(g)) if !(g.is_finite() && g > 0.0) => {
            Err(super::Usage(format!("--gain {g}: must be positive")).into())
        }
        (false, Some(g)) => Ok(UnitsWanted::Gain(g)),
        (false, None) => Ok(UnitsWanted::Estimated),
    }
}

/// Measures `sets` against `scene`, with a progress bar while `T` is built.
/// The warnings are printed before a failure is returned, as they may say why.
fn measure_sets(
    scene: &Scene,
    sets: &[Vec<GivenCapture>],
    wanted: UnitsWanted,
    budget: MemoryBudget,
) -> anyhow::Result<Vec<Measured>> {
    let pb = super::progress::bar(scene.cols(), "building T");
    let mut warnings = Vec::new();
    let refs: Vec<&[GivenCapture]> = sets.iter().map(Vec::as_slice).collect();
    let measured = measure_given_sets(
        scene,
        &refs,
        wanted,
        budget,
        &|done| pb.set_position(done as u64),
        &mut warnings,
    );
    pb.finish_and_clear();
    for w in &warnings {
        eprintln!("warning: {w}");
    }
    Ok(measured?)
}

/// Writes a grey measurement `m` in `units` and its variance beside it when
/// every block has one, and says what it wrote.
/// The line names the blocks in row order, so the file can be checked against the scene.
fn write_grey(
    out: &Path,
    m: &Measurement,
    units: Option<Units>,
    blocks: &[Block],
    wall_elements: usize,
) -> anyhow::Result<()> {
    let units = match units {
        None => "fractions of full scale per microsecond".to_string(),
        Some(u) => format!("units of T l (divided by {:.6e})", u.factor()),
    };
    npy::write_f64(out, &[m.i.len()], &m.i)?;
    let labels: Vec<String> = blocks.iter().map(|b| b.label()).collect();
    println!(
        "wrote {} ({} values: {} blocks {} x {} wall elements), {units}",
        out.display(),
        m.i.len(),
        blocks.len(),
        labels.join(" "),
        wall_elements
    );
    match &m.variance {
        Some(v) => {
            let p = variance_path(out);
            npy::write_f64(&p, &[v.len()], v)?;
            println!("wrote {} (variance of each value)", p.display());
        }
        None => println!("no variance: a block has fewer than 2 frames"),
    }
    Ok(())
}

/// Writes a colour measurement, red, green and blue per row (`[rows, 3]`),
/// and its variance beside it when every colour has one.
fn write_colours(
    out: &Path,
    colours: &[(
        polnlos::measure::Measurement,
        Option<polnlos::measure::Units>,
    )],
    wall_elements: usize,
) -> anyhow::Result<()> {
    let rows = colours[0].0.i.len();
    let c = colours.len();
    let interleave = |f: &dyn Fn(&polnlos::measure::Measurement) -> Option<&Vec<f64>>| {
        let all: Option<Vec<&Vec<f64>>> = colours.iter().map(|(m, _)| f(m)).collect();
        all.map(|all| {
            (0..rows)
                .flat_map(|j| all.iter().map(move |v| v[j]))
                .collect::<Vec<f64>>()
        })
    };
    if let Some(i) = interleave(&|m| Some(&m.i)) {
        npy::write_f64(out, &[rows, c], &i)?;
    }
    let units: Vec<String> = colours
        .iter()
        .map(|(_, u)| u.map_or("raw".to_string(), |u| format!("{:.6e}", u.factor())))
        .collect();
    println!(
        "wrote {} ({rows} rows x {c} colours, red green blue; {} blocks of {wall_elements} wall elements), each colour from its own pixels; divided by {}",
        out.display(),
        rows / wall_elements.max(1),
        units.join(" / ")
    );
    match interleave(&|m| m.variance.as_ref()) {
        Some(v) => {
            let p = variance_path(out);
            npy::write_f64(&p, &[rows, c], &v)?;
            println!("wrote {} (variance of each value)", p.display());
        }
        None => println!("no variance: a block has fewer than 2 frames"),
    }
    Ok(())
}
