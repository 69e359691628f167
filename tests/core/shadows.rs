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
