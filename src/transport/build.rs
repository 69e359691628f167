//! Parallel assembly of `T`, one scene element (column) per task.
//!
//! Everything that depends only on the wall and a pose (direction to the camera,
//! its Smith term, the effective polarizer axis of each angle) is computed once;
//! the inner loop evaluates MODEL.md's entry formula for each (scene sample,
//! wall sample) pair, sharing the unpolarized lobe across a pose's angles.

use std::sync::atomic::{AtomicUsize, Ordering};

use rayon::prelude::*;

use super::{Block, Transport, TransportError};
use crate::optics::brdf::Direction;
use crate::optics::polarizer::effective_axis;
use crate::optics::{Polarization, Vec3};
use crate::scene::{Emitter, Scene};

/// Memory budget for a dense f64 `T`.
const LIMIT_BYTES: f64 = 12.0 * (1u64 << 30) as f64;

/// What one pose contributes, precomputed per wall sample.
struct PoseView {
    /// Direction to the camera from each wall sample.
    out: Vec<Direction>,
    /// Effective analyzer axis per block of this pose, per wall sample;
    /// one `None` block when the pose has no polarizer.
    analyzers: Vec<Option<Vec<Vec3>>>,
    /// Index of this pose's first block.
    first_block: usize,
}

/// Builds `T` for a scene.
pub fn build(scene: &Scene) -> Result<Transport, TransportError> {
    build_with_progress(scene, &|_| {})
}

/// Builds `T`, calling `progress(columns_done)` as columns complete.
pub fn build_with_progress(
    scene: &Scene,
    progress: &(dyn Fn(usize) + Sync),
) -> Result<Transport, TransportError> {
    let rows = scene.rows();
    let cols = scene.cols();
    let bytes = rows as f64 * cols as f64 * 8.0;
    if bytes > LIMIT_BYTES {
        return Err(TransportError::TooLarge {
            rows,
            cols,
            gib: bytes / (1u64 << 30) as f64,
            limit_gib: LIMIT_BYTES / (1u64 << 30) as f64,
        });
    }

    let wall = &scene.wall;
    let brdf = wall.brdf;
    let n = wall.plane.normal;
    let wall_pts = wall.plane.sample_points();
    let mw = wall.plane.samples_per_element();
    let n_wall = wall.plane.grid.count();

    let mut blocks = Vec::with_capacity(scene.block_count());
    let mut views = Vec::with_capacity(scene.poses.len());
    for pose in &scene.poses {
        let out: Vec<Direction> = wall_pts
            .iter()
            .map(|c| brdf.direction(&n, (pose.camera - c).normalize()))
            .collect();
        let first_block = blocks.len();
        let analyzers = if pose.analyzers.is_empty() {
            blocks.push(Block {
                pose: pose.name.clone(),
                polarizer_deg: None,
            });
            vec![None]
        } else {
            pose.analyzers
                .iter()
                .map(|a| {
                    blocks.push(Block {
                        pose: pose.name.clone(),
                        polarizer_deg: Some(a.angle_deg),
                    });
                    // A polarizer facing the wall never sees a ray along its axis;
                    // should it, the ray passes no light through it.
                    Some(
                        out.iter()
                            .map(|o| effective_axis(&a.axis, &o.w).unwrap_or_else(Vec3::zeros))
                            .collect(),
                    )
                })
                .collect()
        };
        views.push(PoseView {
            out,
            analyzers,
            first_block,
        });
    }

    let hidden = &scene.scene;
    let scene_pts = hidden.plane.sample_points();
    let ms = hidden.plane.samples_per_element();
    let n_s = hidden.plane.normal;
    let area = hidden.plane.element_area();
    let weight = area / (mw * ms) as f64;
    let source = hidden.polarization;
    let occluders = &scene.occluders;
    let done = AtomicUsize::new(0);

    let mut data = vec![0.0f64; rows * cols];
    data.par_chunks_mut(rows.max(1))
        .enumerate()
        .for_each(|(k, col)| {
            for s in &scene_pts[k * ms..(k + 1) * ms] {
                for (ws, c) in wall_pts.iter().enumerate() {
                    let d = s - c;
                    let r2 = d.norm_squared();
                    let w_i = d / r2.sqrt();
                    let cos_i = n.dot(&w_i);
                    if cos_i <= 0.0 {
                        continue;
                    }
                    let g = match hidden.emitter {
                        Emitter::Lambertian => (-n_s.dot(&w_i)).max(0.0),
                        Emitter::Isotropic => 1.0,
                    };
                    if g == 0.0 {
                        continue;
                    }
                    if occluders.iter().any(|o| o.blocks(s, c)) {
                        continue;
                    }
                    let base = weight * g * cos_i / r2;
                    let i = brdf.direction(&n, w_i);
                    let j = ws / mw;
                    for view in &views {
                        let o = &view.out[ws];
                        if o.cos <= 0.0 {
                            continue;
                        }
                        let lobe = brdf.lobe(&i, o);
                        for (b, axes) in view.analyzers.iter().enumerate() {
                            let pol = Polarization {
                                analyzer: axes.as_ref().map(|a| &a[ws]),
                                source: source.as_ref(),
                            };
                            let f = brdf.finish(&lobe, &i, o, pol);
                            col[(view.first_block + b) * n_wall + j] += base * f;
                        }
                    }
                }
            }
            progress(done.fetch_add(1, Ordering::Relaxed) + 1);
        });

    Ok(Transport::from_col_major(
        rows,
        cols,
        data,
        blocks,
        wall.plane.grid,
        hidden.plane.grid,
    ))
}
