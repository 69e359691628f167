//! `polnlos calibrate scene`: the bench's geometry fitted to its photos,
//! written into a placed copy of the scene file.

use std::path::{Path, PathBuf};

use anyhow::Context;
use polnlos::calibrate::scene::{Freedom, SceneFit, SceneFitOptions, Shot};
use polnlos::files::truth::TopFirst;
use polnlos::scene::Grid;
use polnlos::transport::MemoryBudget;

/// What `calibrate scene` takes.
#[derive(Debug, clap::Args)]
pub(super) struct SceneArgs {
    /// Scene file (or built-in scene name) whose geometry is the first guess.
    scene: PathBuf,
    /// A photo, .npy of [rows] or [rows, C] (C colour channels), in T's row
    /// order. Repeat it for several photos of one bench: they share one
    /// geometry.
    #[arg(long, value_name = "FILE", required = true)]
    measurement: Vec<PathBuf>,
    /// The image the hidden monitor showed for each --measurement, in the
    /// same order (.npy [rows, cols] or [rows, cols, C], or PNG, on the
    /// scene's grid, top row first; `none` for a photo of an unknown scene): a calibration
    /// shot of a known image poses the fit far better. Give one per
    /// measurement or none.
    #[arg(long, value_name = "FILE")]
    known: Vec<PathBuf>,
    /// What is fitted, comma-separated: occluder-x, occluder-y, occluder-z,
    /// scene-u, scene-v, distance, occluder-yaw, wall-u, wall-v.
    #[arg(
        long,
        value_name = "LIST",
        value_delimiter = ',',
        value_parser = parse_freedom,
        default_value = "occluder-x,occluder-y,occluder-z,scene-u,scene-v,distance"
    )]
    free: Vec<Freedom>,
    /// Largest offset of each length from the file's value, metres.
    #[arg(long, value_name = "M", default_value_t = SceneFitOptions::default().range)]
    range: f64,
    /// Largest turn (occluder-yaw), degrees.
    #[arg(long, value_name = "DEG", default_value_t = SceneFitOptions::default().range_deg)]
    range_deg: f64,
    /// Occluders that move together, by index in file order (e.g. 0,3-11); default all.
    #[arg(long, value_name = "LIST", value_parser = super::parse_indices)]
    occluder: Option<super::Indices>,
    /// The uncertainty: offsets whose misfit, the other freedoms refitted,
    /// stays within this fraction of the lowest.
    #[arg(long, value_name = "FRACTION", default_value_t = SceneFitOptions::default().tolerance)]
    tolerance: f64,
    /// The coarse level's wall, this many times coarser per axis (default:
    /// about 40 elements on its shorter side; 1: no coarse level).
    #[arg(long, value_name = "N")]
    coarse: Option<usize>,
    /// Most T builds the fit may spend, both levels together.
    #[arg(long, value_name = "N", default_value_t = SceneFitOptions::default().max_evaluations)]
    max_evaluations: usize,
    /// Write the placed scene file here (default: print it, mesh paths
    /// relative to the current folder). Its folder must exist.
    #[arg(long, value_name = "FILE")]
    out: Option<PathBuf>,
    /// Write the fit as JSON here.
    #[arg(long, value_name = "FILE")]
    report: Option<PathBuf>,
}

/// A freedom by its name.
fn parse_freedom(s: &str) -> Result<Freedom, super::ArgError> {
    Freedom::parse(s.trim()).ok_or_else(|| super::ArgError::Freedom(s.to_string()))
}

/// The photos with their known images.
fn read_shots(a: &SceneArgs, rows: usize, grid: Grid) -> anyhow::Result<Vec<Shot>> {
    if !a.known.is_empty() && a.known.len() != a.measurement.len() {
        return Err(super::Usage(format!(
            "{} --known but {} --measurement: give one known image per measurement (`none` for a photo of an unknown scene), in the same order, or none",
            a.known.len(),
            a.measurement.len()
        ))
        .into());
    }
    let mut shots = Vec::with_capacity(a.measurement.len());
    for (k, path) in a.measurement.iter().enumerate() {
        let channels = super::read_channels(path, rows)?;
        let known = match a.known.get(k) {
            Some(p) if p.as_os_str() != "none" => Some(known_image(p, grid, channels.len())?),
            _ => None,
        };
        shots.push(Shot { channels, known });
    }
    Ok(shots)
}

