//! `polnlos calibrate geometry`: a pose's homography from an image of the
//! dot target on the wall, written into a scene file to review.

use std::path::PathBuf;

use anyhow::Context;
use polnlos::calibrate::geometry::{detect, fit, scene_with_homography, SceneFolders, Target};
use polnlos::scene::Frame;
use polnlos::transport::MemoryBudget;

use super::{parse_indices, Indices};

/// Calibrate a bench from images.
#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(subcommand)]
    what: What,
}

#[derive(Debug, clap::Subcommand)]
enum What {
    /// Fit a pose's camera→wall homography to an image of a dot target.
    #[command(
        after_help = "Example:\n  polnlos calibrate geometry target-A.png --target dots-5x5 \\\n    --scene brewster-crossed --pose A --out brewster-crossed-calibrated.toml\n\
Prints the dots found and the reprojection error (RMS and largest, pixels);\n\
writes the scene with the pose's homography and camera frame replaced."
    )]
    Geometry(GeometryArgs),
    /// Fit the wall's roughness, refractive index, diffuse weight and the
    /// radiometric gain to a measurement of a point source.
    #[command(
        after_help = "Example:\n  polnlos calibrate wall brewster-rotating --measurement source.npy --source 0.03,-0.02\n\
The measurement is i (all blocks, MODEL.md row order) of a small source at\n\
(u, v) metres from the hidden-scene plane's centre. Prints the fitted values\n\
with standard errors and the residual (JSON); a residual over 25 % of the\n\
measurement is refused (the source position or the poses do not match).\n\
With --variance, the model check compares the misfit with the noise and\n\
scales the standard errors by it; with a polarizer, both polarizer models\n\
are fitted and compared."
    )]
    Wall(WallArgs),
    /// Fit the occluders' position (a translation common to the selected
    /// ones) to one or more photos: the one that minimizes the photos' model
    /// misfit, with an uncertainty that includes the model's error.
    #[command(
        after_help = "Example:\n  polnlos calibrate occluder config/photos/saunders-chair.toml \\\n    --measurement tests/data/saunders-chair/measurement.npy --out chair-placed.toml\n\
The scene's occluders are the first guess. For each candidate translation it\n\
builds T with the occluders moved (area shadows: a monitor block's visible\n\
fraction, continuous in the translation) and fits each photo's differences\n\
(blind to gain and ambient light) by least squares; the misfit summed over\n\
the colour channels of every photo (--measurement, repeatable: several\n\
photos of the same bench) is minimized on a lattice, coarse to fine from\n\
--step down to --min-step, looking past the next ridge, and ends on the\n\
lowest translation it evaluated (docs/realphoto.md). Prints the translation\n\
with its uncertainty (how far the misfit stays within --tolerance of its\n\
lowest: the model's error included), the model check (the misfit over what\n\
the photos' noise alone would leave; give --variance for the noise, else it\n\
is read from the residual), warnings when the fit cannot be trusted, the\n\
moved corner, the objective at start and end, the T builds and seconds; writes the scene with the occluders moved (mesh paths rewritten\n\
for the new file's folder)."
    )]
    Occluder(OccluderArgs),
    /// Fit the bench's geometry (the occluders' place, the hidden plane's
    /// offset in its plane, the wall-to-scene distance; more with --free)
    /// to one or more photos, unknown scenes or calibration shots of known
    /// images, with uncertainties that include the model's error.
    #[command(
        after_help = "Example:\n  polnlos calibrate scene config/photos/saunders-chair.toml \\\n    --measurement tests/data/saunders-chair/measurement.npy --out chair-placed.toml\n\
At each trial geometry it builds T (area shadows, the scene sampled once per\n\
cell) and eliminates the hidden image (or a --known image's gain) and the\n\
photo's background by least squares on the photo's differences; the\n\
residual is descended by Levenberg-Marquardt on a coarse wall, then on the\n\
full one (docs/realphoto.md, \"Fitting the geometry\"). Prints each fitted\n\
offset with its uncertainty, the misfit before and after, the T builds and\n\
seconds, and warnings: a freedom on its bound, freedoms the photos cannot\n\
tell apart, freedoms they do not pin. Writes the scene file with only the\n\
fitted values changed (comments and order kept, mesh paths rewritten for the\n\
new file's folder)."
    )]
    Scene(super::calibrate_scene::SceneArgs),
}

