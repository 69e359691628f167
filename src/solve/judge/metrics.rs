//! Image quality of a recovered scene against the truth (MODEL.md "Metrics"):
//! PSNR with peak 1, ZNCC, and SSIM (Wang et al. 2004: 7x7 Gaussian window,
//! sigma 1.5, K1 = 0.01, K2 = 0.03, 'valid' filtering, population statistics).

use crate::scene::Grid;

/// The three metrics together (the `metrics` object of `report.json`).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Metrics {
    /// Peak signal-to-noise ratio in dB (infinite for a perfect match, serialized `"inf"`).
    #[serde(serialize_with = "crate::solve::json::finite_or_inf")]
    pub psnr_db: f64,
    /// Zero-mean normalized cross-correlation in [-1, 1].
    pub zncc: f64,
    /// Mean structural similarity.
    pub ssim: f64,
}

/// All metrics of `x` against the truth `truth` on `grid`.
pub fn compare(grid: Grid, truth: &[f64], x: &[f64]) -> Metrics {
    Metrics {
        psnr_db: psnr(truth, x),
        zncc: zncc(truth, x),
        ssim: ssim(grid, truth, x),
    }
}

/// `10 log10(1 / MSE)` (peak 1).
pub fn psnr(truth: &[f64], x: &[f64]) -> f64 {
    assert_eq!(truth.len(), x.len());
    let mse = truth
        .iter()
        .zip(x)
        .map(|(a, b)| (a - b) * (a - b))
        .sum::<f64>()
        / truth.len().max(1) as f64;
    if mse == 0.0 {
        f64::INFINITY
    } else {
        -10.0 * mse.log10()
    }
}

/// Zero-mean normalized cross-correlation; 0 when either image is constant.
pub fn zncc(a: &[f64], b: &[f64]) -> f64 {
    assert_eq!(a.len(), b.len());
    let n = a.len().max(1) as f64;
    let ma = a.iter().sum::<f64>() / n;
    let mb = b.iter().sum::<f64>() / n;
    let (mut sab, mut saa, mut sbb) = (0.0, 0.0, 0.0);
    for (x, y) in a.iter().zip(b) {
        let (dx, dy) = (x - ma, y - mb);
        sab += dx * dy;
        saa += dx * dx;
        sbb += dy * dy;
    }
    if saa == 0.0 || sbb == 0.0 {
        0.0
    } else {
        sab / (saa * sbb).sqrt()
    }
}

/// Side of the SSIM window on a grid: 7, or the largest odd size that fits.
pub(crate) fn ssim_window(grid: Grid) -> usize {
    let fit = grid.nu.min(grid.nv).min(7);
    if fit.is_multiple_of(2) {
        fit - 1
    } else {
        fit
    }
}

/// Mean SSIM over every valid window position.
pub fn ssim(grid: Grid, a: &[f64], b: &[f64]) -> f64 {
    assert_eq!(a.len(), grid.count());
    assert_eq!(b.len(), grid.count());
    let w = ssim_window(grid);
    let half = (w / 2) as f64;
    let mut kernel = vec![0.0; w * w];
    for y in 0..w {
        for x in 0..w {
            let (dx, dy) = (x as f64 - half, y as f64 - half);
            kernel[y * w + x] = (-(dx * dx + dy * dy) / (2.0 * 1.5 * 1.5)).exp();
        }
    }
    let ksum: f64 = kernel.iter().sum();
    kernel.iter_mut().for_each(|k| *k /= ksum);
    let (c1, c2) = ((0.01f64).powi(2), (0.03f64).powi(2));
    let mut total = 0.0;
    let mut count = 0usize;
    for oy in 0..=grid.nv - w {
        for ox in 0..=grid.nu - w {
            let (mut ma, mut mb, mut saa, mut sbb, mut sab) = (0.0, 0.0, 0.0, 0.0, 0.0);
            for y in 0..w {
                for x in 0..w {
                    let k = kernel[y * w + x];
                    let j = grid.index(ox + x, oy + y);
                    let (p, q) = (a[j], b[j]);
                    ma += k * p;
                    mb += k * q;
                    saa += k * p * p;
                    sbb += k * q * q;
                    sab += k * p * q;
                }
            }
            let (va, vb, cov) = (saa - ma * ma, sbb - mb * mb, sab - ma * mb);
            total += ((2.0 * ma * mb + c1) * (2.0 * cov + c2))
                / ((ma * ma + mb * mb + c1) * (va + vb + c2));
            count += 1;
        }
    }
    total / count as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn psnr_known_value() {
        // MSE 0.01 everywhere -> 20 dB.
        let a = vec![0.5; 16];
        let b = vec![0.6; 16];
        assert!((psnr(&a, &b) - 20.0).abs() < 1e-9);
        assert!(psnr(&a, &a).is_infinite());
    }

    #[test]
    fn zncc_limits() {
        let a: Vec<f64> = (0..10).map(|i| i as f64).collect();
        let b: Vec<f64> = a.iter().map(|v| 3.0 * v + 1.0).collect();
        let c: Vec<f64> = a.iter().map(|v| -v).collect();
        assert!((zncc(&a, &b) - 1.0).abs() < 1e-15);
        assert!((zncc(&a, &c) + 1.0).abs() < 1e-15);
        assert_eq!(zncc(&a, &[2.0; 10]), 0.0);
    }

    #[test]
    fn ssim_identity_and_window() {
        let g = Grid { nu: 16, nv: 16 };
        let a: Vec<f64> = (0..256).map(|i| ((i * 37) % 101) as f64 / 100.0).collect();
        assert!((ssim(g, &a, &a) - 1.0).abs() < 1e-12);
        assert_eq!(ssim_window(Grid { nu: 3, nv: 3 }), 3);
        assert_eq!(ssim_window(Grid { nu: 8, nv: 6 }), 5);
        assert_eq!(ssim_window(Grid { nu: 1, nv: 9 }), 1);
        // A dimmer copy loses luminance similarity only.
        let b: Vec<f64> = a.iter().map(|v| 0.5 * v).collect();
        let s = ssim(g, &a, &b);
        assert!(s < 0.95 && s > 0.3, "{s}");
    }

    #[test]
    fn ssim_single_window_by_hand() {
        // 1x1 window: SSIM of two pixels p, q is (2pq + c1)(c2)/((p^2 + q^2 + c1)(c2)).
        let g = Grid { nu: 1, nv: 1 };
        let (p, q) = (0.2f64, 0.6f64);
        let c1 = 1e-4;
        let expect = (2.0 * p * q + c1) / (p * p + q * q + c1);
        assert!((ssim(g, &[p], &[q]) - expect).abs() < 1e-12);
    }
}
