//! Adaptive wall supersampling: refine only the wall elements whose
//! integrand varies across the element (an occluder's shadow edge, the
//! narrow specular lobe of a glossy wall), until an error estimate meets a
//! tolerance.
//!
//! MODEL.md fixes `T[j,k]` as the mean over an `m x m` grid of sub-samples.
//! Every wall element starts at `m = 1` with an error estimate from the
//! second differences to its neighbours. While the estimated total error
//! `sqrt(sum_j e_j^2)` exceeds `tolerance * ||T||_F`, the elements with the
//! largest `e_j` are rebuilt at `2m` (up to `max_m`), and their estimate
//! becomes the change between the two levels. An element keeps its finer
//! level, so the estimate is conservative (the change bounds the error of
//! the coarser one). Only the refined elements' samples are
//! evaluated, through the same kernel as the uniform build; the scene side
//! keeps the scene file's `supersample`.

use super::build::{blocks_of, build_rows, WallSamples};
use super::{MemoryBudget, Transport, TransportError};
use crate::optics::Vec3;
use crate::scene::{Plane, Scene};
use crate::stop::Stop;

/// What an adaptive build did.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct AdaptiveStats {
    /// Tolerance on the estimated error, relative to `||T||_F`.
    pub tolerance: f64,
    /// Largest sub-sampling per side allowed.
    pub max_m: usize,
    /// Number of wall elements that ended at each level `m = 1, 2, 4, ...`
    /// (`(m, count)`; an element "at m" kept its `m x m` estimate).
    pub elements_at: Vec<(usize, usize)>,
    /// Estimated `||T - T_exact||_F / ||T||_F` at the end.
    pub estimated_error: f64,
    /// Whether the estimate met the tolerance (else `max_m` was reached first).
    pub met: bool,
    /// Wall samples evaluated in all (the uniform build at `m` evaluates `m^2` per element).
    pub samples: usize,
}

/// Why an adaptive build was refused.
fn check(tolerance: f64, max_m: usize) -> Result<(), TransportError> {
    if !(tolerance > 0.0 && tolerance.is_finite()) {
        return Err(TransportError::Parameter {
            name: "tolerance",
            value: tolerance,
            reason: "must be a positive relative error, e.g. 1e-3",
        });
    }
    if !(1..=64).contains(&max_m) {
        return Err(TransportError::Parameter {
            name: "max-m",
            value: max_m as f64,
            reason: "must be from 1 to 64 sub-samples per side",
        });
    }
    Ok(())
}

/// Builds `T` with adaptive wall supersampling (the scene's own wall
/// `supersample` is ignored: refinement starts at the element centres);
/// `T` and each refinement pass must fit `budget`. With `sampling =
/// "pixels"` the rows already average over exactly the element's pixels:
/// that build is returned, nothing refined (`samples` counts the pixels).
pub fn build_adaptive(
    scene: &Scene,
    tolerance: f64,
    max_m: usize,
    budget: MemoryBudget,
) -> Result<(Transport, AdaptiveStats), TransportError> {
    check(tolerance, max_m)?;
    if scene.wall().sampling == crate::scene::WallSampling::Pixels {
        return pixel_build(scene, tolerance, max_m, budget);
    }
    let sampler = Sampler::of(scene, budget);
    let mut build = Refinement::start(&sampler)?;
    let budget2 = tolerance * tolerance * build.norm2;
    loop {
        let total: f64 = build.est.iter().sum();
        if build.norm2 == 0.0 || total <= budget2 {
            break;
        }
        let Some(pick) = pick(&build.est, &build.level, max_m, total, budget2) else {
            break;
        };
        build.refine(&sampler, &pick)?;
    }
    Ok(build.finish(&sampler, tolerance, max_m))
}

/// The `sampling = "pixels"` build, returned as it is with its pixel count.
/// Why: its rows already average over exactly each element's pixels.
fn pixel_build(
    scene: &Scene,
    tolerance: f64,
    max_m: usize,
    budget: MemoryBudget,
) -> Result<(Transport, AdaptiveStats), TransportError> {
    let samples = WallSamples::of_scene(scene, budget)?;
    let t = super::build(scene, budget)?;
    Ok((
        t,
        AdaptiveStats {
            tolerance,
            max_m,
            elements_at: Vec::new(),
            estimated_error: 0.0,
            met: true,
            samples: samples.points.len(),
        },
    ))
}

