//! The normal-equation pieces shared by ADMM and Tikhonov: `T^T T` (lower
//! triangle, half the flops of a full product) and `T^T i`.

use faer::linalg::matmul::triangular::{matmul, BlockStructure};
use faer::{Accum, Mat, MatRef, Par};

/// Lower triangle of `T^T T` (the strict upper triangle is left zero).
pub fn gram_lower(t: MatRef<'_, f64>, par: Par) -> Mat<f64> {
    let n = t.ncols();
    let mut g = Mat::<f64>::zeros(n, n);
    matmul(
        g.as_mut(),
        BlockStructure::TriangularLower,
        Accum::Replace,
        t.transpose(),
        BlockStructure::Rectangular,
        t,
        BlockStructure::Rectangular,
        1.0,
        par,
    );
    g
}

/// `T^T i`.
pub fn adjoint(t: MatRef<'_, f64>, i: &[f64]) -> Vec<f64> {
    (0..t.ncols())
        .map(|k| {
            let col = t.col(k);
            col.iter().zip(i).map(|(a, b)| a * b).sum()
        })
        .collect()
}

/// Mean of the diagonal of `T^T T`: the squared column norm, the natural unit
/// (MODEL.md units of `lambda`) for default regularization and penalty weights.
pub fn mean_diag(g: &Mat<f64>) -> f64 {
    let n = g.nrows();
    if n == 0 {
        return 0.0;
    }
    (0..n).map(|k| g[(k, k)]).sum::<f64>() / n as f64
}

/// Current parallelism for dense kernels (faer's global setting).
pub fn par() -> Par {
    faer::get_global_parallelism()
}
