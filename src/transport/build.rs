//! Parallel assembly of `T`, one scene element (column) per task.
//!
//! Everything that depends only on the wall and a pose (direction to the
//! camera, its Smith term, each angle's effective polarizer axis `t` and
//! `b = w_o x t`) is computed once, as structure-of-arrays. For each scene
//! sub-sample the column is then filled in two branch-free passes over the
//! wall samples that the compiler vectorizes: the incident geometry, then per
//! pose the specular lobe and per angle the polarizer factor. Only what the
//! scene turns on runs: occlusion tests with occluders (only on the wall
//! samples inside each occluder's projected shadow box, see `shadow`), the
//! Jones path with a polarized source, the diffuse term with `kd > 0`. The `fresnel` diffuse
//! term (MODEL.md revision 2) factors into `T_in` of the incident direction
//! (per scene sample) and an exit factor of the pose and angle (per wall
//! sample, computed once), so it costs one Fresnel evaluation per entry.

use std::f64::consts::PI;
use std::sync::atomic::{AtomicUsize, Ordering};

use rayon::prelude::*;

use super::shadow::Shadows;
use super::{Block, MemoryBudget, Transport, TransportError};
use crate::optics::brdf::Direction;
use crate::optics::polarizer::{analyzer_factor, partial_analyzer_factor};
use crate::optics::{diffuse, ggx, DiffuseModel, Polarization, Vec3};
use crate::scene::{Emitter, PixelMap, Scene, ShadowModel, WallSampling};
use crate::stop::Stop;

/// Three coordinate arrays, one entry per wall sample.
#[derive(Default, Clone)]
struct Soa {
    x: Vec<f64>,
    y: Vec<f64>,
    z: Vec<f64>,
}

impl Soa {
    fn from_vecs(v: impl Iterator<Item = Vec3>) -> Self {
        let mut s = Soa::default();
        for p in v {
            s.x.push(p.x);
            s.y.push(p.y);
            s.z.push(p.z);
        }
        s
    }

    fn get(&self, i: usize) -> Vec3 {
        Vec3::new(self.x[i], self.y[i], self.z[i])
    }
}

/// One polarizer angle of a pose: `t`, `b = w_o x t` and the diffuse exit
/// factor per wall sample (empty without a diffuse term), with a partial
/// polarizer's `1/E` (MODEL.md "On-chip polarizer mosaic": `P(t) + P(t_perp)/E`;
/// the exit factor holds both terms already).
struct AnalyzerView {
    t: Soa,
    b: Soa,
    diffuse_out: Vec<f64>,
    /// `1/E`, 0 for an ideal polarizer.
    leak: f64,
    /// The analyzer itself, for the Jones path.
    analyzer: crate::scene::Analyzer,
}

/// How the samples of a pose fold into its rows.
#[derive(Debug, Clone)]
pub(crate) enum Rows {
    /// `mw` consecutive samples per wall element, equal weights (uniform sampling).
    Uniform {
        /// Samples per element.
        mw: usize,
    },
    /// Sample `s` adds to row `row[s]` with weight `weight[s]` (the weights of a
    /// row sum to 1): the `"pixels"` rows, or one row per pixel for a render.
    Weighted {
        /// Row (wall element, or pixel) of each sample.
        row: Vec<u32>,
        /// Its weight.
        weight: Vec<f64>,
    },
}

/// The wall samples some of one pose's blocks average over: a range of the
/// shared sample points and how they fold into rows. A pose's blocks share
/// theirs, except a mosaic's `"pixels"` rows: each micro-polarizer has its own pixels.
#[derive(Debug, Clone)]
pub(crate) struct PoseSamples {
    /// Index of the pose in the scene.
    pub pose: usize,
    /// Which of its blocks (indices into its analyzers; `0..1` without one).
    pub blocks: std::ops::Range<usize>,
    /// The samples in the shared array.
    pub range: std::ops::Range<usize>,
    /// How they fold into rows.
    pub rows: Rows,
}

/// Every pose's wall samples: shared points (poses that sample alike share
/// theirs, so the incident geometry is computed once) and each pose's part.
#[derive(Debug, Clone)]
pub(crate) struct WallSamples {
    /// World positions of every sample.
    pub points: Vec<Vec3>,
    /// Every block of every pose in exactly one entry, in block order.
    pub poses: Vec<PoseSamples>,
    /// Rows per block.
    pub rows_per_block: usize,
}

impl WallSamples {
    /// Every pose sampling `points` uniformly, `mw` consecutive samples per row.
    pub fn uniform(scene: &Scene, points: Vec<Vec3>, rows_per_block: usize, mw: usize) -> Self {
        let range = 0..points.len();
        WallSamples {
            poses: scene
                .poses()
                .iter()
                .enumerate()
                .map(|(k, pose)| PoseSamples {
                    pose: k,
                    blocks: 0..pose.block_count(),
                    range: range.clone(),
                    rows: Rows::Uniform { mw },
                })
                .collect(),
            points,
            rows_per_block,
        }
    }

    /// The samples `scene`'s rows average over (MODEL.md "Rows that match the
    /// measurement"): with `sampling = "pixels"` each pose's own pixels
    /// through its homography, weighted by their footprints; the wall's
    /// uniform `m x m` sub-samples otherwise.
    pub fn of_scene(scene: &Scene, budget: MemoryBudget) -> Result<Self, TransportError> {
        let all: Vec<usize> = (0..scene.wall().plane.grid.count()).collect();
        Self::of_elements(scene, &all, budget)
    }

