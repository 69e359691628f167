//! `T^T T` of a large scene grid as a low-rank product, and the ADMM system
//! solved through it.
//!
//! Why: the wall blurs the hidden scene, so `T` has far fewer significant
//! singular values than columns (wall 64x64, two poses, scene 64x64: about
//! 300 of 4096 above 1e-7 of the largest). A diagonally pivoted Cholesky of
//! the Gram stops at that rank (`n r^2` flops instead of `n^3 / 3`) and gives
//!
//! * the spectrum of `T` down to the Gram's resolution (the eigenvalues of
//!   the small `W^T W`), instead of a full SVD of `T`;
//! * the columns that span range(T), for the noise estimate;
//! * the ADMM system `W W^T + rho (D^T D + I)` solved by Woodbury's identity
//!   with `D^T D + I` diagonalized by the discrete cosine transform (Neumann
//!   boundaries): about `4 n r` flops per solve instead of two triangular
//!   solves with an `n x n` factor (`2 n^2`, memory-bound), and a change of
//!   `rho` costs an `r x r` Cholesky instead of an `n x n` one.
//!
//! The part of the Gram left out, `E = G - W W^T`, is positive semidefinite
//! with `trace(E) <= LOW_RANK_TOL * trace(G)`, the size of the Gram's own
//! rounding error; it changes `||i - T l||^2` by at most `trace(E) ||l||^2`.

use faer::linalg::matmul::matmul;
use faer::linalg::solvers::{Llt, SolveCore};
use faer::reborrow::{Reborrow, ReborrowMut};
use faer::{Accum, Mat, MatMut, MatRef, Par, Side};

use crate::scene::Grid;
use crate::solve::SolveError;

/// Fewest columns for which [`crate::solve::gram::Normal::new`] tries the low-rank form
/// (below it the dense factor is cheap and exact).
pub const LOW_RANK_MIN_COLS: usize = 512;

/// Trace of the neglected part of the Gram, relative to its trace.
pub(crate) const LOW_RANK_TOL: f64 = 1e-13;

/// The low-rank form is kept only up to `cols / LOW_RANK_MAX_FRACTION`
/// pivots: beyond, the dense factor is as cheap.
pub(crate) const LOW_RANK_MAX_FRACTION: usize = 4;

/// `G ~ W W^T` with the ADMM pieces that do not depend on `rho`.
pub struct LowRank {
    /// `n x r`, rows in the original column order of `T`.
    pub w: Mat<f64>,
    /// Columns of `T` chosen, in pivot order (they span range(T) to the tolerance).
    pub pivots: Vec<usize>,
    /// `trace(G - W W^T)`.
    pub remainder: f64,
    /// `trace(G)`.
    pub trace: f64,
    /// `S^-1 W`, `S = D^T D + I`.
    z: Mat<f64>,
    /// `W^T S^-1 W` (`r x r`, symmetric positive semidefinite).
    m: Mat<f64>,
    neumann: Neumann,
}

