//! How good a photo's reconstruction is: image metrics against a truth
//! (PSNR as is and after each channel's affine fit, ZNCC, SSIM) and the
//! misfit of the unconstrained least-squares fit.

use super::*;

/// Image metrics of a colour result against its truth over all channels
/// (peak 1): PSNR as it is and after each channel's best affine map
/// `a x + b` onto the truth (what a display's gain and offset could fix),
/// ZNCC of all values, SSIM averaged over the channels.
#[derive(Debug, Clone, Copy, serde::Serialize)]
pub struct PhotoMetrics {
    /// PSNR of the result as it is, dB.
    pub psnr_db: f64,
    /// PSNR after each channel's best affine fit, dB.
    pub psnr_affine_db: f64,
    /// Zero-mean normalized cross-correlation over every value.
    pub zncc: f64,
    /// Mean SSIM of the channels.
    pub ssim: f64,
}

/// [`PhotoMetrics`] of `image` against `truth`, both channel by channel on `grid`.
pub(crate) fn photo_metrics(
    grid: crate::scene::Grid,
    truth: &[Vec<f64>],
    image: &[Vec<f64>],
) -> PhotoMetrics {
    use crate::solve::metrics::{psnr, ssim, zncc};
    let flat = |v: &[Vec<f64>]| v.concat();
    let fitted: Vec<Vec<f64>> = truth
        .iter()
        .zip(image)
        .map(|(t, x)| affine_fit(t, x))
        .collect();
    PhotoMetrics {
        psnr_db: psnr(&flat(truth), &flat(image)),
        psnr_affine_db: psnr(&flat(truth), &flat(&fitted)),
        zncc: zncc(&flat(truth), &flat(image)),
        ssim: truth
            .iter()
            .zip(image)
            .map(|(t, x)| ssim(grid, t, x))
            .sum::<f64>()
            / truth.len().max(1) as f64,
    }
}

/// `a x + b` with `a, b` the least-squares fit of `x` to `truth`.
pub(super) fn affine_fit(truth: &[f64], x: &[f64]) -> Vec<f64> {
    let n = x.len().max(1) as f64;
    let (mx, mt) = (x.iter().sum::<f64>() / n, truth.iter().sum::<f64>() / n);
    let sxx: f64 = x.iter().map(|v| (v - mx) * (v - mx)).sum();
    let sxt: f64 = x.iter().zip(truth).map(|(v, t)| (v - mx) * (t - mt)).sum();
    let a = if sxx > 0.0 { sxt / sxx } else { 0.0 };
    x.iter().map(|v| mt + a * (v - mx)).collect()
}

/// Ridge of [`least_squares_misfit`]'s factorization, relative to the mean
/// diagonal of `K^T K`: far below any entry that carries data (the chair's
/// misfit is the same to 5 digits from 1e-9 to 1e-4, docs/realphoto.md).
pub(crate) const LEAST_SQUARES_RIDGE: f64 = 1e-9;

/// The least-squares misfit of the data term with no bound on the scene,
/// summed over the colour channels: `sum_c min_x ||K (i_c - T x)||^2`, `K`
/// the data term's operator (differences, or the block means taken out).
///
/// Why: exact (no iteration count to stop at) and smooth in `T`, so a search
/// over the geometry compares two `T` by their model alone; blind to the
/// gain and background, like the data term (docs/realphoto.md, "Placing the
/// occluders").
pub fn least_squares_misfit(
    t: &Transport,
    data_term: DataTerm,
    channels: &[Vec<f64>],
) -> Result<f64, SolveError> {
    Ok(least_squares_misfits(t, data_term, channels)?.iter().sum())
}

/// [`least_squares_misfit`] channel by channel: `min_x ||K (i_c - T x)||^2`
/// for each `c`, from one factorization of `K^T K`.
///
/// Why: a fit to several photos reports each photo's share of the misfit
/// (`calibrate occluder` with several measurements).
pub(crate) fn least_squares_misfits(
    t: &Transport,
    data_term: DataTerm,
    channels: &[Vec<f64>],
) -> Result<Vec<f64>, SolveError> {
    let fit = LeastSquares::new(t, data_term, channels)?;
    Ok(channels.iter().map(|c| fit.solve(c).1).collect())
}