    /// [`WallSamples::of_scene`] for the wall elements `elements` only (rows
    /// in that order), each sample's point, row and weight checked against
    /// `budget` before the next pose's are made.
    fn of_elements(
        scene: &Scene,
        elements: &[usize],
        budget: MemoryBudget,
    ) -> Result<Self, TransportError> {
        let plane = &scene.wall().plane;
        if scene.wall().sampling == WallSampling::Uniform {
            let all = plane.sample_points();
            let m2 = plane.samples_per_element();
            let points = elements
                .iter()
                .flat_map(|&j| all[j * m2..(j + 1) * m2].iter().copied())
                .collect();
            return Ok(Self::uniform(scene, points, elements.len(), m2));
        }
        let mut points = Vec::new();
        let mut poses = Vec::with_capacity(scene.poses().len());
        for (index, pose) in scene.poses().iter().enumerate() {
            let h = pose
                .homography
                .as_ref()
                .ok_or_else(|| TransportError::NoHomography {
                    pose: pose.name.clone(),
                })?;
            // A mosaic's blocks each average over their micro-polarizer's
            // pixels; every other pose's blocks over all of its pixels.
            let groups: Vec<(std::ops::Range<usize>, Option<[u32; 2]>)> = match pose.mosaic {
                Some(_) => pose
                    .analyzers
                    .iter()
                    .enumerate()
                    .map(|(b, a)| (b..b + 1, a.cell))
                    .collect(),
                None => vec![(0..pose.block_count(), None)],
            };
            for (blocks, cell) in groups {
                let map = PixelMap::cell_plane(h, plane, cell.into(), &pose.name)?;
                let pixels: usize = elements.iter().map(|&j| map.range(j).len()).sum();
                // Each sample keeps its point, row and weight, and per pose the scratch arrays.
                super::check_size(
                    budget,
                    elements.len() * scene.block_count(),
                    scene.cols(),
                    scene.block_count(),
                    (points.len() + pixels) as f64 * 120.0,
                )?;
                let start = points.len();
                let (mut row, mut weight) =
                    (Vec::with_capacity(pixels), Vec::with_capacity(pixels));
                for (k, &j) in elements.iter().enumerate() {
                    for s in map.range(j) {
                        let [u, v] = map.points()[s];
                        points.push(plane.point(u, v));
                        row.push(k as u32);
                        weight.push(map.weights()[s]);
                    }
                }
                poses.push(PoseSamples {
                    pose: index,
                    blocks,
                    range: start..points.len(),
                    rows: Rows::Weighted { row, weight },
                });
            }
        }
        Ok(WallSamples {
            points,
            poses,
            rows_per_block: elements.len(),
        })
    }
}

/// What one pose contributes, precomputed per wall sample.
struct PoseView {
    /// Its samples in the shared array, and how they fold into rows.
    samples: PoseSamples,
    /// Direction to the camera, `n.w_o` and `G1(w_o)` per wall sample.
    w_o: Soa,
    cos_o: Vec<f64>,
    g1_o: Vec<f64>,
    /// The diffuse exit factor without a polarizer (empty without a diffuse term).
    diffuse_open: Vec<f64>,
    /// Analyzers in block order; empty when the pose has no polarizer.
    analyzers: Vec<AnalyzerView>,
    /// Index of this pose's first block.
    first_block: usize,
}

/// Builds `T` for a scene, refusing one over `budget` before allocating it.
pub fn build(scene: &Scene, budget: MemoryBudget) -> Result<Transport, TransportError> {
    build_with_progress(scene, budget, &|_| {}, Stop::default())
}

/// Builds `T` within `budget`, calling `progress(columns_done)` as columns
/// complete, and ends it early with [`TransportError::Stopped`] once `stop`
/// is raised: it is looked at before each column, so a cancelled daemon job
/// waits for one column (milliseconds), not the build.
pub fn build_with_progress(
    scene: &Scene,
    budget: MemoryBudget,
    progress: &(dyn Fn(usize) + Sync),
    stop: Stop<'_>,
) -> Result<Transport, TransportError> {
    let plane = &scene.wall().plane;
    // The wall samples (points and their structure-of-arrays copy) come first: check them with T.
    let samples = plane.grid.count() as f64 * plane.samples_per_element() as f64;
    super::check_size(
        budget,
        scene.rows(),
        scene.cols(),
        scene.block_count(),
        samples * 48.0,
    )?;
    let samples = WallSamples::of_scene(scene, budget)?;
    let data = build_rows(scene, budget, &samples, (progress, stop))?;
    Ok(Transport::from_col_major(
        scene.rows(),
        scene.cols(),
        data,
        blocks_of(scene),
        plane.grid,
        scene.hidden().plane.grid,
    ))
}

