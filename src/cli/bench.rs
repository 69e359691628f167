//! `polnlos bench`: every report of [`polnlos::bench`] (Table 1, Fig. 6,
//! stability, speed against accuracy, transport accuracy against build time,
//! active NLOS, the NumPy peer) as JSON, Markdown and PNG/SVG charts.

use std::fmt::Write as _;
use std::path::PathBuf;

use polnlos::bench::active::{self, ActiveRow};
use polnlos::bench::peer::{self, PeerReport};
use polnlos::bench::sampling::{self, SamplingRow};
use polnlos::bench::speed::{self, SpeedRow, SpeedSummary};
use polnlos::bench::stability::{stability_table, StabilityRow, CASES};
use polnlos::bench::{self, charts, CondRow, RoughRow};
use polnlos::files::{json, write_atomic};

/// Write the bench reports (JSON, Markdown, charts) into a folder.
#[derive(Debug, clap::Args)]
#[command(
    after_help = "Example:\n  polnlos bench --quick --out bench/\nThe full run (about 45 s on 2 cores) adds the 8x8 scene grids, the M and L\nspeed sizes with 3 seeds, finer active and sampling sweeps, and the NumPy\npeer at wall 64x64 x scene 32x32 (run when python3 has NumPy)."
)]
pub struct Args {
    /// Output folder.
    #[arg(long, value_name = "DIR")]
    out: PathBuf,
    /// Small sizes only (about 2 s): 3x3 grids, the S speed size, one seed.
    #[arg(long)]
    quick: bool,
}

#[derive(serde::Serialize)]
struct Output {
    quick: bool,
    conditioning: Vec<CondRow>,
    roughness: Vec<RoughRow>,
    stability: Vec<StabilityRow>,
    speed_seeds: u64,
    speed: Vec<SpeedSummary>,
    speed_runs: Vec<SpeedRow>,
    sampling_reference_m: usize,
    sampling: Vec<SamplingRow>,
    active: Vec<ActiveRow>,
    peer: PeerReport,
    seconds: f64,
}

fn fmt_kappa(k: f64) -> String {
    if k.is_finite() {
        format!("{k:.3e}")
    } else {
        "inf".into()
    }
}

