//! Time-resolved (active) NLOS transport, the paper's appendix (Eqs. 13-15,
//! Fig. 10): a pulsed laser lights one wall spot `p`, light bounces off a
//! hidden voxel of albedo `rho_k` back to wall patch `c`, and a time-resolved
//! detector at the camera bins the photons by path length.
//!
//! MODEL.md does not fix this model; our reading, written out here so an
//! independent implementation can match it:
//!
//! ```text
//! T[(block, j, b), k] = a_k / pi
//!     * f(p; w_l -> w_px) (n.w_px) / |x - p|^2        first bounce, laser side
//!     * (n.w_cx) / |x - c|^2                            voxel to patch
//!     * f(c; w_cx -> w_co, polarizer of the block)      camera-side bounce
//!     * V(p, x) V(x, c)
//!     * [ b = floor((|p - x| + |x - c| - d0) / width) ]
//! ```
//!
//! with `x` the voxel (a scene element centre, area `a_k`, scattering
//! isotropically), `w_l` the direction from `p` to the laser (co-located
//! with the pose's camera), `f` the wall BRDF of MODEL.md (the first bounce
//! without a polarizer: the laser is taken as unpolarized), unit laser power
//! into the spot, and `d0` the shortest `|p - x| + |x - c|` of the scene. The
//! known legs laser-to-`p` and `c`-to-camera are subtracted, as usual. Rows:
//! blocks in scene order, then wall elements, then time bins; columns: voxels.

use rayon::prelude::*;

use super::build::blocks_of;
use super::{MemoryBudget, Transport, TransportError};
use crate::optics::{Polarization, Vec3};
use crate::scene::{Grid, Scene};

/// The active measurement set-up.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ActiveSetup {
    /// Laser spot `p` in wall coordinates (metres from the wall centre, u, v).
    pub spot: (f64, f64),
    /// Path-length width of one time bin, metres (1 cm is 33 ps).
    pub bin_width: f64,
}

impl Default for ActiveSetup {
    fn default() -> Self {
        Self {
            spot: (0.0, 0.0),
            bin_width: 0.01,
        }
    }
}

/// A time-resolved `T` and its time axis.
#[derive(Debug, Clone)]
pub struct ActiveTransport {
    /// The matrix; its `wall_grid` is `(bins, wall elements)`: within a block,
    /// row `j * bins + b` is wall element `j`, time bin `b`.
    pub t: Transport,
    /// Number of time bins.
    pub bins: usize,
    /// Path length `d0` at the start of bin 0, metres.
    pub d0: f64,
}

/// Builds the time-resolved transport of `scene` (wall, voxels on the scene
/// grid, poses as laser + detector positions, occluders), refusing one over `budget`.
pub fn build_active(
    scene: &Scene,
    setup: &ActiveSetup,
    budget: MemoryBudget,
) -> Result<ActiveTransport, TransportError> {
    check_setup(scene, setup)?;
    let wall = &scene.wall().plane;
    let p = wall.point(setup.spot.0, setup.spot.1);
    let patches = element_centres(wall);
    let voxels = element_centres(&scene.hidden().plane);
    let n_wall = patches.len();
    let n_vox = voxels.len();

    let (d0, d1) = path_range(&p, &voxels, &patches);
    let bins = ((d1 - d0) / setup.bin_width).floor() as usize + 1;
    let blocks = blocks_of(scene);
    let per_block = n_wall * bins;
    let rows = per_block * blocks.len();
    super::check_size(budget, rows, n_vox, bins * blocks.len(), 0.0)?;

    let views = block_views(scene, &p, &patches);
    let time = TimeBins {
        d0,
        width: setup.bin_width,
        count: bins,
    };
    let data = fill_columns(scene, &p, &voxels, &patches, &views, &time, rows);
    Ok(ActiveTransport {
        t: Transport::from_col_major(
            rows,
            n_vox,
            data,
            blocks,
            Grid {
                nu: bins,
                nv: n_wall,
            },
            scene.hidden().plane.grid,
        ),
        bins,
        d0,
    })
}

/// Refuses a bin width that is not a positive length, `"pixels"` wall sampling, and a spot off the wall.
/// Checked before anything is computed, so a bad set-up is a named error, not a wrong matrix.
fn check_setup(scene: &Scene, setup: &ActiveSetup) -> Result<(), TransportError> {
    if !(setup.bin_width > 0.0 && setup.bin_width.is_finite()) {
        return Err(TransportError::Parameter {
            name: "bin-width",
            value: setup.bin_width,
            reason: "must be a positive path length in metres",
        });
    }
    if scene.wall().sampling == crate::scene::WallSampling::Pixels {
        return Err(TransportError::ActivePixels);
    }
    if scene.hidden().shadows == crate::scene::ShadowModel::Area {
        return Err(TransportError::ActiveArea);
    }
    let wall = &scene.wall().plane;
    let (hu, hv) = (0.5 * wall.size[0], 0.5 * wall.size[1]);
    if setup.spot.0.abs() > hu || setup.spot.1.abs() > hv {
        return Err(TransportError::Parameter {
            name: "spot",
            value: setup.spot.0.abs().max(setup.spot.1.abs()),
            reason: "the laser spot must lie on the wall",
        });
    }
    Ok(())
}

