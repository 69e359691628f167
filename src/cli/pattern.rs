//! `polnlos pattern`: write a test pattern (disk, bars, letter, flat) as a 16-bit PNG,
//! to use as `--truth` for `polnlos simulate` and `polnlos reconstruct`.

use std::path::PathBuf;

use polnlos::files::image;
use polnlos::scene::Grid;
use polnlos::simulate::patterns::Pattern;

/// Write a test pattern for the hidden scene as a 16-bit grey PNG.
#[derive(Debug, clap::Args)]
#[command(
    after_help = "Examples:\n  polnlos pattern letter --scene brewster-crossed --out letter.png   # on the scene's hidden grid, as the daemon's \"truth\": \"letter\"\n  polnlos pattern letter --size 64 --out letter.png"
)]
pub struct Args {
    /// disk, bars, letter or flat.
    #[arg(value_parser = ["disk", "bars", "letter"])]
    name: String,
    /// Image side in pixels (a square image; resampled to a scene's grid
    /// where it is used).
    #[arg(long, default_value_t = 64, conflicts_with = "scene")]
    size: usize,
    /// Render on this scene's hidden grid (a scene file, or a built-in
    /// scene's name): the image the daemon compares a reconstruction with
    /// when a request names the pattern as its truth.
    #[arg(long, value_name = "SCENE")]
    scene: Option<PathBuf>,
    /// Output PNG.
    #[arg(long, value_name = "FILE")]
    out: PathBuf,
}

pub fn run(a: Args) -> anyhow::Result<()> {
    let grid = match &a.scene {
        Some(path) => super::load_scene(path)?.hidden().plane.grid,
        None => {
            if !(1..=4096).contains(&a.size) {
                return Err(super::Usage("--size must be from 1 to 4096 pixels".into()).into());
            }
            Grid {
                nu: a.size,
                nv: a.size,
            }
        }
    };
    let p = Pattern::from_name(&a.name).ok_or_else(|| {
        super::Usage(format!(
            "unknown pattern {:?}: use disk, bars, letter or flat",
            a.name
        ))
    })?;
    // Written as people look at it: the plane's top (+v) in the first row.
    let img = grid.to_top_first(&p.render(grid), 1);
    image::write_png16(&a.out, grid.nu, grid.nv, &image::unit_to_u16(&img))?;
    println!(
        "wrote {} ({} x {} pixels)",
        a.out.display(),
        grid.nu,
        grid.nv
    );
    Ok(())
}
