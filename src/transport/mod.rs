//! The transport matrix `T` (MODEL.md Eq. 2, "One entry of T"): built in
//! parallel in f64, one row block per (pose, polarizer angle).
//!
//! Row order: pose order, then angle order; within a block, wall elements
//! row-major (v outer, u inner). Column order: scene elements row-major.

pub mod active;
pub mod adaptive;
mod build;
pub mod choose;
mod shadow;

pub use adaptive::build_adaptive;
pub(crate) use build::radiance_at;
pub use build::{blocks_of, build, build_elements, build_with_progress};

use faer::MatRef;

use crate::scene::{Channel, Grid};

/// One block of rows of `T`: a camera pose at one polarizer setting.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Block {
    /// Pose name.
    pub pose: String,
    /// The analyzer its rows saw (a sheet's angle, a mosaic's micro-polarizer, none).
    pub channel: Channel,
}

impl Block {
    /// A file-name-safe label: `A-pol0`, `A-pol22.5`, `B-nopol`, `C-mosaic45`.
    pub fn label(&self) -> String {
        format!("{}-{}", self.pose, self.channel.label())
    }

    /// Whether a capture at `pose` yielding `channels` holds this block.
    pub fn taken_by(&self, pose: &str, channels: &[Channel]) -> bool {
        self.pose == pose && channels.iter().any(|c| c.same(self.channel))
    }

    /// The indices of the blocks of `blocks` a capture at `pose` yielding
    /// `channels` holds, in block order.
    pub fn taken(blocks: &[Block], pose: &str, channels: &[Channel]) -> Vec<usize> {
        (0..blocks.len())
            .filter(|&k| blocks[k].taken_by(pose, channels))
            .collect()
    }
}

/// The stacked transport matrix with the layout needed to read it.
///
/// Its fields are private so that the layout always matches the entries:
/// `rows = blocks x wall-grid cells` and `cols = scene-grid cells`.
#[derive(Debug, Clone)]
pub struct Transport {
    rows: usize,
    cols: usize,
    /// Column-major entries, `data[k * rows + j] = T[j, k]`.
    data: Vec<f64>,
    /// Row blocks, in row order.
    blocks: Vec<Block>,
    /// Wall grid (rows within a block).
    wall_grid: Grid,
    /// Scene grid (columns).
    scene_grid: Grid,
}

/// Why `T` could not be built.
#[derive(Debug, thiserror::Error)]
pub enum TransportError {
    /// The matrix would not fit in the memory budget.
    #[error("T would be {rows} x {cols} ({gib:.1} GiB in f64), over the {limit_gib:.1} GiB budget for T (a quarter of the memory available when polnlos started, or 12 GiB where that is unknown); reduce wall.grid to at most {max_wall_side}x{max_wall_side} elements, or scene.grid, or the number of poses/angles")]
    TooLarge {
        /// Rows asked for.
        rows: usize,
        /// Columns asked for.
        cols: usize,
        /// Size in GiB.
        gib: f64,
        /// Limit in GiB.
        limit_gib: f64,
        /// Largest square wall grid side that would fit with the same columns and blocks.
        max_wall_side: usize,
    },
    /// The build's stop flag was raised (a cancelled job, a stopping daemon).
    #[error("the build of T was stopped on request after {columns} of {of} columns")]
    Stopped {
        /// Columns built before the flag was seen.
        columns: usize,
        /// Columns of `T`.
        of: usize,
    },
    /// A build option is out of range.
    #[error("{name} = {value}: {reason}")]
    Parameter {
        /// Option name, as on the command line.
        name: &'static str,
        /// Given value.
        value: f64,
        /// Acceptable range.
        reason: &'static str,
    },
    /// `"pixels"` rows asked of a pose without a homography.
    #[error("pose {pose:?} has no homography, which wall.sampling = \"pixels\" needs; add one to the pose, or use sampling = \"uniform\"")]
    NoHomography {
        /// Pose name.
        pose: String,
    },
    /// A pose's pixels could not be found on the wall.
    #[error(transparent)]
    Footprint(#[from] crate::scene::FootprintError),
    /// A finer model could not be made from the scene (its edit was refused).
    #[error("choosing how finely to sample T: {0}")]
    Choice(String),
    /// The time-resolved build samples the wall uniformly only.
    #[error("the time-resolved (active) transport samples the wall uniformly; set wall.sampling = \"uniform\"")]
    ActivePixels,
    /// The time-resolved build tests occluders point to point.
    #[error("the time-resolved (active) transport tests occluders between points (the laser spot, a voxel, a wall patch); set scene.shadows = \"point\": area shadows are a passive scene's emitting cells")]
    ActiveArea,
}

/// Bytes a dense `T` (with the working memory built alongside it) may take.
///
/// Passed to every build rather than held globally, so that the front end
/// that knows the machine sizes it once and a test or bench can pick its own.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MemoryBudget(u64);

impl MemoryBudget {
    /// 12 GiB: the budget where the machine's available memory is unknown,
    /// and what tests and benches that build small matrices use.
    pub const DEFAULT: MemoryBudget = MemoryBudget(12 << 30);

