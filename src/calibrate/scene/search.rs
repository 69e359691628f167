//! Levenberg-Marquardt over a handful of geometry numbers whose residual
//! costs a `T` build: forward differences (one build per parameter), steps
//! kept inside a box, every accepted point one that was evaluated.
//!
//! Why not [`crate::calibrate::levenberg`]: its central differences cost
//! two builds per parameter, and its parameter count is fixed at compile
//! time where `calibrate scene` frees what the user asks.

use nalgebra::{DMatrix, DVector};

/// The residual at a point, or why it has none.
pub(crate) type Residual<'a, E> = dyn FnMut(&[f64]) -> Result<Vec<f64>, E> + 'a;

/// How a descent runs.
#[derive(Debug, Clone)]
pub(crate) struct Descent {
    /// Lowest value of each parameter.
    pub lo: Vec<f64>,
    /// Highest value of each parameter.
    pub hi: Vec<f64>,
    /// Forward-difference step of each parameter.
    pub step: Vec<f64>,
    /// A step smaller than this in every parameter ends the descent.
    pub settle: Vec<f64>,
    /// Residual evaluations at most (Jacobians included).
    pub max_evaluations: usize,
    /// An accepted step that lowers the cost by less than this fraction of
    /// it ends the descent.
    pub min_gain: f64,
}

/// Where a descent ended.
#[derive(Debug, Clone)]
pub(crate) struct Descended {
    /// The parameters: a point that was evaluated.
    pub x: Vec<f64>,
    /// `|r(x)|^2`.
    pub cost: f64,
    /// The cost at the start.
    pub start_cost: f64,
    /// `J^T J` at `x` (forward differences), when the descent ended with a
    /// Jacobian there.
    pub jtj: Option<DMatrix<f64>>,
    /// Whether it ended for want of evaluations rather than by settling.
    pub out_of_evaluations: bool,
    /// Parameters that ended on a bound of the box.
    pub on_bound: Vec<usize>,
}

/// `|r|^2`.
fn cost(r: &[f64]) -> f64 {
    r.iter().map(|v| v * v).sum()
}

/// The Jacobian's `J^T J` and `J^T r` at `x` (residual `r`): one evaluation
/// per parameter, stepping away from the nearer bound.
fn normal_equations<E>(
    f: &mut Residual<'_, E>,
    x: &[f64],
    r: &[f64],
    d: &Descent,
) -> Result<(DMatrix<f64>, DVector<f64>), E> {
    let n = x.len();
    let mut columns = Vec::with_capacity(n);
    for i in 0..n {
        let h = if x[i] + d.step[i] <= d.hi[i] {
            d.step[i]
        } else {
            -d.step[i]
        };
        let mut y = x.to_vec();
        y[i] += h;
        let ry = f(&y)?;
        columns.push(
            ry.iter()
                .zip(r)
                .map(|(a, b)| (a - b) / h)
                .collect::<Vec<f64>>(),
        );
    }
    let dot = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(p, q)| p * q).sum::<f64>();
    let jtj = DMatrix::from_fn(n, n, |i, j| dot(&columns[i], &columns[j]));
    let jtr = DVector::from_fn(n, |i, _| dot(&columns[i], r));
    Ok((jtj, jtr))
}

/// `J^T J` at `x`: the end's curvature when the descent left none.
pub(crate) fn curvature<E>(
    f: &mut Residual<'_, E>,
    x: &[f64],
    d: &Descent,
) -> Result<DMatrix<f64>, E> {
    let r = f(x)?;
    Ok(normal_equations(f, x, &r, d)?.0)
}

/// The damped step `-(A + mu diag(A))^-1 g`, none when the damped matrix
/// is not positive definite.
fn damped_step(a: &DMatrix<f64>, g: &DVector<f64>, mu: f64) -> Option<DVector<f64>> {
    let mut m = a.clone();
    let mean = (0..a.nrows()).map(|i| a[(i, i)]).sum::<f64>() / a.nrows().max(1) as f64;
    for i in 0..a.nrows() {
        m[(i, i)] += mu * a[(i, i)].max(1e-12 * mean.max(f64::MIN_POSITIVE));
    }
    m.cholesky().map(|c| -c.solve(g))
}