/// The wall and the shape of `T` an adaptive build samples and fills.
/// Why: the first build and every refinement sample elements the same way.
struct Sampler<'s> {
    scene: &'s Scene,
    budget: MemoryBudget,
    /// The wall plane (its own `supersample` unused).
    plane: &'s Plane,
    /// Wall elements, `plane.grid.count()`.
    n_wall: usize,
    /// Blocks (pose and channel) of `T`'s rows.
    blocks: usize,
    rows: usize,
    cols: usize,
}

impl<'s> Sampler<'s> {
    /// The sampler of `scene`'s wall, each build within `budget`.
    /// Why: reads the scene's shape once for all passes.
    fn of(scene: &'s Scene, budget: MemoryBudget) -> Self {
        let plane = &scene.wall().plane;
        Self {
            scene,
            budget,
            plane,
            n_wall: plane.grid.count(),
            blocks: scene.block_count(),
            rows: scene.rows(),
            cols: scene.cols(),
        }
    }

    /// World positions of the `m x m` sub-samples of each of `elements`, in order.
    /// Why: the same sub-sample positions as MODEL.md's uniform build at `m`.
    fn samples_of(&self, elements: &[usize], m: usize) -> Vec<Vec3> {
        let plane = self.plane;
        let mut p = plane.clone();
        p.supersample = m;
        let mut pts = Vec::with_capacity(elements.len() * m * m);
        for &j in elements {
            let (iu, iv) = plane.grid.coords(j);
            for b in 0..m {
                for a in 0..m {
                    let (u, v) = p.local(iu, iv, a, b);
                    pts.push(p.point(u, v));
                }
            }
        }
        pts
    }

    /// Column-major rows of `T` for `elements` at `m x m` sub-samples, and
    /// the number of samples evaluated.
    /// Why: only these elements' samples go through the uniform build's kernel.
    fn rows_at(&self, elements: &[usize], m: usize) -> Result<(Vec<f64>, usize), TransportError> {
        let pts = self.samples_of(elements, m);
        let count = pts.len();
        let samples = WallSamples::uniform(self.scene, pts, elements.len(), m * m);
        let rows = build_rows(
            self.scene,
            self.budget,
            &samples,
            (&|_| {}, Stop::default()),
        )?;
        Ok((rows, count))
    }
}

/// The elements to refine next: the largest estimates, until the rest of
/// the total fits in half the budget; `None` when no element can be refined.
/// Why: the other half is left for the refined elements' new estimates.
fn pick(
    est: &[f64],
    level: &[usize],
    max_m: usize,
    total: f64,
    budget2: f64,
) -> Option<Vec<usize>> {
    let mut order: Vec<usize> = (0..est.len())
        .filter(|&j| 2 * level[j] <= max_m && est[j] > 0.0)
        .collect();
    if order.is_empty() {
        return None;
    }
    order.sort_by(|&x, &y| est[y].total_cmp(&est[x]));
    let mut rest = total;
    let mut pick: Vec<usize> = Vec::new();
    for j in order {
        if rest <= 0.5 * budget2 {
            break;
        }
        rest -= est[j];
        pick.push(j);
    }
    Some(pick)
}

/// An adaptive build in progress: `T`'s entries, each element's level and
/// squared error estimate, and the samples evaluated so far.
/// Why: each refinement pass updates the four together.
struct Refinement {
    /// Column-major entries of `T`.
    data: Vec<f64>,
    /// `||T||_F^2` of the first build, the scale of the tolerance.
    norm2: f64,
    /// Sub-samples per side of each element.
    level: Vec<usize>,
    /// Squared error estimate of each element.
    est: Vec<f64>,
    samples: usize,
}

impl Refinement {
    /// Every element at `m = 1`, its estimate from the second differences.
    /// Why: one sample per element is the cheapest start that shows where `T` varies.
    fn start(sampler: &Sampler) -> Result<Self, TransportError> {
        let all: Vec<usize> = (0..sampler.n_wall).collect();
        let (data, samples) = sampler.rows_at(&all, 1)?;
        let norm2: f64 = data.iter().map(|v| v * v).sum();
        let est = indicator2(
            &data,
            sampler.rows,
            sampler.cols,
            sampler.blocks,
            sampler.plane.grid,
        );
        Ok(Self {
            data,
            norm2,
            level: vec![1usize; sampler.n_wall],
            est,
            samples,
        })
    }