/// Diagonally pivoted Cholesky of the symmetric positive semidefinite `g`
/// (lower triangle read), stopped when the trace of the Schur complement is
/// at most `tol_abs`: `(W, pivots, remainder)`, or `None` past `max_rank` pivots.
pub(crate) fn pivoted_cholesky(
    g: MatRef<'_, f64>,
    tol_abs: f64,
    max_rank: usize,
    par: Par,
) -> Option<(Mat<f64>, Vec<usize>, f64)> {
    let n = g.nrows();
    let max_rank = max_rank.min(n);
    let mut d: Vec<f64> = (0..n).map(|k| g[(k, k)].max(0.0)).collect();
    let mut done = vec![false; n];
    let mut w = Mat::<f64>::zeros(n, max_rank);
    let mut pivots = Vec::new();
    let mut wp = Mat::<f64>::zeros(max_rank, 1);
    let remainder = loop {
        let (mut rem, mut p, mut dp) = (0.0, 0, -1.0);
        for k in 0..n {
            if !done[k] {
                rem += d[k];
                if d[k] > dp {
                    (p, dp) = (k, d[k]);
                }
            }
        }
        if rem <= tol_abs || dp <= 0.0 {
            break rem;
        }
        let k = pivots.len();
        if k == max_rank {
            return None;
        }
        for j in 0..k {
            wp[(j, 0)] = w[(p, j)];
        }
        let (left, mut right) = w.as_mut().split_at_col_mut(k);
        let mut col = right.rb_mut().col_mut(0);
        for i in 0..n {
            col[i] = if i >= p { g[(i, p)] } else { g[(p, i)] };
        }
        matmul(
            col.rb_mut().as_mat_mut(),
            Accum::Add,
            left.rb(),
            wp.as_ref().subrows(0, k),
            -1.0,
            par,
        );
        let s = dp.sqrt();
        for i in 0..n {
            col[i] = if done[i] { 0.0 } else { col[i] / s };
        }
        col[p] = s;
        done[p] = true;
        for i in 0..n {
            if !done[i] {
                d[i] = (d[i] - col[i] * col[i]).max(0.0);
            }
        }
        pivots.push(p);
    };
    let r = pivots.len();
    let w = w.subcols(0, r).to_owned();
    Some((w, pivots, remainder))
}

impl LowRank {
    /// The low-rank form of the Gram `g` (lower triangle) of a `T` whose
    /// columns lie on `grid`, or `None` when its rank exceeds
    /// `cols / LOW_RANK_MAX_FRACTION` at `LOW_RANK_TOL`.
    pub fn of_gram(g: MatRef<'_, f64>, grid: Grid, par: Par) -> Option<Self> {
        let n = g.nrows();
        let trace: f64 = (0..n).map(|k| g[(k, k)]).sum();
        let (w, pivots, remainder) =
            pivoted_cholesky(g, LOW_RANK_TOL * trace, n / LOW_RANK_MAX_FRACTION, par)?;
        let neumann = Neumann::new(grid);
        let r = w.ncols();
        let mut z = w.clone();
        let mut scratch = vec![0.0; n];
        for k in 0..r {
            let col = z
                .col_mut(k)
                .try_as_col_major_mut()
                .expect("contiguous column");
            neumann.solve(col.as_slice_mut(), &mut scratch);
        }
        let mut m = Mat::<f64>::zeros(r, r);
        matmul(
            m.as_mut(),
            Accum::Replace,
            w.transpose(),
            z.as_ref(),
            1.0,
            par,
        );
        Some(Self {
            w,
            pivots,
            remainder,
            trace,
            z,
            m,
            neumann,
        })
    }

    /// Its rank `r`.
    pub fn rank(&self) -> usize {
        self.pivots.len()
    }

    /// The singular values of `T` it resolves, non-increasing: square roots of
    /// the eigenvalues of `W^T W` (those of `W W^T`, equal to the Gram's
    /// within `remainder`).
    pub fn singular_values(&self) -> Result<Vec<f64>, SolveError> {
        let mut wtw = Mat::<f64>::zeros(self.rank(), self.rank());
        matmul(
            wtw.as_mut(),
            Accum::Replace,
            self.w.transpose(),
            self.w.as_ref(),
            1.0,
            crate::solve::par(),
        );
        let mut e = wtw.self_adjoint_eigenvalues(Side::Lower).map_err(|e| {
            SolveError::Factorization(format!("eigenvalues of W^T W did not converge ({e:?})"))
        })?;
        e.reverse();
        Ok(e.into_iter().map(|v| v.max(0.0).sqrt()).collect())
    }

    /// The factor of `W W^T + rho (D^T D + I)`: the Cholesky of `rho I + M`.
    pub fn factor(&self, rho: f64) -> Result<Llt<f64>, SolveError> {
        let mut a = self.m.clone();
        for k in 0..self.rank() {
            a[(k, k)] += rho;
        }
        a.llt(Side::Lower).map_err(|e| {
            SolveError::Factorization(format!(
                "Cholesky of rho I + W^T S^-1 W failed ({e:?}); rho = {rho}"
            ))
        })
    }