/// A known image (top row first, as [`TopFirst`] reads it) on the scene's
/// grid, one channel per photo channel (a grey image serves every channel).
fn known_image(path: &Path, grid: Grid, channels: usize) -> anyhow::Result<Vec<Vec<f64>>> {
    let image = TopFirst::read(path)?;
    let what = path.display().to_string();
    match image.channels {
        1 => {
            let grey = image.on_grid(grid, 1, &what)?.swap_remove(0);
            Ok(vec![grey; channels])
        }
        _ => Ok(image.on_grid(grid, channels, &what)?),
    }
}

pub(super) fn run(a: SceneArgs, budget: MemoryBudget) -> anyhow::Result<()> {
    // The files written last are checked first: the fit takes minutes.
    let out_dir = match &a.out {
        Some(p) => super::writable_folder(p, "--out")?,
        None => PathBuf::new(),
    };
    if let Some(p) = &a.report {
        super::writable_folder(p, "--report")?;
    }
    let scene = super::load_scene(&a.scene)?;
    let text = super::scene_text(&a.scene)?;
    let shots = read_shots(&a, scene.rows(), scene.hidden().plane.grid)?;
    let options = SceneFitOptions {
        free: a.free.clone(),
        range: a.range,
        range_deg: a.range_deg,
        selected: a.occluder.clone().map(|i| i.0),
        tolerance: a.tolerance,
        coarse: a.coarse,
        max_evaluations: a.max_evaluations,
        budget,
    };
    let tell = |p: polnlos::calibrate::scene::FitProgress| {
        if p.builds.is_multiple_of(10) {
            eprintln!("{} T builds of at most {}", p.builds, p.max_builds);
        }
    };
    let fit = options
        .fit_telling(&scene, &shots, Default::default(), &tell)
        .with_context(|| format!("scene {}", a.scene.display()))?;
    let from_dir = a.scene.parent().unwrap_or(Path::new(""));
    let placed = fit.placed_file(&text, from_dir, &out_dir)?;
    print_fit(&fit);
    if let Some(p) = &a.report {
        polnlos::files::json::write(p, &fit)?;
    }
    super::write_scene_or_print(a.out.as_deref(), &placed, "placed scene")
}

/// The fit as a person reads it, on stderr.
fn print_fit(fit: &SceneFit) {
    for f in &fit.fitted {
        let u = f.freedom.unit();
        eprintln!(
            "{:>13} {:+8.2} {u} ± {:.2} {u} (the residual's scatter alone ± {:.2} {u})",
            f.freedom.name(),
            f.freedom.shown(f.offset),
            f.freedom.shown(f.uncertainty),
            f.freedom.shown(f.sd_noise),
        );
    }
    for l in &fit.levels {
        let wall = match l.factor {
            1 => "full wall".to_string(),
            k => format!("wall {k}x coarser"),
        };
        eprintln!(
            "{wall}: misfit {:.4e} -> {:.4e} ({:+.1} %), {} T builds",
            l.misfit_start,
            l.misfit_end,
            100.0 * (l.misfit_end / l.misfit_start - 1.0),
            l.evaluations
        );
    }
    eprintln!(
        "misfit as written {:.4e}, fitted {:.4e} ({:+.1} %); {} T builds in {:.1} s",
        fit.misfit_as_written,
        fit.misfit_fitted,
        100.0 * (fit.misfit_fitted / fit.misfit_as_written - 1.0),
        fit.evaluations,
        fit.seconds
    );
    for w in &fit.warnings {
        eprintln!("warning: {w}");
    }
}