/// Each channel's residual of the data term of differences, `D i_c - D T x`:
/// with `known[c]` given, `x = g l` (the known image `l`, its gain `g`
/// fitted), else `x` the unconstrained least-squares fit.
///
/// Why: a geometry fit by variable projection differentiates these residuals
/// (`calibrate scene`): the image, gain and background are eliminated at
/// each geometry, and the background drops out of differences.
pub(crate) fn difference_residuals(
    t: &Transport,
    channels: &[Vec<f64>],
    known: Option<&[Vec<f64>]>,
) -> Result<Vec<Vec<f64>>, SolveError> {
    for c in channels {
        check_measurement(t, c)?;
    }
    let Some(known) = known else {
        let fit = LeastSquares::new(t, DataTerm::Differences, channels)?;
        return Ok(channels
            .iter()
            .map(|c| {
                let (x, _) = fit.solve(c);
                let y = difference_values(t, c);
                let kx = difference_values(t, &t.apply(&x));
                y.iter().zip(&kx).map(|(a, b)| a - b).collect()
            })
            .collect());
    };
    if known.len() != channels.len() {
        return Err(SolveError::Parameter {
            name: "known image channels",
            value: known.len() as f64,
            reason: "one known image per colour channel of the photo",
        });
    }
    known
        .iter()
        .zip(channels)
        .map(|(l, c)| {
            if l.len() != t.cols() {
                return Err(SolveError::Parameter {
                    name: "known image cells",
                    value: l.len() as f64,
                    reason: "a known image has one value per cell of the scene's grid",
                });
            }
            let y = difference_values(t, c);
            let kl = difference_values(t, &t.apply(l));
            let kk: f64 = kl.iter().map(|v| v * v).sum();
            let g = if kk > 0.0 {
                kl.iter().zip(&y).map(|(a, b)| a * b).sum::<f64>() / kk
            } else {
                0.0
            };
            Ok(y.iter().zip(&kl).map(|(a, b)| a - g * b).collect())
        })
        .collect()
}

/// The unconstrained least-squares fit of the data term, factored once.
struct LeastSquares<'a> {
    t: &'a Transport,
    data_term: DataTerm,
    k: Transport,
    llt: faer::linalg::solvers::Llt<f64>,
}

impl<'a> LeastSquares<'a> {
    /// `K` and the Cholesky factor of `K^T K` plus [`LEAST_SQUARES_RIDGE`],
    /// after checking that each of `channels` fits `T`.
    fn new(
        t: &'a Transport,
        data_term: DataTerm,
        channels: &[Vec<f64>],
    ) -> Result<Self, SolveError> {
        for c in channels {
            check_measurement(t, c)?;
        }
        let k = match data_term {
            DataTerm::Differences => differences(t),
            DataTerm::Values => centred_columns(t, &vec![false; t.rows()]),
        };
        let mut g = crate::solve::gram::gram_lower(k.as_mat(), crate::solve::par());
        let ridge = LEAST_SQUARES_RIDGE * crate::solve::gram::mean_diag(&g).max(f64::MIN_POSITIVE);
        for j in 0..k.cols() {
            g[(j, j)] += ridge;
        }
        let llt = g.llt(faer::Side::Lower).map_err(|e| {
            SolveError::Factorization(format!(
                "Cholesky of K^T K + {ridge:e} I failed ({e:?}): the data term's columns are not independent"
            ))
        })?;
        Ok(Self {
            t,
            data_term,
            k,
            llt,
        })
    }

    /// The fitted scene `x` of one channel and its misfit `||K (i - T x)||^2`.
    fn solve(&self, c: &[f64]) -> (Vec<f64>, f64) {
        let y = match self.data_term {
            DataTerm::Differences => difference_values(self.t, c),
            DataTerm::Values => centred(self.t, c),
        };
        let k = self.k.as_mat();
        let ky = crate::solve::gram::adjoint(k, &y);
        let rhs = faer::Mat::from_fn(k.ncols(), 1, |r, _| ky[r]);
        let x = faer::linalg::solvers::Solve::solve(&self.llt, &rhs);
        let fit = k * &x;
        let misfit = y
            .iter()
            .enumerate()
            .map(|(r, v)| (v - fit[(r, 0)]).powi(2))
            .sum::<f64>();
        ((0..k.ncols()).map(|r| x[(r, 0)]).collect(), misfit)
    }
}

/// Noise samples [`noise_checks`] averages the noise's misfit over: with
/// 4, a 40 x 40 wall's check read 6 % low over ten photos; with 32, 0.1 %.
const NOISE_SAMPLES: usize = 32;

/// One channel's least-squares misfit beside the misfit its noise alone
/// would leave.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct NoiseCheck {
    /// `min_x ||K (i - T x)||^2`.
    pub misfit: f64,
    /// The misfit the channel's noise alone would leave through the same
    /// fit: the mean over `NOISE_SAMPLES` samples of that noise (a fixed
    /// seed); `None` where the noise cannot be measured.
    pub noise_misfit: Option<f64>,
}