    /// Solves `(W W^T + rho S) x = b` in place (Woodbury):
    /// `x = (y - Z (rho I + M)^-1 Z^T b) / rho` with `y = S^-1 b`.
    /// `ws` is scratch that keeps the solve free of allocation.
    pub fn solve(&self, factor: &Llt<f64>, rho: f64, b: &mut [f64], ws: &mut Workspace) {
        let n = b.len();
        let r = self.rank();
        ws.fit(n, r);
        let bm = MatRef::from_column_major_slice(b, n, 1);
        matmul(
            ws.c.as_mut(),
            Accum::Replace,
            self.z.transpose(),
            bm,
            1.0,
            Par::Seq,
        );
        factor.solve_in_place_with_conj(faer::Conj::No, ws.c.as_mut());
        self.neumann.solve(b, &mut ws.scratch);
        let bm = MatMut::from_column_major_slice_mut(b, n, 1);
        matmul(
            bm,
            Accum::Add,
            self.z.as_ref(),
            ws.c.as_ref(),
            -1.0,
            Par::Seq,
        );
        let inv = 1.0 / rho;
        b.iter_mut().for_each(|v| *v *= inv);
    }
}

/// Scratch of [`LowRank::solve`].
pub struct Workspace {
    c: Mat<f64>,
    scratch: Vec<f64>,
}

impl Default for Workspace {
    fn default() -> Self {
        Self {
            c: Mat::zeros(0, 1),
            scratch: Vec::new(),
        }
    }
}

impl Workspace {
    fn fit(&mut self, n: usize, r: usize) {
        if self.c.nrows() != r {
            self.c = Mat::zeros(r, 1);
        }
        if self.scratch.len() != n {
            self.scratch = vec![0.0; n];
        }
    }
}

/// `S = D^T D + I` on a grid with Neumann boundaries, diagonalized by the
/// orthonormal DCT-II along each axis: `D^T D` is the path-graph Laplacian
/// along u plus along v, with eigenvalues `2 - 2 cos(pi k / N)`.
struct Neumann {
    nu: usize,
    nv: usize,
    /// DCT-II matrices, frequency x position.
    cu: Mat<f64>,
    cv: Mat<f64>,
    /// `1 / (1 + mu_u + mu_v)` per frequency pair, `nu x nv`.
    inv: Mat<f64>,
}

fn dct(n: usize) -> Mat<f64> {
    Mat::from_fn(n, n, |k, j| {
        let c = if k == 0 { 1.0 } else { 2.0 };
        (c / n as f64).sqrt()
            * (std::f64::consts::PI * k as f64 * (j as f64 + 0.5) / n as f64).cos()
    })
}

fn path_eigenvalue(k: usize, n: usize) -> f64 {
    2.0 - 2.0 * (std::f64::consts::PI * k as f64 / n as f64).cos()
}

impl Neumann {
    fn new(grid: Grid) -> Self {
        let (nu, nv) = (grid.nu, grid.nv);
        Self {
            nu,
            nv,
            cu: dct(nu),
            cv: dct(nv),
            inv: Mat::from_fn(nu, nv, |a, b| {
                1.0 / (1.0 + path_eigenvalue(a, nu) + path_eigenvalue(b, nv))
            }),
        }
    }