fn markdown(o: &Output) -> String {
    let mut md = String::from("# polnlos bench\n\n## Conditioning (the paper's Table 1)\n\n| grid | occluder | nopol | rotating | crossed | multi | trend nopol > rotating > crossed > multi |\n|---|---|---|---|---|---|---|\n");
    let mut groups: Vec<(usize, bool)> = o
        .conditioning
        .iter()
        .map(|r| (r.grid, r.occluder))
        .collect();
    groups.dedup();
    for (grid, occ) in groups {
        let k = |c: &str| {
            o.conditioning
                .iter()
                .find(|r| r.grid == grid && r.occluder == occ && r.config == c)
                .map(|r| r.kappa)
                .unwrap_or(f64::NAN)
        };
        let (a, b, c, d) = (k("nopol"), k("rotating"), k("crossed"), k("multi"));
        let trend = if a > b && b > c && c > d {
            "holds"
        } else {
            "does not hold"
        };
        let _ = writeln!(
            md,
            "| {grid}x{grid} | {} | {} | {} | {} | {} | {trend} |",
            if occ { "yes" } else { "no" },
            fmt_kappa(a),
            fmt_kappa(b),
            fmt_kappa(c),
            fmt_kappa(d)
        );
    }
    md.push_str("\n![conditioning](conditioning.png)\n\n## Roughness (the paper's Fig. 6)\n\n| config | occluder | ");
    let alphas = bench::ROUGHNESS;
    md.push_str(
        &alphas
            .iter()
            .map(|a| format!("α = {a}"))
            .collect::<Vec<_>>()
            .join(" | "),
    );
    md.push_str(" |\n|---|---|");
    md.push_str(&"---|".repeat(alphas.len()));
    md.push('\n');
    for occ in [false, true] {
        for config in ["nopol", "crossed", "multi"] {
            let ks: Vec<String> = alphas
                .iter()
                .map(|a| {
                    o.roughness
                        .iter()
                        .find(|r| r.occluder == occ && r.config == config && r.roughness == *a)
                        .map(|r| fmt_kappa(r.kappa))
                        .unwrap_or_default()
                })
                .collect();
            let _ = writeln!(
                md,
                "| {config} | {} | {} |",
                if occ { "yes" } else { "no" },
                ks.join(" | ")
            );
        }
        let ratio: Vec<String> = alphas
            .iter()
            .map(|a| {
                let k = |c: &str| {
                    o.roughness
                        .iter()
                        .find(|r| r.occluder == occ && r.config == c && r.roughness == *a)
                        .map(|r| r.kappa)
                        .unwrap_or(f64::NAN)
                };
                let (a, b) = (k("nopol"), k("crossed"));
                if a.is_infinite() && b.is_infinite() {
                    "n/a".to_string()
                } else {
                    format!("{:.2}", a / b)
                }
            })
            .collect();
        let _ = writeln!(
            md,
            "| improvement nopol/crossed | {} | {} |",
            if occ { "yes" } else { "no" },
            ratio.join(" | ")
        );
    }
    let _ = writeln!(md, "\n`inf`: `T` is rank-deficient at that roughness (no line point on the chart).\n\n![roughness](roughness.png)\n");
    md.push_str("## Stability where methods fail (ADMM-TV, letter pattern, 8x8 scene)\n\n| case | kappa | mean SNR | converged | iterations | primal / dual residual | PSNR dB | finite | warnings |\n|---|---|---|---|---|---|---|---|---|\n");
    for r in &o.stability {
        let _ = writeln!(
            md,
            "| {} | {} | {:.1} | {} | {} | {:.1e} / {:.1e} | {:.2} | {} | {} |",
            r.case,
            fmt_kappa(r.kappa),
            r.snr,
            if r.converged { "yes" } else { "no" },
            r.iterations,
            r.primal_residual,
            r.dual_residual,
            r.psnr_db,
            if r.finite { "yes" } else { "NO" },
            if r.warnings.is_empty() {
                "none".to_string()
            } else {
                r.warnings.join("; ")
            }
        );
    }
    let _ = writeln!(
        md,
        "\n## Transport accuracy against build time\n\nError of T against uniform m = {} (relative Frobenius), median build time of 3 runs.\n\n![sampling](sampling.png)\n\n| case | method | m or tol | seconds | samples per element | error | estimated |\n|---|---|---|---|---|---|---|",
        o.sampling_reference_m
    );
    for r in &o.sampling {
        let _ = writeln!(
            md,
            "| {} | {} | {} | {:.4} | {:.1} | {:.2e} | {} |",
            r.case,
            r.method,
            r.setting,
            r.seconds,
            r.samples_per_element,
            r.error,
            r.estimated_error
                .map(|e| format!("{e:.2e}"))
                .unwrap_or_else(|| "-".into())
        );
    }
    md.push_str("\n## Active NLOS (the paper's appendix, time-resolved T)\n\nLaser and detector at pose A, spot at the wall centre, 1 cm path-length bins (33 ps); voxels on the scene grid. The passive column is the steady-state T of the same scene.\n\n![active](active.png)\n\n| sweep | config | voxel grid | alpha | bins | kappa active | kappa passive |\n|---|---|---|---|---|---|---|\n");
    for r in &o.active {
        let _ = writeln!(
            md,
            "| {} | {} | {} | {} | {} | {} | {} |",
            r.sweep,
            r.config,
            r.grid,
            r.roughness,
            r.bins,
            fmt_kappa(r.kappa_active),
            fmt_kappa(r.kappa_passive)
        );
    }
    md.push_str(&peer_markdown(&o.peer));
    md.push_str("\n## Speed against accuracy\n\n");
    md.push_str(&speed::markdown(&o.speed, o.speed_seeds));
    let _ = writeln!(
        md,
        "\nRun time: {:.1} s{}.",
        o.seconds,
        if o.quick { " (--quick: 3x3 grids)" } else { "" }
    );
    md
}

fn peer_markdown(p: &PeerReport) -> String {
    let mut md = format!(
        "\n## Against a NumPy peer\n\nScene {0}, wall {1}x{1}, scene {2}x{2} (T {3} x {4}); `benches/peer/peer.py`, same scene file and measurement.\n\n",
        p.scene,
        p.wall,
        p.scene_grid,
        p.wall * p.wall * 2,
        p.scene_grid * p.scene_grid
    );
    if let Some(why) = &p.skipped {
        let _ = writeln!(md, "Peer skipped: {why}. polnlos alone: build {:.3} s, T^T T {:.3} s, factorization + {} ADMM iterations {:.3} s.", p.polnlos_build_seconds, p.polnlos_gram_seconds, peer::ITERATIONS, p.polnlos_solve_seconds);
        return md;
    }
    let _ = writeln!(
        md,
        "| step | polnlos s | NumPy {} s | speed-up |\n|---|---|---|---|\n| build T | {:.3} | {:.3} | {:.1}x |\n| T^T T (dense product; NumPy: OpenBLAS syrk) | {:.3} | {:.3} | {:.1}x |\n| factorization + {} ADMM iterations | {:.3} | {:.3} | {:.1}x |\n\nSame T: max |T_numpy - T| / max |T| = {:.1e}. Same recovery: max |l_numpy - l| = {:.1e}; PSNR {:.2} dB (polnlos) and {:.2} dB (NumPy).",
        p.numpy.as_deref().unwrap_or("?"),
        p.polnlos_build_seconds,
        p.peer_build_seconds,
        p.build_speedup,
        p.polnlos_gram_seconds,
        p.peer_gram_seconds,
        p.gram_speedup,
        peer::ITERATIONS,
        p.polnlos_solve_seconds,
        p.peer_solve_seconds,
        p.solve_speedup,
        p.t_difference,
        p.recovery_difference,
        p.polnlos_psnr_db,
        p.peer_psnr_db
    );
    md
}

