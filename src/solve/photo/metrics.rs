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
    let misfit = |c: &Vec<f64>| {
        let y = match data_term {
            DataTerm::Differences => difference_values(t, c),
            DataTerm::Values => centred(t, c),
        };
        let ky = crate::solve::gram::adjoint(k.as_mat(), &y);
        let rhs = faer::Mat::from_fn(k.cols(), 1, |r, _| ky[r]);
        let x = faer::linalg::solvers::Solve::solve(&llt, &rhs);
        let fit = k.as_mat() * &x;
        y.iter()
            .enumerate()
            .map(|(r, v)| (v - fit[(r, 0)]).powi(2))
            .sum::<f64>()
    };
    Ok(channels.iter().map(misfit).collect())
}
