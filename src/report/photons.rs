//! Every photon counts (issue 26): the PSNR of the crossed bench against
//! the total exposure, measured the revision-2 way (one bilinear sample of
//! the frame at each wall element's centre, centre-sampled rows) and the
//! revision-3 way (the footprint-weighted mean of every pixel of the
//! element, pixel rows; MODEL.md "From camera frames to i").
//!
//! Both read the same camera frames: polnlos's camera-frame simulation
//! (each pixel at its own wall point) with per-pixel shot and read noise.
//! The question the chart answers: how much more exposure the old path
//! needs for the same image.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

use super::charts::{panels, Chart, ChartError, Marker, Plot, Series};
use super::BenchError;
use crate::measure::{assemble, CaptureFrames};
use crate::scene::{Frame, FrameGeometry, Scene, WallSampling};
use crate::simulate::camera::expose;
use crate::simulate::patterns::Pattern;
use crate::simulate::unpolarized_peak;
use crate::solve::gram::Normal;
use crate::solve::lambda::NoiseLevel;
use crate::solve::metrics::compare;
use crate::solve::Solver;
use crate::solve::{condition, reconstruct, AdmmSettings, SolveRequest};
use crate::solve::{reconstruct::Context, AUTO_MAX_ITER};
use crate::transport::{build, MemoryBudget, Transport};

/// Photo-electrons at the brightest unpolarized pixel, per step a factor of
/// 5 (so that two steps are the 25x of the issue).
pub const PHOTONS: [f64; 6] = [4e2, 2e3, 1e4, 5e4, 2.5e5, 1.25e6];

/// Read noise per pixel, electrons RMS.
pub const READ_NOISE: f64 = 5.0;

/// Noise seeds averaged per point.
pub(crate) const SEEDS: u64 = 4;

/// Patterns of the comparison.
pub(crate) const PATTERNS: [Pattern; 3] = [Pattern::Disk, Pattern::Bars, Pattern::Letter];

/// Steps [`photons_report`] reports (one per pattern).
pub const STEPS: usize = PATTERNS.len();

/// One pattern at one exposure.
#[derive(Debug, Clone, Serialize)]
pub struct PhotonsRow {
    /// Pattern name.
    pub pattern: String,
    /// Electrons at the brightest unpolarized pixel.
    pub photons: f64,
    /// PSNR of the revision-2 path (mean over the seeds), dB.
    pub centre_sample_db: f64,
    /// PSNR of the revision-3 path, dB.
    pub pixel_means_db: f64,
}

/// The report.
#[derive(Debug, Clone, Serialize)]
pub struct Photons {
    /// Scene.
    pub scene: String,
    /// Read noise, electrons.
    pub read_noise: f64,
    /// Seeds per point.
    pub seeds: u64,
    /// One per pattern and exposure.
    pub rows: Vec<PhotonsRow>,
}

/// The measurement of one frame the revision-2 way: at each element's
/// centre `H(u, v)` the bilinear sample of `frame`, and its variance from
/// the pixels' (`sum w^2 var_p`); `None` when a centre falls off the frame.
fn centre_samples(
    scene: &Scene,
    frame: &Frame,
    variance: &Frame,
    scale: f64,
) -> Option<(Vec<f64>, Vec<f64>)> {
    let wall = &scene.wall().plane;
    let h = scene.poses()[0].homography?;
    let (mut i, mut var) = (Vec::new(), Vec::new());
    for j in 0..wall.grid.count() {
        let (iu, iv) = wall.grid.coords(j);
        let (u, v) = wall.local(iu, iv, 0, 0);
        let (x, y) = h.apply(u, v)?;
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = (x - x0, y - y0);
        let (x0, y0) = (x0 as i64, y0 as i64);
        let (mut s, mut s2) = (0.0, 0.0);
        for (dx, dy, w) in [
            (0, 0, (1.0 - fx) * (1.0 - fy)),
            (1, 0, fx * (1.0 - fy)),
            (0, 1, (1.0 - fx) * fy),
            (1, 1, fx * fy),
        ] {
            let (px, py) = (x0 + dx, y0 + dy);
            if px < 0 || py < 0 || px as usize >= frame.width || py as usize >= frame.height {
                return None;
            }
            let p = py as usize * frame.width + px as usize;
            s += w * f64::from(frame.pixels[p]);
            s2 += w * w * f64::from(variance.pixels[p]);
        }
        i.push(s / scale);
        var.push(s2 / (scale * scale));
    }
    Some((i, var))
}

