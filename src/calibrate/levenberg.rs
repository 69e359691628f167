//! Levenberg-Marquardt for the calibrations' small least-squares fits: the
//! wall's four numbers ([`super::wall`]) and a homography's eight
//! ([`super::geometry`]).
//!
//! Why one loop: both fits damp, step, accept and stop by the same rule, on
//! a Jacobian by central differences (their models are cheap next to
//! writing one by hand, and have at most a handful of parameters).

use nalgebra::{Const, DimMin, SMatrix, SVector};

/// How a fit runs: its bounds and its finite-difference step.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Settings {
    /// Iterations (one Jacobian each) at most.
    pub max_iter: usize,
    /// Damped steps tried in one iteration before the fit stops.
    pub tries: usize,
    /// Central-difference step, relative to each parameter's size (at
    /// least 1e-3).
    pub step: f64,
    /// The fit stops once an accepted step lowers the cost by no more than
    /// this fraction of it.
    pub min_gain: f64,
    /// The fit stops once the cost is below this (an exact fit).
    pub exact: f64,
}

/// The model's Jacobian at a point, by central differences.
#[derive(Debug, Clone)]
pub(crate) struct Jacobian<const N: usize> {
    /// `J^T J`.
    pub jtj: SMatrix<f64, N, N>,
    /// The columns of `J`, one per parameter, one value per data point.
    pub columns: Vec<Vec<f64>>,
}

/// Where a fit ended.
#[derive(Debug, Clone)]
pub(crate) struct Fit<const N: usize> {
    /// The parameters.
    pub p: SVector<f64, N>,
    /// `model(p) - data`.
    pub r: Vec<f64>,
    /// `|r|^2`.
    pub cost: f64,
    /// The Jacobian at `p`: none when the model had no value at a point
    /// beside `p` that it needed.
    pub jacobian: Option<Jacobian<N>>,
    /// Iterations run.
    pub iterations: usize,
}

/// Minimizes `|model(p) - data|^2` from `start`, whose model value `first`
/// the caller has; each trial point is passed through `feasible` (a
/// projection onto the parameters' allowed set) before it is evaluated.
///
/// `model` returns `Ok(None)` where it has no value (a trial there counts as
/// a rejected step; a Jacobian there ends the fit at the current point) and
/// `Err` where the fit must stop with that error. Damping is Marquardt's
/// (`mu` times the diagonal of `J^T J`), 10x up on a rejected step, 0.3x
/// down on an accepted one.
pub(crate) fn minimize<const N: usize, E>(
    model: impl Fn(&SVector<f64, N>) -> Result<Option<Vec<f64>>, E>,
    data: &[f64],
    start: SVector<f64, N>,
    first: &[f64],
    feasible: impl Fn(SVector<f64, N>) -> SVector<f64, N>,
    settings: Settings,
) -> Result<Fit<N>, E>
where
    Const<N>: DimMin<Const<N>, Output = Const<N>>,
{
    let residual = |m: &[f64]| -> Vec<f64> { m.iter().zip(data).map(|(a, b)| a - b).collect() };
    let ss = |r: &[f64]| r.iter().map(|x| x * x).sum::<f64>();
    let r = residual(first);
    let mut fit = Fit {
        p: start,
        cost: ss(&r),
        r,
        jacobian: jacobian(&model, &start, settings.step)?,
        iterations: 0,
    };
    let mut mu = 1e-3;
    while fit.iterations < settings.max_iter {
        let Some(jac) = &fit.jacobian else { break };
        fit.iterations += 1;
        let jtr = SVector::<f64, N>::from_fn(|a, _| {
            jac.columns[a].iter().zip(&fit.r).map(|(j, e)| j * e).sum()
        });
        let mut improved = false;
        for _ in 0..settings.tries {
            let mut m = jac.jtj;
            for d in 0..N {
                m[(d, d)] += mu * jac.jtj[(d, d)].max(1e-30);
            }
            let Some(delta) = m.lu().solve(&(-jtr)) else {
                break;
            };
            let next = feasible(fit.p + delta);
            if let Some(value) = model(&next)? {
                let r = residual(&value);
                let c = ss(&r);
                if c < fit.cost {
                    let gain = (fit.cost - c) / fit.cost.max(1e-300);
                    (fit.p, fit.r, fit.cost) = (next, r, c);
                    mu = (mu * 0.3).max(1e-12);
                    improved = gain > settings.min_gain;
                    break;
                }
            }
            mu *= 10.0;
        }
        if !improved || fit.cost < settings.exact {
            break;
        }
        fit.jacobian = jacobian(&model, &fit.p, settings.step)?;
    }
    Ok(fit)
}

