//! `calibrate occluder` (docs/realphoto.md, "Placing the occluders"): the
//! CLI's refusals of bad input and its files, the fit on simulated photos
//! made unlike the model (the chair, the voxel Π), and (studies,
//! `--ignored`) on the real chair photo and more starts.

use std::path::PathBuf;
use std::process::Command;

use polnlos::calibrate::occluder::{fit_occluder, moved, OccluderFit, OccluderOptions};
use polnlos::files::npy;
use polnlos::scene::{Grid, Scene, ShadowModel};
use polnlos::transport::{build, MemoryBudget};

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// `polnlos calibrate occluder args`.
fn calibrate_occluder(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_polnlos"))
        .args(["calibrate", "occluder"])
        .args(args)
        .env("POLNLOS_CACHE", "off")
        .output()
        .unwrap()
}

/// Bad input is refused before any `T` is built, naming what is wrong.
#[test]
fn calibrate_occluder_refuses_a_bad_selection_and_a_photo_of_another_scene() {
    crate::priority::background();
    let scene = root().join("config/photos/saunders-chair.toml");
    let photo = root().join("tests/data/saunders-chair/measurement.npy");
    let (s, p) = (scene.to_str().unwrap(), photo.to_str().unwrap());
    let out = calibrate_occluder(&[s, "--measurement", p, "--occluder", "0,3-12"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains("occluder 12 is not in the scene, which has 12"),
        "{err}"
    );
    let out = calibrate_occluder(&[s, "--measurement", p, "--range", "0"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(err.contains("range = 0"), "{err}");
    let out = calibrate_occluder(&[s, "--measurement", p, "--occluder", "3-x"]);
    assert_eq!(out.status.code(), Some(2));
    let dir = tempfile::tempdir().unwrap();
    let short = dir.path().join("short.npy");
    npy::write_f64(&short, &[100], &[1.0; 100]).unwrap();
    // The second of two photos is of another scene.
    let out = calibrate_occluder(&[
        s,
        "--measurement",
        p,
        "--measurement",
        short.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(3), "{err}");
    assert!(err.contains("short.npy") && err.contains("15876"), "{err}");
    // A variance for each photo, of the photo's shape.
    let short_s = short.to_str().unwrap();
    let out = calibrate_occluder(&[
        s,
        "--measurement",
        p,
        "--variance",
        short_s,
        "--variance",
        short_s,
    ]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(err.contains("2 --variance but 1 --measurement"), "{err}");
    let out = calibrate_occluder(&[s, "--measurement", p, "--variance", short_s]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(3), "{err}");
    assert!(err.contains("short.npy") && err.contains("15876"), "{err}");
    // A folder that does not exist, or cannot be written, fails at once
    // (before the photo is even read), naming it.
    let missing = dir.path().join("no-such-folder/placed.toml");
    let start = std::time::Instant::now();
    let out = calibrate_occluder(&[s, "--measurement", p, "--out", missing.to_str().unwrap()]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains("--out") && err.contains("no-such-folder") && err.contains("does not exist"),
        "{err}"
    );
    assert!(start.elapsed().as_secs_f64() < 10.0);
    let report = dir.path().join("short.npy/report.json");
    let out = calibrate_occluder(&[s, "--measurement", p, "--report", report.to_str().unwrap()]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains("--report") && err.contains("short.npy"),
        "{err}"
    );
}

/// The CLI end to end on a small Π scene in one folder, its result written
/// to another: the written scene's relative mesh path loads from there, the
/// report holds the fit, and the printout says the uncertainty.
#[test]
fn calibrate_occluder_writes_a_scene_whose_mesh_loads_from_its_new_folder() {
    crate::priority::background();
    let dir = tempfile::tempdir().unwrap();
    let (a, b) = (dir.path().join("a"), dir.path().join("b"));
    std::fs::create_dir_all(&a).unwrap();
    std::fs::create_dir_all(&b).unwrap();
    let pi = root().join("tests/data/pi-occluder");
    std::fs::copy(pi.join("voxels.obj"), a.join("voxels.obj")).unwrap();
    let text = std::fs::read_to_string(pi.join("voxels.toml"))
        .unwrap()
        .replace("grid = [126, 126]", "grid = [21, 21]");
    std::fs::write(a.join("pi.toml"), &text).unwrap();
    let scene = Scene::load(&a.join("pi.toml")).unwrap();
    let t = build(
        &moved(&scene, &[0], [0.003, 0.0, 0.0], 1, ShadowModel::Area).unwrap(),
        MemoryBudget::DEFAULT,
    )
    .unwrap();
    let image = &super::photo::truth()[1];
    let photo = super::photo::photo(&t, image, 2e8, 40.0, 1e-3, 5);
    let npy_path = dir.path().join("photo.npy");
    npy::write_f64(&npy_path, &[photo.len()], &photo).unwrap();
    // Its noise, as `measure` writes it beside a photo of several frames.
    let variance_path = dir.path().join("photo.variance.npy");
    let mean = photo.iter().sum::<f64>() / photo.len() as f64;
    let variance = vec![(1e-3 * mean).powi(2); photo.len()];
    npy::write_f64(&variance_path, &[variance.len()], &variance).unwrap();
    let (placed, report) = (b.join("placed.toml"), b.join("report.json"));
    let out = calibrate_occluder(&[
        a.join("pi.toml").to_str().unwrap(),
        "--measurement",
        npy_path.to_str().unwrap(),
        "--variance",
        variance_path.to_str().unwrap(),
        "--range",
        "0.006",
        "--step",
        "0.004",
        "--min-step",
        "0.002",
        "--out",
        placed.to_str().unwrap(),
        "--report",
        report.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(
        err.contains("translation (") && err.contains(" ± ("),
        "{err}"
    );
    let written = std::fs::read_to_string(&placed).unwrap();
    assert!(written.contains("mesh = \"../a/voxels.obj\""), "{written}");
    let placed_scene = Scene::load(&placed).unwrap();
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&report).unwrap()).unwrap();
    let d: Vec<f64> = (0..3)
        .map(|a| r["translation"][a].as_f64().unwrap())
        .collect();
    assert!(d.iter().all(|x| x.abs() <= 0.006), "{d:?}");
    assert!(r["uncertainty"][0].as_f64().unwrap() > 0.0);
    assert!(r["warnings"].is_array());
    // The model check: none on this 21 x 21 wall (840 rows of differences
    // for the scene's 1044 cells), and the printout says why; the noise
    // given is reported as the check's source.
    assert!(
        err.contains("model check: none (the wall has no more"),
        "{err}"
    );
    assert_eq!(r["noise_from"], "variance", "{r}");
    assert!(
        r["model_error"].is_null() && r["noise_misfit"].is_null(),
        "{r}"
    );
    let want = moved(&scene, &[0], [d[0], d[1], d[2]], 1, ShadowModel::Auto).unwrap();
    let (polnlos::scene::Occluder::Mesh(p), polnlos::scene::Occluder::Mesh(w)) =
        (&placed_scene.occluders()[0], &want.occluders()[0])
    else {
        panic!("the Π is not a mesh");
    };
    let far = p
        .triangles()
        .iter()
        .flatten()
        .zip(w.triangles().iter().flatten())
        .map(|(a, b)| (a - b).norm())
        .fold(0.0, f64::max);
    assert!(far < 1e-12, "the written Π is {far} m from the fitted one");
}

/// The lowest evaluated point's distance from `truth` (metres), per axis
/// and in all.
fn miss(f: &OccluderFit, start: [f64; 3], truth: [f64; 3]) -> ([f64; 3], f64) {
    let e = [0, 1, 2].map(|a| start[a] + f.translation[a] - truth[a]);
    (e, e.iter().map(|x| x * x).sum::<f64>().sqrt())
}

/// Whether the fit's uncertainty covers its error on every axis.
fn covers(f: &OccluderFit, error: [f64; 3]) -> bool {
    (0..3).all(|a| error[a].abs() <= f.uncertainty[a])
}

/// The requirement: the uncertainty covers the error, or the fit
/// warns that it cannot be trusted.
fn honest(f: &OccluderFit, error: [f64; 3]) -> bool {
    covers(f, error) || !f.trusted()
}

/// One line for a study's table: where the fit ended, its uncertainty and
/// warnings.
fn line(label: &str, f: &OccluderFit, error: [f64; 3], distance: f64) -> String {
    let mm = |v: [f64; 3]| {
        format!(
            "({:+.1}, {:+.1}, {:+.1})",
            v[0] * 1e3,
            v[1] * 1e3,
            v[2] * 1e3
        )
    };
    format!(
        "{label}: ends {} mm from the truth, {:.1} mm; ± {} mm (covers: {}; threshold {:.2} %, ripple {:.2} %); model check {:.3}; objective {:.4e} -> {:.4e}; {} builds, {:.1} s; warnings: {}",
        mm(error),
        distance * 1e3,
        mm(f.uncertainty),
        covers(f, error),
        100.0 * f.relative_threshold,
        100.0 * f.ripple / f.objective_end,
        f.model_error.unwrap_or(f64::NAN),
        f.objective_start,
        f.objective_end,
        f.builds,
        f.seconds,
        if f.warnings.is_empty() {
            "none".to_string()
        } else {
            f.warnings
                .iter()
                .map(ToString::to_string)
                .collect::<Vec<_>>()
                .join("; ")
        }
    )
}

/// The chair scene on an `n x n` wall.
fn chair_scene(n: usize) -> Scene {
    Scene::load(&root().join("config/photos/saunders-chair.toml"))
        .unwrap()
        .edit(|p| p.wall.plane.grid = Grid { nu: n, nv: n })
        .unwrap()
}

/// A simulated chair photo on a coarser wall: the scene's light through the
/// chair (point shadows of 36 sources a block, the data the fit does not
/// make: it builds area shadows of one cell a block), with a gain, a
/// background and noise. Started 2 cm off, the fit comes back to the chair,
/// and its uncertainty covers its error or it warns.
#[test]
fn calibrate_occluder_finds_the_chair_of_a_simulated_photo_from_2_cm_off() {
    crate::priority::background();
    let scene = chair_scene(42);
    let all: Vec<usize> = (0..scene.occluders().len()).collect();
    let render = build(
        &moved(&scene, &all, [0.0; 3], 6, ShadowModel::Point).unwrap(),
        MemoryBudget::DEFAULT,
    )
    .unwrap();
    let channels: Vec<Vec<f64>> = super::photo::truth()
        .iter()
        .enumerate()
        .map(|(c, l)| super::photo::photo(&render, l, 2e8, 40.0, 1e-3, 11 + c as u64))
        .collect();
    let off = [0.0141, -0.0141, 0.0];
    let start = moved(&scene, &all, off, 2, ShadowModel::Point).unwrap();
    let f = fit_occluder(&start, &[channels], &OccluderOptions::default()).unwrap();
    let (error, distance) = miss(&f, off, [0.0; 3]);
    eprintln!("{}", line("simulated chair", &f, error, distance));
    assert!(distance < 0.01, "{error:?}");
    assert!(honest(&f, error), "{f:?}");
}

/// How a simulated photo of the Π differs from the model that fits it.
#[derive(Debug, Clone, Copy)]
pub(super) struct Mismatch {
    /// The screen's blocks split this many times per side (the image
    /// interpolated bilinearly onto them), each lit by `sources x sources`
    /// point sources with point shadows.
    pub(super) split: usize,
    /// Point sources per side of each split block.
    pub(super) sources: usize,
    /// Wall samples per side of each photo element.
    pub(super) wall: usize,
    /// The screen's vertical lobe exponent (the model's is 18).
    pub(super) lobe: f64,
    /// The Π's size in the photo relative to the model's (about its centre).
    pub(super) scale: f64,
}

/// The photo's mismatch of `tests/data/pi-occluder`'s simulations: the
/// screen twice as fine, interpolated (no block edge where the model's
/// are), lit by 2 x 2 point sources each, the photo's elements averaged
/// over 2 x 2 wall points.
pub(super) const SCREEN: Mismatch = Mismatch {
    split: 2,
    sources: 2,
    wall: 2,
    lobe: 18.0,
    scale: 1.0,
};

/// The chair photo's truth (29 x 36 blocks, scene order) interpolated
/// bilinearly onto blocks split `k` times per side.
fn split_image(l: &[f64], k: usize) -> Vec<f64> {
    let (nu, nv) = (36usize, 29usize);
    let at = |u: usize, v: usize| l[v * nu + u];
    let mut out = Vec::with_capacity(nu * nv * k * k);
    for iv in 0..nv * k {
        for iu in 0..nu * k {
            let u = ((iu as f64 + 0.5) / k as f64 - 0.5).clamp(0.0, (nu - 1) as f64);
            let v = ((iv as f64 + 0.5) / k as f64 - 0.5).clamp(0.0, (nv - 1) as f64);
            let (u0, v0) = (u.floor() as usize, v.floor() as usize);
            let (u1, v1) = ((u0 + 1).min(nu - 1), (v0 + 1).min(nv - 1));
            let (fu, fv) = (u - u0 as f64, v - v0 as f64);
            out.push(
                (1.0 - fv) * ((1.0 - fu) * at(u0, v0) + fu * at(u1, v0))
                    + fv * ((1.0 - fu) * at(u0, v1) + fu * at(u1, v1)),
            );
        }
    }
    out
}

/// The voxel Π of `tests/data/pi-occluder` in the chair's place on an
/// `n x n` wall, as the fit models it (area shadows, one cell a block).
fn pi_scene(n: usize) -> Scene {
    Scene::load(&root().join("tests/data/pi-occluder/voxels.toml"))
        .unwrap()
        .edit(|p| p.wall.plane.grid = Grid { nu: n, nv: n })
        .unwrap()
}

/// The voxel Π of `tests/data/pi-occluder` in the chair's place on an
/// `n x n` wall, as the fit models it (area shadows, one cell a block), and
/// a photo of it made with `m`, a gain, a background and 0.1 % noise, one
/// per image in `images` (each 3 colour channels of 36 x 29 blocks).
pub(super) fn pi_photo(
    n: usize,
    m: Mismatch,
    images: &[Vec<Vec<f64>>],
) -> (Scene, Vec<Vec<Vec<f64>>>) {
    let fit = pi_scene(n);
    let render = fit
        .clone()
        .edit(|p| {
            p.wall.plane.supersample = m.wall;
            let g = p.hidden.plane.grid;
            p.hidden.plane.grid = Grid {
                nu: g.nu * m.split,
                nv: g.nv * m.split,
            };
            p.hidden.plane.supersample = m.sources;
            p.hidden.shadows = ShadowModel::Point;
            p.hidden.lobe = Some([1.0, m.lobe]);
            for o in &mut p.occluders {
                if let polnlos::scene::Occluder::Mesh(mesh) = o {
                    let tri = mesh.triangles();
                    let n = (tri.len() * 3) as f64;
                    let c = tri
                        .iter()
                        .flatten()
                        .fold(polnlos::optics::Vec3::zeros(), |s, p| s + p)
                        / n;
                    let scaled = tri
                        .iter()
                        .map(|t| t.map(|p| c + (p - c) * m.scale))
                        .collect();
                    *mesh = std::sync::Arc::new(polnlos::scene::Mesh::new(
                        scaled,
                        mesh.source().clone(),
                    ));
                }
            }
        })
        .unwrap();
    let t = build(&render, MemoryBudget::DEFAULT).unwrap();
    let photos = images
        .iter()
        .enumerate()
        .map(|(i, image)| {
            image
                .iter()
                .enumerate()
                .map(|(c, l)| {
                    let fine = split_image(l, m.split);
                    let g = [2.0e8, 2.4e8, 2.9e8][c % 3];
                    super::photo::photo(&t, &fine, g, 1.7e5, 1e-3, 47 + (10 * i + c) as u64)
                })
                .collect()
        })
        .collect();
    (fit, photos)
}

/// The noise variance of photos made by `pi_photo` (0.1 % of each
/// channel's mean, which the noise leaves within 1e-5 of itself).
fn known_variances(photos: &[Vec<Vec<f64>>]) -> Vec<Vec<Vec<f64>>> {
    photos
        .iter()
        .map(|p| {
            p.iter()
                .map(|c| {
                    let mean = c.iter().sum::<f64>() / c.len() as f64;
                    vec![(1e-3 * mean).powi(2); c.len()]
                })
                .collect()
        })
        .collect()
}

/// Fits the Π of `scene` started `off` from the truth, given the photos'
/// noise; the fit's error.
fn fit_pi(
    scene: &Scene,
    photos: &[Vec<Vec<f64>>],
    off: [f64; 3],
    options: &OccluderOptions,
) -> (OccluderFit, [f64; 3], f64) {
    let start = moved(scene, &[0], off, 1, ShadowModel::Area).unwrap();
    let options = OccluderOptions {
        variances: Some(known_variances(photos)),
        ..options.clone()
    };
    let f = fit_occluder(&start, photos, &options).unwrap();
    let (error, distance) = miss(&f, off, [0.0; 3]);
    (f, error, distance)
}

/// Issue 47: the voxel Π photographed unlike the model (a screen twice as
/// fine and interpolated, point sources, the photo's elements averaged over
/// 2 x 2 wall points; a gain, a background, noise), fitted from 2 cm off
/// along x: the fit lands within 1 cm of the truth and its uncertainty
/// covers its error or it warns. Two photos of the same bench (the chair's
/// screen and its mirror image) fit together.
#[test]
fn calibrate_occluder_places_a_voxel_pi_photographed_unlike_the_model() {
    crate::priority::background();
    let image = super::photo::truth();
    let mirrored: Vec<Vec<f64>> = image
        .iter()
        .map(|l| {
            l.chunks(36)
                .flat_map(|row| row.iter().rev().copied())
                .collect()
        })
        .collect();
    let (scene, photos) = pi_photo(42, SCREEN, &[image, mirrored]);
    let options = OccluderOptions {
        range: 0.03,
        ..OccluderOptions::default()
    };
    let (f, error, distance) = fit_pi(&scene, &photos, [0.02, 0.0, 0.0], &options);
    eprintln!(
        "{}",
        line("voxel Π, 2 photos, +20 mm x", &f, error, distance)
    );
    assert_eq!(f.objective_photos.len(), 2);
    let sum: f64 = f.objective_photos.iter().map(|p| p[1]).sum();
    assert!((sum - f.objective_end).abs() <= 1e-9 * f.objective_end);
    assert!(distance < 0.01, "{error:?}");
    assert!(honest(&f, error), "{f:?}");
}

/// The three starts of the done-when, 2 cm off the truth.
const STARTS: [[f64; 3]; 3] = [[0.02, 0.0, 0.0], [-0.0141, 0.0141, 0.0], [0.0, 0.0, -0.02]];

/// A study, not in the suite: the voxel Π under four mismatches, each from
/// the three starts, on a 63 x 63 wall: 12 fits of 89-296 `T` builds at
/// about 0.5 s each (1053 s in all). Wherever the lowest misfit any fit found lies within 1 cm of
/// the truth, every fit must land within 1 cm; everywhere, its uncertainty
/// covers its error or it warns. Run it with
/// `cargo test --locked --test suite -- --ignored --nocapture calibrate_occluder_study_pi`.
#[test]
#[ignore]
fn calibrate_occluder_study_pi_mismatches_from_three_starts() {
    crate::priority::background();
    let image = super::photo::truth();
    let cases = [
        ("screen x2, 2x2 sources, wall 2x2", SCREEN),
        (
            "the same, lobe cos^12",
            Mismatch {
                lobe: 12.0,
                ..SCREEN
            },
        ),
        (
            "the same, Π 5 % larger",
            Mismatch {
                scale: 1.05,
                ..SCREEN
            },
        ),
        (
            "blocks as the model's, 8x8 sources",
            Mismatch {
                split: 1,
                sources: 8,
                wall: 1,
                lobe: 18.0,
                scale: 1.0,
            },
        ),
    ];
    let mut failed = Vec::new();
    for (label, m) in cases {
        let (scene, photos) = pi_photo(63, m, std::slice::from_ref(&image));
        let fits: Vec<_> = STARTS
            .iter()
            .map(|&off| fit_pi(&scene, &photos, off, &OccluderOptions::default()))
            .collect();
        // The lowest misfit found by any fit, and where.
        let (low, at) = fits
            .iter()
            .zip(STARTS)
            .flat_map(|((f, _, _), off)| {
                f.probes
                    .iter()
                    .map(move |p| (p.objective, [0, 1, 2].map(|a| off[a] + p.translation[a])))
            })
            .fold(
                (f64::INFINITY, [0.0; 3]),
                |b, p| if p.0 < b.0 { p } else { b },
            );
        let near = at.iter().map(|x| x * x).sum::<f64>().sqrt() < 0.01;
        let truth = polnlos::solve::photo::least_squares_misfit(
            &build(&scene, MemoryBudget::DEFAULT).unwrap(),
            polnlos::solve::photo::DataTerm::Differences,
            &photos.concat(),
        )
        .unwrap();
        eprintln!(
            "{label}: lowest misfit {low:.4e} at ({:+.1}, {:+.1}, {:+.1}) mm from the truth; at the truth {truth:.4e} ({:+.2} %)",
            at[0] * 1e3,
            at[1] * 1e3,
            at[2] * 1e3,
            100.0 * (truth / low - 1.0)
        );
        for ((f, error, distance), off) in fits.iter().zip(STARTS) {
            let name = format!(
                "  {label}, start ({:+.1}, {:+.1}, {:+.1}) mm",
                off[0] * 1e3,
                off[1] * 1e3,
                off[2] * 1e3
            );
            eprintln!("{}", line(&name, f, *error, *distance));
            if (near && *distance >= 0.01) || !honest(f, *error) {
                failed.push(name);
            }
        }
    }
    assert!(failed.is_empty(), "{failed:?}");
}

/// The chair photo: started with the chair 2 cm off its measured position
/// (`Occ_LLcorner_true`) from the three starts, the fit places it within
/// 1 cm, and its uncertainty covers its error or it warns.
///
/// A study, not in the suite: each fit takes 60-100 `T` builds of the
/// 126 x 126 wall at about 2 s each (2-3 minutes on the idle 2-core
/// machine), against the suite's 5-minute budget (docs/test-times.md); the
/// simulated chair above holds the same search on a 42 x 42 wall. Run it
/// with `cargo test --locked --test suite -- --ignored --nocapture calibrate_occluder_places`.
#[test]
#[ignore]
fn calibrate_occluder_places_the_photo_s_chair_within_1_cm_from_2_cm_off() {
    crate::priority::background();
    use polnlos::solve::photo::split_channels;

    let data = root().join("tests/data/saunders-chair");
    let geometry: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(data.join("geometry.json")).unwrap())
            .unwrap();
    let corner = |key: &str| -> Vec<f64> {
        let v = &geometry["occluder"][key];
        (0..3).map(|a| v[a].as_f64().unwrap()).collect()
    };
    let (truth, quads) = (
        corner("Occ_LLcorner_true"),
        corner("Occ_LLcorner_used_for_quads"),
    );
    let scene = Scene::load(&root().join("config/photos/saunders-chair.toml")).unwrap();
    let photo = npy::read(&data.join("measurement.npy")).unwrap();
    let channels = split_channels(&photo.shape, &photo.data, scene.rows()).unwrap();
    let all: Vec<usize> = (0..scene.occluders().len()).collect();
    // The quads' translation that puts the chair at its measured position.
    let at = [0, 1, 2].map(|a| truth[a] - quads[a]);
    let mut failed = Vec::new();
    for off in STARTS {
        let from = [0, 1, 2].map(|a| at[a] + off[a]);
        let start = moved(&scene, &all, from, 2, scene.hidden().shadows).unwrap();
        let f = fit_occluder(
            &start,
            std::slice::from_ref(&channels),
            &OccluderOptions::default(),
        )
        .unwrap();
        let (error, distance) = miss(&f, from, at);
        let quads_off = miss(&f, from, [0.0; 3]).1;
        let name = format!(
            "chair, start ({:+.1}, {:+.1}, {:+.1}) mm",
            off[0] * 1e3,
            off[1] * 1e3,
            off[2] * 1e3
        );
        eprintln!(
            "{} (from the file's quads: {:.1} mm)",
            line(&name, &f, error, distance),
            quads_off * 1e3
        );
        if distance >= 0.01 || !honest(&f, error) {
            failed.push(name);
        }
    }
    assert!(failed.is_empty(), "{failed:?}");
}

/// The model check at the truth, evaluated once, given the photos' noise:
/// on the Π photographed by the model itself it is 1 and does not warn;
/// photographed with the screen's lobe cos^12 (the model's cos^18) and the
/// screen twice as fine it is more, and warns. The noise is 0.1 % either
/// way. Without the noise given, the residual's roughness gives it: 1 for
/// the model's own photo, but the other's error, rough at this 42 x 42
/// wall, reads as noise there and the check falls below 1.
#[test]
fn the_model_check_tells_the_model_s_own_photo_from_one_made_unlike_it() {
    crate::priority::background();
    use polnlos::calibrate::occluder::{FitWarning, NoiseFrom};
    let image = super::photo::truth();
    let scene = pi_scene(42);
    let t = build(&scene, MemoryBudget::DEFAULT).unwrap();
    let own: Vec<Vec<f64>> = (0..3)
        .map(|c| {
            let g = [2.0e8, 2.4e8, 2.9e8][c];
            super::photo::photo(&t, &image[c], g, 1.7e5, 1e-3, 47 + c as u64)
        })
        .collect();
    let lobe = Mismatch {
        lobe: 12.0,
        ..SCREEN
    };
    let (_, other) = pi_photo(42, lobe, std::slice::from_ref(&image));
    let photos = [vec![own], other];
    let check = |photo: &[Vec<Vec<f64>>], given: bool| {
        let once = OccluderOptions {
            max_evaluations: 1,
            starts: 1,
            variances: given.then(|| known_variances(photo)),
            ..OccluderOptions::default()
        };
        let f = fit_occluder(&scene, photo, &once).unwrap();
        let warns = f
            .warnings
            .iter()
            .any(|w| matches!(w, FitWarning::ModelError { .. }));
        let from = if given {
            NoiseFrom::Variance
        } else {
            NoiseFrom::Roughness
        };
        assert_eq!(f.noise_from, from);
        (f.model_error.unwrap(), warns)
    };
    let (own_given, own_warns) = check(&photos[0], true);
    let (other_given, other_warns) = check(&photos[1], true);
    let (own_rough, _) = check(&photos[0], false);
    let (other_rough, _) = check(&photos[1], false);
    eprintln!("model check, noise given: own {own_given:.4}, other {other_given:.4}; from the roughness: own {own_rough:.4}, other {other_rough:.4}");
    assert!((own_given - 1.0).abs() < 0.06, "{own_given}");
    assert!(!own_warns);
    assert!(other_given > 3.0, "{other_given}");
    assert!(other_warns);
    assert!((own_rough - 1.0).abs() < 0.05, "{own_rough}");
    assert!(other_rough < other_given, "{other_rough}");
}