    /// Rebuilds the elements of `pick` at twice their level, level by level
    /// from the coarsest (an element refined at one level may be again at the next).
    /// Why: a level's elements share one build (the same samples per row).
    fn refine(&mut self, sampler: &Sampler, pick: &[usize]) -> Result<(), TransportError> {
        let mut levels: Vec<usize> = pick.iter().map(|&j| self.level[j]).collect();
        levels.sort_unstable();
        levels.dedup();
        for m in levels {
            let group: Vec<usize> = pick
                .iter()
                .copied()
                .filter(|&j| self.level[j] == m)
                .collect();
            self.refine_group(sampler, &group, m)?;
        }
        Ok(())
    }

    /// Rebuilds `group` (all at level `m`) at `2m`; each one's estimate becomes the change.
    /// Why: the change between the two levels bounds the coarser one's error.
    fn refine_group(
        &mut self,
        sampler: &Sampler,
        group: &[usize],
        m: usize,
    ) -> Result<(), TransportError> {
        let (rows, cols, blocks, n_wall) =
            (sampler.rows, sampler.cols, sampler.blocks, sampler.n_wall);
        let m2 = 2 * m;
        let sub_rows = group.len() * blocks;
        let (finer, count) = sampler.rows_at(group, m2)?;
        self.samples += count;
        let mut change = vec![0.0f64; group.len()];
        for k in 0..cols {
            for b in 0..blocks {
                for (a, &j) in group.iter().enumerate() {
                    let new = finer[k * sub_rows + b * group.len() + a];
                    let slot = &mut self.data[k * rows + b * n_wall + j];
                    change[a] += (new - *slot) * (new - *slot);
                    *slot = new;
                }
            }
        }
        for (a, &j) in group.iter().enumerate() {
            self.level[j] = m2;
            self.est[j] = change[a];
        }
        Ok(())
    }

    /// `T` and the statistics of the finished build.
    /// Why: the estimate reported is the one the refinement stopped on.
    fn finish(self, sampler: &Sampler, tolerance: f64, max_m: usize) -> (Transport, AdaptiveStats) {
        let total: f64 = self.est.iter().sum();
        let estimated_error = if self.norm2 > 0.0 {
            (total / self.norm2).sqrt()
        } else {
            0.0
        };
        let elements_at = elements_at(&self.level);
        let t = Transport::from_col_major(
            sampler.rows,
            sampler.cols,
            self.data,
            blocks_of(sampler.scene),
            sampler.plane.grid,
            sampler.scene.hidden().plane.grid,
        );
        (
            t,
            AdaptiveStats {
                tolerance,
                max_m,
                elements_at,
                estimated_error,
                met: estimated_error <= tolerance,
                samples: self.samples,
            },
        )
    }
}

/// `(m, count)` of the elements at each level `m = 1, 2, 4, ...` up to the finest.
/// Why: [`AdaptiveStats::elements_at`] lists every level, empty ones too.
fn elements_at(level: &[usize]) -> Vec<(usize, usize)> {
    let m = level.iter().copied().max().unwrap_or(1);
    let mut elements_at: Vec<(usize, usize)> = Vec::new();
    let mut lv = 1;
    while lv <= m.max(1) {
        let count = level.iter().filter(|&&l| l == lv).count();
        elements_at.push((lv, count));
        lv *= 2;
    }
    elements_at
}

/// Squared error estimate of each element's centre value as its mean: the
/// midpoint rule's error is about `h^2 f'' / 24` per axis and the second
/// difference to the neighbours is `h^2 f''`, so the estimate is
/// `sum over columns and blocks of (max |second difference| / 8)^2` (a margin
/// of 3 for jumps and mixed terms). Edge elements use the nearest centred
/// difference; on a grid side under 3 every element gets an infinite estimate.
fn indicator2(
    data: &[f64],
    rows: usize,
    cols: usize,
    blocks: usize,
    grid: crate::scene::Grid,
) -> Vec<f64> {
    let n_wall = grid.count();
    if grid.nu < 3 || grid.nv < 3 {
        return vec![f64::INFINITY; n_wall];
    }
    let mut ind = vec![0.0f64; n_wall];
    for k in 0..cols {
        for b in 0..blocks {
            let f = &data[k * rows + b * n_wall..k * rows + (b + 1) * n_wall];
            for (j, slot) in ind.iter_mut().enumerate() {
                let (iu, iv) = grid.coords(j);
                let cu = iu.clamp(1, grid.nu - 2);
                let cv = iv.clamp(1, grid.nv - 2);
                let du = f[grid.index(cu - 1, iv)] - 2.0 * f[grid.index(cu, iv)]
                    + f[grid.index(cu + 1, iv)];
                let dv = f[grid.index(iu, cv - 1)] - 2.0 * f[grid.index(iu, cv)]
                    + f[grid.index(iu, cv + 1)];
                let e = du.abs().max(dv.abs()) / 8.0;
                *slot += e * e;
            }
        }
    }
    ind
}

