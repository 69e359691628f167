//! Wall and radiometric calibration: the wall's GGX roughness `alpha`,
//! refractive index and diffuse weight `kd`, and the radiometric gain, from
//! captures of a point source at a known place on the hidden-scene plane.
//!
//! The model is MODEL.md's forward model itself: a point source is the
//! hidden scene shrunk to one small element at the source, so the predicted
//! measurement is `gain * T(alpha, ior, kd) e` with `T` built by the same
//! code as always. Levenberg-Marquardt fits the four numbers; their standard
//! errors come from `s^2 (J^T J)^-1` with `s^2` the residual variance. A fit
//! whose residual stays large is refused: the geometry (source position,
//! poses) does not match the capture, and its numbers would mean nothing.

use nalgebra::{SMatrix, SVector};

use crate::scene::{Grid, Scene};
use crate::transport::{build, TransportError};

/// Why a wall fit could not be made.
#[derive(Debug, thiserror::Error)]
pub enum WallFitError {
    /// The point-source transport could not be built for these parameters.
    #[error("the point-source model of the scene could not be built: {0}")]
    Model(#[source] TransportError),
    /// The measurement does not have one value per row of the scene's `T`.
    #[error("the measurement has {measurement} values but the scene's T has {rows} rows (one per wall element of every pose and polarizer angle, MODEL.md row order)")]
    Length {
        /// Values in the measurement.
        measurement: usize,
        /// Rows of `T`.
        rows: usize,
    },
    /// The best fit leaves too much of the measurement unexplained.
    #[error("the point-source model leaves {percent:.0}% of the measurement unexplained (at most {limit:.0}% is accepted): the source position or the poses' homographies do not match the capture, so no wall parameters are reported")]
    Unexplained {
        /// `100 ||i - model|| / ||i||`.
        percent: f64,
        /// The accepted limit, percent.
        limit: f64,
    },
}

/// Side of the small square that stands for the point source, metres.
const SOURCE_SIDE_M: f64 = 0.005;
/// Largest relative residual `||i - model|| / ||i||` of an accepted fit.
pub const MAX_RELATIVE_RESIDUAL: f64 = 0.25;

/// Where the point source is: metres from the hidden-scene plane's centre
/// along its `u` and `v` axes.
#[derive(Debug, Clone, Copy, PartialEq, serde::Deserialize, serde::Serialize)]
pub struct PointSource {
    /// Along the scene plane's `u`.
    pub u: f64,
    /// Along the scene plane's `v`.
    pub v: f64,
}

/// The fitted numbers: wall material and radiometric gain.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct WallParams {
    /// GGX roughness.
    pub alpha: f64,
    /// Refractive index.
    pub ior: f64,
    /// Diffuse weight.
    pub kd: f64,
    /// Measurement per unit of `T l` for the source (fraction of full scale
    /// per microsecond when `i` is in those units).
    pub gain: f64,
}

/// A fit with standard errors.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct WallFit {
    /// Best values.
    pub params: WallParams,
    /// Their standard errors (same fields).
    pub sigma: WallParams,
    /// RMS of the residual, in the units of `i`.
    pub residual_rms: f64,
    /// `||i - model|| / ||i||`.
    pub relative_residual: f64,
    /// Levenberg-Marquardt iterations.
    pub iterations: usize,
}

impl WallParams {
    fn to_vec(self) -> SVector<f64, 4> {
        SVector::from([self.alpha, self.ior, self.kd, self.gain])
    }

    /// Within the model's ranges (MODEL.md: alpha in (0, 1], ior > 1, kd >= 0).
    fn from_vec(p: &SVector<f64, 4>) -> Self {
        Self {
            alpha: p[0].clamp(0.01, 1.0),
            ior: p[1].clamp(1.01, 5.0),
            kd: p[2].clamp(0.0, 10.0),
            gain: p[3].max(1e-300),
        }
    }
}

/// The scene with its hidden plane shrunk to the point source and the wall
/// material set to `p`.
fn point_scene(scene: &Scene, source: &PointSource, p: &WallParams) -> Scene {
    let mut s = scene.clone();
    let plane = &mut s.scene.plane;
    plane.center = plane.center + plane.u * source.u + plane.v * source.v;
    plane.size = [SOURCE_SIDE_M, SOURCE_SIDE_M];
    plane.grid = Grid { nu: 1, nv: 1 };
    s.wall.brdf.alpha = p.alpha;
    s.wall.brdf.eta = p.ior;
    s.wall.brdf.kd = p.kd;
    s
}

