//! Benchmarks of the numeric core on the reference size: wall 64x64,
//! scene 32x32, two poses (B and C of the Brewster bench, crossed polarizer),
//! i.e. T is 8192 x 1024.
//!
//! Run: `cargo bench --bench core`. Targets on the 2-core bench machine:
//! T build < 0.25 s; Gram + Cholesky + 200 ADMM iterations < 0.25 s; a
//! 2048x2048 frame measured from all its wall pixels < 20 ms (5.8 ms measured).

use polnlos::scene::Scene;
use polnlos::simulate::patterns::Pattern;
use polnlos::solve::LAMBDA_REL;
use polnlos::solve::{admm_tv, AdmmSettings};
use polnlos::transport::{build, MemoryBudget};

fn main() {
    faer::set_global_parallelism(faer::Par::rayon(0));
    divan::main();
}

fn scene() -> Scene {
    let path =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("config/scenes/brewster-multi.toml");
    let text = std::fs::read_to_string(path)
        .expect("config/scenes/brewster-multi.toml")
        .replace("grid = [32, 32]", "grid = [64, 64]")
        .replace("grid = [8, 8]", "grid = [32, 32]");
    Scene::from_toml_str(&text).expect("bench scene")
}

#[divan::bench(sample_count = 10)]
fn transport_build_64x64_32x32_2poses(bencher: divan::Bencher) {
    let s = scene();
    bencher.bench(|| build(divan::black_box(&s), MemoryBudget::DEFAULT).expect("T"));
}

#[divan::bench(sample_count = 10)]
fn gram_cholesky_admm200_64x64_32x32_2poses(bencher: divan::Bencher) {
    let s = scene();
    let t = build(&s, MemoryBudget::DEFAULT).expect("T");
    let i = t.apply(&Pattern::Letter.render(t.scene_grid()));
    // Fixed rho (no residual balancing): the cost of exactly one factorization
    // and 200 iterations.
    let unit = t.mean_column_norm2();
    let settings = AdmmSettings {
        lambda: Some(LAMBDA_REL * unit),
        rho: Some(LAMBDA_REL * unit),
        max_iter: 200,
        tol: 1e-30,
        ..Default::default()
    };
    bencher.bench(|| {
        let r = admm_tv(&t, divan::black_box(&i), &settings).expect("ADMM");
        assert_eq!(r.stats.iterations, 200);
        r
    });
}

/// The reference bench's pose A seen by a 2048x2048 sensor (4x the 512x512
/// frame's scale): ~1.35 million wall pixels, ~1300 per element.
fn sensor_2048() -> (polnlos::scene::Homography, polnlos::scene::Plane) {
    let s = Scene::builtin("brewster-crossed")
        .and_then(Result::ok)
        .expect("built-in scene");
    let h = s.poses()[0].homography.expect("pose A").matrix();
    // x' = 4 x + 1.5: pixel centres of the finer sensor on the same image.
    let scale = |r: usize, a: f64| {
        [
            a * h[r][0] + 1.5 * h[2][0],
            a * h[r][1] + 1.5 * h[2][1],
            a * h[r][2] + 1.5 * h[2][2],
        ]
    };
    let m = [scale(0, 4.0), scale(1, 4.0), h[2]];
    (
        polnlos::scene::Homography::new(m).expect("invertible"),
        s.wall().plane.clone(),
    )
}

/// MODEL.md revision 3: each element the footprint-weighted mean of its
/// pixels, with its variance, over a 2048x2048 frame (the map made once, as
/// the daemon caches it). Goal: under 20 ms on 2 cores.
#[divan::bench(sample_count = 20)]
fn measure_all_pixels_2048x2048(bencher: divan::Bencher) {
    let (h, wall) = sensor_2048();
    let g = polnlos::scene::FrameGeometry::plain(2048, 2048);
    let map = polnlos::scene::PixelMap::frame(&h, &wall, g, "A").expect("wall in frame");
    let frame: Vec<f32> = (0..2048 * 2048).map(|k| (k % 4093) as f32).collect();
    let var: Vec<f32> = (0..2048 * 2048).map(|k| 1.0 + (k % 7) as f32).collect();
    let var_of = |p: usize| f64::from(var[p]);
    bencher.bench(|| map.average(divan::black_box(&frame), Some(&var_of)));
}

/// Making that map: once per pose and frame geometry.
#[divan::bench(sample_count = 10)]
fn pixel_map_2048x2048(bencher: divan::Bencher) {
    let (h, wall) = sensor_2048();
    let g = polnlos::scene::FrameGeometry::plain(2048, 2048);
    bencher.bench(|| polnlos::scene::PixelMap::frame(&h, &wall, g, "A").expect("wall in frame"));
}

/// `T` of the crossed bench (32x32 wall, 8x8 scene) with rows over each
/// element's ~82 pixels against centre samples.
#[divan::bench(args = ["uniform", "pixels"], sample_count = 10)]
fn transport_build_crossed_sampling(bencher: divan::Bencher, sampling: &str) {
    let text = polnlos::scene::builtin::text("brewster-crossed")
        .expect("built-in")
        .replace("ks = 1.0", &format!("ks = 1.0\nsampling = \"{sampling}\""));
    let s = Scene::from_toml_str(&text).expect("bench scene");
    bencher.bench(|| build(divan::black_box(&s), MemoryBudget::DEFAULT).expect("T"));
}
