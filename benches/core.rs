//! Benchmarks of the numeric core on the reference size: wall 64x64,
//! scene 32x32, two poses (B and C of the Brewster bench, crossed polarizer),
//! i.e. T is 8192 x 1024.
//!
//! Run: `cargo bench --bench core`. Targets on the 2-core bench machine:
//! T build < 0.25 s; Gram + Cholesky + 200 ADMM iterations < 0.25 s.

use polnlos::scene::Scene;
use polnlos::simulate::patterns::Pattern;
use polnlos::solve::admm::LAMBDA_REL;
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
