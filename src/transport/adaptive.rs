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
use crate::scene::Scene;

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
        let samples = WallSamples::of_scene(scene, budget)?;
        let t = super::build(scene, budget)?;
        return Ok((
            t,
            AdaptiveStats {
                tolerance,
                max_m,
                elements_at: Vec::new(),
                estimated_error: 0.0,
                met: true,
                samples: samples.points.len(),
            },
        ));
    }
    let plane = &scene.wall().plane;
    let n_wall = plane.grid.count();
    let blocks = scene.block_count();
    let rows = scene.rows();
    let cols = scene.cols();

    let samples_of = |elements: &[usize], m: usize| {
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
    };

    let all: Vec<usize> = (0..n_wall).collect();
    let mut data = build_rows(
        scene,
        budget,
        &WallSamples::uniform(scene, samples_of(&all, 1), n_wall, 1),
        &|_| {},
    )?;
    let mut samples = n_wall;
    let norm2: f64 = data.iter().map(|v| v * v).sum();
    let budget2 = tolerance * tolerance * norm2;
    let mut est = indicator2(&data, rows, cols, blocks, plane.grid);
    let mut level = vec![1usize; n_wall];
    loop {
        let total: f64 = est.iter().sum();
        if norm2 == 0.0 || total <= budget2 {
            break;
        }
        // Refine the largest estimates until the rest fits in half the budget.
        let mut order: Vec<usize> = (0..n_wall)
            .filter(|&j| 2 * level[j] <= max_m && est[j] > 0.0)
            .collect();
        if order.is_empty() {
            break;
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
        let mut levels: Vec<usize> = pick.iter().map(|&j| level[j]).collect();
        levels.sort_unstable();
        levels.dedup();
        for m in levels {
            let group: Vec<usize> = pick.iter().copied().filter(|&j| level[j] == m).collect();
            let m2 = 2 * m;
            let pts = samples_of(&group, m2);
            samples += pts.len();
            let sub_rows = group.len() * blocks;
            let finer = build_rows(
                scene,
                budget,
                &WallSamples::uniform(scene, pts, group.len(), m2 * m2),
                &|_| {},
            )?;
            let mut change = vec![0.0f64; group.len()];
            for k in 0..cols {
                for b in 0..blocks {
                    for (a, &j) in group.iter().enumerate() {
                        let new = finer[k * sub_rows + b * group.len() + a];
                        let slot = &mut data[k * rows + b * n_wall + j];
                        change[a] += (new - *slot) * (new - *slot);
                        *slot = new;
                    }
                }
            }
            for (a, &j) in group.iter().enumerate() {
                level[j] = m2;
                est[j] = change[a];
            }
        }
    }
    let total: f64 = est.iter().sum();
    let estimated_error = if norm2 > 0.0 {
        (total / norm2).sqrt()
    } else {
        0.0
    };
    let m = level.iter().copied().max().unwrap_or(1);

    let mut elements_at: Vec<(usize, usize)> = Vec::new();
    let mut lv = 1;
    while lv <= m.max(1) {
        let count = level.iter().filter(|&&l| l == lv).count();
        elements_at.push((lv, count));
        lv *= 2;
    }
    let t = Transport::from_col_major(
        rows,
        cols,
        data,
        blocks_of(scene),
        plane.grid,
        scene.hidden().plane.grid,
    );
    Ok((
        t,
        AdaptiveStats {
            tolerance,
            max_m,
            elements_at,
            estimated_error,
            met: estimated_error <= tolerance,
            samples,
        },
    ))
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
pub fn relative_error(a: &Transport, reference: &Transport) -> f64 {
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