    /// A budget of `bytes`, at least 1 MiB.
    ///
    /// The floor keeps a machine that reports almost no free memory able to
    /// build the smallest scenes.
    pub fn new(bytes: u64) -> Self {
        Self(bytes.max(1 << 20))
    }

    /// The budget in bytes.
    pub fn bytes(self) -> u64 {
        self.0
    }
}

impl Default for MemoryBudget {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// Refuses a `rows x cols` f64 matrix (plus `extra_bytes` of working
/// memory) over `budget`, naming what to reduce; each wall element
/// contributes `rows_per_wall_element` rows.
pub(crate) fn check_size(
    budget: MemoryBudget,
    rows: usize,
    cols: usize,
    rows_per_wall_element: usize,
    extra_bytes: f64,
) -> Result<(), TransportError> {
    let limit = budget.bytes() as f64;
    let bytes = rows as f64 * cols as f64 * 8.0 + extra_bytes;
    if bytes <= limit {
        return Ok(());
    }
    let per_element = (rows_per_wall_element.max(1) * cols.max(1) * 8) as f64;
    let gib = |b: f64| b / (1u64 << 30) as f64;
    Err(TransportError::TooLarge {
        rows,
        cols,
        gib: gib(bytes),
        limit_gib: gib(limit),
        max_wall_side: (limit / per_element).sqrt().floor() as usize,
    })
}

impl Transport {
    /// Wraps column-major entries; `data.len()` must be `rows * cols`, `rows`
    /// the blocks times the wall grid's cells and `cols` the scene grid's cells
    /// (a layout that does not add up is a bug of the caller: it panics).
    pub fn from_col_major(
        rows: usize,
        cols: usize,
        data: Vec<f64>,
        blocks: Vec<Block>,
        wall_grid: Grid,
        scene_grid: Grid,
    ) -> Self {
        assert_eq!(
            data.len(),
            rows * cols,
            "transport data does not match its shape"
        );
        assert_eq!(
            rows,
            blocks.len() * wall_grid.count(),
            "transport rows are not the blocks times the wall grid's cells"
        );
        assert_eq!(
            cols,
            scene_grid.count(),
            "transport columns are not the scene grid's cells"
        );
        Self {
            rows,
            cols,
            data,
            blocks,
            wall_grid,
            scene_grid,
        }
    }

    /// `mean(diag(T^T T))`, the mean squared column norm: the unit in which
    /// the solvers' default lambda and rho are given.
    pub fn mean_column_norm2(&self) -> f64 {
        if self.cols == 0 {
            return 0.0;
        }
        self.data.iter().map(|v| v * v).sum::<f64>() / self.cols as f64
    }

    /// Row blocks, in row order (pose, then polarizer angle).
    pub fn blocks(&self) -> &[Block] {
        &self.blocks
    }

    /// Wall grid: the rows within one block.
    pub fn wall_grid(&self) -> Grid {
        self.wall_grid
    }

    /// Scene grid: the columns.
    pub fn scene_grid(&self) -> Grid {
        self.scene_grid
    }

    /// Number of rows (measurements).
    pub fn rows(&self) -> usize {
        self.rows
    }

    /// Number of columns (scene elements).
    pub fn cols(&self) -> usize {
        self.cols
    }

    /// Entry `T[j, k]`.
    pub fn get(&self, j: usize, k: usize) -> f64 {
        self.data[k * self.rows + j]
    }

    /// Column `k` (the wall response to scene element `k`, all blocks stacked).
    pub fn col(&self, k: usize) -> &[f64] {
        &self.data[k * self.rows..(k + 1) * self.rows]
    }

    /// Column-major entries.
    pub fn col_major(&self) -> &[f64] {
        &self.data
    }

    /// A faer view for the dense linear algebra.
    pub fn as_mat(&self) -> MatRef<'_, f64> {
        MatRef::from_column_major_slice(&self.data, self.rows, self.cols)
    }

    /// Rows of block `b`.
    pub fn block_rows(&self, b: usize) -> std::ops::Range<usize> {
        let n = self.wall_grid.count();
        b * n..(b + 1) * n
    }