    /// `x <- S^-1 x` for `x` row-major on the grid (`iv * nu + iu`), that is
    /// a column-major `nu x nv` matrix `X`: `Cu^T ((Cu X Cv^T) ./ den) Cv`.
    fn solve(&self, x: &mut [f64], scratch: &mut [f64]) {
        let (nu, nv) = (self.nu, self.nv);
        let mut xm = MatMut::from_column_major_slice_mut(x, nu, nv);
        let mut t = MatMut::from_column_major_slice_mut(scratch, nu, nv);
        matmul(
            t.rb_mut(),
            Accum::Replace,
            self.cu.as_ref(),
            xm.rb(),
            1.0,
            Par::Seq,
        );
        matmul(
            xm.rb_mut(),
            Accum::Replace,
            t.rb(),
            self.cv.transpose(),
            1.0,
            Par::Seq,
        );
        for b in 0..nv {
            for a in 0..nu {
                xm[(a, b)] *= self.inv[(a, b)];
            }
        }
        matmul(
            t.rb_mut(),
            Accum::Replace,
            xm.rb(),
            self.cv.as_ref(),
            1.0,
            Par::Seq,
        );
        matmul(
            xm.rb_mut(),
            Accum::Replace,
            self.cu.transpose(),
            t.rb(),
            1.0,
            Par::Seq,
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::solve::tv::{add_divergence_adjoint, gradient};
    use crate::transport::MemoryBudget;

    /// A Gram of rank `r` with eigenvalues spread over `decades`, `n x n`.
    fn low_rank_gram(n: usize, r: usize, decades: f64) -> Mat<f64> {
        // Columns of a smooth random-ish matrix, scaled.
        let t = Mat::<f64>::from_fn(3 * n, r, |i, k| {
            let x = ((i * 7919 + k * 104729) % 1000) as f64 / 1000.0 - 0.5;
            x * 10f64.powf(-decades * k as f64 / r as f64)
        });
        let mix = Mat::<f64>::from_fn(r, n, |k, j| (((k + 3) * (j + 11)) % 17) as f64 / 17.0 - 0.4);
        let tt = &t * &mix;
        tt.transpose() * &tt
    }

    fn s_apply(grid: Grid, x: &[f64]) -> Vec<f64> {
        let n = grid.count();
        let mut g = vec![0.0; 2 * n];
        gradient(grid, x, &mut g);
        let mut out = x.to_vec();
        add_divergence_adjoint(grid, &g, &mut out);
        out
    }

    #[test]
    fn neumann_inverts_d_transpose_d_plus_identity() {
        let grid = Grid { nu: 5, nv: 3 };
        let n = grid.count();
        let x: Vec<f64> = (0..n).map(|k| ((k * 13) % 7) as f64 - 2.5).collect();
        let mut y = s_apply(grid, &x);
        Neumann::new(grid).solve(&mut y, &mut vec![0.0; n]);
        for (a, b) in x.iter().zip(&y) {
            assert!((a - b).abs() < 1e-12, "{a} {b}");
        }
    }

    #[test]
    fn pivoted_cholesky_stops_at_the_rank() {
        let g = low_rank_gram(60, 12, 4.0);
        let trace: f64 = (0..60).map(|k| g[(k, k)]).sum();
        let (w, piv, rem) = pivoted_cholesky(g.as_ref(), 1e-13 * trace, 60, Par::Seq).unwrap();
        assert_eq!(piv.len(), w.ncols());
        assert!(w.ncols() <= 12, "rank {}", w.ncols());
        let e = &g - &w * w.transpose();
        let err = (0..60)
            .flat_map(|i| (0..60).map(move |j| (i, j)))
            .map(|(i, j)| e[(i, j)].abs())
            .fold(0.0, f64::max);
        assert!(err <= 1e-12 * trace && rem <= 1e-13 * trace, "{err} {rem}");
        assert!(pivoted_cholesky(g.as_ref(), 1e-13 * trace, 5, Par::Seq).is_none());
    }

    #[test]
    fn woodbury_solves_the_admm_system() {
        let grid = Grid { nu: 8, nv: 6 };
        let n = grid.count();
        let g = low_rank_gram(n, 10, 3.0);
        let lr = LowRank::of_gram(g.as_ref(), grid, Par::Seq).unwrap();
        let rho = 1e-3 * g[(0, 0)];
        let f = lr.factor(rho).unwrap();
        let x: Vec<f64> = (0..n).map(|k| ((k * 5) % 11) as f64 / 11.0).collect();
        let sx = s_apply(grid, &x);
        let mut b: Vec<f64> = (0..n)
            .map(|i| (0..n).map(|j| g[(i, j)] * x[j]).sum::<f64>() + rho * sx[i])
            .collect();
        lr.solve(&f, rho, &mut b, &mut Workspace::default());
        for (a, c) in x.iter().zip(&b) {
            assert!((a - c).abs() < 1e-8, "{a} {c}");
        }
    }

    /// Pseudo-random numbers in [-0.5, 0.5) (an LCG: reproducible, no dependency).
    fn noise(seed: u64, rows: usize, cols: usize) -> Mat<f64> {
        let mut x = seed;
        Mat::from_fn(rows, cols, |_, _| {
            x = x
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (x >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        })
    }

    #[test]
    fn spectrum_matches_the_svd_above_the_resolution() {
        // T = U diag(s) V^T, 192 x 64 of rank 12, kappa 1e5 over the rank.
        let (m, n, r) = (192, 64, 12);
        let u = noise(1, m, r).qr().compute_thin_Q();
        let v = noise(2, n, r).qr().compute_thin_Q();
        let s = Mat::<f64>::from_fn(r, r, |i, j| {
            if i == j {
                10f64.powf(-5.0 * i as f64 / (r - 1) as f64)
            } else {
                0.0
            }
        });
        let t = &u * &s * v.transpose();
        let g = t.transpose() * &t;
        let lr = LowRank::of_gram(g.as_ref(), Grid { nu: 8, nv: 8 }, Par::Seq).unwrap();
        let ours = lr.singular_values().unwrap();
        let svd = t.singular_values().unwrap();
        assert_eq!(lr.rank(), r);
        for k in 0..r {
            assert!(
                (ours[k] / svd[k] - 1.0).abs() < 1e-6,
                "{k}: {} {}",
                ours[k],
                svd[k]
            );
        }
        let c = crate::solve::Conditioning::from_low_rank(m, n, &lr).unwrap();
        assert_eq!(c.rank, r);
        assert!(c.is_rank_deficient());
    }

    #[test]
    fn admm_through_the_low_rank_form_matches_the_dense_factor() {
        use crate::solve::gram::Normal;
        use crate::solve::solvers::{AdmmSettings, Solver};
        let scene = crate::scene::Scene::builtin("brewster-multi")
            .unwrap()
            .unwrap()
            .edit(|s| s.hidden.plane.grid = Grid { nu: 24, nv: 24 })
            .unwrap();
        let t = crate::transport::build(&scene, MemoryBudget::DEFAULT).unwrap();
        let truth = crate::simulate::patterns::Pattern::Letter.render(t.scene_grid());
        let i: Vec<f64> = t
            .apply(&truth)
            .iter()
            .zip(noise(3, t.rows(), 1).col(0).iter())
            .map(|(a, b)| a * (1.0 + 0.02 * b))
            .collect();
        let dense = Normal::new(t.as_mat(), &i);
        let low = Normal::of(&t, &i);
        assert!(low.low_rank().is_some());
        let settings = AdmmSettings {
            lambda: Some(1e-3 * dense.unit()),
            max_iter: 5000,
            tol: 1e-5,
            ..AdmmSettings::default()
        };
        let a = Solver::ADMM_TV
            .run(&settings.problem(&t, &i, &dense))
            .unwrap();
        let b = Solver::ADMM_TV
            .run(&settings.problem(&t, &i, &low))
            .unwrap();
        println!(
            "dense {} iterations, low-rank {}",
            a.stats.iterations, b.stats.iterations
        );
        assert!(a.stats.converged && b.stats.converged);
        let diff = a
            .image
            .iter()
            .zip(&b.image)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f64::max);
        let misfit = (a.stats.data_misfit / b.stats.data_misfit - 1.0).abs();
        assert!(
            diff < 1e-3 && misfit < 1e-4,
            "image {diff:.2e}, misfit {misfit:.2e}"
        );
    }
}
