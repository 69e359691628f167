//! Area shadows of a mesh with internal faces (issue 47, item 4):
//! `tests/data/pi-occluder/`, a Π of 28 voxel cubes with every cube's 12
//! triangles (each shared face twice) against the same solid as 3 boxes, in
//! the chair photo's geometry (docs/realphoto.md, "Area shadows").

use std::path::PathBuf;

use polnlos::scene::{Occluder, Scene, ShadowModel};
use polnlos::transport::{build, MemoryBudget, Transport};

fn pi(name: &str) -> Scene {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data/pi-occluder");
    Scene::load(&dir.join(format!("{name}.toml"))).unwrap()
}

/// The largest entry difference relative to the largest entry of `b`.
fn max_relative_difference(a: &Transport, b: &Transport) -> f64 {
    assert_eq!((a.rows(), a.cols()), (b.rows(), b.cols()));
    let top = b.col_major().iter().fold(0.0f64, |m, x| m.max(x.abs()));
    a.col_major()
        .iter()
        .zip(b.col_major())
        .fold(0.0f64, |m, (x, y)| m.max((x - y).abs()))
        / top
}

#[test]
fn area_shadows_of_a_voxel_mesh_with_internal_faces_equal_its_outer_surface() {
    crate::priority::background();
    let (voxels, boxes) = (pi("voxels"), pi("boxes"));
    for (scene, n) in [(&voxels, 336), (&boxes, 36)] {
        let Occluder::Mesh(m) = &scene.occluders()[0] else {
            panic!("a mesh")
        };
        assert_eq!(m.triangles().len(), n);
        assert_eq!(scene.hidden().shadows, ShadowModel::Area);
    }
    let budget = MemoryBudget::DEFAULT;
    let (a, b) = (
        build(&voxels, budget).unwrap(),
        build(&boxes, budget).unwrap(),
    );
    let d = max_relative_difference(&a, &b);
    assert!(d <= 1e-12, "area T: voxels against boxes differ by {d:e}");
    // The Π's shadow is on the wall: many entries partly shaded.
    let open = build(
        &boxes.clone().edit(|p| p.occluders.clear()).unwrap(),
        budget,
    )
    .unwrap();
    let partial = b
        .col_major()
        .iter()
        .zip(open.col_major())
        .filter(|(x, y)| **x > 0.0 && **x < (1.0 - 1e-6) * **y)
        .count();
    assert!(partial > 10_000, "{partial} entries in a penumbra");
    // Point shadows are untouched: the two meshes give the same T to the bit.
    let point = |s: &Scene| {
        let s = s
            .clone()
            .edit(|p| p.hidden.shadows = ShadowModel::Point)
            .unwrap();
        build(&s, budget).unwrap()
    };
    assert_eq!(point(&voxels).col_major(), point(&boxes).col_major());
}

/// What the automatic shadow choice says of the reference scenes: the
/// rendered occluder case (scene supersample 32) has a negligible penumbra,
/// so it keeps MODEL.md's point sources outright; the occluder benches' is
/// wider, so point shadows stay their choice until a photo says otherwise;
/// and the time-resolved build takes a scene that left `shadows` out.
#[test]
fn the_reference_scenes_keep_point_shadows() {
    crate::priority::background();
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let rendered =
        Scene::load(&root.join("tests/data/rendered/occluder-crossed/scene.toml")).unwrap();
    let c = rendered.shadow_choice();
    eprintln!("rendered occluder-crossed: {c:?}");
    assert_eq!((c.model, c.open), (ShadowModel::Point, false));
    assert!(c.penumbra.unwrap() < polnlos::scene::NEGLIGIBLE_PENUMBRA);
    for name in [
        "occluder-crossed",
        "occluder-crossed-3x3",
        "occluder-multi",
        "occluder-nopol-3x3",
        "occluder-rotating",
    ] {
        let s = Scene::load(&root.join(format!("config/scenes/{name}.toml"))).unwrap();
        assert_eq!(s.hidden().shadows, ShadowModel::Auto);
        let c = s.shadow_choice();
        eprintln!("{name}: {c:?}");
        assert_eq!(c.model, ShadowModel::Point, "{name}");
    }
    let chair = Scene::load(&root.join("config/photos/saunders-chair.toml")).unwrap();
    eprintln!("chair: {:?}", chair.shadow_choice());
    let bench = Scene::load(&root.join("config/scenes/occluder-crossed-3x3.toml")).unwrap();
    let active = polnlos::transport::active::build_active(
        &bench,
        &polnlos::transport::active::ActiveSetup::default(),
        MemoryBudget::DEFAULT,
    );
    assert!(active.is_ok(), "{:?}", active.err());
}

