//! `polnlos reconstruct --photo`: a photograph with unknown gain and ambient
//! light, every colour channel through one `T` (docs/realphoto.md).

use std::time::Instant;

use polnlos::files::truth::TopFirst;
use polnlos::files::{image, json, npy};
use polnlos::solve::photo::{photo_transport, PhotoReport, PhotoSettings};
use polnlos::solve::radiometry::RadiometryChoice;

use super::reconstruct::{Args, LambdaArg};
use polnlos::transport::MemoryBudget;

/// `reconstruct --photo`: `a` as `reconstruct` parsed it (clap refuses the
/// options a photo does not take).
pub fn run(a: Args, budget: MemoryBudget) -> anyhow::Result<()> {
    let start = Instant::now();
    let scene = super::load_scene(&a.scene)?;
    let grid = scene.hidden().plane.grid;
    let rows = scene.rows();
    let channels = super::read_channels(&a.measurement, rows)?;
    let truth = a
        .truth
        .as_ref()
        .map(|p| truth_channels(p, grid, channels.len()))
        .transpose()?;
    super::out_dir(&a.out)?;
    let pb = super::progress::bar(scene.cols(), "building T");
    let t0 = Instant::now();
    let cached = super::build_transport(&scene, budget, &|done| pb.set_position(done as u64))?;
    pb.finish_and_clear();
    let d = PhotoSettings::default();
    let settings = PhotoSettings {
        data_term: a.data_term,
        lambda: a.lambda.and_then(LambdaArg::value),
        iterations: a.solve.max_iter.unwrap_or(d.iterations),
        ..d
    };
    // The file left `shadows` out and the penumbra is not negligible: the
    // photo says whether point or area shadows explain it better.
    let chosen = photo_transport(
        &scene,
        cached,
        || -> anyhow::Result<_> {
            let area = scene.with_area_shadows()?;
            let pb = super::progress::bar(scene.cols(), "building T (area shadows)");
            let cached =
                super::build_transport(&area, budget, &|done| pb.set_position(done as u64))?;
            pb.finish_and_clear();
            Ok(cached)
        },
        &channels,
        &settings,
    )?;
    let shadows = chosen.shadows.clone();
    eprintln!("note: {} shadows: {}", shadows.model.name(), shadows.reason);
    let transport_seconds = t0.elapsed().as_secs_f64();
    let result = chosen.reconstruct(&channels, truth.as_deref(), &settings)?;
    let transport_cache = chosen.t.source;
    let c = result.channels.len();
    let n = grid.count();
    let interleave = |f: &dyn Fn(usize, usize) -> f64| -> Vec<f64> {
        (0..n)
            .flat_map(|k| (0..c).map(move |ch| (k, ch)))
            .map(|(k, ch)| f(k, ch))
            .collect()
    };
    // Written as people look at them: the plane's top (+v) in the first row.
    let image = grid.to_top_first(&interleave(&|k, ch| result.channels[ch].image[k]), c);
    let x = grid.to_top_first(&interleave(&|k, ch| result.channels[ch].x[k]), c);
    npy::write_f64(&a.out.join("recovered.npy"), &[grid.nv, grid.nu, c], &image)?;
    npy::write_f64(&a.out.join("fitted.npy"), &[grid.nv, grid.nu, c], &x)?;
    if c == 3 {
        let rgb: Vec<u8> = image
            .iter()
            .map(|v| (v.clamp(0.0, 1.0) * 255.0).round() as u8)
            .collect();
        image::write_png_rgb8(&a.out.join("recovered.png"), grid.nu, grid.nv, &rgb)?;
    } else {
        let first = grid.to_top_first(&result.channels[0].image, 1);
        image::write_png16(
            &a.out.join("recovered.png"),
            grid.nu,
            grid.nv,
            &image::unit_to_u16(&first),
        )?;
    }
    let report = PhotoReport {
        scene: super::scene_name(&a.scene),
        radiometry: RadiometryChoice::photo_flag(),
        transport_seconds,
        transport_cache: Some(transport_cache),
        shadows: Some(shadows),
        total_seconds: start.elapsed().as_secs_f64(),
        result,
    };
    json::write(&a.out.join("report.json"), &report)?;
    let result = &report.result;
    for w in &result.warnings {
        eprintln!("warning: {w}");
    }
    for (k, ch) in result.channels.iter().enumerate() {
        println!(
            "channel {k}: gain {:.4e} (± {:.1e}), background {} (± {}), lambda {:.3e}, residual rms {:.3e}",
            ch.gain,
            ch.gain_sd,
            fmt(&ch.background),
            fmt(&ch.background_sd),
            ch.lambda,
            ch.residual_sd
        );
    }
    if let Some(m) = &result.metrics {
        println!(
            "PSNR {:.2} dB ({:.2} dB after each channel's affine fit), ZNCC {:.4}, SSIM {:.4}",
            m.psnr_db, m.psnr_affine_db, m.zncc, m.ssim
        );
    }
    println!(
        "recovered {}x{} scene, {c} channel(s), into {} in {:.2} s (T {:.2} s)",
        grid.nu,
        grid.nv,
        a.out.display(),
        report.total_seconds,
        transport_seconds
    );
    Ok(())
}

fn fmt(v: &[f64]) -> String {
    v.iter()
        .map(|x| format!("{x:.4e}"))
        .collect::<Vec<_>>()
        .join(", ")
}

/// The truth as channels on `grid`: an image top row first ([`TopFirst`]),
/// grey (every channel alike) or one value a channel.
fn truth_channels(
    path: &std::path::Path,
    grid: polnlos::scene::Grid,
    c: usize,
) -> anyhow::Result<Vec<Vec<f64>>> {
    Ok(TopFirst::read(path)?.on_grid(grid, c, &path.display().to_string())?)
}
