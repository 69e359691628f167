//! Command-line interface: argument definitions and dispatch to one module per
//! subcommand. Each subcommand reads files, calls the library and writes files.

#[cfg(feature = "report")]
mod bench;
#[cfg(all(feature = "report", feature = "daemon"))]
mod bench_live;
mod calibrate;
mod calibrate_scene;
mod cond;
mod grid;
mod measure;
mod pattern;
mod photo;
mod progress;
mod reconstruct;
#[cfg(feature = "daemon")]
mod serve;
mod simulate;
mod transport;

use std::path::{Path, PathBuf};

use anyhow::Context;
use clap::{Parser, Subcommand};

use polnlos::scene::Scene;

/// Polarization-enhanced passive non-line-of-sight imaging.
///
/// Build the light-transport matrix of a scene file, check its conditioning,
/// simulate wall images of a hidden scene, and recover the hidden scene from
/// a measurement. Scene files are TOML (see MODEL.md); examples ship in
/// config/scenes/.
#[derive(Debug, Parser)]
#[command(
    name = "polnlos",
    version,
    propagate_version = true,
    after_help = "Exit status: 0 done; 1 the work failed (camera, solver, disk while writing);\n\
2 wrong command line, or a data directory another daemon holds; 3 a file you named\n\
(scene, measurement, image, config, data directory) is missing, unreadable or wrong."
)]
pub struct Cli {
    /// Worker threads for the numeric core (default: all cores).
    #[arg(long, global = true, value_name = "N")]
    threads: Option<usize>,
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Build the transport matrix T of a scene and save it as .npy.
    Transport(transport::Args),
    /// Print the conditioning of T: singular values, condition number, rank.
    Cond(cond::Args),
    /// Render a noisy measurement i = T l of a truth image.
    Simulate(simulate::Args),
    /// Turn camera frames (TIFF) into a measurement: the daemon's stacking, offline.
    Measure(measure::Args),
    /// Recover the hidden scene from a measurement.
    Reconstruct(reconstruct::Args),
    /// Write a test pattern (disk, bars, letter, flat) as a PNG truth image.
    Pattern(pattern::Args),
    /// Recommend the finest scene grid the measurement supports (also
    /// accepted as `plan`).
    #[command(alias = "plan")]
    Grid(grid::Args),
    /// Write the bench reports: Table 1 and Fig. 6, stability, speed against
    /// accuracy, transport sampling, active NLOS, the NumPy peer (JSON,
    /// Markdown, charts).
    #[cfg(feature = "report")]
    Bench(bench::Args),
    /// Calibrate a bench from images (geometry: homographies from a dot target).
    Calibrate(calibrate::Args),
    /// Run the acquisition daemon: camera, capture and reconstruction queues, HTTP API.
    #[cfg(feature = "daemon")]
    Serve(serve::Args),
}

/// Runs the parsed command line.
pub fn run(cli: Cli) -> anyhow::Result<()> {
    if let Some(n) = cli.threads {
        anyhow::ensure!(n >= 1, "--threads must be at least 1");
        rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build_global()
            .context("cannot start the worker threads")?;
    }
    faer::set_global_parallelism(faer::Par::rayon(0));
    // Every command that builds T builds it within this one budget.
    let budget = polnlos::files::space::transport_memory_budget();
    match cli.command {
        Command::Transport(a) => transport::run(a, budget),
        Command::Cond(a) => cond::run(a, budget),
        Command::Simulate(a) => simulate::run(a, budget),
        Command::Measure(a) => measure::run(a, budget),
        Command::Reconstruct(a) if a.photo => photo::run(a, budget),
        Command::Reconstruct(a) => reconstruct::run(a, budget),
        Command::Pattern(a) => pattern::run(a),
        Command::Calibrate(a) => calibrate::run(a, budget),
        #[cfg(feature = "daemon")]
        Command::Serve(a) => serve::run(a, budget),
        #[cfg(feature = "report")]
        Command::Bench(a) => bench::run(a, budget),
        Command::Grid(a) => grid::run(a, budget),
    }
}

/// An option's value that does not read as what the option takes: the
/// value as given, and what was expected (clap prints it with the option).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ArgError {
    /// Not two numbers separated by a comma.
    #[error("{given:?} is not U,V (two numbers in metres, e.g. {example})")]
    Pair {
        /// The value as given.
        given: String,
        /// An example of the option's form.
        example: &'static str,
    },
    /// Not a list of indices and ranges.
    #[error("{0:?} is not a list of occluder indices such as 0,3-11")]
    Indices(String),
    /// Neither a number nor `auto`.
    #[error("{0:?} is neither a number nor `auto`")]
    Lambda(String),
    /// Not a freedom `calibrate scene` fits.
    #[error("{0:?} is not a freedom: one of occluder-x, occluder-y, occluder-z, scene-u, scene-v, distance, occluder-yaw, wall-u, wall-v")]
    Freedom(String),
}

/// A command line that asks for something that cannot be (exit status 2).
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct Usage(pub String);

