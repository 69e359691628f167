//! The residual whiteness principle (RWP) for the TV weight: the λ whose
//! residual `i - T l_λ`, whitened by the noise, looks most like white noise
//! (Lanza, Pragliola, Sgallari, "Residual whiteness principle for
//! parameter-free image restoration", ETNA 53, 2020).
//!
//! Why this rule: it needs no noise level (only its shape across rows, when
//! known) and it was built for TV with ADMM. Whiteness is measured per block
//! on the wall grid (one block is one wall image, its rows row-major), by the
//! normalized circular 2-D autocorrelation of the residual, as the paper does
//! on its (periodic) image grid.

use crate::scene::Grid;
use crate::solve::gram::Normal;
use crate::solve::lambda::{check_noise, NoiseLevel, Path};
use crate::solve::solvers::AdmmSettings;
use crate::solve::{check_measurement, Reconstruction, SolveError};
use crate::transport::Transport;

/// Scan range of [`admm_tv_whiteness`], log10 of λ relative to `mean(diag(T^T T))`.
pub(crate) const SCAN_REL: (f64, f64) = (-7.0, 1.0);
/// Scan steps over [`SCAN_REL`] (a quarter decade each).
pub(crate) const SCAN_STEPS: usize = 32;
/// Golden-section steps between the scan minimum's neighbours.
pub(crate) const GOLDEN_STEPS: usize = 6;

/// How the whiteness λ was found (what [`admm_tv_whiteness`] reports).
#[derive(Debug, Clone, serde::Serialize)]
pub struct WhitenessChoice {
    /// λ chosen (MODEL.md units).
    pub lambda: f64,
    /// Its whiteness measure (sum over blocks; about 1 a block for white noise).
    pub whiteness: f64,
    /// Every (λ, whiteness) evaluated, in order.
    pub trials: Vec<(f64, f64)>,
}

/// The whiteness measure of a residual: per block of `wall` rows, `r_j /
/// sigma_j` (`variance` given) or `r_j`, its circular 2-D autocorrelation
/// normalized by the zero lag, and the sum of its squares over every other
/// lag; summed over the blocks. White noise gives about 1 a block (each of
/// the `n - 1` lags has variance about `1/n`); a residual with structure
/// (smooth signal left unfit) gives more. A row without a positive
/// variance counts as 0; rows past the last whole block are left out.
///
/// Why per block: the rows of one block are one wall image, neighbours in
/// space; rows of different blocks are not neighbours.
pub fn whiteness(wall: Grid, residual: &[f64], variance: Option<&[f64]>) -> f64 {
    let n = wall.count();
    if n == 0 {
        return 0.0;
    }
    let mut r = vec![0.0; n];
    residual
        .chunks_exact(n)
        .enumerate()
        .map(|(b, block)| {
            for (j, (out, &v)) in r.iter_mut().zip(block).enumerate() {
                *out = match variance.map(|var| var.get(b * n + j).copied()) {
                    Some(Some(s2)) if s2 > 0.0 => v / s2.sqrt(),
                    Some(_) => 0.0,
                    None => v,
                };
            }
            block_whiteness(wall, &r)
        })
        .sum()
}

/// `sum_{lag != 0} rho(lag)^2` of one wall image (see [`whiteness`]); 0 for
/// an all-zero residual.
fn block_whiteness(wall: Grid, r: &[f64]) -> f64 {
    let (nu, nv) = (wall.nu, wall.nv);
    let zero: f64 = r.iter().map(|v| v * v).sum();
    if zero == 0.0 {
        return 0.0;
    }
    let mut sum = 0.0;
    for dv in 0..nv {
        for du in 0..nu {
            if du == 0 && dv == 0 {
                continue;
            }
            let mut a = 0.0;
            for v in 0..nv {
                let row = &r[v * nu..(v + 1) * nu];
                let other = &r[((v + dv) % nv) * nu..((v + dv) % nv + 1) * nu];
                // u + du wraps once: two straight runs.
                let split = nu - du;
                a += row[..split]
                    .iter()
                    .zip(&other[du..])
                    .map(|(x, y)| x * y)
                    .sum::<f64>();
                a += row[split..]
                    .iter()
                    .zip(&other[..du])
                    .map(|(x, y)| x * y)
                    .sum::<f64>();
            }
            let rho = a / zero;
            sum += rho * rho;
        }
    }
    sum
}

