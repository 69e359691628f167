//! Progress bars on a terminal only: hidden when stderr is a pipe or a file.

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

/// A bar over `len` steps that draws only on an interactive stderr.
pub fn bar(len: usize, what: &str) -> ProgressBar {
    let pb = ProgressBar::with_draw_target(Some(len as u64), ProgressDrawTarget::stderr());
    if let Ok(style) =
        ProgressStyle::with_template("{msg:>12} [{bar:40}] {pos}/{len} {elapsed_precise} eta {eta}")
    {
        pb.set_style(style.progress_chars("=> "));
    }
    pb.set_message(what.to_string());
    pb
}

/// Builds `T` within `budget`, with a bar over its columns.
pub fn build_transport(
    scene: &polnlos::scene::Scene,
    budget: polnlos::transport::MemoryBudget,
) -> anyhow::Result<(polnlos::transport::Transport, f64)> {
    let pb = bar(scene.cols(), "building T");
    let start = std::time::Instant::now();
    let progress = |done: usize| pb.set_position(done as u64);
    let t = polnlos::transport::build_with_progress(scene, budget, &progress, Default::default())?;
    pb.finish_and_clear();
    Ok((t, start.elapsed().as_secs_f64()))
}
