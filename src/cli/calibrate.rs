//! `polnlos calibrate geometry`: a pose's homography from an image of the
//! dot target on the wall, written into a scene file to review.

use std::path::PathBuf;

use anyhow::Context;
use polnlos::calibrate::geometry::{detect, fit, scene_with_homography, Target};
use polnlos::measure::Frame;
use polnlos::transport::MemoryBudget;

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

fn parse_pair(s: &str) -> Result<(f64, f64), String> {
    let bad = || format!("{s:?} is not U,V (two numbers in metres, e.g. 0.03,-0.02)");
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
    }
}

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
    if !a.variance.is_empty() && a.variance.len() != a.measurement.len() {
        return Err(super::Usage(format!(
            "{} --measurement but {} --variance: give one variance per measurement, in the same order, or none",
            a.measurement.len(),
            a.variance.len()
        ))
        .into());
    }
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
    let out = scene_with_homography(&scene_text, &a.pose, &f.homography, region)?;
    eprintln!(
        "pose {}: {} dots, reprojection error RMS {:.3} px, largest {:.3} px",
        a.pose, f.dots, f.rms_px, f.max_px
    );
    let m = f.homography.matrix();
    eprintln!("homography = {m:?}");
    match &a.out {
        Some(p) => {
            polnlos::files::write_atomic(p, out.as_bytes())?;
            println!("calibrated scene written to {}", p.display());
        }
        None => print!("{out}"),
    }
    Ok(())
}