/// Minimizes `|f(x)|^2` from `start` inside the box of `d`.
pub(crate) fn descend<E>(
    f: &mut Residual<'_, E>,
    start: &[f64],
    d: &Descent,
) -> Result<Descended, E> {
    let n = start.len();
    let clamp = |x: Vec<f64>| -> Vec<f64> {
        x.iter()
            .enumerate()
            .map(|(i, v)| v.clamp(d.lo[i], d.hi[i]))
            .collect()
    };
    let mut x = clamp(start.to_vec());
    let mut r = f(&x)?;
    let mut evaluations = 1;
    let start_cost = cost(&r);
    let mut c = start_cost;
    let mut mu = 1e-3;
    let mut jtj_here = None;
    let mut out_of_evaluations = false;
    loop {
        if evaluations + n > d.max_evaluations {
            out_of_evaluations = true;
            break;
        }
        let (a, g) = normal_equations(f, &x, &r, d)?;
        evaluations += n;
        jtj_here = Some(a.clone());
        let mut moved = false;
        let mut settled = false;
        while evaluations < d.max_evaluations && mu < 1e8 {
            let Some(delta) = damped_step(&a, &g, mu) else {
                mu *= 10.0;
                continue;
            };
            let y = clamp(x.iter().zip(delta.iter()).map(|(p, q)| p + q).collect());
            if y.iter()
                .zip(&x)
                .zip(&d.settle)
                .all(|((p, q), s)| (p - q).abs() < *s)
            {
                // A small step is the end only while the damping is light:
                // a heavily damped one is small because the steps failed.
                settled = mu <= 1.0;
                break;
            }
            let ry = f(&y)?;
            evaluations += 1;
            let cy = cost(&ry);
            if cy < c {
                let gain = (c - cy) / c.max(f64::MIN_POSITIVE);
                (x, r, c) = (y, ry, cy);
                mu = (mu * 0.3).max(1e-7);
                moved = true;
                jtj_here = None;
                settled = gain < d.min_gain;
                break;
            }
            mu *= 10.0;
        }
        if !moved && !settled && evaluations >= d.max_evaluations {
            out_of_evaluations = true;
        }
        if !moved || settled {
            if moved && evaluations + n <= d.max_evaluations {
                jtj_here = Some(normal_equations(f, &x, &r, d)?.0);
            }
            break;
        }
    }
    let on_bound = (0..n)
        .filter(|&i| x[i] <= d.lo[i] || x[i] >= d.hi[i])
        .collect();
    Ok(Descended {
        x,
        cost: c,
        start_cost,
        jtj: jtj_here,
        out_of_evaluations,
        on_bound,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn descent(n: usize) -> Descent {
        Descent {
            lo: vec![-1.0; n],
            hi: vec![1.0; n],
            step: vec![1e-6; n],
            settle: vec![1e-9; n],
            max_evaluations: 200,
            min_gain: 1e-12,
        }
    }

    #[test]
    fn a_linear_least_squares_problem_is_solved_to_its_minimum() {
        // r(x) = A x - b with a unique minimum at (0.3, -0.2).
        let mut f = |x: &[f64]| -> Result<Vec<f64>, ()> {
            Ok(vec![
                2.0 * (x[0] - 0.3),
                x[1] + 0.2,
                x[0] - 0.3 + x[1] + 0.2,
            ])
        };
        let d = descend(&mut f, &[0.0, 0.0], &descent(2)).unwrap();
        assert!(
            (d.x[0] - 0.3).abs() < 1e-6 && (d.x[1] + 0.2).abs() < 1e-6,
            "{:?}",
            d.x
        );
        assert!(d.cost < 1e-10 && d.start_cost > 0.1);
        assert!(d.jtj.is_some() && d.on_bound.is_empty() && !d.out_of_evaluations);
    }

    #[test]
    fn a_minimum_outside_the_box_ends_on_its_bound() {
        let mut f = |x: &[f64]| -> Result<Vec<f64>, ()> { Ok(vec![x[0] - 3.0, 0.1 * x[0]]) };
        let d = descend(&mut f, &[0.0], &descent(1)).unwrap();
        assert_eq!(d.x, vec![1.0]);
        assert_eq!(d.on_bound, vec![0]);
    }

    #[test]
    fn a_nonlinear_valley_is_followed_and_the_budget_is_kept() {
        // Rosenbrock's valley as residuals: minimum at (1, 1), inside a box to 2.
        let mut f = |x: &[f64]| -> Result<Vec<f64>, ()> {
            Ok(vec![10.0 * (x[1] - x[0] * x[0]), 1.0 - x[0]])
        };
        let mut d = descent(2);
        d.hi = vec![2.0; 2];
        d.lo = vec![-2.0; 2];
        let end = descend(&mut f, &[-1.2, 1.0], &d).unwrap();
        assert!(
            (end.x[0] - 1.0).abs() < 1e-4 && (end.x[1] - 1.0).abs() < 1e-4,
            "{:?}",
            end.x
        );
        d.max_evaluations = 7;
        let calls = std::cell::Cell::new(0);
        let mut counted = |x: &[f64]| {
            calls.set(calls.get() + 1);
            f(x)
        };
        let short = descend(&mut counted, &[-1.2, 1.0], &d).unwrap();
        assert!(
            calls.get() <= 7 && short.out_of_evaluations,
            "{}",
            calls.get()
        );
    }
}