/// PSNR of `i` (variance `var`) reconstructed with `t` against `truth`.
fn psnr(t: &Transport, i: &[f64], var: Vec<f64>, truth: &[f64]) -> Result<f64, BenchError> {
    Ok(auto(t, i, var, truth)?.0)
}

/// PSNR and λ (relative to `mean(diag(T^T T))`) of the automatic λ.
fn auto(t: &Transport, i: &[f64], var: Vec<f64>, truth: &[f64]) -> Result<(f64, f64), BenchError> {
    let cond = condition(t)?;
    let solved = reconstruct(
        t,
        i,
        Some(NoiseLevel::measured(var)),
        &cond,
        &SolveRequest::default(),
        Context::default(),
    )?;
    let lambda = solved
        .report
        .lambda_choice
        .as_ref()
        .map_or(f64::NAN, |c| c.lambda / t.mean_column_norm2());
    Ok((
        compare(t.scene_grid(), truth, &solved.image).psnr_db,
        lambda,
    ))
}

/// The crossed bench both ways: the scenes and transports of the two paths.
struct Bench {
    name: String,
    centre: Scene,
    pixels: Scene,
    t_centre: Transport,
    t_pixels: Transport,
}

/// One measurement, `(i, variance)`.
type Measurement = (Vec<f64>, Vec<f64>);

impl Bench {
    fn new(name: &str, budget: MemoryBudget) -> Result<Self, BenchError> {
        let base = super::builtin(name)?;
        let centre = super::edit(name, base.clone(), |s| {
            s.wall.sampling = WallSampling::Uniform;
            s.wall.plane.supersample = 1;
        })?;
        let pixels = super::edit(name, base, |s| s.wall.sampling = WallSampling::Pixels)?;
        let (t_centre, t_pixels) = (build(&centre, budget)?, build(&pixels, budget)?);
        Ok(Self {
            name: name.into(),
            centre,
            pixels,
            t_centre,
            t_pixels,
        })
    }

    /// The truth of `pattern`, its unpolarized peak and its clean frame.
    fn frame(
        &self,
        pattern: Pattern,
        budget: MemoryBudget,
    ) -> Result<(Vec<f64>, f64, Frame), BenchError> {
        let truth = pattern.render(self.pixels.hidden().plane.grid);
        let peak = unpolarized_peak(&self.pixels, &self.t_pixels, &truth, budget)?;
        let clean =
            crate::simulate::camera::render(&self.pixels, &truth, FrameGeometry::plain(512, 512))
                .into_iter()
                .find_map(|(_, f)| f)
                .ok_or_else(|| BenchError::Scene {
                    name: self.name.clone(),
                    reason: "its pose has no homography to render frames through".into(),
                })?;
        Ok((truth, peak, clean))
    }

    /// The frame `clean` exposed at `scale` with noise seed `seed`, measured
    /// the revision-2 way and the revision-3 way.
    fn measure(
        &self,
        clean: &Frame,
        scale: f64,
        seed: u64,
    ) -> Result<(Measurement, Measurement), BenchError> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let (mean, variance) = expose(clean, scale, READ_NOISE, &mut rng);
        let old = centre_samples(&self.centre, &mean, &variance, scale).ok_or_else(|| {
            BenchError::Scene {
                name: self.name.clone(),
                reason: "a wall element's centre is imaged off the frame".into(),
            }
        })?;
        let capture = CaptureFrames::exposure(
            "frame".into(),
            self.pixels.poses()[0].name.clone(),
            vec![self.t_pixels.blocks()[0].channel],
            (mean, variance),
            scale,
        );
        let m = assemble(&self.pixels, self.t_pixels.blocks(), &[capture]).map_err(|e| {
            BenchError::Scene {
                name: self.name.clone(),
                reason: e.to_string(),
            }
        })?;
        Ok((old, (m.i, m.variance.unwrap_or_default())))
    }
}