    /// The rows of blocks `keep` (indices into [`Transport::blocks`], in
    /// ascending order): the `T` of a measurement that has only those blocks.
    ///
    /// Why: an interim reconstruction while a plan is still capturing solves
    /// with the blocks taken so far (MODEL.md's row order is kept).
    pub fn select_blocks(&self, keep: &[usize]) -> Transport {
        let n = self.wall_grid.count();
        let rows = keep.len() * n;
        let mut data = Vec::with_capacity(rows * self.cols);
        for k in 0..self.cols {
            let col = self.col(k);
            for &b in keep {
                data.extend_from_slice(&col[self.block_rows(b)]);
            }
        }
        let blocks = keep.iter().map(|&b| self.blocks[b].clone()).collect();
        Transport::from_col_major(
            rows,
            self.cols,
            data,
            blocks,
            self.wall_grid,
            self.scene_grid,
        )
    }

    /// A copy with the rows `drop` (indices in `0..rows`, others ignored)
    /// all zero: rows whose measurement is missing (a saturated element)
    /// then add nothing to any fit, and the block layout stays.
    pub fn with_rows_zeroed(&self, drop: &[usize]) -> Transport {
        let mut data = self.data.clone();
        for k in 0..self.cols {
            let col = &mut data[k * self.rows..(k + 1) * self.rows];
            for &j in drop.iter().filter(|&&j| j < self.rows) {
                col[j] = 0.0;
            }
        }
        Transport::from_col_major(
            self.rows,
            self.cols,
            data,
            self.blocks.clone(),
            self.wall_grid,
            self.scene_grid,
        )
    }

    /// `i = T l`: the noiseless measurement of scene `l` (MODEL.md Eq. 2).
    pub fn apply(&self, l: &[f64]) -> Vec<f64> {
        assert_eq!(l.len(), self.cols, "scene vector length");
        let mut out = vec![0.0; self.rows];
        for (k, &lk) in l.iter().enumerate() {
            if lk != 0.0 {
                for (o, t) in out.iter_mut().zip(self.col(k)) {
                    *o += t * lk;
                }
            }
        }
        out
    }

    /// Row-major entries (the order of a C-order `.npy`).
    pub fn to_row_major(&self) -> Vec<f64> {
        let mut out = vec![0.0; self.data.len()];
        for k in 0..self.cols {
            for (j, &t) in self.col(k).iter().enumerate() {
                out[j * self.cols + k] = t;
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_build_over_its_budget_is_refused_before_it_allocates() {
        assert_eq!(MemoryBudget::new(0).bytes(), 1 << 20);
        let scene = crate::scene::Scene::builtin("brewster-crossed")
            .and_then(Result::ok)
            .expect("built-in scene")
            .edit(|s| s.hidden.plane.grid = Grid { nu: 24, nv: 24 })
            .expect("a valid grid");
        // 1024 rows x 576 columns in f64 is 4.5 MiB.
        let e = build(&scene, MemoryBudget::new(1 << 20)).unwrap_err();
        assert!(
            matches!(
                e,
                TransportError::TooLarge {
                    rows: 1024,
                    cols: 576,
                    ..
                }
            ),
            "{e}"
        );
        assert!(build(&scene, MemoryBudget::new(64 << 20)).is_ok());
    }

    #[test]
    fn selected_blocks_are_the_rows_of_those_blocks_in_order() {
        let scene = crate::scene::Scene::builtin("brewster-rotating-3x3")
            .and_then(Result::ok)
            .expect("built-in scene");
        let t = build(&scene, MemoryBudget::new(1 << 30)).expect("T");
        assert_eq!(t.blocks().len(), 4);
        let s = t.select_blocks(&[1, 3]);
        let n = t.wall_grid().count();
        assert_eq!((s.rows(), s.cols()), (2 * n, t.cols()));
        assert_eq!(s.blocks(), &[t.blocks()[1].clone(), t.blocks()[3].clone()]);
        for k in 0..t.cols() {
            for j in 0..n {
                assert_eq!(s.get(j, k), t.get(n + j, k));
                assert_eq!(s.get(n + j, k), t.get(3 * n + j, k));
            }
        }
        // Every block kept is T itself.
        assert_eq!(t.select_blocks(&[0, 1, 2, 3]).col_major(), t.col_major());
    }

    #[test]
    fn mean_column_norm2_is_the_mean_diagonal_of_the_gram_matrix() {
        // Columns (3, 4) and (0, 2): squared norms 25 and 4.
        let t = Transport::from_col_major(
            2,
            2,
            vec![3.0, 4.0, 0.0, 2.0],
            vec![Block {
                pose: "A".into(),
                channel: crate::scene::Channel::None,
            }],
            Grid { nu: 2, nv: 1 },
            Grid { nu: 2, nv: 1 },
        );
        assert_eq!(t.mean_column_norm2(), 14.5);
    }
}
