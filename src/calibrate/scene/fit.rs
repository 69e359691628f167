//! The fit's procedure: a lattice over the occluders' translation and a
//! descent on a coarse wall, then a descent on the full wall, and the
//! uncertainties at its end.
//!
//! Why apart from the types: the types are the fit's contract with its
//! callers; this is how it gets there.

use std::time::Instant;

use super::*;
use crate::calibrate::occluder::{search as lattice, shadow_pitch, SearchOptions};

/// The residuals of every shot at the placement `x` of `free` on `level`
/// (a scene with its photos): one `T` build.
struct Residuals<'a> {
    free: &'a [Freedom],
    selected: &'a [usize],
    pivot: Vec3,
    budget: MemoryBudget,
    stop: Stop<'a>,
    builds: usize,
    /// Told after each build.
    progress: &'a dyn Fn(FitProgress),
    /// What the search may spend ([`SceneFitOptions::max_evaluations`]).
    max_builds: usize,
}

impl Residuals<'_> {
    fn at(
        &mut self,
        scene: &Scene,
        shots: &[Shot],
        photos: &[Vec<Vec<f64>>],
        x: &[f64],
    ) -> Result<Vec<f64>, SceneFitError> {
        if self.stop.raised() {
            return Err(SceneFitError::Stopped);
        }
        let at = placement(self.free, x);
        let moved = scene.clone().edit(|p| {
            p.hidden.plane.supersample = 1;
            p.hidden.shadows = ShadowModel::Area;
            place::place(p, self.selected, self.pivot, &at);
        })?;
        let t =
            build_with_progress(&moved, self.budget, &|_| {}, self.stop).map_err(|e| match e {
                TransportError::Stopped { .. } => SceneFitError::Stopped,
                e => SceneFitError::Transport(e),
            })?;
        self.builds += 1;
        (self.progress)(FitProgress {
            builds: self.builds,
            max_builds: self.max_builds,
        });
        let mut out = Vec::new();
        for (shot, channels) in shots.iter().zip(photos) {
            for r in difference_residuals(&t, channels, shot.known.as_deref())? {
                out.extend(r);
            }
        }
        Ok(out)
    }
}

/// The placement of `free` at `x`.
fn placement(free: &[Freedom], x: &[f64]) -> Placement {
    let mut p = Placement::default();
    for (f, v) in free.iter().zip(x) {
        p.set(*f, *v);
    }
    p
}

/// Where occluder-x, -y and -z stand in `free`, when all three are free.
fn occluder_axes(free: &[Freedom]) -> Option<[usize; 3]> {
    let at = |f: Freedom| free.iter().position(|g| *g == f);
    Some([
        at(Freedom::OccluderX)?,
        at(Freedom::OccluderY)?,
        at(Freedom::OccluderZ)?,
    ])
}

/// The coarse level's factor: about 40 wall elements on the shorter side.
fn coarse_factor(scene: &Scene, asked: Option<usize>) -> usize {
    let g = scene.wall().plane.grid;
    asked.unwrap_or((g.nu.min(g.nv) / 40).max(1))
}

/// [`SceneFitOptions::fit`].
pub(super) fn fit_scene(
    scene: &Scene,
    shots: &[Shot],
    options: &SceneFitOptions,
    stop: Stop<'_>,
    progress: &dyn Fn(FitProgress),
) -> Result<SceneFit, SceneFitError> {
    let start = Instant::now();
    check_shots(scene, shots)?;
    let free = free_list(scene, options)?;
    let range = [
        positive("range", options.range)?,
        positive("range-deg", options.range_deg)?,
    ];
    positive("tolerance", options.tolerance)?;
    let selected = match scene.occluders().is_empty() {
        true => Vec::new(),
        false => crate::calibrate::occluder::selection(scene, options.selected.as_deref())?,
    };
    let pivot = match selected.is_empty() {
        true => Vec3::zeros(),
        false => place::pivot(scene, &selected),
    };
    let mut fit = Fit {
        scene,
        shots,
        photos: shots.iter().map(|s| s.channels.clone()).collect(),
        options,
        range,
        residuals: Residuals {
            free: &free,
            selected: &selected,
            pivot,
            budget: options.budget,
            stop,
            builds: 0,
            progress,
            max_builds: options.max_evaluations,
        },
    };
    let (x, first) = fit.first_guess()?;
    let (end, fine) = fit.refine(x)?;
    let dof = degrees_of_freedom(scene, shots, free.len());
    let at_end = End {
        x: &end.x,
        cost: end.cost,
        jtj: end.jtj.as_ref(),
        dof,
    };
    let (fitted, mut warnings) = uncertainties(&free, &at_end, options.tolerance, |f| fit.bound(f));
    for &i in &end.on_bound {
        warnings.insert(0, SceneFitWarning::OnBound { freedom: free[i] });
    }
    let evaluations = fit.residuals.builds;
    if end.out_of_evaluations {
        warnings.push(SceneFitWarning::OutOfEvaluations { evaluations });
    }
    Ok(SceneFit {
        placement: placement(&free, &end.x),
        selected: selected.clone(),
        fitted,
        misfit_as_written: fine.misfit_start,
        misfit_fitted: end.cost,
        levels: first.into_iter().chain([fine]).collect(),
        warnings,
        evaluations,
        seconds: start.elapsed().as_secs_f64(),
    })
}