/// The wall radiance each block's camera sees at single wall points, for a
/// hidden scene `l` (MODEL.md "One entry of T" at one point, no averaging):
/// `points[p]` are wall coordinates (u, v) for pose `p`; the answer holds,
/// per block in `T`'s order, one value per point of its pose. How a camera
/// frame is rendered pixel by pixel, each pixel at its own wall point.
pub(crate) fn radiance_at(scene: &Scene, points: &[Vec<[f64; 2]>], l: &[f64]) -> Vec<Vec<f64>> {
    let plane = &scene.wall().plane;
    let longest = points.iter().map(Vec::len).max().unwrap_or(0);
    let mut all = Vec::with_capacity(points.iter().map(Vec::len).sum());
    let mut poses = Vec::with_capacity(scene.poses().len());
    for (k, _) in scene.poses().iter().enumerate() {
        let own = points.get(k).map_or(&[][..], Vec::as_slice);
        let start = all.len();
        all.extend(own.iter().map(|&[u, v]| plane.point(u, v)));
        poses.push(PoseSamples {
            pose: k,
            blocks: 0..scene.poses()[k].block_count(),
            range: start..all.len(),
            rows: Rows::Weighted {
                row: (0..own.len() as u32).collect(),
                weight: vec![1.0; own.len()],
            },
        });
    }
    let samples = WallSamples {
        points: all,
        poses,
        rows_per_block: longest,
    };
    let flat = apply_rows(scene, &samples, l);
    let mut out = Vec::with_capacity(scene.block_count());
    for (k, pose) in scene.poses().iter().enumerate() {
        let n = points.get(k).map_or(0, Vec::len);
        for _ in 0..pose.block_count() {
            let b = out.len();
            out.push(flat[b * longest..b * longest + n].to_vec());
        }
    }
    out
}

/// The rows of `T` for the wall elements `elements` only, in every block
/// (column-major, `blocks x elements.len()` rows, block-major as in `T`):
/// checking a model on a sample of rows without building all of `T`.
pub fn build_elements(
    scene: &Scene,
    elements: &[usize],
    budget: MemoryBudget,
) -> Result<Vec<f64>, TransportError> {
    let n = scene.wall().plane.grid.count();
    if let Some(&j) = elements.iter().find(|&&j| j >= n) {
        return Err(TransportError::Parameter {
            name: "element",
            value: j as f64,
            reason: "must be a wall element of the scene",
        });
    }
    build_rows(
        scene,
        budget,
        &WallSamples::of_elements(scene, elements, budget)?,
        (&|_| {}, Stop::default()),
    )
}

/// The row blocks of a scene's `T`, in stacking order (pose, then angle):
/// which capture goes where in the measurement, known without building `T`.
pub fn blocks_of(scene: &Scene) -> Vec<Block> {
    scene
        .poses()
        .iter()
        .flat_map(|pose| {
            pose.channels().into_iter().map(|channel| Block {
                pose: pose.name.clone(),
                channel,
            })
        })
        .collect()
}