#[derive(Debug, clap::Args)]
struct OccluderArgs {
    /// Scene file (or built-in scene name) whose occluders are the first guess.
    scene: PathBuf,
    /// A photo, .npy of [rows] or [rows, C] (C colour channels), in T's row
    /// order. Repeat it for several photos of the same bench: their misfits add.
    #[arg(long, value_name = "FILE", required = true)]
    measurement: Vec<PathBuf>,
    /// Each photo's noise variance (`measure`'s <out>.variance.npy, the
    /// photo's shape), one per --measurement in the same order: the model
    /// check's noise. Without it, the noise is read from the fit's residual.
    #[arg(long, value_name = "FILE")]
    variance: Vec<PathBuf>,
    /// Occluders that move together, by index in file order (e.g. 0,3-11); default all.
    #[arg(long, value_name = "LIST", value_parser = parse_indices)]
    occluder: Option<Indices>,
    /// Largest translation searched along each axis, metres.
    #[arg(long, value_name = "M", default_value_t = polnlos::calibrate::occluder::RANGE)]
    range: f64,
    /// First step, metres (default: 4 shadow pitches, see docs/realphoto.md).
    #[arg(long, value_name = "M")]
    step: Option<f64>,
    /// Last step, metres (default: one shadow pitch).
    #[arg(long, value_name = "M")]
    min_step: Option<f64>,
    /// The uncertainty region: translations whose misfit is within this
    /// fraction of the lowest (docs/realphoto.md, "Placing the occluders").
    #[arg(long, value_name = "FRACTION", default_value_t = polnlos::calibrate::occluder::TOLERANCE)]
    tolerance: f64,
    /// Most T builds the search may spend (about 1-2 s each on the chair).
    #[arg(long, value_name = "N", default_value_t = polnlos::calibrate::occluder::MAX_EVALUATIONS)]
    max_evaluations: usize,
    /// Descents from different starts on the same lattice (the scene's
    /// position, then two first steps out along the diagonals): when one
    /// ends in another low the fit warns that its position depends on where
    /// it starts. 1: one descent (a third of the time).
    #[arg(long, value_name = "N", default_value_t = polnlos::calibrate::occluder::STARTS)]
    starts: usize,
    /// Scene supersample of each T the search builds (default: 1 with area
    /// shadows; with point shadows the scene's, at least 6).
    #[arg(long, value_name = "N")]
    supersample: Option<usize>,
    /// Shadows of each T the search builds: area (continuous in the
    /// translation), point (MODEL.md's point sources, rough below a
    /// millimetre) or auto (the scene's choice without a photo: point unless
    /// the file says area).
    #[arg(long, value_enum, default_value_t = polnlos::scene::ShadowModel::Area)]
    shadows: polnlos::scene::ShadowModel,
    /// Write the scene with the occluders moved here (default: print it,
    /// mesh paths relative to the current folder). Its folder must exist.
    #[arg(long, value_name = "FILE")]
    out: Option<PathBuf>,
    /// Write the fit and every objective evaluation as JSON here.
    #[arg(long, value_name = "FILE")]
    report: Option<PathBuf>,
}

#[derive(Debug, clap::Args)]
struct WallArgs {
    /// Scene file (or built-in scene name): wall, poses and hidden-scene plane.
    scene: PathBuf,
    /// Measurement of the point source, .npy (one value per row of T).
    /// Repeat it, with one --source each in the same order, to fit several
    /// positions of the same source together.
    #[arg(long, value_name = "FILE", required = true)]
    measurement: Vec<PathBuf>,
    /// Source position U,V in metres from the hidden-scene plane's centre,
    /// one per --measurement.
    #[arg(long, value_name = "U,V", value_parser = parse_pair, required = true)]
    source: Vec<(f64, f64)>,
    /// Variance of each value of the measurement, .npy (e.g. frame-to-frame
    /// variance of the mean), one per --measurement: the fit then says
    /// whether the model explains the data to its noise (chi-square).
    #[arg(long, value_name = "FILE")]
    variance: Vec<PathBuf>,
}