/// One fit's inputs and its residuals.
struct Fit<'a> {
    scene: &'a Scene,
    shots: &'a [Shot],
    photos: Vec<Vec<Vec<f64>>>,
    options: &'a SceneFitOptions,
    /// Largest length (metres) and turn (degrees).
    range: [f64; 2],
    residuals: Residuals<'a>,
}

impl Fit<'_> {
    /// The range of `f`.
    fn bound(&self, f: &Freedom) -> f64 {
        self.range[usize::from(f.angular())]
    }

    /// A descent's settings with a forward-difference step of
    /// `length_step` metres (0.2° for a turn) and `budget` builds.
    fn descent(&self, length_step: f64, budget: usize) -> search::Descent {
        let free = self.residuals.free;
        let each = |length: f64, angle: f64| -> Vec<f64> {
            free.iter()
                .map(|f| if f.angular() { angle } else { length })
                .collect()
        };
        search::Descent {
            lo: free.iter().map(|f| -self.bound(f)).collect(),
            hi: free.iter().map(|f| self.bound(f)).collect(),
            step: each(length_step, 0.2),
            settle: each(length_step / 10.0, 0.02),
            max_evaluations: budget.max(free.len() + 2),
            min_gain: 1e-6,
        }
    }

    /// The first guess: the occluders' translation on a lattice (the
    /// misfit of the shadows' place has several lows a descent can end in),
    /// then a descent of every freedom, both on the coarse wall when there
    /// is one; none of it on a small wall with no occluder freedom.
    fn first_guess(&mut self) -> Result<(Vec<f64>, Option<Level>), SceneFitError> {
        let t0 = Instant::now();
        let free = self.residuals.free;
        let mut x = vec![0.0; free.len()];
        let factor = coarse_factor(self.scene, self.options.coarse);
        let coarse = place::coarse_wall(self.scene, factor, &self.photos)?;
        let (level, photos, factor) = match &coarse {
            Some((s, p)) => (s, p, factor),
            None => (self.scene, &self.photos, 1),
        };
        let budget = self.options.max_evaluations / 2;
        let (mut start_cost, mut end_cost) = (None, f64::NAN);
        if let Some(axes) = occluder_axes(free) {
            let range = self.range[0];
            let pitch = shadow_pitch(level, self.residuals.selected);
            let (shots, residuals) = (self.shots, &mut self.residuals);
            let mut misfit = |d: [f64; 3]| -> Result<f64, SceneFitError> {
                let mut y = vec![0.0; free.len()];
                for (a, i) in axes.iter().enumerate() {
                    y[*i] = d[a];
                }
                let r = residuals.at(level, shots, photos, &y)?;
                Ok(r.iter().map(|v| v * v).sum())
            };
            let found = lattice(
                &mut misfit,
                &SearchOptions {
                    step: (4.0 * pitch).min(range),
                    min_step: pitch.min(range),
                    range,
                    relative_threshold: self.options.tolerance,
                    max_evaluations: budget * 2 / 3,
                    starts: 3,
                },
            )?;
            for (a, i) in axes.iter().enumerate() {
                x[*i] = found.point[a];
            }
            (start_cost, end_cost) = (Some(found.value), found.value);
        }
        if coarse.is_some() {
            let d = self.descent(0.002, budget.saturating_sub(self.residuals.builds));
            let shots = self.shots;
            let residuals = &mut self.residuals;
            let end = search::descend(
                &mut |x: &[f64]| residuals.at(level, shots, photos, x),
                &x,
                &d,
            )?;
            start_cost = Some(start_cost.unwrap_or(end.start_cost));
            end_cost = end.cost;
            x = end.x;
        }
        let level = start_cost.map(|misfit_start| Level {
            factor,
            misfit_start,
            misfit_end: end_cost,
            evaluations: self.residuals.builds,
            end: placement(free, &x),
            seconds: t0.elapsed().as_secs_f64(),
        });
        Ok((x, level))
    }

    /// A descent on the full wall from `x`, and from the file's geometry
    /// again when `x` fits the full wall worse than it; the end is never
    /// worse than the file's geometry, which is evaluated too.
    fn refine(&mut self, x: Vec<f64>) -> Result<(search::Descended, Level), SceneFitError> {
        let t0 = Instant::now();
        let before = self.residuals.builds;
        let n = x.len();
        let (scene, shots) = (self.scene, self.shots);
        let written = vec![0.0; n];
        let misfit_as_written: f64 = self
            .residuals
            .at(scene, shots, &self.photos, &written)?
            .iter()
            .map(|v| v * v)
            .sum();
        let run = |fit: &mut Self, from: &[f64]| {
            let left = fit
                .options
                .max_evaluations
                .saturating_sub(fit.residuals.builds);
            let d = fit.descent(0.001, left);
            let (photos, residuals) = (&fit.photos, &mut fit.residuals);
            search::descend(
                &mut |x: &[f64]| residuals.at(scene, shots, photos, x),
                from,
                &d,
            )
        };
        let mut end = run(self, &x)?;
        if end.start_cost > misfit_as_written && x.iter().any(|v| *v != 0.0) {
            let again = run(self, &written)?;
            if again.cost < end.cost {
                end = again;
            }
        }
        if end.cost > misfit_as_written {
            end = search::Descended {
                x: written,
                cost: misfit_as_written,
                start_cost: misfit_as_written,
                jtj: None,
                out_of_evaluations: end.out_of_evaluations,
                on_bound: Vec::new(),
            };
        }
        if end.jtj.is_none() {
            // The uncertainty needs the curvature at the end: one Jacobian
            // past the budget.
            let d = self.descent(0.001, 0);
            let (photos, residuals) = (&self.photos, &mut self.residuals);
            end.jtj = Some(search::curvature(
                &mut |x: &[f64]| residuals.at(scene, shots, photos, x),
                &end.x,
                &d,
            )?);
        }
        let level = Level {
            factor: 1,
            misfit_start: misfit_as_written,
            misfit_end: end.cost,
            evaluations: self.residuals.builds - before,
            end: placement(self.residuals.free, &end.x),
            seconds: t0.elapsed().as_secs_f64(),
        };
        Ok((end, level))
    }
}