/// Column-major entries of `T` for the rows `samples` describe: each pose's
/// block rows average over its samples (the uniform build passes the whole
/// wall; the adaptive one the elements it refines). Rows are
/// `blocks x samples.rows_per_block`.
pub(crate) fn build_rows(
    scene: &Scene,
    budget: MemoryBudget,
    samples: &WallSamples,
    (progress, stop): (&(dyn Fn(usize) + Sync), Stop<'_>),
) -> Result<Vec<f64>, TransportError> {
    let rows = samples.rows_per_block * scene.block_count();
    let cols = scene.cols();
    super::check_size(budget, rows, cols, scene.block_count(), 0.0)?;
    let ctx_parts = Parts::new(scene, samples);
    let ctx = ctx_parts.ctx(scene, samples);
    let done = AtomicUsize::new(0);
    let mut data = vec![0.0f64; rows * cols];
    let longest = ctx_parts.longest();
    columns_mut(&mut data, rows).for_each_init(
        || Scratch::new(samples.points.len(), longest),
        |sc, (k, col)| {
            if stop.raised() {
                return;
            }
            fill_column(sc, col, k, &ctx);
            progress(done.fetch_add(1, Ordering::Relaxed) + 1);
        },
    );
    if stop.raised() {
        return Err(TransportError::Stopped {
            columns: done.into_inner(),
            of: cols,
        });
    }
    Ok(data)
}

/// `T l` for the rows `samples` describe, without holding `T`: every
/// column is made as [`build_rows`] makes it and added in, weighted by `l`.
/// How a camera frame is rendered pixel by pixel (one row per pixel).
pub(crate) fn apply_rows(scene: &Scene, samples: &WallSamples, l: &[f64]) -> Vec<f64> {
    let rows = samples.rows_per_block * scene.block_count();
    let parts = Parts::new(scene, samples);
    let ctx = parts.ctx(scene, samples);
    let longest = parts.longest();
    let lit: Vec<usize> = (0..scene.cols().min(l.len()))
        .filter(|&k| l[k] != 0.0)
        .collect();
    // A few runs of columns, each with one pair of `rows`-long buffers (a
    // frame's pixels times its blocks): a pair per rayon split, as `fold`
    // gives, spent more time faulting fresh pages in than on the columns.
    let per_run = lit.len().div_ceil(2 * rayon::current_num_threads()).max(1);
    lit.par_chunks(per_run)
        .map(|run| {
            let mut sc = Scratch::new(samples.points.len(), longest);
            let (mut col, mut acc) = (vec![0.0; rows], vec![0.0; rows]);
            for &k in run {
                col.fill(0.0);
                fill_column(&mut sc, &mut col, k, &ctx);
                acc.iter_mut().zip(&col).for_each(|(a, c)| *a += l[k] * c);
            }
            acc
        })
        .reduce_with(|mut a, b| {
            a.iter_mut().zip(&b).for_each(|(x, y)| *x += y);
            a
        })
        .unwrap_or_else(|| vec![0.0; rows])
}

/// The per-pose views and scene samples a build shares between its tasks.
struct Parts {
    views: Vec<PoseView>,
    wall_soa: Soa,
    scene_pts: Vec<Vec3>,
    /// The occluders' pieces against the wall samples; `None` without occluders.
    shadows: Option<Shadows>,
}

impl Parts {
    fn new(scene: &Scene, samples: &WallSamples) -> Self {
        let wall = &scene.wall();
        let brdf = wall.brdf;
        let n = wall.plane.normal;
        let wall_soa = Soa::from_vecs(samples.points.iter().copied());
        let diffuse_on = brdf.kd != 0.0;
        // The diffuse exit factor of one block at every wall sample (MODEL.md P_diff
        // without its T_in): only when the scene has a diffuse term.
        let exit = |dirs: &[Vec3], cos_o: &[f64], t: Option<&[Vec3]>| -> Vec<f64> {
            if !diffuse_on {
                return Vec::new();
            }
            (0..dirs.len())
                .map(|j| match brdf.diffuse {
                    DiffuseModel::Lambert => {
                        if t.is_some() {
                            0.5
                        } else {
                            1.0
                        }
                    }
                    DiffuseModel::Fresnel => {
                        diffuse::exit(&n, &dirs[j], cos_o[j], brdf.eta, t.map(|t| &t[j]))
                    }
                })
                .collect()
        };

        // Each pose's first block in T's order.
        let mut first = Vec::with_capacity(scene.poses().len());
        scene.poses().iter().fold(0, |at, p| {
            first.push(at);
            at + p.block_count()
        });
        let mut views = Vec::with_capacity(samples.poses.len());
        for own in &samples.poses {
            let pose = &scene.poses()[own.pose];
            let dirs: Vec<Vec3> = samples.points[own.range.clone()]
                .iter()
                .map(|c| (pose.camera - c).normalize())
                .collect();
            let cos_o: Vec<f64> = dirs.iter().map(|w| n.dot(w)).collect();
            let g1_o = cos_o
                .iter()
                .map(|&c| ggx::smith_g1(c, brdf.alpha))
                .collect();
            let own_analyzers = pose.analyzers.get(own.blocks.clone()).unwrap_or(&[]);
            let mut analyzers = Vec::with_capacity(own_analyzers.len());
            for a in own_analyzers {
                // A polarizer facing the wall never sees a ray along its axis;
                // should it, the ray passes no light (t = 0).
                let t: Vec<Vec3> = dirs
                    .iter()
                    .map(|w| a.effective_axis(scene.polarizer(), w))
                    .collect();
                let b: Vec<Vec3> = dirs.iter().zip(&t).map(|(w, t)| w.cross(t)).collect();
                let leak = a.extinction.map_or(0.0, |e| 1.0 / e);
                let mut diffuse_out = exit(&dirs, &cos_o, Some(&t));
                if leak != 0.0 && !diffuse_out.is_empty() {
                    // t_perp = normalize(w_o x t) = b / |b|.
                    let t_perp: Vec<Vec3> = dirs
                        .iter()
                        .zip(&t)
                        .map(|(w, t)| crate::scene::perpendicular(t, w))
                        .collect();
                    let perp = exit(&dirs, &cos_o, Some(&t_perp));
                    diffuse_out
                        .iter_mut()
                        .zip(perp)
                        .for_each(|(o, p)| *o += leak * p);
                }
                analyzers.push(AnalyzerView {
                    diffuse_out,
                    t: Soa::from_vecs(t.into_iter()),
                    b: Soa::from_vecs(b.into_iter()),
                    leak,
                    analyzer: *a,
                });
            }
            views.push(PoseView {
                samples: own.clone(),
                diffuse_open: exit(&dirs, &cos_o, None),
                w_o: Soa::from_vecs(dirs.into_iter()),
                cos_o,
                g1_o,
                analyzers,
                first_block: first[own.pose] + own.blocks.start,
            });
        }

        Parts {
            views,
            wall_soa,
            scene_pts: scene.hidden().plane.sample_points(),
            shadows: Shadows::new(
                scene.occluders(),
                &wall.plane,
                &samples.points,
                (scene.shadow_choice().model == ShadowModel::Area).then_some(&scene.hidden().plane),
            ),
        }
    }

    /// The most samples one pose has (the per-pose scratch length).
    fn longest(&self) -> usize {
        self.views
            .iter()
            .map(|v| v.samples.range.len())
            .max()
            .unwrap_or(0)
    }

    fn ctx<'a>(&'a self, scene: &'a Scene, samples: &'a WallSamples) -> Ctx<'a> {
        let hidden = scene.hidden();
        let brdf = scene.wall().brdf;
        let ms = hidden.plane.samples_per_element();
        Ctx {
            scene,
            views: &self.views,
            wall_pts: &samples.points,
            wall_soa: &self.wall_soa,
            scene_pts: &self.scene_pts,
            shadows: self.shadows.as_ref(),
            ms,
            n_wall: samples.rows_per_block,
            n: scene.wall().plane.normal,
            n_s: hidden.plane.normal,
            lambertian: hidden.emitter == Emitter::Lambertian,
            lobe: hidden.lobe.map(|[nu, nv]| Lobe {
                u: hidden.plane.u,
                v: hidden.plane.v,
                nu: HalfPower::of(nu),
                nv: HalfPower::of(nv),
            }),
            weight: hidden.plane.element_area() / ms as f64,
            brdf,
            diffuse: brdf.kd / PI,
            fresnel_in: brdf.kd != 0.0 && brdf.diffuse == DiffuseModel::Fresnel,
            ks_on: brdf.ks != 0.0,
        }
    }
}