/// The comparison on the built-in scene `name` (one pose with a
/// homography), calling `step()` once per pattern.
pub(crate) fn photons_report(
    name: &str,
    budget: MemoryBudget,
    step: &mut dyn FnMut(),
) -> Result<Photons, BenchError> {
    let bench = Bench::new(name, budget)?;
    let mut rows = Vec::new();
    for pattern in PATTERNS {
        let (truth, peak, clean) = bench.frame(pattern, budget)?;
        for photons in PHOTONS {
            let scale = photons / peak.max(1e-300);
            let (mut old, mut new) = (0.0, 0.0);
            for seed in 0..SEEDS {
                let ((i, var), (i_new, var_new)) = bench.measure(&clean, scale, seed)?;
                old += psnr(&bench.t_centre, &i, var, &truth)?;
                new += psnr(&bench.t_pixels, &i_new, var_new, &truth)?;
            }
            rows.push(PhotonsRow {
                pattern: pattern.name().into(),
                photons,
                centre_sample_db: old / SEEDS as f64,
                pixel_means_db: new / SEEDS as f64,
            });
        }
        step();
    }
    Ok(Photons {
        scene: name.into(),
        read_noise: READ_NOISE,
        seeds: SEEDS,
        rows,
    })
}

/// One path at one exposure: the automatic λ against a grid of λs chosen
/// with the truth ([`best_lambda`]). λs are relative to `mean(diag(T^T T))`.
#[derive(Debug, Clone, Serialize)]
pub struct BestLambdaRow {
    /// Pattern name.
    pub pattern: String,
    /// Electrons at the brightest unpolarized pixel.
    pub photons: f64,
    /// "revision 2" (centre samples) or "revision 3" (pixel means).
    pub path: &'static str,
    /// PSNR with the automatic λ, mean over the seeds (as [`photons_report`]), dB.
    pub auto_db: f64,
    /// The automatic λs, geometric mean over the seeds.
    pub auto_lambda: f64,
    /// Mean over the seeds of each seed's best PSNR on the grid, dB.
    pub best_per_seed_db: f64,
    /// The best seed-mean PSNR at one λ of the grid, dB.
    pub best_common_db: f64,
    /// That λ.
    pub best_common_lambda: f64,
    /// Whether that λ is the grid's first or last.
    pub at_grid_edge: bool,
}

/// The automatic λ against the best λ of the grid `log10(λ / mean(diag(T^T
/// T)))` from `lo` to `hi` in `steps` equal steps, on the frames of
/// `photons_report` (same exposures, seeds and measurements) for
/// `pattern` at each of `photons`, both paths. Each grid λ is a cold
/// ADMM-TV solve with the automatic λ's iteration cap.
pub fn best_lambda(
    name: &str,
    budget: MemoryBudget,
    pattern: Pattern,
    photons: &[f64],
    (lo, hi, steps): (f64, f64, usize),
) -> Result<Vec<BestLambdaRow>, BenchError> {
    let bench = Bench::new(name, budget)?;
    let (truth, peak, clean) = bench.frame(pattern, budget)?;
    let grid: Vec<f64> = (0..=steps)
        .map(|k| 10f64.powf(lo + (hi - lo) * k as f64 / steps.max(1) as f64))
        .collect();
    let mut rows = Vec::new();
    for &p in photons {
        let scale = p / peak.max(1e-300);
        // Per path: sums of the automatic PSNR and log λ, of each seed's
        // best, and of the PSNR at every grid λ.
        let mut sums = [
            (0.0, 0.0, 0.0, vec![0.0; grid.len()]),
            (0.0, 0.0, 0.0, vec![0.0; grid.len()]),
        ];
        for seed in 0..SEEDS {
            let (old, new) = bench.measure(&clean, scale, seed)?;
            for (k, (t, (i, var))) in [(&bench.t_centre, old), (&bench.t_pixels, new)]
                .into_iter()
                .enumerate()
            {
                let (db, lambda) = auto(t, &i, var, &truth)?;
                let unit = t.mean_column_norm2();
                let normal = Normal::new(t.as_mat(), &i);
                let mut best = f64::NEG_INFINITY;
                for (g, &rel) in grid.iter().enumerate() {
                    let settings = AdmmSettings {
                        lambda: Some(rel * unit),
                        max_iter: AUTO_MAX_ITER,
                        ..Default::default()
                    };
                    let image = Solver::ADMM_TV
                        .run(&settings.problem(t, &i, &normal))?
                        .image;
                    let psnr = compare(t.scene_grid(), &truth, &image).psnr_db;
                    best = best.max(psnr);
                    sums[k].3[g] += psnr;
                }
                sums[k].0 += db;
                sums[k].1 += lambda.ln();
                sums[k].2 += best;
            }
        }
        let n = SEEDS as f64;
        for (k, (db, ln_lambda, best, at)) in sums.into_iter().enumerate() {
            let (g, common) = at
                .iter()
                .enumerate()
                .max_by(|a, b| a.1.total_cmp(b.1))
                .map_or((0, f64::NAN), |(g, s)| (g, s / n));
            rows.push(BestLambdaRow {
                pattern: pattern.name().into(),
                photons: p,
                path: ["revision 2", "revision 3"][k],
                auto_db: db / n,
                auto_lambda: (ln_lambda / n).exp(),
                best_per_seed_db: best / n,
                best_common_db: common,
                best_common_lambda: grid[g],
                at_grid_edge: g == 0 || g + 1 == grid.len(),
            });
        }
    }
    Ok(rows)
}