/// The centre of every element of `plane` (its sample points at supersample 1).
/// The active model takes each wall patch and each voxel as one point, not an average.
fn element_centres(plane: &crate::scene::Plane) -> Vec<Vec3> {
    let mut c = plane.clone();
    c.supersample = 1;
    c.sample_points()
}

/// The shortest and longest path `|p - x| + |x - c|` over voxels `x` and wall patches `c`.
/// The shortest is `d0`, the start of bin 0; with the longest they fix the number of bins.
fn path_range(p: &Vec3, voxels: &[Vec3], patches: &[Vec3]) -> (f64, f64) {
    let path = |x: &Vec3, c: &Vec3| (x - p).norm() + (x - c).norm();
    let (mut d0, mut d1) = (f64::INFINITY, f64::NEG_INFINITY);
    for x in voxels {
        for c in patches {
            let d = path(x, c);
            d0 = d0.min(d);
            d1 = d1.max(d);
        }
    }
    (d0, d1)
}

/// The time axis: `d0` at the start of bin 0, bin `width` and `count` bins, metres of path.
/// Kept together because every entry's bin is computed from all three.
struct TimeBins {
    d0: f64,
    width: f64,
    count: usize,
}

/// Per block, computed once: the direction from the spot to the laser and,
/// per patch, the direction to the camera and the effective analyzer axis.
struct BlockView {
    w_l: Vec3,
    analyzer: Option<crate::scene::Analyzer>,
    to_camera: Vec<(Vec3, Option<Vec3>)>,
}

/// One [`BlockView`] per block of `scene`, in block order, for spot `p` and wall `patches`.
/// Computed once, outside the per-voxel loop, which only reads them.
fn block_views(scene: &Scene, p: &Vec3, patches: &[Vec3]) -> Vec<BlockView> {
    let p = *p;
    scene
        .poses()
        .iter()
        .flat_map(|pose| {
            let axes: Vec<Option<crate::scene::Analyzer>> = if pose.analyzers.is_empty() {
                vec![None]
            } else {
                pose.analyzers.iter().copied().map(Some).collect()
            };
            let model = scene.polarizer();
            let cam = pose.camera;
            axes.into_iter().map(move |q| BlockView {
                w_l: (cam - p).normalize(),
                analyzer: q,
                to_camera: patches
                    .iter()
                    .map(|c| {
                        let w_co = (cam - c).normalize();
                        let t = q.map(|a| a.effective_axis(model, &w_co));
                        (w_co, t)
                    })
                    .collect(),
            })
        })
        .collect()
}