/// Where the fit ended, for its uncertainties.
struct End<'a> {
    x: &'a [f64],
    cost: f64,
    jtj: Option<&'a nalgebra::DMatrix<f64>>,
    /// The residual's degrees of freedom.
    dof: usize,
}

/// Rows of differences less the unknowns: the residual's degrees of freedom.
fn degrees_of_freedom(scene: &Scene, shots: &[Shot], free: usize) -> usize {
    let g = scene.wall().plane.grid;
    let per_channel =
        scene.block_count() * (g.nu.saturating_sub(1) * g.nv + g.nu * g.nv.saturating_sub(1));
    let (mut rows, mut unknowns) = (0, free);
    for s in shots {
        rows += per_channel * s.channels.len();
        unknowns += match s.known {
            Some(_) => s.channels.len(),
            None => scene.cols() * s.channels.len(),
        };
    }
    rows.saturating_sub(unknowns).max(1)
}

/// Each freedom's uncertainty from `J^T J` at the end ([`Fitted`]), and the
/// warnings its covariance gives: freedoms the photos cannot tell apart,
/// and freedoms they do not pin within their range.
fn uncertainties(
    free: &[Freedom],
    end: &End<'_>,
    tolerance: f64,
    bound: impl Fn(&Freedom) -> f64,
) -> (Vec<Fitted>, Vec<SceneFitWarning>) {
    let mut warnings = Vec::new();
    let (x, cost, dof) = (end.x, end.cost, end.dof);
    let Some(a) = end.jtj else {
        warnings.push(SceneFitWarning::NoUncertainty);
        let fitted = free
            .iter()
            .zip(x)
            .map(|(f, v)| Fitted {
                freedom: *f,
                offset: *v,
                uncertainty: f64::INFINITY,
                sd_noise: f64::INFINITY,
            })
            .collect();
        return (fitted, warnings);
    };
    let svd = a.clone().svd(true, true);
    let top = svd.singular_values.max();
    let c = svd
        .pseudo_inverse(top * 1e-12)
        .unwrap_or_else(|_| nalgebra::DMatrix::from_element(a.nrows(), a.ncols(), f64::INFINITY));
    let s2 = cost / dof as f64;
    let fitted: Vec<Fitted> = free
        .iter()
        .zip(x)
        .enumerate()
        .map(|(i, (f, v))| {
            let cii = if c[(i, i)] > 0.0 {
                c[(i, i)]
            } else {
                f64::INFINITY
            };
            Fitted {
                freedom: *f,
                offset: *v,
                uncertainty: (tolerance * cost * cii).sqrt(),
                sd_noise: (s2 * cii).sqrt(),
            }
        })
        .collect();
    for i in 0..free.len() {
        for j in i + 1..free.len() {
            let r = c[(i, j)] / (c[(i, i)] * c[(j, j)]).sqrt();
            if r.abs() > CONFOUNDED {
                warnings.push(SceneFitWarning::Confounded {
                    a: free[i],
                    b: free[j],
                    correlation: r,
                });
            }
        }
    }
    for f in &fitted {
        if f.uncertainty.is_nan() || f.uncertainty >= bound(&f.freedom) {
            warnings.push(SceneFitWarning::Unconstrained { freedom: f.freedom });
        }
    }
    (fitted, warnings)
}
