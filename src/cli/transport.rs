//! `polnlos transport`: build T and save it as a standard .npy.

use std::path::PathBuf;

use polnlos::files::npy;
use polnlos::transport::MemoryBudget;

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
    /// The time-resolved (active NLOS) T instead: a laser at each pose's
    /// camera lights one wall spot; rows are (block, wall element, time bin).
    #[arg(long, conflicts_with = "adaptive")]
    active: bool,
    /// Active: path-length width of a time bin, metres (0.01 m = 33 ps).
    #[arg(
        long = "bin-width",
        value_name = "M",
        default_value_t = 0.01,
        requires = "active"
    )]
    bin_width: f64,
    /// Active: laser spot in wall coordinates, metres from the wall centre
    /// (default 0,0).
    #[arg(long, value_name = "U,V", requires = "active")]
    spot: Option<Spot>,
}

/// `--spot U,V`: two numbers, one argument.
#[derive(Debug, Clone, Copy)]
struct Spot(f64, f64);

impl std::str::FromStr for Spot {
    type Err = super::ArgError;
    fn from_str(s: &str) -> Result<Self, super::ArgError> {
        let bad = || super::ArgError::Pair {
            given: s.to_string(),
            example: "0.05,0",
        };
        let (u, v) = s.split_once(',').ok_or_else(bad)?;
        let num = |t: &str| t.trim().parse::<f64>().map_err(|_| bad());
        Ok(Spot(num(u)?, num(v)?))
    }
}

/// `T` as a C-order .npy, float32 or float64.
fn write_t(
    out: &std::path::Path,
    t: &polnlos::transport::Transport,
    f32: bool,
) -> anyhow::Result<()> {
    let shape = [t.rows(), t.cols()];
    let data = t.to_row_major();
    if f32 {
        npy::write_f32(out, &shape, &data)?;
    } else {
        npy::write_f64(out, &shape, &data)?;
    }
    Ok(())
}

pub fn run(a: Args, budget: MemoryBudget) -> anyhow::Result<()> {
    let scene = super::load_scene(&a.scene)?;
    if a.active {
        let Spot(u, v) = a.spot.unwrap_or(Spot(0.0, 0.0));
        let setup = polnlos::transport::active::ActiveSetup {
            spot: (u, v),
            bin_width: a.bin_width,
        };
        let start = std::time::Instant::now();
        let at = polnlos::transport::active::build_active(&scene, &setup, budget)?;
        write_t(&a.out, &at.t, a.f32)?;
        let shape = [at.t.rows(), at.t.cols()];
        eprintln!(
            "active T: {} x {} ({} blocks x {} wall elements x {} time bins of {} m from path length {:.4} m) built in {:.3} s, written to {}",
            shape[0],
            shape[1],
            at.t.blocks().len(),
            at.t.wall_grid().nv,
            at.bins,
            a.bin_width,
            at.d0,
            start.elapsed().as_secs_f64(),
            a.out.display()
        );
        return Ok(());
    }
    let (t, secs) = match a.adaptive {
        None => super::progress::build_transport(&scene, budget)?,
        Some(tol) => {
            let start = std::time::Instant::now();
            let (t, st) = polnlos::transport::build_adaptive(&scene, tol, a.max_m, budget)?;
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
    write_t(&a.out, &t, a.f32)?;
    eprintln!(
        "T: {} x {} ({} blocks) built in {:.3} s, written to {}",
        t.rows(),
        t.cols(),
        t.blocks().len(),
        secs,
        a.out.display()
    );
    Ok(())
}
