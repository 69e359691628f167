//! `x <- (L L^T)^-1 x` for a dense Cholesky factor `L`, one right-hand side:
//! ADMM's l-update (MODEL.md Eq. 12) runs it at every iteration.
//!
//! Why not faer's triangular solves here: for one right-hand side they
//! reduce to matrix-vector products whose generic SIMD loops are
//! instantiated in polnlos's own codegen units; without cross-unit inlining
//! (the test profile) they ran at a fraction of memory speed, 81 % of the
//! lambda tests' time. Two sweeps over `L`'s columns, an `axpy` forward and a
//! dot product backward, stream `L` once each at any profile. faer still
//! solves systems large enough to split over threads.

use faer::MatRef;

/// Solves `L L^T x = b` in place (`x` holds `b`), `L` lower triangular and
/// square with contiguous columns; `None` (nothing touched) when `L` is not
/// laid out so or its order is not `x.len()`, for the caller's general path.
pub(crate) fn solve_llt_in_place(l: MatRef<'_, f64>, x: &mut [f64]) -> Option<()> {
    let n = x.len();
    // A unit row stride makes every column contiguous.
    if l.nrows() != n || l.ncols() != n || l.row_stride() != 1 {
        return None;
    }
    forward(l, x);
    backward(l, x);
    Some(())
}

/// Column `j` of `L` from row `j` down (contiguous: the caller checked the row stride).
#[inline(always)]
fn lower_col<'a>(l: MatRef<'a, f64>, j: usize) -> &'a [f64] {
    match l.col(j).try_as_col_major() {
        Some(c) => &c.as_slice()[j..],
        None => &[],
    }
}

/// `L y = b`: column `j` of `L` below the diagonal scales `y_j` out of the
/// rows below it.
#[multiversion::multiversion(targets("x86_64+avx2+fma"))]
fn forward(l: MatRef<'_, f64>, x: &mut [f64]) {
    let n = x.len();
    for j in 0..n {
        let col = lower_col(l, j);
        let xj = x[j] / col[0];
        x[j] = xj;
        let (below, lower) = (&mut x[j + 1..n], &col[1..]);
        let m = below.len().min(lower.len());
        for i in 0..m {
            below[i] -= xj * lower[i];
        }
    }
}

/// `L^T x = y`: row `j` of `L^T` is column `j` of `L`, a dot product with
/// the solved entries below `j`.
#[multiversion::multiversion(targets("x86_64+avx2+fma"))]
fn backward(l: MatRef<'_, f64>, x: &mut [f64]) {
    let n = x.len();
    for j in (0..n).rev() {
        let col = lower_col(l, j);
        let s = dot(&col[1..], &x[j + 1..n]);
        x[j] = (x[j] - s) / col[0];
    }
}

/// `a . b` over eight partial sums, so that the loop vectorizes (a single
/// running sum fixes the order of the additions and cannot).
#[inline(always)]
fn dot(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len().min(b.len());
    let (a, b) = (&a[..n], &b[..n]);
    let whole = n - n % 8;
    let mut acc = [0.0f64; 8];
    let mut i = 0;
    while i < whole {
        let (pa, pb) = (&a[i..i + 8], &b[i..i + 8]);
        for k in 0..8 {
            acc[k] += pa[k] * pb[k];
        }
        i += 8;
    }
    let mut s = ((acc[0] + acc[4]) + (acc[1] + acc[5])) + ((acc[2] + acc[6]) + (acc[3] + acc[7]));
    for k in whole..n {
        s += a[k] * b[k];
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use faer::linalg::solvers::{Llt, SolveCore};
    use faer::{Mat, Side};
    use proptest::prelude::*;

    /// An SPD matrix `A A^T + n I` from a seed.
    fn spd(n: usize, seed: u64) -> Mat<f64> {
        let mut s = seed | 1;
        let mut next = || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            (s >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        let a = Mat::<f64>::from_fn(n, n, |_, _| next());
        let mut m = &a * a.transpose();
        for k in 0..n {
            m[(k, k)] += n as f64;
        }
        m
    }

    proptest! {
        /// The same solution as faer's two triangular solves, to rounding.
        #[test]
        fn solves_as_faer_does(n in 1usize..70, seed in any::<u64>()) {
            let m = spd(n, seed);
            let llt = Llt::new(m.as_ref(), Side::Lower).unwrap();
            let b: Vec<f64> = (0..n).map(|k| (k as f64 * 0.37).sin()).collect();
            let mut ours = b.clone();
            solve_llt_in_place(llt.L(), &mut ours).unwrap();
            let mut theirs = Mat::from_fn(n, 1, |i, _| b[i]);
            llt.solve_in_place_with_conj(faer::Conj::No, theirs.as_mut());
            for i in 0..n {
                prop_assert!((ours[i] - theirs[(i, 0)]).abs() <= 1e-12 * (1.0 + theirs[(i, 0)].abs()));
            }
            // And it solves the system: A x = b.
            for i in 0..n {
                let r: f64 = (0..n).map(|j| m[(i, j)] * ours[j]).sum::<f64>() - b[i];
                prop_assert!(r.abs() < 1e-9 * n as f64);
            }
        }
    }

    #[test]
    fn a_wrong_shape_or_layout_is_left_to_the_caller() {
        let m = spd(4, 3);
        let llt = Llt::new(m.as_ref(), Side::Lower).unwrap();
        let mut x = vec![1.0; 3];
        assert!(solve_llt_in_place(llt.L(), &mut x).is_none());
        assert_eq!(x, [1.0; 3]);
        let mut x = vec![1.0; 4];
        assert!(solve_llt_in_place(llt.L().transpose(), &mut x).is_none());
        assert_eq!(x, [1.0; 4]);
    }
}