/// The measurement the model predicts for the source: `gain * T e`, in
/// MODEL.md row order.
pub fn predict(
    scene: &Scene,
    source: &PointSource,
    p: &WallParams,
) -> Result<Vec<f64>, WallFitError> {
    let t = build(&point_scene(scene, source, p)).map_err(WallFitError::Model)?;
    Ok(t.apply(&[1.0]).into_iter().map(|v| v * p.gain).collect())
}

/// Fits alpha, ior, kd and the gain to measurement `i` of a point source
/// at `source`, from `start`.
pub fn fit(
    scene: &Scene,
    source: &PointSource,
    i: &[f64],
    start: WallParams,
) -> Result<WallFit, WallFitError> {
    let model = |p: &SVector<f64, 4>| predict(scene, source, &WallParams::from_vec(p));
    let first = model(&start.to_vec())?;
    if first.len() != i.len() {
        return Err(WallFitError::Length {
            measurement: i.len(),
            rows: first.len(),
        });
    }
    let residual = |m: &[f64]| -> Vec<f64> { i.iter().zip(m).map(|(a, b)| a - b).collect() };
    let ss = |r: &[f64]| r.iter().map(|x| x * x).sum::<f64>();
    let mut p = start.to_vec();
    let mut r = residual(&first);
    let mut cost = ss(&r);
    let mut mu = 1e-3;
    let mut iterations = 0;
    let mut jac = jacobian(&model, &p)?;
    for _ in 0..60 {
        iterations += 1;
        let jtj = jac.0;
        let jtr =
            SVector::<f64, 4>::from_fn(|a, _| jac.1[a].iter().zip(&r).map(|(j, e)| j * e).sum());
        let mut improved = false;
        for _ in 0..12 {
            let mut m = jtj;
            for d in 0..4 {
                m[(d, d)] += mu * jtj[(d, d)].max(1e-30);
            }
            let Some(delta) = m.lu().solve(&jtr) else {
                break;
            };
            let next = WallParams::from_vec(&(p + delta)).to_vec();
            let rn = residual(&model(&next)?);
            let c = ss(&rn);
            if c < cost {
                let gain = (cost - c) / cost.max(1e-300);
                (p, r, cost) = (next, rn, c);
                mu = (mu * 0.3).max(1e-12);
                improved = gain > 1e-12;
                break;
            }
            mu *= 10.0;
        }
        if !improved {
            break;
        }
        jac = jacobian(&model, &p)?;
    }
    let norm = i.iter().map(|x| x * x).sum::<f64>().sqrt().max(1e-300);
    let relative_residual = cost.sqrt() / norm;
    if relative_residual > MAX_RELATIVE_RESIDUAL {
        return Err(WallFitError::Unexplained {
            percent: 100.0 * relative_residual,
            limit: 100.0 * MAX_RELATIVE_RESIDUAL,
        });
    }
    let dof = (i.len() as f64 - 4.0).max(1.0);
    let s2 = cost / dof;
    let cov = jac.0.try_inverse().map(|c| c * s2);
    let sd = |k: usize| {
        cov.as_ref()
            .map_or(f64::INFINITY, |c| c[(k, k)].max(0.0).sqrt())
    };
    Ok(WallFit {
        params: WallParams::from_vec(&p),
        sigma: WallParams {
            alpha: sd(0),
            ior: sd(1),
            kd: sd(2),
            gain: sd(3),
        },
        residual_rms: (cost / i.len() as f64).sqrt(),
        relative_residual,
        iterations,
    })
}

/// [`fit`] from the scene file's own wall material, with the gain that best
/// scales that material's prediction onto `i` (linear least squares).
pub fn fit_from_scene(
    scene: &Scene,
    source: &PointSource,
    i: &[f64],
) -> Result<WallFit, WallFitError> {
    let b = scene.wall.brdf;
    let unit = WallParams {
        alpha: b.alpha,
        ior: b.eta,
        kd: b.kd,
        gain: 1.0,
    };
    let m = predict(scene, source, &unit)?;
    let (dot, nn) = m
        .iter()
        .zip(i)
        .fold((0.0, 0.0), |(d, n), (a, x)| (d + a * x, n + a * a));
    let gain = if nn > 0.0 && dot > 0.0 { dot / nn } else { 1.0 };
    fit(scene, source, i, WallParams { gain, ..unit })
}