/// The folder the file `path` (named by the option `option`) will be
/// written in, checked to exist and to take a new file (`""` for the
/// current folder).
///
/// Why: a command that computes for minutes checks where it writes first,
/// so a typo in a folder fails at once, naming it.
fn writable_folder(path: &Path, option: &str) -> anyhow::Result<PathBuf> {
    let dir = path.parent().unwrap_or(Path::new(""));
    let shown = if dir.as_os_str().is_empty() {
        Path::new(".")
    } else {
        dir
    };
    if !shown.is_dir() {
        return Err(Usage(format!(
            "{option} {}: the folder {} does not exist",
            path.display(),
            shown.display()
        ))
        .into());
    }
    let probe = shown.join(format!(".polnlos-write-check-{}", std::process::id()));
    match std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(&probe)
    {
        Ok(_) => {
            let _ = std::fs::remove_file(&probe);
            Ok(dir.to_path_buf())
        }
        Err(e) => Err(Usage(format!(
            "{option} {}: cannot write in the folder {}: {e}",
            path.display(),
            shown.display()
        ))
        .into()),
    }
}

/// The built-in scene named by `path`, when no file of that name exists.
fn builtin(path: &Path) -> Option<&'static str> {
    if path.exists() {
        return None;
    }
    polnlos::scene::builtin::text(&path.to_string_lossy())
}

/// The text of a scene file, or of a built-in scene by name.
fn scene_text(path: &Path) -> anyhow::Result<String> {
    match builtin(path) {
        Some(text) => Ok(text.to_string()),
        None => std::fs::read_to_string(path)
            .with_context(|| format!("cannot read scene file {}", path.display())),
    }
}

/// A `.npy` of `[rows]` or `[rows, C]` split into its C channels, each of
/// `rows` values, or an error naming the file.
fn read_channels(path: &Path, rows: usize) -> anyhow::Result<Vec<Vec<f64>>> {
    let m = polnlos::files::npy::read(path)?;
    Ok(
        polnlos::solve::photo::split_channels(&m.shape, &m.data, rows)
            .map_err(|e| polnlos::files::FileError::format(path, e.to_string()))?,
    )
}

/// Loads a scene file, or a built-in scene by name (`brewster-crossed-3x3`,
/// as the daemon knows them) when no such file exists; the error names the
/// file, the key and the reason.
fn load_scene(path: &Path) -> anyhow::Result<Scene> {
    Ok(Scene::load_or_builtin(path)?)
}

/// `scene`'s `T` through the command line's cache of built matrices
/// (`POLNLOS_CACHE`; `off` builds every time): one build serves every call
/// of the same scene.
fn build_transport(
    scene: &Scene,
    budget: polnlos::transport::MemoryBudget,
    progress: &(dyn Fn(usize) + Sync),
) -> Result<polnlos::files::transport_cache::Cached, polnlos::transport::TransportError> {
    match polnlos::files::transport_cache::TransportCache::from_env() {
        Some(cache) => cache.build(scene, budget, progress),
        None => Ok(polnlos::files::transport_cache::Cached {
            t: polnlos::transport::build_with_progress(
                scene,
                budget,
                progress,
                Default::default(),
            )?,
            source: "built",
        }),
    }
}

/// What a [`build_transport`] source means, for a note.
fn cache_words(source: &str) -> &'static str {
    match source {
        "hit" => "read from the cache of built matrices (POLNLOS_CACHE=off builds it anew)",
        "stored" => "built and kept in the cache of built matrices for the next call",
        _ => "built",
    }
}

/// The scene's name: its file stem.
fn scene_name(path: &Path) -> String {
    path.file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "scene".into())
}

/// Creates an output folder (and its parents).
fn out_dir(dir: &PathBuf) -> anyhow::Result<()> {
    std::fs::create_dir_all(dir)
        .with_context(|| format!("cannot create the output folder {}", dir.display()))
}

/// Occluder indices as `--occluder` lists them.
#[derive(Debug, Clone)]
struct Indices(Vec<usize>);

/// `0,3-11` as the indices it names, in order.
fn parse_indices(s: &str) -> Result<Indices, ArgError> {
    let bad = || ArgError::Indices(s.to_string());
    let mut out = Vec::new();
    for part in s.split(',').map(str::trim) {
        match part.split_once('-') {
            Some((a, b)) => {
                let (a, b) = (
                    a.trim().parse::<usize>().map_err(|_| bad())?,
                    b.trim().parse::<usize>().map_err(|_| bad())?,
                );
                if a > b || b - a > 100_000 {
                    return Err(bad());
                }
                out.extend(a..=b);
            }
            None => out.push(part.parse::<usize>().map_err(|_| bad())?),
        }
    }
    Ok(Indices(out))
}

/// A scene file a calibration wrote: to `out` (atomically, then said on
/// stdout as `what written to PATH`), or printed when no `--out` is given.
fn write_scene_or_print(out: Option<&Path>, text: &str, what: &str) -> anyhow::Result<()> {
    match out {
        Some(p) => {
            polnlos::files::write_atomic(p, text.as_bytes())?;
            println!("{what} written to {}", p.display());
        }
        None => print!("{text}"),
    }
    Ok(())
}