/// The columns of a column-major `T` (`rows` long) with their index, in
/// parallel, each zeroed by a write before a task fills it.
///
/// Why the write: a zeroed allocation's pages are not mapped yet, and a
/// first touch by `+=` (a read) maps the shared zero page, then faults again
/// to copy it on the write, flushing the other cores' TLBs for every page (a
/// third of a 64x64 build's time).
pub(super) fn columns_mut(
    data: &mut [f64],
    rows: usize,
) -> impl IndexedParallelIterator<Item = (usize, &mut [f64])> {
    data.par_chunks_mut(rows.max(1))
        .map(|col| {
            col.fill(0.0);
            col
        })
        .enumerate()
}

/// A screen's off-axis falloff (scene `lobe`): its in-plane axes and exponents.
struct Lobe {
    u: Vec3,
    v: Vec3,
    nu: HalfPower,
    nv: HalfPower,
}

/// `x^(n/2)` for a lobe exponent `n`: by multiplications (and one square
/// root) when `n` is a whole number, as a monitor's usually is, since `powf`
/// was most of the chair photo's `T` (1 s of 1.7 s); both agree to ~1e-15.
#[derive(Clone, Copy)]
enum HalfPower {
    /// `x^k`, times `sqrt(x)` when `odd`.
    Whole { k: i32, odd: bool },
    /// `x^e` for any other exponent `e = n/2`.
    Real(f64),
}

impl HalfPower {
    /// The power for exponent `n` (a validated lobe exponent, 0 to 1000).
    fn of(n: f64) -> Self {
        if n.fract() == 0.0 && (0.0..=1000.0).contains(&n) {
            let n = n as i32;
            HalfPower::Whole {
                k: n / 2,
                odd: n % 2 == 1,
            }
        } else {
            HalfPower::Real(0.5 * n)
        }
    }

    #[inline(always)]
    fn of_square(self, x2: f64) -> f64 {
        match self {
            HalfPower::Whole { k, odd: false } => x2.powi(k),
            HalfPower::Whole { k, odd: true } => x2.powi(k) * x2.sqrt(),
            HalfPower::Real(e) => x2.powf(e),
        }
    }
}

/// Everything a column needs, shared read-only by all tasks.
struct Ctx<'a> {
    scene: &'a Scene,
    views: &'a [PoseView],
    wall_pts: &'a [Vec3],
    wall_soa: &'a Soa,
    scene_pts: &'a [Vec3],
    /// Which wall samples the occluders block, per scene point.
    shadows: Option<&'a Shadows>,
    ms: usize,
    n_wall: usize,
    n: Vec3,
    n_s: Vec3,
    lambertian: bool,
    /// The screen's off-axis falloff, when the file asks for one.
    lobe: Option<Lobe>,
    weight: f64,
    brdf: crate::optics::Brdf,
    /// `kd / pi`; 0 without a diffuse term.
    diffuse: f64,
    /// Whether `T_in` varies with the incident direction (the `fresnel` diffuse term).
    fresnel_in: bool,
    ks_on: bool,
}

/// Column `k` of `T`: every block's response to scene element `k`.
#[multiversion::multiversion(targets("x86_64+avx2+fma"))]
fn fill_column<'a>(sc: &mut Scratch, col: &mut [f64], k: usize, c: &Ctx<'a>) {
    let n_wall = c.n_wall;
    for s in &c.scene_pts[k * c.ms..(k + 1) * c.ms] {
        sc.incident(
            s,
            c.wall_soa,
            &c.n,
            &c.n_s,
            c.lambertian,
            c.brdf.alpha,
            c.weight,
        );
        if let Some(lobe) = &c.lobe {
            sc.lobe(lobe, &c.n_s);
        }
        if c.fresnel_in {
            sc.transmittance_in(c.brdf.eta);
        }
        if let Some(shadows) = c.shadows {
            shadows.shade(s, c.wall_pts, &mut sc.base);
        }
        for view in c.views {
            if let Some(e_src) = c.scene.hidden().polarization.as_ref() {
                sc.polarized_source(view, e_src, &c.brdf, &c.n, col, n_wall);
                continue;
            }
            sc.pose(view, &c.brdf, c.ks_on);
            for blk in 0..view.analyzers.len().max(1) {
                let a = view.analyzers.get(blk);
                let out = a.map_or(&view.diffuse_open, |a| &a.diffuse_out);
                sc.block(view.samples.range.clone(), a, c.ks_on, c.diffuse, out);
                let out = &mut col
                    [(view.first_block + blk) * n_wall..(view.first_block + blk + 1) * n_wall];
                let value = &sc.value[..view.samples.range.len()];
                match &view.samples.rows {
                    Rows::Uniform { mw: 1 } => {
                        for (o, v) in out.iter_mut().zip(value) {
                            *o += v;
                        }
                    }
                    Rows::Uniform { mw } => {
                        let inv = 1.0 / *mw as f64;
                        for (ws, v) in value.iter().enumerate() {
                            out[ws / mw] += v * inv;
                        }
                    }
                    Rows::Weighted { row, weight } => {
                        for ((r, w), v) in row.iter().zip(weight).zip(value) {
                            out[*r as usize] += w * v;
                        }
                    }
                }
            }
        }
    }
}