/// The Jacobian of `model` at `p` by central differences, `step` relative
/// to each parameter (at least 1e-3 of one); none where the model has no
/// value at one of the points.
fn jacobian<const N: usize, E>(
    model: &impl Fn(&SVector<f64, N>) -> Result<Option<Vec<f64>>, E>,
    p: &SVector<f64, N>,
    step: f64,
) -> Result<Option<Jacobian<N>>, E> {
    let mut columns = Vec::with_capacity(N);
    for k in 0..N {
        let h = step * p[k].abs().max(1e-3);
        let (mut a, mut b) = (*p, *p);
        a[k] += h;
        b[k] -= h;
        let (Some(ma), Some(mb)) = (model(&a)?, model(&b)?) else {
            return Ok(None);
        };
        columns.push(
            ma.iter()
                .zip(&mb)
                .map(|(x, y)| (x - y) / (2.0 * h))
                .collect::<Vec<f64>>(),
        );
    }
    let jtj = SMatrix::<f64, N, N>::from_fn(|a, b| {
        columns[a].iter().zip(&columns[b]).map(|(x, y)| x * y).sum()
    });
    Ok(Some(Jacobian { jtj, columns }))
}

#[cfg(test)]
mod tests {
    use super::*;

    const SETTINGS: Settings = Settings {
        max_iter: 100,
        tries: 12,
        step: 1e-7,
        min_gain: 1e-15,
        exact: 1e-28,
    };

    /// `a exp(-b x)` at the points `x`.
    fn decay(p: &SVector<f64, 2>, x: &[f64]) -> Vec<f64> {
        x.iter().map(|x| p[0] * (-p[1] * x).exp()).collect()
    }

    #[test]
    fn recovers_a_nonlinear_model_from_far_off() {
        let x: Vec<f64> = (0..20).map(|k| k as f64 * 0.25).collect();
        let truth = SVector::<f64, 2>::new(3.0, 0.7);
        let data = decay(&truth, &x);
        let start = SVector::<f64, 2>::new(1.0, 2.0);
        let model = |p: &SVector<f64, 2>| Ok::<_, ()>(Some(decay(p, &x)));
        let fit = minimize(model, &data, start, &decay(&start, &x), |p| p, SETTINGS).unwrap();
        assert!((fit.p - truth).norm() < 1e-8, "{:?}", fit.p);
        assert!(fit.cost < 1e-16, "{}", fit.cost);
        let jac = fit.jacobian.expect("a Jacobian at the end");
        // d/da at the truth is exp(-b x): 1 at x = 0.
        assert!((jac.columns[0][0] - 1.0).abs() < 1e-6);
    }

    #[test]
    fn the_projection_holds_and_a_model_without_value_or_in_error_stops_the_fit() {
        let x: Vec<f64> = (0..20).map(|k| k as f64 * 0.25).collect();
        let data = decay(&SVector::<f64, 2>::new(3.0, 0.7), &x);
        // The rate is kept at most 0.6: the fit ends on that bound, at the
        // amplitude that fits best there.
        let model = |p: &SVector<f64, 2>| Ok::<_, ()>(Some(decay(p, &x)));
        let start = SVector::<f64, 2>::new(1.0, 0.1);
        let bound = |mut p: SVector<f64, 2>| {
            p[1] = p[1].min(0.6);
            p
        };
        let fit = minimize(model, &data, start, &decay(&start, &x), bound, SETTINGS).unwrap();
        assert!(fit.p[1] <= 0.6 && fit.p[1] > 0.59, "{:?}", fit.p);
        // No value beside the start: the fit ends there, with no Jacobian.
        let nowhere = |p: &SVector<f64, 2>| Ok::<_, ()>((p[1] < 0.0).then(|| decay(p, &x)));
        let fit = minimize(nowhere, &data, start, &decay(&start, &x), |p| p, SETTINGS).unwrap();
        assert_eq!((fit.p, fit.iterations), (start, 0));
        assert!(fit.jacobian.is_none());
        // An error ends the fit with it.
        let failing = |_: &SVector<f64, 2>| Err::<Option<Vec<f64>>, _>("no model");
        let e = minimize(failing, &data, start, &decay(&start, &x), |p| p, SETTINGS);
        assert_eq!(e.unwrap_err(), "no model");
    }
}