/// PSNR against photons, one panel per pattern, both paths.
pub fn chart(r: &Photons) -> Result<Chart, ChartError> {
    let plots: Vec<Plot> = PATTERNS
        .iter()
        .map(|p| {
            let rows: Vec<&PhotonsRow> = r.rows.iter().filter(|x| x.pattern == p.name()).collect();
            Plot {
                title: p.name().into(),
                x_label: "electrons at the unpolarized peak (total exposure)".into(),
                y_label: "PSNR (dB)".into(),
                x_log: true,
                y_log: false,
                x_integer: false,
                series: vec![
                    Series::line(
                        "revision 3: every pixel",
                        0,
                        rows.iter().map(|x| (x.photons, x.pixel_means_db)).collect(),
                    ),
                    Series {
                        marker: Marker::Cross,
                        thin: true,
                        ..Series::line(
                            "revision 2: one centre sample",
                            1,
                            rows.iter()
                                .map(|x| (x.photons, x.centre_sample_db))
                                .collect(),
                        )
                    },
                ],
            }
        })
        .collect();
    panels(&plots)
}

impl super::Report for Photons {
    fn json(&self) -> serde_json::Map<String, serde_json::Value> {
        super::shape::fields(vec![("photons", serde_json::to_value(self))])
    }

    fn charts(&self) -> Result<Vec<(String, Chart)>, ChartError> {
        Ok(vec![("photons".into(), chart(self)?)])
    }

    fn markdown(&self) -> String {
        use std::fmt::Write as _;
        let mut md = String::from("## Every photon counts: PSNR against exposure (issue 26)\n\n");
        let _ = writeln!(
            md,
            "`{}` (crossed polarizer, 32x32 wall, 8x8 scene): the same camera frames (polnlos's simulation, per-pixel shot noise and {} e- read noise) measured by one bilinear sample at each element's centre with centre-sampled rows (revision 2), and by the footprint-weighted mean of all of the element's pixels with pixel rows (revision 3); automatic λ, {} seeds. The last column compares revision 3 with revision 2 given 25x the exposure.\n\n![photons](photons.png)\n",
            self.scene, self.read_noise, self.seeds
        );
        md.push_str("| pattern | e- at the peak | revision 2 | revision 3 | revision 2 at 25x |\n|---|---|---|---|---|\n");
        for r in &self.rows {
            let at25 = self
                .rows
                .iter()
                .find(|x| x.pattern == r.pattern && (x.photons / r.photons - 25.0).abs() < 1e-6)
                .map_or("-".to_string(), |x| format!("{:.2} dB", x.centre_sample_db));
            let _ = writeln!(
                md,
                "| {} | {:.1e} | {:.2} dB | {:.2} dB | {at25} |",
                r.pattern, r.photons, r.centre_sample_db, r.pixel_means_db
            );
        }
        md.push('\n');
        md
    }
}