/// [`least_squares_misfits`] beside the misfit each channel's noise alone
/// would leave: with `variances` (per channel, per row of `T`), noise of
/// that variance; without, white noise of the variance the roughness of the
/// fit's residual gives ([`roughness_variance`], over the roughness unit
/// white noise's residual keeps). No noise misfit where the data term has
/// no more rows than `T` has columns.
///
/// Why: the misfit over the noise's is the model check, near 1 when the
/// model explains the photo (docs/realphoto.md, "The model check"). A
/// photo with no frame-to-frame variance has only its residual: the light
/// on the wall is smooth, so the residual's roughness is mostly noise, but
/// a model error rough from one element to the next reads as noise too,
/// so that estimate is high where the model is wrong and the check low.
pub(crate) fn noise_checks(
    t: &Transport,
    data_term: DataTerm,
    channels: &[Vec<f64>],
    variances: Option<&[Vec<f64>]>,
) -> Result<Vec<NoiseCheck>, SolveError> {
    use rand::SeedableRng;
    use rand_distr::{Distribution, StandardNormal};
    let fit = LeastSquares::new(t, data_term, channels)?;
    if let Some(v) = variances {
        if v.len() != channels.len() {
            return Err(SolveError::Parameter {
                name: "variance channels",
                value: v.len() as f64,
                reason: "one noise variance per colour channel of the measurement",
            });
        }
        for c in v {
            check_measurement(t, c)?;
            if let Some(bad) = c.iter().find(|x| **x < 0.0) {
                return Err(SolveError::Parameter {
                    name: "variance",
                    value: *bad,
                    reason: "a noise variance must be >= 0",
                });
            }
        }
    }
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0x6e6f697365);
    // The misfit noise of standard deviation `sd(row)` leaves and, with
    // `rough`, the roughness its residual keeps, over the samples.
    let mut noise = |sd: &dyn Fn(usize) -> f64, rough: bool| {
        let (mut misfit, mut roughness) = (0.0, 0.0);
        for _ in 0..NOISE_SAMPLES {
            let n: Vec<f64> = (0..t.rows())
                .map(|j| sd(j) * Distribution::<f64>::sample(&StandardNormal, &mut rng))
                .collect();
            let (x, m) = fit.solve(&n);
            misfit += m / NOISE_SAMPLES as f64;
            if rough {
                roughness +=
                    residual_roughness(t, &n, &x).unwrap_or(f64::NAN) / NOISE_SAMPLES as f64;
            }
        }
        (misfit, roughness)
    };
    // With no more rows than cells the fit takes up nearly all of the noise
    // and of the model's error alike, and their ratio says little (on a
    // 21 x 21 wall, 840 rows of differences for 1044 cells, the model's own
    // photo read 0.75): no check.
    let rows = match data_term {
        DataTerm::Differences => difference_rows(t),
        DataTerm::Values => t.rows(),
    };
    if rows <= t.cols() {
        return Ok(channels
            .iter()
            .map(|c| NoiseCheck {
                misfit: fit.solve(c).1,
                noise_misfit: None,
            })
            .collect());
    }
    // Unit white noise's misfit and roughness: the scale of the roughness
    // estimate. Its samples are drawn first either way, so that a given
    // variance's samples follow them in the one seeded stream; its
    // roughness is measured only where a channel has no variance.
    let white = noise(&|_| 1.0, variances.is_none());
    let mut out = Vec::with_capacity(channels.len());
    for (k, c) in channels.iter().enumerate() {
        let (x, misfit) = fit.solve(c);
        let noise_misfit = match variances.and_then(|v| v.get(k)) {
            Some(v) => Some(noise(&|j| v[j].sqrt(), false).0),
            None => residual_roughness(t, c, &x)
                .map(|r| r / white.1 * white.0)
                .filter(|m| m.is_finite()),
        };
        out.push(NoiseCheck {
            misfit,
            noise_misfit,
        });
    }
    Ok(out)
}

/// [`roughness_variance`] of `i - T x`.
fn residual_roughness(t: &Transport, i: &[f64], x: &[f64]) -> Option<f64> {
    let residual: Vec<f64> = i.iter().zip(t.apply(x)).map(|(v, m)| v - m).collect();
    roughness_variance(t.wall_grid(), &residual)
}

/// Fewest pseudo-residuals [`roughness_variance`] takes a median of.
const MIN_PSEUDO_RESIDUALS: usize = 16;