fn parse_pair(s: &str) -> Result<(f64, f64), super::ArgError> {
    let bad = || super::ArgError::Pair {
        given: s.to_string(),
        example: "0.03,-0.02",
    };
    let (u, v) = s.split_once(',').ok_or_else(bad)?;
    match (u.trim().parse::<f64>(), v.trim().parse::<f64>()) {
        (Ok(u), Ok(v)) if u.is_finite() && v.is_finite() => Ok((u, v)),
        _ => Err(bad()),
    }
}

#[derive(Debug, clap::Args)]
struct GeometryArgs {
    /// Image of the target as the pose sees it (grey PNG or TIFF, 8/16-bit or
    /// 32-bit float such as a capture's mean.tiff).
    image: PathBuf,
    /// Target file (TOML: radius_m, dots), or a built-in target by name (`dots-5x5`).
    #[arg(long, value_name = "FILE")]
    target: PathBuf,
    /// Scene file (or built-in scene name) whose pose to calibrate.
    #[arg(long, value_name = "SCENE")]
    scene: PathBuf,
    /// Pose name in the scene.
    #[arg(long, value_name = "NAME")]
    pose: String,
    /// Write the calibrated scene file here (default: print it).
    #[arg(long, value_name = "FILE")]
    out: Option<PathBuf>,
}

pub fn run(a: Args, budget: MemoryBudget) -> anyhow::Result<()> {
    match a.what {
        What::Geometry(g) => geometry(g),
        What::Wall(w) => wall(w, budget),
        What::Occluder(o) => occluder(o, budget),
        What::Scene(s) => super::calibrate_scene::run(s, budget),
    }
}

fn occluder(a: OccluderArgs, budget: MemoryBudget) -> anyhow::Result<()> {
    use polnlos::calibrate::occluder::{fit_occluder, scene_with_occluders_moved, OccluderOptions};
    // The files written last are checked first: the search takes minutes.
    let out_dir = match &a.out {
        Some(p) => super::writable_folder(p, "--out")?,
        None => PathBuf::new(),
    };
    if let Some(p) = &a.report {
        super::writable_folder(p, "--report")?;
    }
    let scene = super::load_scene(&a.scene)?;
    let scene_text = super::scene_text(&a.scene)?;
    let (photos, variances) = read_photos(&a, scene.rows())?;
    let options = OccluderOptions {
        selected: a.occluder.map(|i| i.0),
        range: a.range,
        step: a.step,
        min_step: a.min_step,
        supersample: a.supersample,
        shadows: a.shadows,
        tolerance: a.tolerance,
        max_evaluations: a.max_evaluations,
        starts: a.starts,
        budget,
        variances: (!variances.is_empty()).then_some(variances),
    };
    let f = fit_occluder(&scene, &photos, &options)
        .with_context(|| format!("scene {}", a.scene.display()))?;
    let from_dir = a.scene.parent().unwrap_or(std::path::Path::new(""));
    let out =
        scene_with_occluders_moved(&scene_text, from_dir, &f.selected, f.translation, &out_dir)?;
    let mm = |v: [f64; 3]| {
        format!(
            "({:+.1}, {:+.1}, {:+.1}) mm",
            v[0] * 1e3,
            v[1] * 1e3,
            v[2] * 1e3
        )
    };
    let plain = |v: [f64; 3]| {
        format!(
            "({:.1}, {:.1}, {:.1}) mm",
            v[0] * 1e3,
            v[1] * 1e3,
            v[2] * 1e3
        )
    };
    eprintln!(
        "occluders {:?}: translation {} ± {}, corner {:?} -> [{:.4}, {:.4}, {:.4}] m",
        f.selected,
        mm(f.translation),
        plain(f.uncertainty),
        f.corner_start,
        f.corner_end[0],
        f.corner_end[1],
        f.corner_end[2]
    );
    let sides: Vec<String> = (0..3)
        .map(|k| {
            format!(
                "{} -{:.1}/+{:.1}",
                ["x", "y", "z"][k],
                f.extent[k][0] * 1e3,
                f.extent[k][1] * 1e3
            )
        })
        .collect();
    eprintln!(
        "uncertainty {} mm: where the misfit stays within {:.2} % of its lowest (--tolerance {:.2} %, its ripple {:.2} % x {}); the noise's share alone ± {}",
        sides.join(", "),
        100.0 * f.relative_threshold,
        100.0 * f.tolerance,
        100.0 * f.ripple / f.objective_end,
        polnlos::calibrate::occluder::RIPPLE_FACTOR,
        plain(f.sd_noise),
    );
    eprintln!(
        "objective {:.4e} -> {:.4e} ({:.2} %), {} T builds at supersample {}, steps {:.1}-{:.1} mm, {:.1} s",
        f.objective_start,
        f.objective_end,
        100.0 * (f.objective_end / f.objective_start - 1.0),
        f.builds,
        f.supersample,
        f.steps[0] * 1e3,
        f.steps[1] * 1e3,
        f.seconds
    );
    eprintln!("{}", model_check_line(&f));
    if a.measurement.len() > 1 {
        for (path, [start, end]) in a.measurement.iter().zip(&f.objective_photos) {
            eprintln!("  {}: objective {start:.4e} -> {end:.4e}", path.display());
        }
    }
    for w in &f.warnings {
        eprintln!("warning: the fit cannot be trusted: {w}");
    }
    if a.shadows == polnlos::scene::ShadowModel::Point {
        eprintln!("{POINT_SHADOWS_WARNING}");
    }
    eprintln!("{UNCERTAINTY_NOTE}");
    if let Some(p) = &a.report {
        polnlos::files::json::write(p, &f)?;
    }
    super::write_scene_or_print(a.out.as_deref(), &out, "scene with the occluders moved")
}