/// ZNCC of the photo `i` reconstructed through `t` against `truth`.
fn zncc(t: &Transport, i: &[f64], truth: &[f64]) -> f64 {
    use polnlos::solve::photo::{reconstruct_photo, PhotoSettings};
    let r = reconstruct_photo(
        t,
        &[i.to_vec()],
        Some(&[truth.to_vec()]),
        &PhotoSettings::default(),
    )
    .unwrap();
    r.metrics.unwrap().zncc
}

/// Issue 47: a scene that leaves `shadows` out reconstructs a photo within
/// 0.01 ZNCC of the better of point and area shadows. The photos are
/// rendered unlike the model: the Π's shadows from point sources 8 x 8 a
/// block (nearly a continuous screen), or from the model's own one point
/// a block; each with a gain, a background and noise. The reconstruction
/// samples the screen once a block, as the file does.
#[test]
fn a_scene_without_a_shadows_key_reconstructs_as_well_as_the_better_model() {
    crate::priority::background();
    use polnlos::solve::photo::{photo_transport, PhotoSettings};
    use polnlos::solve::SolveError;
    use rand::SeedableRng;
    use rand_distr::{Distribution, StandardNormal};
    let budget = MemoryBudget::DEFAULT;
    // The chair photo's geometry with the Π, on a 63 x 63 wall.
    let base = pi("boxes")
        .edit(|p| {
            p.hidden.shadows = ShadowModel::Auto;
            p.wall.plane.grid = polnlos::scene::Grid { nu: 63, nv: 63 };
        })
        .unwrap();
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let rgb = root.join("tests/data/saunders-chair/truth_rgb.npy");
    // The mushroom's green channel, rows in scene order.
    let grid = polnlos::scene::Grid { nu: 36, nv: 29 };
    let truth = polnlos::files::truth::TopFirst::read(&rgb)
        .unwrap()
        .on_grid(grid, 3, "truth")
        .unwrap()
        .swap_remove(1);
    assert_eq!(truth.len(), base.cols());
    let t_point = build(&base, budget).unwrap();
    let area = base
        .clone()
        .edit(|p| p.hidden.shadows = ShadowModel::Area)
        .unwrap();
    let t_area = build(&area, budget).unwrap();
    for (label, m) in [
        ("point sources 8 x 8 a block", 8),
        ("point sources 1 a block", 1),
    ] {
        let render = base
            .clone()
            .edit(|p| {
                p.hidden.plane.supersample = m;
                p.hidden.shadows = ShadowModel::Point;
            })
            .unwrap();
        let clean = build(&render, budget).unwrap().apply(&truth);
        let top = clean.iter().fold(0.0f64, |a, b| a.max(*b));
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(47);
        let i: Vec<f64> = clean
            .iter()
            .map(|v| {
                let z: f64 = StandardNormal.sample(&mut rng);
                3.0e4 * v / top + 500.0 + 30.0 * z
            })
            .collect();
        let settings = PhotoSettings::default();
        let chosen = photo_transport(
            &base,
            &t_point,
            || Ok::<_, SolveError>(&t_area),
            std::slice::from_ref(&i),
            &settings,
        )
        .unwrap();
        let choice = &chosen.shadows;
        let (zp, za) = (zncc(&t_point, &i, &truth), zncc(&t_area, &i, &truth));
        // The reconstruction on the chosen T (its model formed by the choice).
        let auto = chosen
            .reconstruct(
                std::slice::from_ref(&i),
                Some(std::slice::from_ref(&truth)),
                &settings,
            )
            .unwrap()
            .metrics
            .unwrap()
            .zncc;
        let picked = if choice.model == ShadowModel::Area {
            za
        } else {
            zp
        };
        assert!((auto - picked).abs() < 1e-12, "{auto} {picked}");
        eprintln!(
            "{label}: ZNCC point {zp:.4}, area {za:.4}, auto {auto:.4} ({})",
            choice.reason
        );
        assert!(auto >= zp.max(za) - 0.01, "{label}: {choice:?}");
    }
}
