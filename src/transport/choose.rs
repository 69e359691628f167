//! How finely `T` is sampled, chosen from the noise it must explain
//! (MODEL.md "Rows that match the measurement": a reconstruction, which
//! knows the noise, may raise `supersample` and switch to `"pixels"` where
//! the scene file leaves them out, and reports what it used).
//!
//! Why: too coarse a model puts its error into the image, where no residual
//! shows it; too fine a one costs build time for nothing. The rule: the
//! model's error, estimated against the next finer model on a sample of
//! rows, stays below a third of the noise of those rows.

use super::{MemoryBudget, TransportError};
use crate::scene::{Scene, WallSampling};

/// The most the model error may be, as a fraction of the noise (rms over rows).
pub(crate) const TARGET: f64 = 1.0 / 3.0;
/// Finest scene supersampling a choice goes to (its error falls as `1/m^2`
/// on smooth integrands; an occluder's edge wants a file value).
pub(crate) const MAX_SCENE_SUPERSAMPLE: usize = 8;
/// Finest uniform wall supersampling a choice goes to (poses without a homography).
pub(crate) const MAX_WALL_SUPERSAMPLE: usize = 8;
/// Wall elements per block the error is estimated on.
const SAMPLED_ELEMENTS: usize = 48;

/// What a reconstruction sampled `T` with, and the error it estimated.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct ModelChoice {
    /// `[wall] sampling` used.
    pub sampling: WallSampling,
    /// `[wall] supersample` used.
    pub wall_supersample: usize,
    /// `[scene] supersample` used.
    pub scene_supersample: usize,
    /// The model's estimated error over the noise: rms over the sampled rows
    /// of `((T - T_finer) 1)_j / sigma_j`, wall and scene parts together.
    pub error_over_noise: f64,
    /// The keys polnlos chose (the file left them out); the others are the file's.
    pub chosen: Vec<&'static str>,
}

/// The scene whose `T` a reconstruction with per-row noise `variance` (in
/// units of `T l`, MODEL.md row order) should use, and what was chosen; the
/// scene as given when the file sets every sampling key.
pub fn choose(
    scene: &Scene,
    variance: &[f64],
    budget: MemoryBudget,
) -> Result<(Scene, ModelChoice), TransportError> {
    let left = scene.left_out();
    let mut current = scene.clone();
    let mut chosen = Vec::new();
    let homographies = scene.poses().iter().all(|p| p.homography.is_some());
    let sample = sampled_elements(scene);
    // The wall: pixel rows match the measurement exactly; uniform rows are
    // kept while their error against them is small enough.
    let mut wall_error = 0.0;
    if homographies && left.sampling && scene.wall().sampling == WallSampling::Uniform {
        let pixels = with(&current, |p| p.wall.sampling = WallSampling::Pixels)?;
        wall_error = error(&current, &pixels, &sample, variance, budget)?;
        if wall_error > TARGET {
            current = pixels;
            wall_error = 0.0;
            chosen.push("wall.sampling");
        }
    }
    if current.wall().sampling == WallSampling::Uniform && left.wall_supersample {
        let reference = if homographies {
            Some(with(&current, |p| p.wall.sampling = WallSampling::Pixels)?)
        } else {
            None
        };
        loop {
            let m = current.wall().plane.supersample;
            let finer = match &reference {
                Some(r) => r.clone(),
                None => with(&current, |p| p.wall.plane.supersample = 2 * m)?,
            };
            wall_error = error(&current, &finer, &sample, variance, budget)?;
            if wall_error <= TARGET || 2 * m > MAX_WALL_SUPERSAMPLE {
                break;
            }
            current = with(&current, |p| p.wall.plane.supersample = 2 * m)?;
            if !chosen.contains(&"wall.supersample") {
                chosen.push("wall.supersample");
            }
        }
    }
    let mut scene_error = 0.0;
    if left.scene_supersample {
        loop {
            let m = current.hidden().plane.supersample;
            let finer = with(&current, |p| p.hidden.plane.supersample = 2 * m)?;
            scene_error = error(&current, &finer, &sample, variance, budget)?;
            if scene_error <= TARGET || 2 * m > MAX_SCENE_SUPERSAMPLE {
                break;
            }
            current = finer;
            if !chosen.contains(&"scene.supersample") {
                chosen.push("scene.supersample");
            }
        }
    }
    let choice = ModelChoice {
        sampling: current.wall().sampling,
        wall_supersample: current.wall().plane.supersample,
        scene_supersample: current.hidden().plane.supersample,
        error_over_noise: (wall_error * wall_error + scene_error * scene_error).sqrt(),
        chosen,
    };
    Ok((current, choice))
}

/// `scene` changed by `change`, with the changed keys no longer "left out"
/// (so that a chosen value is written back as the file's).
fn with(
    scene: &Scene,
    change: impl FnOnce(&mut crate::scene::SceneParts),
) -> Result<Scene, TransportError> {
    scene
        .clone()
        .edit(change)
        .map_err(|e| TransportError::Choice(e.to_string()))
}

