//! The normal-equation pieces shared by ADMM and Tikhonov: `T^T T` (lower
//! triangle, half the flops of a full product) and `T^T i`.

use faer::linalg::matmul::triangular::{matmul, BlockStructure};
use std::sync::Arc;

use faer::{Accum, Mat, MatRef, Par};

use crate::solve::lowrank::{LowRank, LOW_RANK_MIN_COLS};
use crate::solve::par;
use crate::transport::Transport;

/// Lower triangle of `T^T T` (the strict upper triangle is left zero).
pub(crate) fn gram_lower(t: MatRef<'_, f64>, par: Par) -> Mat<f64> {
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
pub(crate) fn adjoint(t: MatRef<'_, f64>, i: &[f64]) -> Vec<f64> {
    (0..t.ncols())
        .map(|k| {
            let col = t.col(k);
            col.iter().zip(i).map(|(a, b)| a * b).sum()
        })
        .collect()
}

/// Mean of the diagonal of `T^T T`: the squared column norm, the natural unit
/// (MODEL.md units of `lambda`) for default regularization and penalty weights.
pub(crate) fn mean_diag(g: &Mat<f64>) -> f64 {
    let n = g.nrows();
    if n == 0 {
        return 0.0;
    }
    (0..n).map(|k| g[(k, k)]).sum::<f64>() / n as f64
}

/// `T^T T` of one transport matrix with what every solve on it reuses: its
/// scale and, for a large low-rank `T`, its low-rank form. It depends on `T`
/// alone, so the daemon caches one per scene (shared through an `Arc`).
pub struct Gram {
    /// Lower triangle of `T^T T`.
    pub lower: Mat<f64>,
    /// `mean(diag(T^T T))`, the unit of `lambda` and `rho` defaults.
    pub scale: f64,
    /// `T^T T ~ W W^T` when `T` has many columns and low numerical rank
    /// ([`Gram::of`]): ADMM then solves through it (see `crate::solve::lowrank`).
    pub low_rank: Option<LowRank>,
    /// Seconds it took.
    pub seconds: f64,
}

impl Gram {
    /// Forms `T^T T` (dense only).
    pub fn new(t: MatRef<'_, f64>) -> Self {
        let start = std::time::Instant::now();
        let lower = gram_lower(t, par());
        let scale = mean_diag(&lower);
        Self {
            lower,
            scale,
            low_rank: None,
            seconds: start.elapsed().as_secs_f64(),
        }
    }

    /// [`Gram::new`] for `t`, with its low-rank form when `t` has at least
    /// `LOW_RANK_MIN_COLS` columns and a numerical rank of at most a
    /// quarter of them.
    pub fn of(t: &Transport) -> Self {
        let start = std::time::Instant::now();
        let mut gram = Self::new(t.as_mat());
        if t.cols() >= LOW_RANK_MIN_COLS {
            gram.low_rank = LowRank::of_gram(gram.lower.as_ref(), t.scene_grid(), par());
        }
        gram.seconds = start.elapsed().as_secs_f64();
        gram
    }
}

/// The normal-equation pieces of one measurement: the (shared) Gram of `T`
/// and `T^T i`, computed once for every solve on it (e.g. the trials of an
/// automatic lambda).
pub struct Normal {
    /// `T^T T` and its low-rank form.
    pub gram: Arc<Gram>,
    /// `T^T i`.
    pub ti: Vec<f64>,
    /// Seconds it took (the Gram's included when it was formed here).
    pub seconds: f64,
}

/// The first of `normals` (from 0) not on the first one's Gram; `None`
/// when they all share it.
/// Why: colours solved together share one factor of their Gram, so they
/// must be of one `T` (an `Arc` of the Gram, as the daemon caches it).
#[cfg(any(test, feature = "daemon"))]
pub(crate) fn off_gram<'a>(normals: impl IntoIterator<Item = &'a Normal>) -> Option<usize> {
    let mut normals = normals.into_iter();
    let first = normals.next()?;
    normals
        .position(|n| !Arc::ptr_eq(&n.gram, &first.gram))
        .map(|k| k + 1)
}

impl Normal {
    /// Forms `T^T T` (dense only) and `T^T i`.
    pub fn new(t: MatRef<'_, f64>, i: &[f64]) -> Self {
        let start = std::time::Instant::now();
        let gram = Arc::new(Gram::new(t));
        Self {
            ti: adjoint(t, i),
            gram,
            seconds: start.elapsed().as_secs_f64(),
        }
    }

    /// [`Normal::new`] with the Gram of [`Gram::of`] (its low-rank form for
    /// a large `T`).
    pub fn of(t: &Transport, i: &[f64]) -> Self {
        let start = std::time::Instant::now();
        let mut normal = Self::with(Arc::new(Gram::of(t)), t, i);
        normal.seconds = start.elapsed().as_secs_f64();
        normal
    }

    /// With a Gram already formed for this `t` (e.g. a scene's cached one):
    /// only `T^T i` is computed.
    pub fn with(gram: Arc<Gram>, t: &Transport, i: &[f64]) -> Self {
        let start = std::time::Instant::now();
        let ti = adjoint(t.as_mat(), i);
        Self {
            gram,
            ti,
            seconds: start.elapsed().as_secs_f64(),
        }
    }

    /// Lower triangle of `T^T T`.
    pub fn lower(&self) -> &Mat<f64> {
        &self.gram.lower
    }

    /// The Gram's low-rank form, if it has one.
    pub fn low_rank(&self) -> Option<&LowRank> {
        self.gram.low_rank.as_ref()
    }

    /// `mean(diag(T^T T))`, the unit of `lambda` and `rho` defaults.
    pub fn scale(&self) -> f64 {
        self.gram.scale
    }

    /// `scale`, or 1 for an all-zero `T`.
    pub fn unit(&self) -> f64 {
        if self.gram.scale > 0.0 {
            self.gram.scale
        } else {
            1.0
        }
    }
}