/// Per-thread buffers reused across columns: the incident geometry for
/// every wall sample, the rest for the samples of one pose at a time.
struct Scratch {
    /// Incident direction `w_i`.
    w_i: Soa,
    /// `n.w_i` and `G1(w_i)`.
    cos_i: Vec<f64>,
    g1_i: Vec<f64>,
    /// `a_k g (n.w_i) / |s - c|^2` over the sample count; 0 where the entry is 0.
    base: Vec<f64>,
    /// The diffuse term's `T_in` (MODEL.md): 1 unless the `fresnel` term fills it.
    t_in: Vec<f64>,
    /// Per pose: `w_i.w_o`-derived specular weight, Fresnel `Rs`, `Rp`, `|w_i x w_o|^2`; 0 weight where `n.w_o <= 0`.
    spec: Vec<f64>,
    rs: Vec<f64>,
    rp: Vec<f64>,
    cross2: Vec<f64>,
    /// 1 where the camera of the current pose sees the wall sample (`n.w_o > 0`), else 0.
    open: Vec<f64>,
    /// `base * f` for the current block.
    value: Vec<f64>,
}

impl Scratch {
    /// Buffers for `n` wall samples, of which one pose has `per_pose` at most.
    fn new(n: usize, per_pose: usize) -> Self {
        let z = || vec![0.0; n];
        let p = || vec![0.0; per_pose];
        Self {
            w_i: Soa {
                x: z(),
                y: z(),
                z: z(),
            },
            cos_i: z(),
            g1_i: z(),
            base: z(),
            t_in: vec![1.0; n],
            spec: p(),
            rs: p(),
            rp: p(),
            cross2: p(),
            open: p(),
            value: p(),
        }
    }

    /// Incident geometry from scene point `s` to every wall sample.
    ///
    /// Every array is re-sliced to the same length first, so that the bounds
    /// checks vanish and the loop vectorizes (likewise in `pose` and `block`).
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn incident(
        &mut self,
        s: &Vec3,
        c: &Soa,
        n: &Vec3,
        n_s: &Vec3,
        lambertian: bool,
        alpha: f64,
        weight: f64,
    ) {
        let len = self.base.len();
        let (cx, cy, cz) = (&c.x[..len], &c.y[..len], &c.z[..len]);
        let Scratch {
            w_i,
            cos_i,
            g1_i,
            base,
            ..
        } = self;
        let (wx, wy, wz) = (&mut w_i.x[..len], &mut w_i.y[..len], &mut w_i.z[..len]);
        let (ci_out, g1_out, base) = (&mut cos_i[..len], &mut g1_i[..len], &mut base[..len]);
        for j in 0..len {
            let (dx, dy, dz) = (s.x - cx[j], s.y - cy[j], s.z - cz[j]);
            let r2 = dx * dx + dy * dy + dz * dz;
            let inv = 1.0 / r2.sqrt();
            let (ux, uy, uz) = (dx * inv, dy * inv, dz * inv);
            let ci = n.x * ux + n.y * uy + n.z * uz;
            let g = if lambertian {
                (-(n_s.x * ux + n_s.y * uy + n_s.z * uz)).max(0.0)
            } else {
                1.0
            };
            wx[j] = ux;
            wy[j] = uy;
            wz[j] = uz;
            ci_out[j] = ci;
            g1_out[j] = ggx::smith_g1(ci, alpha);
            base[j] = if ci > 0.0 {
                weight * g * ci * inv * inv
            } else {
                0.0
            };
        }
    }

    /// Multiplies `base` by the screen's `cos^nu(theta_u) cos^nv(theta_v)`
    /// (scene `lobe`): `cos theta_u = (n_s.d) / |(n_s.d, u.d)|` for the ray
    /// `d = -w_i` from the screen to the wall sample, likewise for `v`.
    #[inline(always)]
    fn lobe(&mut self, lobe: &Lobe, n_s: &Vec3) {
        let len = self.base.len();
        let (wx, wy, wz) = (&self.w_i.x[..len], &self.w_i.y[..len], &self.w_i.z[..len]);
        let base = &mut self.base[..len];
        let (u, v) = (&lobe.u, &lobe.v);
        for j in 0..len {
            let dn = -(n_s.x * wx[j] + n_s.y * wy[j] + n_s.z * wz[j]);
            let du = u.x * wx[j] + u.y * wy[j] + u.z * wz[j];
            let dv = v.x * wx[j] + v.y * wy[j] + v.z * wz[j];
            let (cu2, cv2) = (dn * dn / (dn * dn + du * du), dn * dn / (dn * dn + dv * dv));
            let f = if dn > 0.0 {
                lobe.nu.of_square(cu2) * lobe.nv.of_square(cv2)
            } else {
                0.0
            };
            base[j] *= f;
        }
    }

    /// `T_in = 1 - (Rs(θi) + Rp(θi))/2` at every wall sample (MODEL.md "Diffuse term").
    #[inline(always)]
    fn transmittance_in(&mut self, eta: f64) {
        let len = self.base.len();
        let (ci, t_in) = (&self.cos_i[..len], &mut self.t_in[..len]);
        for j in 0..len {
            let (ts, tp) = diffuse::transmittances(ci[j].max(0.0), eta);
            t_in[j] = 0.5 * (ts + tp);
        }
    }

