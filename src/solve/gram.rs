//! The normal-equation pieces shared by ADMM and Tikhonov: `T^T T` (lower
//! triangle, half the flops of a full product) and `T^T i`.

use faer::linalg::matmul::triangular::{matmul, BlockStructure};
use faer::{Accum, Mat, MatRef, Par};

use super::lowrank::{LowRank, LOW_RANK_MIN_COLS};
use crate::transport::Transport;

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

/// The normal-equation pieces of one measurement, computed once and shared by
/// every solve on it (e.g. the trials of an automatic lambda).
pub struct Normal {
    /// Lower triangle of `T^T T`.
    pub gram: Mat<f64>,
    /// `T^T i`.
    pub ti: Vec<f64>,
    /// `mean(diag(T^T T))`, the unit of `lambda` and `rho` defaults.
    pub scale: f64,
    /// `T^T T ~ W W^T` when `T` has many columns and low numerical rank
    /// ([`Normal::of`]): ADMM then solves through it (see [`super::lowrank`]).
    pub low_rank: Option<LowRank>,
    /// Seconds it took.
    pub seconds: f64,
}

impl Normal {
    /// Forms `T^T T` and `T^T i`.
    pub fn new(t: MatRef<'_, f64>, i: &[f64]) -> Self {
        let start = std::time::Instant::now();
        let gram = gram_lower(t, par());
        let ti = adjoint(t, i);
        let scale = mean_diag(&gram);
        Self {
            gram,
            ti,
            scale,
            low_rank: None,
            seconds: start.elapsed().as_secs_f64(),
        }
    }

    /// [`Normal::new`] for `t`, with the low-rank form of the Gram when `t`
    /// has at least [`LOW_RANK_MIN_COLS`] columns and a numerical rank of at
    /// most a quarter of them.
    pub fn of(t: &Transport, i: &[f64]) -> Self {
        let start = std::time::Instant::now();
        let mut normal = Self::new(t.as_mat(), i);
        if t.cols() >= LOW_RANK_MIN_COLS {
            normal.low_rank = LowRank::of_gram(normal.gram.as_ref(), t.scene_grid, par());
        }
        normal.seconds = start.elapsed().as_secs_f64();
        normal
    }

    /// `scale`, or 1 for an all-zero `T`.
    pub fn unit(&self) -> f64 {
        if self.scale > 0.0 {
            self.scale
        } else {
            1.0
        }
    }
}

/// Current parallelism for dense kernels (faer's global setting).
pub fn par() -> Par {
    faer::get_global_parallelism()
}