/// The noise variance of one wall element of a measurement, from the
/// measurement alone: `(1.4826 median |e|)^2` over the pseudo-residuals
/// `e = (y_{k-1} - 2 y_k + y_{k+1}) / sqrt(6)` along u and along v of each
/// block's wall image (Gasser, Sroka and Jennen-Steinmetz, 1986; each has
/// the variance of one element's noise when the light is locally linear).
/// `None` with fewer than 16 of them or a value that is not finite.
///
/// Why: a single photo has no frame-to-frame variance, and its residual
/// against `T` counts the model's error as noise; the light on a rough wall
/// is smooth from one element to the next, so its second differences are
/// mostly noise, and the median passes over the few shadow edges. Where
/// the light curves within three elements the estimate is high, never low.
pub(crate) fn roughness_variance(grid: crate::scene::Grid, i: &[f64]) -> Option<f64> {
    let nw = grid.count();
    if nw == 0 || !i.len().is_multiple_of(nw) || i.iter().any(|v| !v.is_finite()) {
        return None;
    }
    let mut e = Vec::new();
    for block in i.chunks(nw) {
        let at = |u: usize, v: usize| block[grid.index(u, v)];
        for v in 0..grid.nv {
            for u in 1..grid.nu.saturating_sub(1) {
                e.push((at(u - 1, v) - 2.0 * at(u, v) + at(u + 1, v)).abs());
            }
        }
        for v in 1..grid.nv.saturating_sub(1) {
            for u in 0..grid.nu {
                e.push((at(u, v - 1) - 2.0 * at(u, v) + at(u, v + 1)).abs());
            }
        }
    }
    if e.len() < MIN_PSEUDO_RESIDUALS {
        return None;
    }
    let mid = e.len() / 2;
    let (_, median, _) = e.select_nth_unstable_by(mid, f64::total_cmp);
    let sd = 1.4826 * *median / 6f64.sqrt();
    Some(sd * sd)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::Grid;
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};

    /// A smooth wall image (a ramp and a gentle bump) with a hard shadow
    /// edge across it, and Gaussian noise of `sd`.
    fn image(grid: Grid, sd: f64, seed: u64) -> Vec<f64> {
        let noise = Normal::new(0.0, sd).expect("a positive sd");
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        (0..grid.count())
            .map(|j| {
                let (u, v) = grid.coords(j);
                let (x, y) = (u as f64 / grid.nu as f64, v as f64 / grid.nv as f64);
                let light =
                    100.0 + 40.0 * x + 30.0 * (-(x - 0.5).powi(2) - (y - 0.4).powi(2)).exp();
                let shadow = if x + 0.3 * y > 0.6 { 0.5 } else { 1.0 };
                light * shadow + noise.sample(&mut rng)
            })
            .collect()
    }

    #[test]
    fn roughness_gives_the_noise_of_a_smooth_image_with_a_shadow_edge() {
        let grid = Grid { nu: 63, nv: 63 };
        for (sd, seed) in [(0.1, 1), (1.0, 2), (3.0, 3)] {
            let var = roughness_variance(grid, &image(grid, sd, seed)).expect("enough elements");
            let got = var.sqrt();
            assert!((got / sd - 1.0).abs() < 0.06, "sd {sd}: got {got}");
        }
        // Two blocks: the same noise, from twice the residuals.
        let two = [image(grid, 1.0, 4), image(grid, 1.0, 5)].concat();
        let got = roughness_variance(grid, &two)
            .expect("enough elements")
            .sqrt();
        assert!((got - 1.0).abs() < 0.04, "two blocks: {got}");
    }

    #[test]
    fn roughness_of_a_noiseless_image_is_its_curvature_alone() {
        let grid = Grid { nu: 40, nv: 30 };
        // A plane has no second difference: no noise.
        let plane: Vec<f64> = (0..grid.count())
            .map(|j| {
                let (u, v) = grid.coords(j);
                3.0 + 0.5 * u as f64 - 0.25 * v as f64
            })
            .collect();
        assert_eq!(roughness_variance(grid, &plane), Some(0.0));
        // Too few elements, a length that is not whole blocks, a NaN.
        assert_eq!(roughness_variance(Grid { nu: 3, nv: 3 }, &[1.0; 9]), None);
        assert_eq!(roughness_variance(grid, &plane[1..]), None);
        let mut nan = plane.clone();
        nan[7] = f64::NAN;
        assert_eq!(roughness_variance(grid, &nan), None);
    }
}
