//! A scene's measurement reconstructed end to end: the sampling keys the
//! file left out chosen from the noise, `T` built, its conditioning, the solve
//! and the report.
//!
//! Why: `polnlos reconstruct` and the Python bindings must give the same
//! image and report for the same inputs, so both call [`reconstruct_scene`].

use super::conditioning::condition_with;
use super::gram::Normal;
use super::lambda::NoiseLevel;
use super::reconstruct::{reconstruct_prepared, Context, Solved};
use super::{SolveError, SolveRequest};
use crate::scene::Scene;
use crate::stop::Stop;
use crate::transport::{MemoryBudget, TransportError};

/// What a scene's reconstruction needs beside the scene and the request.
#[derive(Default)]
pub struct SceneInput<'a> {
    /// The measurement, one value per row of `T`.
    pub measurement: &'a [f64],
    /// The noise level when known (a variance per row, a camera model).
    pub noise: Option<NoiseLevel>,
    /// The truth on the scene grid, for the report's metrics.
    pub truth: Option<&'a [f64]>,
    /// Take κ and the rank from a full SVD of `T`, not from `T^T T`.
    pub full_spectrum: bool,
    /// The scene's name in the report.
    pub name: String,
    /// Ends the solve early when raised.
    pub stop: Stop<'a>,
}

/// Why a scene's reconstruction failed.
#[derive(Debug, thiserror::Error)]
pub enum SceneSolveError {
    /// Building (or choosing the sampling of) `T` failed.
    #[error(transparent)]
    Transport(#[from] TransportError),
    /// The solve failed.
    #[error(transparent)]
    Solve(#[from] SolveError),
}

/// Reconstructs `input.measurement` of `scene` as `req` asks; `progress`
/// hears how many columns of `T` are built.
///
/// With the noise known, the sampling keys the scene file leaves out are
/// chosen so that the model error stays below a third of it (MODEL.md, "From
/// camera frames to i"), and the report says what was used.
pub fn reconstruct_scene(
    scene: &Scene,
    input: SceneInput<'_>,
    req: &SolveRequest,
    budget: MemoryBudget,
    progress: &(dyn Fn(usize) + Sync),
) -> Result<Solved, SceneSolveError> {
    reconstruct_scene_with(scene, input, req, budget, &|s: &Scene| {
        crate::transport::build_with_progress(s, budget, progress, Stop::default())
    })
}

/// [`reconstruct_scene`] with `T` of the scene it settles on from `build`
/// (a cache of built matrices, in the command-line tool).
pub fn reconstruct_scene_with(
    scene: &Scene,
    input: SceneInput<'_>,
    req: &SolveRequest,
    budget: MemoryBudget,
    build: &dyn Fn(&Scene) -> Result<crate::transport::Transport, TransportError>,
) -> Result<Solved, SceneSolveError> {
    req.check()?;
    // Rows not measured (NaN: a saturated pixel, as `polnlos measure`
    // writes them) take no part: zero in i, in T and in the variance.
    let mut input = input;
    let mut known = input.measurement.to_vec();
    let missing = super::zero_unmeasured(
        &mut known,
        input.noise.as_mut().map(|n| n.variance.as_mut_slice()),
    );
    input.measurement = &known;
    let choice = match &input.noise {
        Some(n) if scene.left_out() != Default::default() => Some(
            crate::transport::choose::choose(scene, &n.variance, budget)?,
        ),
        _ => None,
    };
    let scene = choice.as_ref().map_or(scene, |(s, _)| s);
    let start = std::time::Instant::now();
    let t = build(scene)?;
    let t = match missing.is_empty() {
        true => t,
        false => t.with_rows_zeroed(&missing),
    };
    let transport_seconds = start.elapsed().as_secs_f64();
    // A solver that needs T^T T forms it anyway: form it once, here, and take
    // the conditioning from its low-rank form unless the full spectrum is asked for.
    let normal = if req.solver.needs().gram {
        super::check_measurement(&t, input.measurement)?;
        Some(Normal::of(&t, input.measurement))
    } else {
        None
    };
    let gram = normal
        .as_ref()
        .filter(|_| !input.full_spectrum)
        .map(|n| &*n.gram);
    let cond = condition_with(&t, gram)?;
    let mut solved = reconstruct_prepared(
        &t,
        input.measurement,
        input.noise,
        &cond,
        normal.as_ref(),
        req,
        Context {
            scene: input.name,
            transport_seconds,
            truth: input.truth,
            stop: input.stop,
        },
    )?;
    solved.report.model = choice.map(|(_, c)| c);
    if let Some(w) = super::unmeasured_warning(&missing, known.len()) {
        solved.report.warnings.insert(0, w);
    }
    Ok(solved)
}
