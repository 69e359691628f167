//! `polnlos grid`: which scene grid the measurement supports.

use std::path::PathBuf;

use polnlos::simulate::NoiseModel;
use polnlos::solve::resolution::finest_grid;
use polnlos::transport::MemoryBudget;

/// Recommend the finest scene grid the measurement supports.
#[derive(Debug, clap::Args)]
#[command(
    after_help = "For each candidate grid: kappa(T) and the pseudo-inverse's expected per-element RMS error \
(noise amplification, in units of the [0, 1] radiance range) under the camera model; the finest grid below \
--tolerance is recommended. Example:\n  polnlos grid config/scenes/occluder-crossed.toml --photons 20000"
)]
pub struct Args {
    /// Scene file (TOML); its own scene grid is ignored.
    scene: PathBuf,
    /// Photo-electrons per pixel at the brightest element of the unpolarized
    /// image of a fully lit scene; where every pose has a homography an element
    /// is measured from all its pixels, so it collects that many times more.
    #[arg(long, default_value_t = NoiseModel::default().photons)]
    photons: f64,
    /// Read noise, electrons RMS.
    #[arg(long = "read-noise", default_value_t = NoiseModel::default().read_noise)]
    read_noise: f64,
    /// Digitizer bit depth.
    #[arg(long, default_value_t = NoiseModel::default().bits)]
    bits: u32,
    /// Candidate grid sides, comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "2,3,4,6,8,12,16")]
    grids: Vec<usize>,
    /// Largest acceptable RMS error per element (fraction of the radiance range).
    #[arg(long, default_value_t = 0.1)]
    tolerance: f64,
    /// Print JSON.
    #[arg(long)]
    json: bool,
}

pub fn run(a: Args, budget: MemoryBudget) -> anyhow::Result<()> {
    anyhow::ensure!(
        a.grids.iter().all(|g| (1..=64).contains(g)),
        "--grids must be sides from 1 to 64"
    );
    anyhow::ensure!(a.tolerance > 0.0, "--tolerance must be positive");
    let scene = super::load_scene(&a.scene)?;
    let mut grids = a.grids.clone();
    grids.sort_unstable();
    grids.dedup();
    let noise = NoiseModel {
        photons: a.photons,
        read_noise: a.read_noise,
        bits: a.bits,
        seed: 0,
    };
    let p = finest_grid(&scene, &noise, &grids, a.tolerance, budget)?;
    if a.json {
        println!("{}", serde_json::to_string_pretty(&p)?);
        return Ok(());
    }
    println!(
        "{:>6}  {:>12}  {:>6}  {:>14}  supported",
        "grid", "kappa", "rank", "noise ampl."
    );
    for r in &p.rows {
        let k = if r.kappa.is_finite() {
            format!("{:.3e}", r.kappa)
        } else {
            "inf".into()
        };
        let n = if r.noise_amplification.is_finite() {
            format!("{:.3e}", r.noise_amplification)
        } else {
            "inf".into()
        };
        println!(
            "{:>6}  {k:>12}  {:>6}  {n:>14}  {}",
            format!("{0}x{0}", r.grid),
            r.rank,
            if r.supported { "yes" } else { "no" }
        );
    }
    match p.recommended {
        Some(g) => println!("recommended: {g}x{g} (finest grid with RMS error <= {} of the range)", p.tolerance),
        None => println!("no candidate grid is supported at this noise level: collect more light (--photons), add poses, or accept a regularized result"),
    }
    Ok(())
}
