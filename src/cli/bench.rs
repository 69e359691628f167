//! `polnlos bench`: every report of [`polnlos::report`] (Table 1, Fig. 6,
//! stability, transport accuracy against build time, active NLOS, the
//! automatic λ against the best, the NumPy peer, speed against accuracy), each written the same way: its fields in
//! `bench.json`, its charts as PNG and SVG, its section of `bench.md`.

use std::path::PathBuf;

use polnlos::files::{json, write_atomic};
use polnlos::report::{charts, BenchSelection};
use polnlos::transport::MemoryBudget;

/// Write the bench reports (JSON, Markdown, charts) into a folder.
#[derive(Debug, clap::Args)]
#[command(
    after_help = "Writes bench.json, bench.md and the charts conditioning, roughness, sampling,\n\
active, lambda, rendered, scaling and speed-accuracy-<size> (PNG and SVG).\n\
Example:\n  polnlos bench --quick --out bench/\n\
The full run (about 2 min on 2 cores) adds the 8x8 scene grids, the M and L\n\
speed sizes with 3 seeds, finer active and sampling sweeps, the automatic-λ\n\
sweep on 4 scenes at 16x16 (1e3, 1e4, 1e5 photo-electrons, 3 patterns), and\n\
the NumPy peer at wall 64x64 x scene 32x32, and `reconstruct` end to end at\n\
scene grids 16x16 to 64x64 beside the NumPy peer (the peers run when python3 has NumPy)."
)]
pub struct Args {
    /// Output folder.
    #[arg(long, value_name = "DIR")]
    out: PathBuf,
    /// Small sizes only (about 2 s): 3x3 grids, the S speed size, one seed.
    #[arg(long)]
    quick: bool,
    /// Folder of the Mitsuba-rendered cases (validation/mitsuba/).
    #[arg(long, value_name = "DIR", default_value = polnlos::report::DEFAULT_DIR)]
    rendered: PathBuf,
}

/// Writes `DIR/NAME.png` and `DIR/NAME.svg`.
fn write_chart(dir: &std::path::Path, name: &str, c: &charts::Chart) -> anyhow::Result<()> {
    write_atomic(&dir.join(format!("{name}.png")), &c.png)?;
    write_atomic(&dir.join(format!("{name}.svg")), c.svg.as_bytes())?;
    Ok(())
}

pub fn run(a: Args, budget: MemoryBudget) -> anyhow::Result<()> {
    super::out_dir(&a.out)?;
    let start = std::time::Instant::now();
    let selection = BenchSelection {
        rendered: a.rendered.clone(),
        ..if a.quick {
            BenchSelection::quick()
        } else {
            BenchSelection::full()
        }
    };
    let pb = super::progress::bar(selection.steps(), "bench");
    let work = std::env::temp_dir().join(format!("polnlos-peer-{}", std::process::id()));
    let reports = selection.run(budget, &work, &mut || pb.inc(1))?;
    pb.finish_and_clear();
    let seconds = start.elapsed().as_secs_f64();

    let mut out = serde_json::Map::new();
    out.insert("quick".into(), selection.quick.into());
    out.insert("plan".into(), serde_json::to_value(&selection)?);
    let mut md = String::from("# polnlos bench\n\n");
    for r in &reports {
        out.extend(r.json());
        for (name, c) in r.charts()? {
            write_chart(&a.out, &name, &c)?;
        }
        md.push_str(&r.markdown());
    }
    out.insert("seconds".into(), seconds.into());
    let quick = if selection.quick {
        " (--quick: 3x3 grids)"
    } else {
        ""
    };
    md.push_str(&format!("Run time: {seconds:.1} s{quick}.\n"));
    json::write(&a.out.join("bench.json"), &out)?;
    write_atomic(&a.out.join("bench.md"), md.as_bytes())?;
    eprintln!("bench written to {} in {seconds:.1} s", a.out.display());
    Ok(())
}
