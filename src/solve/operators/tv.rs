//! Forward differences on the scene grid and isotropic total variation
//! (MODEL.md Eq. 12, `TV2D`), with Neumann boundaries (no difference across
//! the last row or column).

use crate::scene::Grid;

/// `D l`: horizontal differences in `out[..n]`, vertical in `out[n..]`.
pub fn gradient(grid: Grid, l: &[f64], out: &mut [f64]) {
    let n = grid.count();
    let (dx, dy) = out.split_at_mut(n);
    for iv in 0..grid.nv {
        for iu in 0..grid.nu {
            let j = grid.index(iu, iv);
            dx[j] = if iu + 1 < grid.nu {
                l[j + 1] - l[j]
            } else {
                0.0
            };
            dy[j] = if iv + 1 < grid.nv {
                l[j + grid.nu] - l[j]
            } else {
                0.0
            };
        }
    }
}

/// `out += D^T z` for `z = (zx, zy)` laid out as [`gradient`] writes it.
pub(crate) fn add_divergence_adjoint(grid: Grid, z: &[f64], out: &mut [f64]) {
    let n = grid.count();
    let (zx, zy) = z.split_at(n);
    for iv in 0..grid.nv {
        for iu in 0..grid.nu {
            let j = grid.index(iu, iv);
            if iu + 1 < grid.nu {
                out[j + 1] += zx[j];
                out[j] -= zx[j];
            }
            if iv + 1 < grid.nv {
                out[j + grid.nu] += zy[j];
                out[j] -= zy[j];
            }
        }
    }
}

/// Isotropic TV, `sum_j sqrt(dx_j^2 + dy_j^2)`.
pub(crate) fn total_variation(grid: Grid, l: &[f64]) -> f64 {
    let n = grid.count();
    let mut g = vec![0.0; 2 * n];
    gradient(grid, l, &mut g);
    (0..n).map(|j| g[j].hypot(g[n + j])).sum()
}

/// Adds `scale * D^T D` to the lower triangle of a column-major `n x n` matrix
/// through `add(row, col, value)` with `row >= col`.
pub(crate) fn add_laplacian_lower(grid: Grid, scale: f64, mut add: impl FnMut(usize, usize, f64)) {
    for iv in 0..grid.nv {
        for iu in 0..grid.nu {
            let j = grid.index(iu, iv);
            let mut pair = |a: usize, b: usize| {
                add(a, a, scale);
                add(b, b, scale);
                add(b.max(a), b.min(a), -scale);
            };
            if iu + 1 < grid.nu {
                pair(j, j + 1);
            }
            if iv + 1 < grid.nv {
                pair(j, j + grid.nu);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn adjoint_is_the_transpose() {
        let grid = Grid { nu: 4, nv: 3 };
        let n = grid.count();
        let l: Vec<f64> = (0..n).map(|i| ((i * 7) % 5) as f64 - 1.3).collect();
        let z: Vec<f64> = (0..2 * n)
            .map(|i| ((i * 3) % 7) as f64 * 0.5 - 1.0)
            .collect();
        let mut dl = vec![0.0; 2 * n];
        gradient(grid, &l, &mut dl);
        let mut dtz = vec![0.0; n];
        add_divergence_adjoint(grid, &z, &mut dtz);
        let lhs: f64 = dl.iter().zip(&z).map(|(a, b)| a * b).sum();
        let rhs: f64 = l.iter().zip(&dtz).map(|(a, b)| a * b).sum();
        assert!((lhs - rhs).abs() < 1e-12);
    }

    #[test]
    fn laplacian_matches_d_transpose_d() {
        let grid = Grid { nu: 3, nv: 2 };
        let n = grid.count();
        let mut m = vec![0.0; n * n];
        add_laplacian_lower(grid, 1.0, |r, c, v| m[c * n + r] += v);
        for k in 0..n {
            let mut e = vec![0.0; n];
            e[k] = 1.0;
            let mut de = vec![0.0; 2 * n];
            gradient(grid, &e, &mut de);
            let mut dtde = vec![0.0; n];
            add_divergence_adjoint(grid, &de, &mut dtde);
            for r in k..n {
                assert_eq!(m[k * n + r], dtde[r], "({r},{k})");
            }
        }
    }

    #[test]
    fn tv_of_a_step() {
        let grid = Grid { nu: 4, nv: 2 };
        let l = [0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 1.0, 1.0];
        assert_eq!(total_variation(grid, &l), 2.0);
        assert_eq!(total_variation(grid, &[0.5; 8]), 0.0);
    }
}
