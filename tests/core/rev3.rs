//! MODEL.md revision 3 against an independent implementation
//! (`validation/mitsuba/model.py`, numpy, sharing no code with the crate;
//! its outputs are committed in `tests/data/rev3/`): the measurement of a
//! camera frame (every pixel of a wall element, footprint-weighted) and the
//! `sampling = "pixels"` rows of `T`, each to 1e-9.

use std::path::{Path, PathBuf};

use polnlos::files::npy;
use polnlos::measure::wall_means;
use polnlos::scene::{Frame, FrameGeometry, Homography, PixelMap, Scene, WallSampling};
use polnlos::transport::{build, MemoryBudget};

fn data(rel: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/rev3")
        .join(rel)
}

fn read(path: &Path) -> npy::Array {
    npy::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// `T` of `scene` against the independent implementation's `T.npy` at
/// `want`: every entry to 1e-9 of itself (entries below 1e-3 of the peak to
/// 1e-9 of that).
fn equals_the_independent_reading(case: &str, scene: &Scene, want: &Path) {
    let t = build(scene, MemoryBudget::DEFAULT).unwrap();
    let want = read(want);
    assert_eq!(want.shape, vec![t.rows(), t.cols()], "{case}");
    let peak = want.data.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let mut worst = 0.0f64;
    for j in 0..t.rows() {
        for k in 0..t.cols() {
            let (a, b) = (t.get(j, k), want.data[j * t.cols() + k]);
            worst = worst.max((a - b).abs() / (1e-300 + b.abs().max(1e-6 * peak)));
            assert!(
                (a - b).abs() <= 1e-9 * b.abs().max(1e-3 * peak),
                "{case}: T[{j},{k}] = {a}, the independent reading has {b}"
            );
        }
    }
    println!(
        "{case}: {} x {}, worst relative difference {worst:.1e}",
        t.rows(),
        t.cols()
    );
}

#[test]
fn pixel_rows_equal_the_independent_implementation() {
    let cases = [
        "brewster-crossed-3x3-pixels",
        "brewster-multi-3x3-pixels",
        "occluder-rotating-3x3-pixels",
        "occluder-multi-3x3-pixels-kd",
    ];
    for case in cases {
        let scene = Scene::load(&data(case).join("scene.toml")).unwrap();
        assert_eq!(scene.wall().sampling, WallSampling::Pixels, "{case}");
        equals_the_independent_reading(case, &scene, &data(case).join("T.npy"));
    }
}

#[test]
fn a_frame_measures_to_the_independent_footprint_weighted_means() {
    let frame = read(&data("measure/frame.npy"));
    let (height, width) = (frame.shape[0], frame.shape[1]);
    let frame = Frame {
        width,
        height,
        pixels: frame.data.iter().map(|&v| v as f32).collect(),
    };
    let variance: Vec<f32> = read(&data("measure/variance.npy"))
        .data
        .iter()
        .map(|&v| v as f32)
        .collect();
    let h = read(&data("measure/H.npy")).data;
    let h = Homography::new([[h[0], h[1], h[2]], [h[3], h[4], h[5]], [h[6], h[7], h[8]]]).unwrap();
    let scene = Scene::builtin("brewster-crossed-3x3").unwrap().unwrap();
    let wall = &scene.wall().plane;
    let i = wall_means(&frame, &h, wall, "A").unwrap();
    let map = PixelMap::frame(&h, wall, FrameGeometry::plain(width, height), "A").unwrap();
    let var_of = |p: usize| f64::from(variance[p]);
    let (_, var) = map.average(&frame.pixels, Some(&var_of));
    let var = var.unwrap();
    let (want_i, want_var, counts) = (
        read(&data("measure/i.npy")).data,
        read(&data("measure/var.npy")).data,
        read(&data("measure/counts.npy")).data,
    );
    assert_eq!(i.len(), want_i.len());
    for j in 0..i.len() {
        assert_eq!(
            map.range(j).len() as f64,
            counts[j],
            "pixels of element {j}"
        );
        assert!(
            (i[j] - want_i[j]).abs() <= 1e-9 * want_i[j].abs(),
            "i[{j}] = {}, independent {}",
            i[j],
            want_i[j]
        );
        assert!(
            (var[j] - want_var[j]).abs() <= 1e-9 * want_var[j],
            "var[{j}] = {}, independent {}",
            var[j],
            want_var[j]
        );
    }
}

/// Polarizer-mosaic poses (MODEL.md "On-chip polarizer mosaic") against the
/// independent implementation (`validation/mitsuba/make_mosaic.py`, data in
/// `tests/data/mosaic/`): partial micro-polarizers, each angle's `"pixels"`
/// rows over its own 2x2 sub-lattice, a sheet pose beside a mosaic one.
#[test]
fn mosaic_rows_equal_the_independent_implementation() {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data/mosaic");
    let mut cases: Vec<PathBuf> = std::fs::read_dir(&root)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.join("T.npy").exists())
        .collect();
    cases.sort();
    assert!(cases.len() >= 4, "{cases:?}");
    for dir in cases {
        let case = dir.file_name().unwrap().to_string_lossy().into_owned();
        let scene = Scene::load(&dir.join("scene.toml")).unwrap();
        assert!(scene.poses().iter().any(|p| p.mosaic.is_some()), "{case}");
        equals_the_independent_reading(&case, &scene, &dir.join("T.npy"));
    }
}