/// Writes `DIR/NAME.png` and `DIR/NAME.svg`.
fn write_chart(dir: &std::path::Path, name: &str, c: &charts::Chart) -> anyhow::Result<()> {
    write_atomic(&dir.join(format!("{name}.png")), &c.png)?;
    write_atomic(&dir.join(format!("{name}.svg")), c.svg.as_bytes())?;
    Ok(())
}

pub fn run(a: Args) -> anyhow::Result<()> {
    super::out_dir(&a.out)?;
    let start = std::time::Instant::now();
    let grids: &[usize] = if a.quick { &[3] } else { &[3, 8] };
    let (active_grids, active_rough): (&[usize], usize) = if a.quick {
        (&[2, 3], 3)
    } else {
        (&[2, 3, 4, 6, 8], 6)
    };
    let (sizes, seeds, budgets): (&[speed::Size], u64, &[usize]) = if a.quick {
        (&speed::SIZES[..1], 1, &[10, 50, 200])
    } else {
        (&speed::SIZES, 3, &speed::BUDGETS)
    };
    let pb = super::progress::bar(
        bench::conditioning_len(grids)
            + bench::roughness_len()
            + CASES
            + sizes.len() * seeds as usize
            + 2
            + active::active_len(active_grids)
            + 1,
        "bench",
    );
    let conditioning = bench::conditioning_table(grids, &mut || pb.inc(1))?;
    let roughness = bench::roughness_sweep(*grids.last().unwrap_or(&3), &mut || pb.inc(1))?;
    let stability = stability_table(&mut || pb.inc(1))?;
    let speed_runs = speed::speed_sweep(sizes, seeds, budgets, &mut || pb.inc(1))?;
    let (sgrid, reference_m) = if a.quick { (3, 12) } else { (8, 24) };
    let sampling = sampling::sampling_sweep(sgrid, reference_m, &mut || pb.inc(1))?;
    let active = active::active_sweep(active_grids, active_rough, &mut || pb.inc(1))?;
    let (pw, ps) = if a.quick { (32, 8) } else { (64, 32) };
    let work = std::env::temp_dir().join(format!("polnlos-peer-{}", std::process::id()));
    let peer = peer::compare("brewster-multi", pw, ps, &work);
    let _ = std::fs::remove_dir_all(&work);
    let peer = peer?;
    pb.inc(1);
    pb.finish_and_clear();
    let out = Output {
        quick: a.quick,
        conditioning,
        roughness,
        stability,
        speed_seeds: seeds,
        speed: speed::summarize(&speed_runs),
        speed_runs,
        sampling_reference_m: reference_m,
        sampling,
        active,
        peer,
        seconds: start.elapsed().as_secs_f64(),
    };
    let c = active::chart(&out.active)?;
    write_chart(&a.out, "active", &c)?;
    let c = sampling::chart(&out.sampling, reference_m)?;
    write_chart(&a.out, "sampling", &c)?;
    for (name, c) in speed::charts(&out.speed)? {
        write_chart(&a.out, &name, &c)?;
    }

    let mut groups: Vec<(String, Vec<f64>)> = Vec::new();
    for r in &out.conditioning {
        let label = format!(
            "{}x{}{}",
            r.grid,
            r.grid,
            if r.occluder { " + occluder" } else { "" }
        );
        match groups.last_mut() {
            Some((l, v)) if *l == label => v.push(r.kappa),
            _ => groups.push((label, vec![r.kappa])),
        }
    }
    let c = charts::log_bars(
        "Condition number of T (Table 1)",
        "kappa(T)",
        &bench::CONFIGS,
        &groups,
    )?;
    write_chart(&a.out, "conditioning", &c)?;

    let mut series = Vec::new();
    for occ in [false, true] {
        for config in ["nopol", "crossed", "multi"] {
            series.push(charts::Series {
                thin: occ,
                ..charts::Series::line(
                    format!("{config}{}", if occ { " + occluder" } else { "" }),
                    series.len(),
                    out.roughness
                        .iter()
                        .filter(|r| r.occluder == occ && r.config == config)
                        .map(|r| (r.roughness, r.kappa))
                        .collect(),
                )
            });
        }
    }
    let grid = out.roughness.first().map(|r| r.grid).unwrap_or(3);
    let c = charts::log_lines(
        &format!("kappa(T) against wall roughness ({grid}x{grid} scene)"),
        "GGX roughness alpha",
        "kappa(T)",
        series,
    )?;
    write_chart(&a.out, "roughness", &c)?;

    json::write(&a.out.join("bench.json"), &out)?;
    write_atomic(&a.out.join("bench.md"), markdown(&out).as_bytes())?;
    eprintln!(
        "bench written to {} in {:.1} s",
        a.out.display(),
        out.seconds
    );
    Ok(())
}