/// `||a - b||_F / ||b||_F` over all entries (`b` the reference).
pub(crate) fn relative_error(a: &Transport, reference: &Transport) -> f64 {
    let (mut num, mut den) = (0.0, 0.0);
    for (x, r) in a.col_major().iter().zip(reference.col_major()) {
        num += (x - r) * (x - r);
        den += r * r;
    }
    if den == 0.0 {
        if num == 0.0 {
            0.0
        } else {
            f64::INFINITY
        }
    } else {
        (num / den).sqrt()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::transport::build;

    fn scene(name: &str) -> Scene {
        Scene::builtin(name).unwrap().unwrap()
    }

    #[test]
    fn a_tolerance_that_refines_everything_equals_the_uniform_build() {
        // With a tiny tolerance and max_m = 2 every element ends at m = 2 (the
        // scene is 3x3, so no second difference is exactly 0):
        // exactly MODEL.md's uniform m = 2 (same samples, same order).
        let s = scene("occluder-crossed-3x3");
        let (t, st) = build_adaptive(&s, 1e-300, 2, MemoryBudget::DEFAULT).unwrap();
        let u = uniform(&s, 2);
        assert_eq!(st.elements_at, vec![(1, 0), (2, 32 * 32)]);
        assert!(!st.met);
        let worst = t
            .col_major()
            .iter()
            .zip(u.col_major())
            .map(|(a, b)| (a - b).abs() / b.abs().max(1e-300))
            .filter(|r| r.is_finite())
            .fold(0.0, f64::max);
        assert!(worst < 1e-12, "{worst}");
    }

    fn uniform(s: &Scene, m: usize) -> Transport {
        let u = s.clone().edit(|s| s.wall.plane.supersample = m).unwrap();
        build(&u, MemoryBudget::DEFAULT).unwrap()
    }

    #[test]
    fn on_a_glossy_wall_it_beats_uniform_sampling_of_the_same_cost() {
        // Narrow specular lobe (alpha 0.05); the reference is uniform m = 16.
        let s = scene("brewster-crossed")
            .edit(|s| s.wall.brdf.alpha = 0.05)
            .unwrap();
        let reference = uniform(&s, 16);
        let (t, st) = build_adaptive(&s, 1e-2, 16, MemoryBudget::DEFAULT).unwrap();
        assert!(st.met);
        let refined: usize = st.elements_at.iter().skip(1).map(|e| e.1).sum();
        assert!(refined < 32 * 32 / 2, "{:?}", st.elements_at);
        let e = relative_error(&t, &reference);
        // The estimate is honest to a factor 4.
        assert!(
            e < 4.0 * st.estimated_error && st.estimated_error < 4.0 * e,
            "{e} vs {st:?}"
        );
        // More accurate than uniform m = 4 with fewer samples than its 16 per element.
        let e4 = relative_error(&uniform(&s, 4), &reference);
        assert!(e < e4, "adaptive {e} vs uniform m = 4 {e4}");
        assert!(st.samples < 16 * 32 * 32, "{}", st.samples);
    }

    #[test]
    fn behind_an_occluder_it_refines_the_shadow_edges_first() {
        let s = scene("occluder-crossed-3x3");
        let (t1, _) = build_adaptive(&s, 1.0, 16, MemoryBudget::DEFAULT).unwrap();
        let (t, st) = build_adaptive(&s, 3e-2, 16, MemoryBudget::DEFAULT).unwrap();
        let refined: usize = st.elements_at.iter().skip(1).map(|e| e.1).sum();
        assert!(refined > 0 && refined < 32 * 32 / 2, "{:?}", st.elements_at);
        let reference = uniform(&s, 16);
        assert!(relative_error(&t, &reference) < 0.7 * relative_error(&t1, &reference));
    }

    #[test]
    fn bad_parameters_are_named() {
        let s = scene("brewster-crossed-3x3");
        let e = build_adaptive(&s, 0.0, 8, MemoryBudget::DEFAULT).unwrap_err();
        assert!(e.to_string().starts_with("tolerance = 0"), "{e}");
        let e = build_adaptive(&s, 1e-3, 0, MemoryBudget::DEFAULT).unwrap_err();
        assert!(e.to_string().starts_with("max-m = 0"), "{e}");
    }
}