    /// The unpolarized specular lobe of one pose.
    #[inline(always)]
    fn pose(&mut self, v: &PoseView, brdf: &crate::optics::Brdf, ks_on: bool) {
        let r = v.samples.range.clone();
        let len = r.len();
        let Scratch {
            w_i,
            cos_i,
            g1_i,
            spec,
            rs,
            rp,
            cross2,
            open,
            ..
        } = self;
        let cos_o = &v.cos_o[..len];
        let open = &mut open[..len];
        for j in 0..len {
            open[j] = if cos_o[j] > 0.0 { 1.0 } else { 0.0 };
        }
        if !ks_on {
            return;
        }
        let (ix, iy, iz) = (&w_i.x[r.clone()], &w_i.y[r.clone()], &w_i.z[r.clone()]);
        let (ox, oy, oz) = (&v.w_o.x[..len], &v.w_o.y[..len], &v.w_o.z[..len]);
        let (ci, g1i, g1o) = (&cos_i[r.clone()], &g1_i[r], &v.g1_o[..len]);
        let (spec, rs, rp, cross2) = (
            &mut spec[..len],
            &mut rs[..len],
            &mut rp[..len],
            &mut cross2[..len],
        );
        for j in 0..len {
            let c2 = ix[j] * ox[j] + iy[j] * oy[j] + iz[j] * oz[j];
            let lobe = brdf.lobe_from_cosines(ci[j], g1i[j], cos_o[j], g1o[j], c2);
            let r = lobe.fresnel.reflectances();
            let ok = ci[j] > 0.0 && cos_o[j] > 0.0;
            spec[j] = if ok { lobe.weight } else { 0.0 };
            rs[j] = r.rs;
            rp[j] = r.rp;
            let (xx, xy, xz) = (
                iy[j] * oz[j] - iz[j] * oy[j],
                iz[j] * ox[j] - ix[j] * oz[j],
                ix[j] * oy[j] - iy[j] * ox[j],
            );
            cross2[j] = xx * xx + xy * xy + xz * xz;
        }
    }

    /// `value = base * f` for one block of the current pose (analyzer or
    /// none); `out` is the block's diffuse exit factor, empty without one.
    #[inline(always)]
    fn block(
        &mut self,
        r: std::ops::Range<usize>,
        a: Option<&AnalyzerView>,
        ks_on: bool,
        diffuse: f64,
        out: &[f64],
    ) {
        let len = r.len();
        let Scratch {
            w_i,
            base,
            t_in,
            spec,
            rs,
            rp,
            cross2,
            open,
            value,
            ..
        } = self;
        let (base, spec, rs, rp, cross2, open) = (
            &base[r.clone()],
            &spec[..len],
            &rs[..len],
            &rp[..len],
            &cross2[..len],
            &open[..len],
        );
        let value = &mut value[..len];
        match a {
            Some(a) => {
                let (ix, iy, iz) = (&w_i.x[r.clone()], &w_i.y[r.clone()], &w_i.z[r.clone()]);
                let (tx, ty, tz) = (&a.t.x[..len], &a.t.y[..len], &a.t.z[..len]);
                let (bx, by, bz) = (&a.b.x[..len], &a.b.y[..len], &a.b.z[..len]);
                // An ideal polarizer (every sheet) pays nothing for the
                // partial one's second axis.
                let leak = a.leak;
                for j in 0..len {
                    let wi_b = ix[j] * bx[j] + iy[j] * by[j] + iz[j] * bz[j];
                    let wi_t = ix[j] * tx[j] + iy[j] * ty[j] + iz[j] * tz[j];
                    let sp = match (ks_on, leak == 0.0) {
                        (false, _) => 0.0,
                        (true, true) => {
                            spec[j] * analyzer_factor(rs[j], rp[j], wi_b, wi_t, cross2[j])
                        }
                        (true, false) => {
                            spec[j]
                                * partial_analyzer_factor(rs[j], rp[j], wi_b, wi_t, cross2[j], leak)
                        }
                    };
                    value[j] = base[j] * open[j] * sp;
                }
            }
            None => {
                for j in 0..len {
                    let sp = if ks_on {
                        spec[j] * 0.5 * (rs[j] + rp[j])
                    } else {
                        0.0
                    };
                    value[j] = base[j] * open[j] * sp;
                }
            }
        }
        if !out.is_empty() {
            // kd/pi T_in(θi) exit(θo, t): MODEL.md's diffuse term.
            let (t_in, out) = (&t_in[r], &out[..len]);
            for j in 0..len {
                value[j] += base[j] * open[j] * diffuse * t_in[j] * out[j];
            }
        }
    }