/// `--variance` given once per `--measurement`, or not at all.
fn one_variance_each(variance: &[PathBuf], measurement: &[PathBuf]) -> Result<(), super::Usage> {
    if variance.is_empty() || variance.len() == measurement.len() {
        return Ok(());
    }
    Err(super::Usage(format!(
        "{} --variance but {} --measurement: give one variance per measurement, in the same order, or none",
        variance.len(),
        measurement.len()
    )))
}

/// One photo's colour channels, each one value per row of `T`.
type Channels = Vec<Vec<f64>>;

/// The photos of `calibrate occluder` (`--measurement`), each split into
/// its colour channels, and their variances (`--variance`: none, or one per
/// photo with its channels), each checked against the scene's `rows`.
fn read_photos(a: &OccluderArgs, rows: usize) -> anyhow::Result<(Vec<Channels>, Vec<Channels>)> {
    let mut photos = Vec::with_capacity(a.measurement.len());
    for path in &a.measurement {
        photos.push(super::read_channels(path, rows)?);
    }
    one_variance_each(&a.variance, &a.measurement)?;
    let mut variances = Vec::with_capacity(a.variance.len());
    for (path, photo) in a.variance.iter().zip(&photos) {
        let channels = super::read_channels(path, rows)?;
        if channels.len() != photo.len() {
            return Err(polnlos::files::FileError::format(
                path,
                format!(
                    "{} channels, but its measurement has {}",
                    channels.len(),
                    photo.len()
                ),
            )
            .into());
        }
        variances.push(channels);
    }
    Ok((photos, variances))
}

/// The printout's model check line: the misfit over the noise's, and
/// where the noise came from.
fn model_check_line(f: &polnlos::calibrate::occluder::OccluderFit) -> String {
    use polnlos::calibrate::occluder::{NoiseFrom, MODEL_ERROR};
    let from = match f.noise_from {
        NoiseFrom::Variance => "the noise from --variance",
        NoiseFrom::Roughness => "the noise from the roughness of the fit's residual, which a model error rough from one wall element to the next inflates: give --variance for a check that cannot read low",
    };
    match f.model_error {
        Some(r) => format!(
            "model check: the lowest misfit is {r:.3} times what the photos' noise alone would leave ({from}; near 1 when the model explains the photos, above {MODEL_ERROR} a warning)"
        ),
        None => "model check: none (the wall has no more elements' differences than the scene has cells, too few to tell the model's error from the noise)".to_string(),
    }
}

/// Printed with `--shadows point` (docs/realphoto.md, "Placing the occluders").
const POINT_SHADOWS_WARNING: &str = "warning: with point shadows the objective jumps as a shadow edge crosses a wall sample; on the chair photo the fit started 2 cm off ended 20 mm from the measured position (area shadows, the default: 4.1-7.5 mm from three starts) (docs/realphoto.md, \"Placing the occluders\")";

