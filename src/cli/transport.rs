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
    /// Adaptive wall supersampling to this relative error (e.g. 1e-3): only
    /// elements whose integrand varies (shadow edges, a narrow specular lobe)
    /// are refined; replaces the file's wall supersample.
    #[arg(long, value_name = "TOL")]
    adaptive: Option<f64>,
    /// Largest sub-sampling per side for --adaptive.
    #[arg(long = "max-m", value_name = "M", default_value_t = 16)]
    max_m: usize,
}

pub fn run(a: Args) -> anyhow::Result<()> {
    let scene = super::load_scene(&a.scene)?;
    let (t, secs) = match a.adaptive {
        None => super::progress::build_transport(&scene)?,
        Some(tol) => {
            let start = std::time::Instant::now();
            let (t, st) = polnlos::transport::build_adaptive(&scene, tol, a.max_m)?;
            let levels: Vec<String> = st
                .elements_at
                .iter()
                .filter(|e| e.1 > 0)
                .map(|(m, n)| format!("{n} at m = {m}"))
                .collect();
            eprintln!(
                "adaptive supersampling: wall elements {}; estimated error {:.2e}{}",
                levels.join(", "),
                st.estimated_error,
                if st.met {
                    String::new()
                } else {
                    format!(" (above --adaptive {tol:e}: raise --max-m or accept it)")
                }
            );
            (t, start.elapsed().as_secs_f64())
        }
    };
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
