//! `polnlos transport`: build T and save it as a standard .npy.

use std::path::PathBuf;

use polnlos::files::npy;

/// Build the transport matrix of a scene.
#[derive(Debug, clap::Args)]
#[command(
    after_help = "Rows are (pose, polarizer angle) blocks of wall elements, row-major (v outer, u inner); \
columns are scene elements, row-major. Example:\n  polnlos transport config/scenes/brewster-crossed.toml --out T.npy"
)]
pub struct Args {
    /// Scene file (TOML).
    scene: PathBuf,
    /// Output .npy file (C order, rows x cols).
    #[arg(long, value_name = "FILE")]
    out: PathBuf,
    /// Store float32 instead of float64 (half the size; about 1e-7 relative rounding).
    #[arg(long)]
    f32: bool,
}

pub fn run(a: Args) -> anyhow::Result<()> {
    let scene = super::load_scene(&a.scene)?;
    let (t, secs) = super::progress::build_transport(&scene)?;
    let shape = [t.rows(), t.cols()];
    let data = t.to_row_major();
    if a.f32 {
        npy::write_f32(&a.out, &shape, &data)?;
    } else {
        npy::write_f64(&a.out, &shape, &data)?;
    }
    eprintln!(
        "T: {} x {} ({} blocks) built in {:.3} s, written to {}",
        t.rows(),
        t.cols(),
        t.blocks.len(),
        secs,
        a.out.display()
    );
    Ok(())
}