type Model<'a> = dyn Fn(&SVector<f64, 4>) -> Result<Vec<f64>, WallFitError> + 'a;

/// `J^T J` and the columns of `J` (derivatives of the model) by central
/// differences.
fn jacobian(
    model: &Model<'_>,
    p: &SVector<f64, 4>,
) -> Result<(SMatrix<f64, 4, 4>, Vec<Vec<f64>>), WallFitError> {
    let mut cols = Vec::with_capacity(4);
    for k in 0..4 {
        let step = 1e-5 * p[k].abs().max(1e-3);
        let (mut a, mut b) = (*p, *p);
        a[k] += step;
        b[k] -= step;
        let (ma, mb) = (model(&a)?, model(&b)?);
        cols.push(
            ma.iter()
                .zip(&mb)
                .map(|(x, y)| (x - y) / (2.0 * step))
                .collect::<Vec<f64>>(),
        );
    }
    let jtj = SMatrix::<f64, 4, 4>::from_fn(|a, b| {
        cols[a].iter().zip(&cols[b]).map(|(x, y)| x * y).sum()
    });
    Ok((jtj, cols))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scene() -> Scene {
        match Scene::builtin("brewster-rotating") {
            Some(Ok(s)) => s,
            _ => panic!("scene"),
        }
    }

    /// Adds relative noise `level` (uniform, fixed seed).
    fn noisy(v: &[f64], level: f64) -> Vec<f64> {
        let peak = v.iter().copied().fold(0.0, f64::max);
        let mut seed = 0x9E37_79B9_7F4A_7C15u64;
        v.iter()
            .map(|x| {
                seed ^= seed << 13;
                seed ^= seed >> 7;
                seed ^= seed << 17;
                let u = (seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5;
                x + level * peak * u
            })
            .collect()
    }

    #[test]
    fn simulated_point_source_captures_give_back_the_wall() {
        let s = scene();
        let source = PointSource { u: 0.03, v: -0.02 };
        let truth = WallParams {
            alpha: 0.3,
            ior: 1.5,
            kd: 0.05,
            gain: 2.0,
        };
        let i = noisy(&predict(&s, &source, &truth).expect("model"), 0.005);
        let start = WallParams {
            alpha: 0.5,
            ior: 1.3,
            kd: 0.0,
            gain: 1.0,
        };
        let f = fit(&s, &source, &i, start).expect("fit");
        println!("{f:?}");
        let p = f.params;
        assert!((p.alpha - 0.3).abs() < 0.02, "{f:?}");
        assert!((p.ior - 1.5).abs() < 0.05, "{f:?}");
        assert!((p.kd - 0.05).abs() < 0.01, "{f:?}");
        assert!((p.gain / 2.0 - 1.0).abs() < 0.05, "{f:?}");
        // The standard errors are honest: the truth within 5 of them.
        assert!((p.alpha - 0.3).abs() < 5.0 * f.sigma.alpha + 1e-3, "{f:?}");
        assert!(f.sigma.alpha > 0.0 && f.sigma.alpha.is_finite());
    }

    #[test]
    fn a_capture_of_another_geometry_is_refused_not_fitted() {
        let s = scene();
        let truth = WallParams {
            alpha: 0.3,
            ior: 1.5,
            kd: 0.05,
            gain: 2.0,
        };
        let i = predict(&s, &PointSource { u: 0.06, v: 0.06 }, &truth).expect("model");
        let e = fit(&s, &PointSource { u: -0.06, v: -0.06 }, &i, truth).expect_err("wrong place");
        assert!(e.to_string().contains("do not match the capture"), "{e}");
        assert!(!e.to_string().contains("dots"), "{e}");
        let WallFitError::Unexplained { percent, limit } = e else {
            panic!("{e}")
        };
        assert!(percent > limit && limit == 25.0, "{percent} {limit}");
        let short = fit(&s, &PointSource { u: 0.06, v: 0.06 }, &i[1..], truth).expect_err("short");
        assert!(
            matches!(short, WallFitError::Length { measurement, rows } if rows == i.len() && measurement == rows - 1),
            "{short}"
        );
    }
}
