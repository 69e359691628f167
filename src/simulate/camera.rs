//! The camera inside the simulation: frames rendered pixel by pixel, each
//! pixel showing the wall radiance at its own wall point `H^-1(p)` (MODEL.md
//! "From camera frames to i"), not one value painted over an element.
//!
//! Why: a wall element's pixels see different wall points, and a camera that
//! paints each element flat agrees with a centre-sampled `T` by construction,
//! hiding exactly the error the measurement and the `"pixels"` rows deal with.

use crate::scene::{Frame, FrameGeometry, Scene};
use crate::transport::{blocks_of, radiance_at, Block};

/// The clean frame of every block of `scene` lit by `l` (units of `T l`),
/// for frames of `geometry`: each pixel at its own wall point, 0 where it
/// sees no wall; `None` for a pose without a homography.
pub fn render(scene: &Scene, l: &[f64], geometry: FrameGeometry) -> Vec<(Block, Option<Frame>)> {
    let plane = &scene.wall().plane;
    let [hu, hv] = [plane.size[0] / 2.0, plane.size[1] / 2.0];
    let [w, h] = geometry.size;
    // Per pose: the frame pixels that see the wall, and their wall points.
    let mut pixels: Vec<Vec<usize>> = Vec::with_capacity(scene.poses().len());
    let mut points: Vec<Vec<[f64; 2]>> = Vec::with_capacity(scene.poses().len());
    for pose in scene.poses() {
        let (mut px, mut pt) = (Vec::new(), Vec::new());
        if let Some(hom) = pose.homography.as_ref() {
            for y in 0..h {
                for x in 0..w {
                    let (sx, sy) = geometry.centre(x, y);
                    if let Some((u, v)) = hom.invert(sx, sy) {
                        if (-hu..hu).contains(&u) && (-hv..hv).contains(&v) {
                            px.push(y * w + x);
                            pt.push([u, v]);
                        }
                    }
                }
            }
        }
        pixels.push(px);
        points.push(pt);
    }
    let values = radiance_at(scene, &points, l);
    let blocks = blocks_of(scene);
    let mut out = Vec::with_capacity(blocks.len());
    let mut b = 0;
    for (k, pose) in scene.poses().iter().enumerate() {
        for _ in 0..pose.block_count() {
            let frame = pose.homography.is_some().then(|| {
                let mut f = Frame::zeros(w, h);
                for (&p, &v) in pixels[k].iter().zip(&values[b]) {
                    f.pixels[p] = v as f32;
                }
                f
            });
            out.push((blocks[b].clone(), frame));
            b += 1;
        }
    }
    out
}

/// One exposure of `clean` (units of `T l`) on a camera of `electrons_per_unit`
/// and `read_noise` electrons RMS: each pixel's electrons with Gaussian shot
/// and read noise (variance `e + read_noise^2`) drawn from `rng`, and that
/// variance, both in electrons (digital numbers at unit gain).
pub fn expose(
    clean: &Frame,
    electrons_per_unit: f64,
    read_noise: f64,
    rng: &mut impl rand::Rng,
) -> (Frame, Frame) {
    use rand_distr::{Distribution, StandardNormal};
    let mut mean = Frame::zeros(clean.width, clean.height);
    let mut variance = Frame::zeros(clean.width, clean.height);
    for (p, &v) in clean.pixels.iter().enumerate() {
        let e = (f64::from(v) * electrons_per_unit).max(0.0);
        let var = e + read_noise * read_noise;
        let z: f64 = StandardNormal.sample(rng);
        mean.pixels[p] = (e + var.sqrt() * z) as f32;
        variance.pixels[p] = var as f32;
    }
    (mean, variance)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::measure::{assemble, CaptureFrames};
    use crate::transport::MemoryBudget;

    fn crossed(sampling: &str, wall_m: usize) -> Scene {
        let text = crate::scene::builtin::text("brewster-crossed")
            .expect("built-in")
            .replace(
                "supersample = 1\nroughness",
                &format!("supersample = {wall_m}\nsampling = \"{sampling}\"\nroughness"),
            );
        Scene::from_toml_str(&text).expect("valid scene")
    }

    /// The measurement of a rendered frame against `T l`: relative rms and max.
    fn misfit(scene: &Scene, frame_scene: &Scene, l: &[f64]) -> (f64, f64) {
        let (block, frame) = render(frame_scene, l, FrameGeometry::plain(512, 512))
            .into_iter()
            .next()
            .expect("one block");
        let capture = CaptureFrames {
            name: "render".into(),
            pose: block.pose.clone(),
            channels: vec![block.channel],
            mean: frame.expect("pose A has a homography"),
            variance: None,
            frames: 1,
            full_scale: 1.0,
            exposure_us: 1.0,
            offset: [0, 0],
            binning: [1, 1],
            bayer: None,
        };
        let m = assemble(scene, &[block], &[capture]).expect("the wall is in the frame");
        let t = crate::transport::build(scene, MemoryBudget::DEFAULT).expect("T");
        let want = t.apply(l);
        let scale = want.iter().map(|v| v * v).sum::<f64>().sqrt() / (want.len() as f64).sqrt();
        let (mut rms, mut max) = (0.0, 0.0f64);
        for (a, b) in m.i.iter().zip(&want) {
            rms += (a - b) * (a - b);
            max = max.max((a - b).abs() / scale);
        }
        ((rms / want.len() as f64).sqrt() / scale, max)
    }

    #[test]
    fn pixel_rows_explain_a_rendered_frame_exactly_and_uniform_rows_do_not() {
        let pixels = crossed("pixels", 1);
        let l: Vec<f64> = (0..pixels.cols())
            .map(|k| 0.2 + (k % 7) as f64 / 8.0)
            .collect();
        // The frame is f32: the pixel rows match it to its rounding.
        let (rms, max) = misfit(&pixels, &pixels, &l);
        assert!(rms < 1e-6 && max < 1e-5, "pixels: rms {rms} max {max}");
        // Centre samples, and even 4x4 sub-samples, miss how pixels straddle elements.
        let (rms1, _) = misfit(&crossed("uniform", 1), &pixels, &l);
        let (rms4, _) = misfit(&crossed("uniform", 4), &pixels, &l);
        assert!(rms1 > 1e-3 && rms4 > 5e-4, "uniform: {rms1} {rms4}");
        eprintln!("pixels rms {rms} max {max}; uniform m=1 rms {rms1}, m=4 rms {rms4}");
    }
}
