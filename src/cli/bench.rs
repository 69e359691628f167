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
    /// Live view instead of the offline reports: `polnlos serve` on the
    /// fake camera per configuration (wall and scene grids, mono and
    /// colour), writing live.json, live.md and live.png (with --quick: the
    /// demo bench only).
    #[cfg(feature = "daemon")]
    #[arg(long)]
    live: bool,
    /// Seconds each live session is measured for.
    #[cfg(feature = "daemon")]
    #[arg(long, value_name = "S", default_value_t = 10.0, requires = "live")]
    live_seconds: f64,
    /// Then hold the first configuration's session this many minutes,
    /// reading the daemon's memory every 5 s (live-soak.png; 60 for the
    /// hour the issue asks).
    #[cfg(feature = "daemon")]
    #[arg(long, value_name = "MIN", default_value_t = 0.0, requires = "live")]
    soak_minutes: f64,
    /// Loopback address of the fake cameras the live bench starts (another
    /// than 127.0.0.1 leaves that one's camera port to other daemons).
    #[cfg(feature = "daemon")]
    #[arg(
        long,
        value_name = "IP",
        default_value = "127.0.0.1",
        requires = "live"
    )]
    camera_address: std::net::Ipv4Addr,
}

/// Writes `DIR/NAME.png` and `DIR/NAME.svg`.
fn write_chart(dir: &std::path::Path, name: &str, c: &charts::Chart) -> anyhow::Result<()> {
    write_atomic(&dir.join(format!("{name}.png")), &c.png)?;
    write_atomic(&dir.join(format!("{name}.svg")), c.svg.as_bytes())?;
    Ok(())
}

pub fn run(a: Args, budget: MemoryBudget) -> anyhow::Result<()> {
    super::out_dir(&a.out)?;
    #[cfg(feature = "daemon")]
    if a.live {
        return live(&a);
    }
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

/// `--live`: the live benchmark alone, into live.json, live.md and its charts.
#[cfg(feature = "daemon")]
fn live(a: &Args) -> anyhow::Result<()> {
    use polnlos::report::Report;
    anyhow::ensure!(
        a.live_seconds.is_finite() && (1.0..=3600.0).contains(&a.live_seconds),
        "--live-seconds {}: give 1 to 3600",
        a.live_seconds
    );
    anyhow::ensure!(
        a.soak_minutes.is_finite() && (0.0..=1440.0).contains(&a.soak_minutes),
        "--soak-minutes {}: give 0 to 1440",
        a.soak_minutes
    );
    let start = std::time::Instant::now();
    let pb = super::progress::bar(super::bench_live::steps(a.quick), "live bench");
    let report = super::bench_live::run(
        super::bench_live::Selection {
            quick: a.quick,
            seconds: a.live_seconds,
            soak_minutes: a.soak_minutes,
            camera_address: a.camera_address,
        },
        &mut || pb.inc(1),
    )?;
    pb.finish_and_clear();
    for (name, c) in report.charts()? {
        write_chart(&a.out, &name, &c)?;
    }
    let seconds = start.elapsed().as_secs_f64();
    let mut out = report.json();
    out.insert("seconds".into(), seconds.into());
    json::write(&a.out.join("live.json"), &out)?;
    let md = format!(
        "# polnlos bench --live\n\n{}Run time: {seconds:.1} s.\n",
        report.markdown()
    );
    write_atomic(&a.out.join("live.md"), md.as_bytes())?;
    eprintln!(
        "live bench written to {} in {seconds:.1} s",
        a.out.display()
    );
    Ok(())
}
