//! `polnlos cond`: singular values and condition number of T.

use std::path::PathBuf;

use polnlos::solve::condition;
use polnlos::transport::MemoryBudget;

/// Print the conditioning of T.
#[derive(Debug, clap::Args)]
#[command(after_help = "Example:\n  polnlos cond config/scenes/brewster-crossed-3x3.toml --json")]
pub struct Args {
    /// Scene file (TOML).
    scene: PathBuf,
    /// Print JSON (with every singular value) instead of text.
    #[arg(long)]
    json: bool,
}

/// The JSON printed by `polnlos cond --json`.
#[derive(serde::Serialize)]
struct Output<'a> {
    scene: String,
    rows: usize,
    cols: usize,
    blocks: &'a [polnlos::transport::Block],
    #[serde(serialize_with = "polnlos::solve::json::finite_or_inf")]
    kappa: f64,
    rank: usize,
    threshold: f64,
    singular_values: &'a [f64],
    transport_seconds: f64,
    svd_seconds: f64,
}

pub fn run(a: Args, budget: MemoryBudget) -> anyhow::Result<()> {
    let scene = super::load_scene(&a.scene)?;
    let (t, transport_seconds) = super::progress::build_transport(&scene, budget)?;
    let start = std::time::Instant::now();
    let c = condition(&t)?;
    let svd_seconds = start.elapsed().as_secs_f64();
    if a.json {
        let out = Output {
            scene: super::scene_name(&a.scene),
            rows: c.rows,
            cols: c.cols,
            blocks: t.blocks(),
            kappa: c.kappa,
            rank: c.rank,
            threshold: c.threshold,
            singular_values: &c.singular_values,
            transport_seconds,
            svd_seconds,
        };
        println!("{}", serde_json::to_string_pretty(&out)?);
    } else {
        let smax = c.singular_values.first().copied().unwrap_or(0.0);
        let smin = c.singular_values.last().copied().unwrap_or(0.0);
        println!("scene      {}", super::scene_name(&a.scene));
        println!(
            "T          {} x {} ({} blocks)",
            c.rows,
            c.cols,
            t.blocks().len()
        );
        println!("sigma_max  {smax:.6e}");
        println!("sigma_min  {smin:.6e}");
        if c.kappa.is_finite() {
            println!("kappa      {:.6e}", c.kappa);
        } else {
            println!("kappa      inf (rank-deficient)");
        }
        println!("rank       {} of {}", c.rank, c.cols);
    }
    Ok(())
}