/// About [`SAMPLED_ELEMENTS`] wall elements spread over the wall, in order.
fn sampled_elements(scene: &Scene) -> Vec<usize> {
    let n = scene.wall().plane.grid.count();
    let step = n.div_ceil(SAMPLED_ELEMENTS).max(1);
    (step / 2..n).step_by(step).collect()
}

/// rms over the sampled rows of `((T_a - T_b) 1)_j / sigma_j`.
fn error(
    a: &Scene,
    b: &Scene,
    sample: &[usize],
    variance: &[f64],
    budget: MemoryBudget,
) -> Result<f64, TransportError> {
    let (ra, rb) = (row_sums(a, sample, budget)?, row_sums(b, sample, budget)?);
    let n_wall = a.wall().plane.grid.count();
    let (mut sum, mut count) = (0.0, 0usize);
    for (r, (x, y)) in ra.iter().zip(&rb).enumerate() {
        let (block, k) = (r / sample.len(), r % sample.len());
        let var = variance
            .get(block * n_wall + sample[k])
            .copied()
            .unwrap_or(0.0);
        if var > 0.0 && var.is_finite() {
            sum += (x - y) * (x - y) / var;
            count += 1;
        }
    }
    Ok(if count == 0 {
        0.0
    } else {
        (sum / count as f64).sqrt()
    })
}

/// `(T 1)` on the sampled elements of every block: the rows of `T` that
/// `scene` samples, for those elements only.
fn row_sums(
    scene: &Scene,
    sample: &[usize],
    budget: MemoryBudget,
) -> Result<Vec<f64>, TransportError> {
    let rows = sample.len() * scene.block_count();
    let data = super::build_elements(scene, sample, budget)?;
    let mut sums = vec![0.0; rows];
    for col in data.chunks(rows.max(1)) {
        sums.iter_mut().zip(col).for_each(|(s, v)| *s += v);
    }
    Ok(sums)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn crossed(extra_wall: &str, scene_m: Option<usize>) -> Scene {
        let mut text = crate::scene::builtin::text("brewster-crossed")
            .expect("built-in")
            .replace(
                "supersample = 1\nroughness",
                &format!("{extra_wall}roughness"),
            );
        text = match scene_m {
            Some(m) => text.replace(
                "supersample = 1\nemitter",
                &format!("supersample = {m}\nemitter"),
            ),
            None => text.replace("supersample = 1\nemitter", "emitter"),
        };
        Scene::from_toml_str(&text).expect("valid scene")
    }

    #[test]
    fn low_noise_asks_for_pixel_rows_and_a_finer_scene_high_noise_for_neither() {
        let scene = crossed("", None);
        assert!(scene.left_out().sampling && scene.left_out().scene_supersample);
        let t = crate::transport::build(&scene, MemoryBudget::DEFAULT).expect("T");
        let level = t.apply(&vec![1.0; t.cols()]);
        // 1 % noise: the centre-sampled model's ~0.1 % error is well below a third of it.
        let loud: Vec<f64> = level.iter().map(|v| (0.01 * v).powi(2)).collect();
        let (s, c) = choose(&scene, &loud, MemoryBudget::DEFAULT).expect("choice");
        assert_eq!(
            (c.sampling, c.scene_supersample),
            (WallSampling::Uniform, 1),
            "{c:?}"
        );
        assert!(c.error_over_noise <= TARGET && c.chosen.is_empty(), "{c:?}");
        assert_eq!(s, scene);
        // 0.01 % noise: pixel rows, and the scene sampled finer.
        let quiet: Vec<f64> = level.iter().map(|v| (1e-4 * v).powi(2)).collect();
        let (s, c) = choose(&scene, &quiet, MemoryBudget::DEFAULT).expect("choice");
        assert_eq!(c.sampling, WallSampling::Pixels, "{c:?}");
        assert!(c.scene_supersample >= 2, "{c:?}");
        assert!(c.chosen.contains(&"wall.sampling") && c.chosen.contains(&"scene.supersample"));
        assert_eq!(s.wall().sampling, WallSampling::Pixels);
    }

    #[test]
    fn keys_the_file_sets_are_kept_whatever_the_noise() {
        let scene = crossed("supersample = 1\nsampling = \"uniform\"\n", Some(1));
        let t = crate::transport::build(&scene, MemoryBudget::DEFAULT).expect("T");
        let quiet: Vec<f64> = t
            .apply(&vec![1.0; t.cols()])
            .iter()
            .map(|v| (1e-5 * v).powi(2))
            .collect();
        let (s, c) = choose(&scene, &quiet, MemoryBudget::DEFAULT).expect("choice");
        assert_eq!(s, scene);
        assert!(c.chosen.is_empty());
        assert_eq!(c.error_over_noise, 0.0, "nothing was compared: {c:?}");
    }
}
