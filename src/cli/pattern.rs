//! `polnlos pattern`: write a test pattern (disk, bars, letter) as a 16-bit PNG,
//! to use as `--truth` for `polnlos simulate`.

use std::path::PathBuf;

use polnlos::files::image;
use polnlos::scene::Grid;
use polnlos::simulate::patterns::Pattern;

/// Write a test pattern for the hidden scene as a 16-bit grey PNG.
#[derive(Debug, clap::Args)]
#[command(after_help = "Example:\n  polnlos pattern letter --size 64 --out letter.png")]
pub struct Args {
    /// disk, bars or letter.
    #[arg(value_parser = ["disk", "bars", "letter"])]
    name: String,
    /// Image side in pixels.
    #[arg(long, default_value_t = 64)]
    size: usize,
    /// Output PNG.
    #[arg(long, value_name = "FILE")]
    out: PathBuf,
}

pub fn run(a: Args) -> anyhow::Result<()> {
    if !(1..=4096).contains(&a.size) {
        return Err(super::Usage("--size must be from 1 to 4096 pixels".into()).into());
    }
    let p = Pattern::from_name(&a.name).ok_or_else(|| {
        super::Usage(format!(
            "unknown pattern {:?}: use disk, bars or letter",
            a.name
        ))
    })?;
    let img = p.render(Grid {
        nu: a.size,
        nv: a.size,
    });
    image::write_png16(&a.out, a.size, a.size, &image::unit_to_u16(&img))?;
    Ok(())
}
