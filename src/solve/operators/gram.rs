//! The normal-equation pieces shared by ADMM and Tikhonov: `T^T T` (lower
//! triangle, half the flops of a full product) and `T^T i`.

use faer::linalg::matmul::triangular::{matmul, BlockStructure};
use std::sync::Arc;

use faer::{Accum, Mat, MatRef, Par};

use crate::solve::lowrank::{LowRank, LOW_RANK_MIN_COLS};
use crate::solve::par;
use crate::stop::Stop;
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

/// Multiply-adds of one block of rows in [`gram_lower_until`]: about a tenth
/// of a second on two cores.
const GRAM_BLOCK_FLOPS: usize = 1 << 28;

/// [`gram_lower`] summed over blocks of rows of `t`, looking at `stop`
/// before each block; `None` once it is raised.
/// Why: a large `T`'s Gram takes seconds, and a cancelled job must not wait
/// for it.
pub(crate) fn gram_lower_until(t: MatRef<'_, f64>, par: Par, stop: Stop<'_>) -> Option<Mat<f64>> {
    let (rows, n) = (t.nrows(), t.ncols());
    let block = (GRAM_BLOCK_FLOPS / (n * n).max(1)).clamp(256, rows.max(256));
    let mut g = Mat::<f64>::zeros(n, n);
    let mut start = 0;
    while start < rows {
        if stop.raised() {
            return None;
        }
        let len = block.min(rows - start);
        let part = t.subrows(start, len);
        matmul(
            g.as_mut(),
            BlockStructure::TriangularLower,
            Accum::Add,
            part.transpose(),
            BlockStructure::Rectangular,
            part,
            BlockStructure::Rectangular,
            1.0,
            par,
        );
        start += len;
    }
    Some(g)
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
        Self::formed(t, None, Stop::default()).expect("a default stop is never raised")
    }

    /// [`Gram::new`], looking at `stop` between blocks of rows of `t`;
    /// `None` once it is raised.
    pub fn new_until(t: MatRef<'_, f64>, stop: Stop<'_>) -> Option<Self> {
        Self::formed(t, None, stop)
    }

    /// [`Gram::new`] for `t`, with its low-rank form when `t` has at least
    /// `LOW_RANK_MIN_COLS` columns and a numerical rank of at most a
    /// quarter of them.
    pub fn of(t: &Transport) -> Self {
        Self::of_until(t, Stop::default()).expect("a default stop is never raised")
    }

    /// [`Gram::of`], looking at `stop` between blocks of rows of `T`;
    /// `None` once it is raised.
    pub fn of_until(t: &Transport, stop: Stop<'_>) -> Option<Self> {
        let grid = (t.cols() >= LOW_RANK_MIN_COLS).then(|| t.scene_grid());
        Self::formed(t.as_mat(), grid, stop)
    }

    /// `T^T T`, with its low-rank form on `grid` when one is given and the
    /// rank allows it; `None` when `stop` was raised.
    fn formed(
        t: MatRef<'_, f64>,
        grid: Option<crate::scene::Grid>,
        stop: Stop<'_>,
    ) -> Option<Self> {
        let start = std::time::Instant::now();
        let lower = gram_lower_until(t, par(), stop)?;
        let scale = mean_diag(&lower);
        let low_rank = grid.and_then(|grid| LowRank::of_gram(lower.as_ref(), grid, par()));
        Some(Self {
            lower,
            scale,
            low_rank,
            seconds: start.elapsed().as_secs_f64(),
        })
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
        Self::of_until(t, i, Stop::default()).expect("a default stop is never raised")
    }

    /// [`Normal::of`], its Gram ended early (`None`) once `stop` is raised.
    pub fn of_until(t: &Transport, i: &[f64], stop: Stop<'_>) -> Option<Self> {
        let start = std::time::Instant::now();
        let mut normal = Self::with(Arc::new(Gram::of_until(t, stop)?), t, i);
        normal.seconds = start.elapsed().as_secs_f64();
        Some(normal)
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

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::{AtomicBool, Ordering};

    /// A tall `rows x cols` matrix with entries that differ everywhere.
    fn tall(rows: usize, cols: usize) -> Mat<f64> {
        Mat::from_fn(rows, cols, |i, j| {
            ((i * 7 + j * 13) % 17) as f64 / 17.0 + 0.01 * j as f64
        })
    }

    #[test]
    fn the_gram_by_blocks_of_rows_equals_the_gram_at_once_and_stops_on_its_flag() {
        // Past one block of rows (the block has at least 256 rows).
        let t = tall(1500, 24);
        let whole = gram_lower(t.as_ref(), Par::Seq);
        let flag = AtomicBool::new(false);
        let blocks = gram_lower_until(t.as_ref(), Par::Seq, Stop::on(&flag)).expect("no stop");
        let scale = whole[(0, 0)].abs();
        for j in 0..24 {
            for i in j..24 {
                assert!(
                    (whole[(i, j)] - blocks[(i, j)]).abs() <= 1e-12 * scale,
                    "({i}, {j}): {} against {}",
                    blocks[(i, j)],
                    whole[(i, j)]
                );
            }
        }
        flag.store(true, Ordering::Relaxed);
        assert!(gram_lower_until(t.as_ref(), Par::Seq, Stop::on(&flag)).is_none());
    }
}