/// ADMM-TV with λ chosen by the residual whiteness principle: a quarter-decade
/// scan of λ over `SCAN_REL` (one warm path, one Gram), the λ of least
/// [`whiteness`], refined by golden section in log λ between its scan
/// neighbours. `noise` only whitens the rows (its scale does not matter).
///
/// Why: Lanza et al. (ETNA 53, 2020) choose the TV weight of an ADMM
/// solve this way, with no noise level.
pub fn admm_tv_whiteness(
    t: &Transport,
    i: &[f64],
    normal: &Normal,
    noise: Option<&NoiseLevel>,
    settings: &AdmmSettings,
) -> Result<(Reconstruction, WhitenessChoice), SolveError> {
    check_measurement(t, i)?;
    if let Some(n) = noise {
        check_noise(n, i)?;
    }
    let wall = t.wall_grid();
    let variance = noise.map(|n| n.variance.as_slice());
    let unit = normal.unit();
    let mut path = Path::new(settings.problem(t, i, normal), true);
    let mut trials: Vec<(f64, f64)> = Vec::new();
    let mut best: Option<(f64, Reconstruction)> = None;
    let mut eval = |log_lambda: f64,
                    path: &mut Path<'_>,
                    best: &mut Option<(f64, Reconstruction)>|
     -> Result<f64, SolveError> {
        let lambda = 10f64.powf(log_lambda);
        let r = path.solve(lambda)?;
        let pred = t.apply(&r.image);
        let res: Vec<f64> = i.iter().zip(&pred).map(|(a, b)| a - b).collect();
        let w = whiteness(wall, &res, variance);
        trials.push((lambda, w));
        if best.as_ref().is_none_or(|(bw, _)| w < *bw) {
            *best = Some((w, r));
        }
        Ok(w)
    };
    let base = unit.max(f64::MIN_POSITIVE).log10();
    let step = (SCAN_REL.1 - SCAN_REL.0) / SCAN_STEPS as f64;
    let scan: Vec<f64> = (0..=SCAN_STEPS)
        .map(|k| base + SCAN_REL.0 + step * k as f64)
        .collect();
    let mut values = Vec::with_capacity(scan.len());
    for &x in &scan {
        values.push(eval(x, &mut path, &mut best)?);
    }
    let k = values
        .iter()
        .enumerate()
        .min_by(|a, b| a.1.total_cmp(b.1))
        .map_or(0, |(k, _)| k);
    // Golden section on [x_{k-1}, x_{k+1}] (clamped to the scan).
    let (mut a, mut b) = (scan[k.saturating_sub(1)], scan[(k + 1).min(scan.len() - 1)]);
    let g = 0.5 * (5f64.sqrt() - 1.0);
    let (mut c, mut d) = (b - g * (b - a), a + g * (b - a));
    let (mut fc, mut fd) = (
        eval(c, &mut path, &mut best)?,
        eval(d, &mut path, &mut best)?,
    );
    for _ in 2..GOLDEN_STEPS {
        if fc < fd {
            (b, d, fd) = (d, c, fc);
            c = b - g * (b - a);
            fc = eval(c, &mut path, &mut best)?;
        } else {
            (a, c, fc) = (c, d, fd);
            d = a + g * (b - a);
            fd = eval(d, &mut path, &mut best)?;
        }
    }
    let (w, rec) = best.ok_or(SolveError::Parameter {
        name: "lambda",
        value: f64::NAN,
        reason: "no λ was tried",
    })?;
    let choice = WhitenessChoice {
        lambda: rec.stats.lambda.unwrap_or(0.0),
        whiteness: w,
        trials,
    };
    Ok((rec, choice))
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_distr::Distribution;

    fn gaussian(n: usize, seed: u64) -> Vec<f64> {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        (0..n)
            .map(|_| rand_distr::StandardNormal.sample(&mut rng))
            .collect()
    }

    #[test]
    fn white_noise_measures_about_one_a_block() {
        let wall = Grid { nu: 32, nv: 32 };
        // Two blocks, the second 100x louder with its variance given: whitened, both white.
        let mut r = gaussian(2 * wall.count(), 3);
        r[wall.count()..].iter_mut().for_each(|v| *v *= 100.0);
        let var: Vec<f64> = (0..r.len())
            .map(|j| if j < wall.count() { 1.0 } else { 1e4 })
            .collect();
        let w = whiteness(wall, &r, Some(&var));
        assert!((1.6..2.4).contains(&w), "{w}");
        // Unweighted, each block is still white on its own.
        let w = whiteness(wall, &r, None);
        assert!((1.6..2.4).contains(&w), "{w}");
    }

    #[test]
    fn a_smooth_residual_is_far_from_white() {
        let wall = Grid { nu: 32, nv: 32 };
        let noise = gaussian(wall.count(), 5);
        let smooth: Vec<f64> = (0..wall.count())
            .map(|j| {
                let (u, v) = wall.coords(j);
                (u as f64 / 5.0).sin() + (v as f64 / 7.0).cos()
            })
            .collect();
        let white = whiteness(wall, &noise, None);
        let mixed: Vec<f64> = noise.iter().zip(&smooth).map(|(a, b)| a + b).collect();
        assert!(whiteness(wall, &mixed, None) > 10.0 * white);
        assert!(whiteness(wall, &smooth, None) > 50.0 * white);
        assert_eq!(whiteness(wall, &vec![0.0; wall.count()], None), 0.0);
    }
}