/// What the uncertainty means, as measured (docs/realphoto.md, "Placing the occluders").
const UNCERTAINTY_NOTE: &str = "note: the ± spans the translations whose misfit stays within the threshold of the lowest, the model's error included as the misfit shows it (on the chair photo, three starts 2 cm off ended 4.1-7.5 mm from the measured position, ± 12-34 mm); a model error that shapes the misfit itself can still move its lowest point further, which the warnings above say when the search sees it (docs/realphoto.md, \"Placing the occluders\")";

fn wall(a: WallArgs, budget: MemoryBudget) -> anyhow::Result<()> {
    use polnlos::calibrate::wall::{fit_sources_from_scene, PointSource, SourceMeasurement};
    if a.measurement.len() != a.source.len() {
        return Err(super::Usage(format!(
            "{} --measurement but {} --source: give one source position per measurement, in the same order",
            a.measurement.len(),
            a.source.len()
        ))
        .into());
    }
    one_variance_each(&a.variance, &a.measurement)?;
    let scene = super::load_scene(&a.scene)?;
    let read = |paths: &[PathBuf]| {
        paths
            .iter()
            .map(|path| polnlos::files::npy::read(path).map(|m| m.data))
            .collect::<Result<Vec<_>, _>>()
    };
    let measured = read(&a.measurement)?;
    let variances = read(&a.variance)?;
    for (path, (v, i)) in a.variance.iter().zip(variances.iter().zip(&measured)) {
        if v.len() != i.len() || v.iter().any(|x| !(x.is_finite() && *x >= 0.0)) {
            return Err(super::Usage(format!(
                "{}: a variance needs {} finite values >= 0, one per value of its measurement",
                path.display(),
                i.len()
            ))
            .into());
        }
    }
    let sets: Vec<SourceMeasurement> = a
        .source
        .iter()
        .zip(&measured)
        .enumerate()
        .map(|(k, (&(u, v), i))| SourceMeasurement {
            source: PointSource { u, v },
            i,
            variance: variances.get(k).map(Vec::as_slice),
        })
        .collect();
    // Starts from the scene file's own material.
    let f = fit_sources_from_scene(&scene, &sets, budget).with_context(|| {
        let files: Vec<String> = a
            .measurement
            .iter()
            .map(|p| p.display().to_string())
            .collect();
        format!("measurement {}", files.join(", "))
    })?;
    println!("{}", serde_json::to_string_pretty(&f)?);
    Ok(())
}

fn geometry(a: GeometryArgs) -> anyhow::Result<()> {
    // A file, or a built-in target by name when no such file exists.
    let builtin = a
        .target
        .to_str()
        .filter(|_| !a.target.exists())
        .and_then(Target::builtin_text);
    let text = match builtin {
        Some(t) => t.to_string(),
        None => std::fs::read_to_string(&a.target).with_context(|| {
            format!(
                "cannot read target file {} (built-in targets: {})",
                a.target.display(),
                polnlos::calibrate::geometry::BUILTIN_TARGETS
                    .iter()
                    .map(|t| t.0)
                    .collect::<Vec<_>>()
                    .join(", ")
            )
        })?,
    };
    let target = Target::from_toml_str(&text)
        .with_context(|| format!("target file {}", a.target.display()))?;
    let scene_text = super::scene_text(&a.scene)?;
    let img = polnlos::files::image::read_gray(&a.image)?;
    let frame = Frame {
        width: img.width,
        height: img.height,
        pixels: img.data.iter().map(|&v| v as f32).collect(),
    };
    let blobs = detect(&frame);
    let f = fit(&target, &blobs).with_context(|| format!("image {}", a.image.display()))?;
    let region = [0, 0, img.width as u32, img.height as u32];
    let from = a.scene.parent().unwrap_or(std::path::Path::new(""));
    let to = match &a.out {
        Some(p) => p.parent().unwrap_or(std::path::Path::new("")),
        None => from,
    };
    let folders = SceneFolders { from, to };
    let out = scene_with_homography(&scene_text, &a.pose, &f.homography, region, folders)?;
    eprintln!(
        "pose {}: {} dots, reprojection error RMS {:.3} px, largest {:.3} px",
        a.pose, f.dots, f.rms_px, f.max_px
    );
    let m = f.homography.matrix();
    eprintln!("homography = {m:?}");
    super::write_scene_or_print(a.out.as_deref(), &out, "calibrated scene")
}