/// The column-major entries of `T`, one voxel per column in parallel (the formula of this module's doc).
/// The first bounce is computed once per voxel and block, the camera-side bounce per patch and block.
fn fill_columns(
    scene: &Scene,
    p: &Vec3,
    voxels: &[Vec3],
    patches: &[Vec3],
    views: &[BlockView],
    time: &TimeBins,
    rows: usize,
) -> Vec<f64> {
    let p = *p;
    let n = scene.wall().plane.normal;
    let brdf = scene.wall().brdf;
    let area = scene.hidden().plane.element_area();
    let (d0, bins) = (time.d0, time.count);
    let per_block = patches.len() * bins;
    let mut data = vec![0.0; rows * voxels.len()];
    super::build::columns_mut(&mut data, rows).for_each(|(k, col)| {
        let x = voxels[k];
        let to_x = x - p;
        let r_px = to_x.norm();
        let w_px = to_x / r_px;
        if n.dot(&w_px) <= 0.0 || scene.occluders().iter().any(|o| o.blocks(&x, &p)) {
            return;
        }
        let no_polarizer = Polarization {
            analyzer: None,
            source: None,
        };
        let first: Vec<f64> = views
            .iter()
            .map(|v| {
                area / std::f64::consts::PI
                    * brdf.eval(&n, &v.w_l, &w_px, no_polarizer)
                    * n.dot(&w_px)
                    / (r_px * r_px)
            })
            .collect();
        for (j, c) in patches.iter().enumerate() {
            let to_x = x - c;
            let r = to_x.norm();
            let w_cx = to_x / r;
            let cos = n.dot(&w_cx);
            if cos <= 0.0 || scene.occluders().iter().any(|o| o.blocks(&x, c)) {
                continue;
            }
            let b = (((r_px + r - d0) / time.width).floor() as usize).min(bins - 1);
            for (blk, v) in views.iter().enumerate() {
                if first[blk] == 0.0 {
                    continue;
                }
                let (w_co, t) = &v.to_camera[j];
                let through = |t: Option<&Vec3>| {
                    brdf.eval(
                        &n,
                        &w_cx,
                        w_co,
                        Polarization {
                            analyzer: t,
                            source: None,
                        },
                    )
                };
                // A partial polarizer also passes 1/E of the crossed axis.
                let f_c = match (&v.analyzer, t) {
                    (Some(a), Some(t)) => a.weigh(t, w_co, |t| through(Some(t))),
                    _ => through(None),
                };
                col[blk * per_block + j * bins + b] += first[blk] * cos / (r * r) * f_c;
            }
        }
    });
    data
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scene(name: &str) -> Scene {
        Scene::builtin(name).unwrap().unwrap()
    }

    #[test]
    fn one_entry_matches_the_formula_written_out() {
        let s = scene("brewster-nopol-3x3");
        let a = build_active(&s, &ActiveSetup::default(), MemoryBudget::DEFAULT).unwrap();
        let wall = &s.wall().plane;
        let (j, k) = (wall.grid.index(20, 9), 4);
        let c = wall.point(wall.local(20, 9, 0, 0).0, wall.local(20, 9, 0, 0).1);
        let sp = &s.hidden().plane;
        let (iu, iv) = sp.grid.coords(k);
        let (u, v) = sp.local(iu, iv, 0, 0);
        let x = sp.point(u, v);
        let p = wall.center;
        let o = s.poses()[0].camera;
        let n = wall.normal;
        let no = Polarization {
            analyzer: None,
            source: None,
        };
        let (wl, wpx, wcx, wco) = (
            (o - p).normalize(),
            (x - p).normalize(),
            (x - c).normalize(),
            (o - c).normalize(),
        );
        let expect = sp.element_area() / std::f64::consts::PI
            * s.wall().brdf.eval(&n, &wl, &wpx, no)
            * n.dot(&wpx)
            / (x - p).norm_squared()
            * n.dot(&wcx)
            / (x - c).norm_squared()
            * s.wall().brdf.eval(&n, &wcx, &wco, no);
        let b = (((x - p).norm() + (x - c).norm() - a.d0) / 0.01).floor() as usize;
        let got = a.t.get(j * a.bins + b, k);
        assert!((got / expect - 1.0).abs() < 1e-12, "{got} vs {expect}");
        // Every other bin of that (patch, voxel) is empty.
        for bb in (0..a.bins).filter(|&bb| bb != b) {
            assert_eq!(a.t.get(j * a.bins + bb, k), 0.0);
        }
    }

    #[test]
    fn the_crossed_polarizer_only_removes_light_and_time_covers_the_paths() {
        let open = build_active(
            &scene("brewster-nopol-3x3"),
            &ActiveSetup::default(),
            MemoryBudget::DEFAULT,
        )
        .unwrap();
        let crossed = build_active(
            &scene("brewster-crossed-3x3"),
            &ActiveSetup::default(),
            MemoryBudget::DEFAULT,
        )
        .unwrap();
        assert_eq!(open.t.rows(), crossed.t.rows());
        let mut fewer = 0;
        for (a, b) in crossed.t.col_major().iter().zip(open.t.col_major()) {
            assert!(*a <= *b * (1.0 + 1e-12));
            if *a < 0.5 * *b {
                fewer += 1;
            }
        }
        assert!(fewer > 0);
        // Path lengths on the bench span about 0.17 m (the wall is 0.30 m wide).
        assert!((10..40).contains(&open.bins), "{}", open.bins);
        assert!(open.d0 > 0.6 && open.d0 < 1.0, "{}", open.d0);
    }

    #[test]
    fn bad_setups_are_named() {
        let s = scene("brewster-nopol-3x3");
        let e = build_active(
            &s,
            &ActiveSetup {
                bin_width: 0.0,
                ..ActiveSetup::default()
            },
            MemoryBudget::DEFAULT,
        )
        .unwrap_err();
        assert!(e.to_string().starts_with("bin-width = 0"), "{e}");
        let e = build_active(
            &s,
            &ActiveSetup {
                spot: (0.5, 0.0),
                ..ActiveSetup::default()
            },
            MemoryBudget::DEFAULT,
        )
        .unwrap_err();
        assert!(e.to_string().contains("spot"), "{e}");
        // Area shadows are a passive scene's; the active build would
        // silently test points.
        let area = s
            .edit(|p| p.hidden.shadows = crate::scene::ShadowModel::Area)
            .unwrap();
        let e = build_active(&area, &ActiveSetup::default(), MemoryBudget::DEFAULT).unwrap_err();
        assert!(e.to_string().contains("shadows = \"point\""), "{e}");
    }
}