    /// A linearly polarized scene (MODEL.md Eq. 11): the Jones path, per element.
    #[allow(clippy::too_many_arguments)]
    fn polarized_source(
        &mut self,
        v: &PoseView,
        e_src: &Vec3,
        brdf: &crate::optics::Brdf,
        n: &Vec3,
        col: &mut [f64],
        n_wall: usize,
    ) {
        let start = v.samples.range.start;
        for j in 0..v.samples.range.len() {
            let g = start + j;
            if self.base[g] == 0.0 || v.cos_o[j] <= 0.0 {
                continue;
            }
            let i = Direction {
                w: self.w_i.get(g),
                cos: self.cos_i[g],
                g1: self.g1_i[g],
            };
            let o = Direction {
                w: v.w_o.get(j),
                cos: v.cos_o[j],
                g1: v.g1_o[j],
            };
            let lobe = brdf.lobe(&i, &o);
            for blk in 0..v.analyzers.len().max(1) {
                let through = |t: Option<&Vec3>| {
                    brdf.finish(
                        &lobe,
                        n,
                        &i,
                        &o,
                        Polarization {
                            analyzer: t,
                            source: Some(e_src),
                        },
                    )
                };
                let f = match v.analyzers.get(blk) {
                    None => through(None),
                    Some(a) => a.analyzer.weigh(&a.t.get(j), &o.w, |t| through(Some(t))),
                };
                let (row, weight) = match &v.samples.rows {
                    Rows::Uniform { mw } => (j / mw, 1.0 / *mw as f64),
                    Rows::Weighted { row, weight } => (row[j] as usize, weight[j]),
                };
                col[(v.first_block + blk) * n_wall + row] += weight * self.base[g] * f;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scene(name: &str) -> Scene {
        Scene::builtin(name)
            .expect("a built-in scene")
            .expect("it parses")
    }

    /// A scene image with every element different (none zero), so that a
    /// column taken twice or left out changes `T l`.
    fn image(n: usize) -> Vec<f64> {
        (0..n)
            .map(|k| 0.2 + 0.7 * ((k * 37 % 101) as f64 / 101.0))
            .collect()
    }

    #[test]
    fn a_build_stops_within_the_columns_in_flight_when_its_flag_is_raised() {
        let scene = scene("brewster-crossed");
        let cols = scene.cols();
        let flag = std::sync::atomic::AtomicBool::new(false);
        let raise_at = 5;
        let progress = |done: usize| {
            if done == raise_at {
                flag.store(true, Ordering::Relaxed);
            }
        };
        match build_with_progress(&scene, MemoryBudget::default(), &progress, Stop::on(&flag)) {
            Err(TransportError::Stopped { columns, of }) => {
                assert_eq!(of, cols);
                // Each worker finishes the column it holds, no more.
                let in_flight = rayon::current_num_threads();
                assert!(
                    (raise_at..=raise_at + in_flight).contains(&columns),
                    "{columns} columns built after the flag at {raise_at} with {in_flight} threads"
                );
            }
            other => panic!(
                "a raised flag must stop the build, got {:?}",
                other.map(|t| t.cols())
            ),
        }
        // No flag: the same build completes and equals the plain one.
        let whole = build_with_progress(&scene, MemoryBudget::default(), &|_| {}, Stop::default())
            .expect("T");
        let plain = build(&scene, MemoryBudget::default()).expect("T");
        assert_eq!(whole.as_mat(), plain.as_mat());
    }

    #[test]
    fn blocks_stack_poses_then_their_angles_in_file_order() {
        let s = scene("brewster-multi-3x3");
        let blocks = blocks_of(&s);
        assert_eq!(blocks.len(), s.block_count());
        let expected: Vec<(String, Vec<crate::scene::Channel>)> = s
            .poses()
            .iter()
            .map(|p| (p.name.clone(), p.channels()))
            .collect();
        let mut k = 0;
        for (pose, channels) in &expected {
            for ch in channels {
                assert_eq!(&blocks[k].pose, pose, "block {k}");
                assert_eq!(&blocks[k].channel, ch, "block {k}");
                k += 1;
            }
        }
        assert_eq!(k, blocks.len());
        assert!(
            expected.len() > 1,
            "the test needs a scene of several poses"
        );
    }

    #[test]
    fn t_applied_without_the_matrix_is_the_built_matrix_times_l() {
        for name in ["brewster-rotating-3x3", "occluder-multi-3x3"] {
            let s = scene(name);
            let t = build(&s, MemoryBudget::DEFAULT).expect("T");
            let l = image(t.cols());
            let samples = WallSamples::of_scene(&s, MemoryBudget::DEFAULT).expect("samples");
            let free = apply_rows(&s, &samples, &l);
            let full = t.apply(&l);
            assert_eq!(free.len(), full.len(), "{name}");
            let scale = full.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            assert!(scale > 0.0, "{name}: T l is zero");
            for (j, (a, b)) in free.iter().zip(&full).enumerate() {
                assert!(
                    (a - b).abs() <= 1e-12 * scale,
                    "{name} row {j}: {a:e} vs {b:e}"
                );
            }
        }
    }

    #[test]
    fn rows_of_chosen_elements_are_those_rows_of_t_in_every_block() {
        let s = scene("brewster-rotating-3x3");
        let t = build(&s, MemoryBudget::DEFAULT).expect("T");
        let nw = s.wall().plane.grid.count();
        let elements = [0, nw / 2, nw - 1];
        let data = build_elements(&s, &elements, MemoryBudget::DEFAULT).expect("rows");
        let rows = s.block_count() * elements.len();
        assert_eq!(data.len(), rows * t.cols());
        for b in 0..s.block_count() {
            for (e, &j) in elements.iter().enumerate() {
                let r = b * elements.len() + e;
                for k in 0..t.cols() {
                    let (got, want) = (data[k * rows + r], t.get(b * nw + j, k));
                    assert!(
                        (got - want).abs() <= 1e-12 * want.abs().max(1e-300),
                        "block {b} element {j} column {k}: {got:e} vs {want:e}"
                    );
                }
            }
        }
    }

    #[test]
    fn an_element_beyond_the_wall_is_refused_naming_it() {
        let s = scene("brewster-crossed-3x3");
        let n = s.wall().plane.grid.count();
        let e = build_elements(&s, &[0, n], MemoryBudget::DEFAULT).unwrap_err();
        assert!(e.to_string().contains(&n.to_string()), "{e}");
    }

    #[test]
    fn half_powers_agree_with_powf() {
        for n in [0.0, 1.0, 2.0, 3.0, 18.0, 19.0, 1.5, 999.0, 1000.0, 0.25] {
            let p = HalfPower::of(n);
            assert_eq!(matches!(p, HalfPower::Real(_)), n.fract() != 0.0, "{n}");
            for k in 0..=200 {
                let x2 = (k as f64 / 200.0).powi(2);
                let (got, want) = (p.of_square(x2), x2.powf(0.5 * n));
                assert!(
                    (got - want).abs() <= 1e-13 * want.abs() + 1e-300,
                    "n = {n}, x2 = {x2}: {got:e} vs {want:e}"
                );
            }
        }
    }
}
