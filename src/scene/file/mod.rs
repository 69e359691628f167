//! The TOML schema of a scene file: parsing it (here), validating it into
//! a [`Scene`] (`validate.rs`) and writing a scene back in its terms
//! (`write.rs`).

use std::path::Path;
use std::sync::Arc;

use serde::{Deserialize, Serialize};

use super::mesh::{self, MeshError};
use super::occluder::{Mesh, MeshSource};
use super::{
    crossed_axis, Analyzer, CameraFrame, Emitter, Grid, HiddenScene, Homography, LeftOut, Mosaic,
    MosaicLayout, Occluder, Plane, Pose, Scene, SceneError, SceneParts, ShadowModel, Wall,
    WallSampling,
};
use crate::optics::{Brdf, DiffuseModel, PolarizerModel, Vec3};

mod validate;
mod write;

use validate::*;

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawFile {
    wall: RawWall,
    scene: RawScenePlane,
    #[serde(default)]
    pose: Vec<RawPose>,
    #[serde(default)]
    occluder: Vec<RawOccluder>,
    /// Read as a table so that an unknown key is an error naming it.
    polarizer: Option<toml::Table>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawWall {
    center: [f64; 3],
    normal: [f64; 3],
    u_axis: [f64; 3],
    size: [f64; 2],
    grid: [i64; 2],
    supersample: Option<i64>,
    roughness: f64,
    ior: f64,
    #[serde(default = "unit")]
    ks: f64,
    #[serde(default)]
    kd: f64,
    /// Read as a value so that a wrong one is an error naming the key.
    diffuse: Option<toml::Value>,
    /// Likewise.
    sampling: Option<toml::Value>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawScenePlane {
    center: [f64; 3],
    normal: [f64; 3],
    u_axis: [f64; 3],
    size: [f64; 2],
    grid: [i64; 2],
    supersample: Option<i64>,
    #[serde(default = "lambertian")]
    emitter: Emitter,
    lobe: Option<[f64; 2]>,
    polarization: Option<[f64; 3]>,
    shadows: Option<ShadowModel>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawPose {
    name: String,
    camera: [f64; 3],
    polarizer_deg: Option<Vec<f64>>,
    /// `"mosaic"`: an on-chip polarizer mosaic instead of a sheet.
    analyzer: Option<String>,
    sensor_deg: Option<f64>,
    extinction: Option<f64>,
    layout: Option<String>,
    homography: Option<[[f64; 3]; 3]>,
    region: Option<[i64; 4]>,
    binning: Option<[i64; 2]>,
}

#[derive(Deserialize, Serialize, Default)]
#[serde(deny_unknown_fields)]
struct RawOccluder {
    #[serde(skip_serializing_if = "Option::is_none")]
    rect: Option<RawRect>,
    #[serde(skip_serializing_if = "Option::is_none")]
    sphere: Option<RawSphere>,
    /// An OBJ or STL file, relative to the scene file's folder.
    #[serde(skip_serializing_if = "Option::is_none")]
    mesh: Option<String>,
    /// The mesh's unit in metres (`0.001` for millimetres); default 1.
    #[serde(skip_serializing_if = "Option::is_none")]
    scale: Option<f64>,
    /// Added to every mesh vertex after `scale`, metres.
    #[serde(skip_serializing_if = "Option::is_none")]
    offset: Option<[f64; 3]>,
    /// The mesh already read and checked: an edited scene keeps its
    /// triangles instead of reading the file again.
    #[serde(skip)]
    loaded: Option<Arc<Mesh>>,
}

#[derive(Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
struct RawRect {
    center: [f64; 3],
    half_u: [f64; 3],
    half_v: [f64; 3],
}

#[derive(Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
struct RawSphere {
    center: [f64; 3],
    radius: f64,
}

fn unit() -> f64 {
    1.0
}
fn lambertian() -> Emitter {
    Emitter::Lambertian
}

/// Largest exponent of a `lobe`: cos^1000 is already a 3-degree beam.
const MAX_LOBE: f64 = 1000.0;

/// Largest grid side accepted; a typo like `grid = [32000, 32000]` should be an
/// error, not an attempt to allocate a terabyte.
const MAX_GRID: i64 = 4096;
/// Largest supersampling per side. A partial occluder's shadow edge makes
/// the integrand discontinuous, so its error falls only as 1/m: against a
/// path tracer a 0.06 m occluder on the bench needs m = 32 to reach the
/// render's 0.3 % noise (validation/mitsuba/README.md). The memory this costs
/// on the wall is checked with `T` itself.
const MAX_SUPERSAMPLE: i64 = 32;

/// Parses and validates scene text whose relative paths (`mesh`) are in `dir`.
pub(super) fn parse(text: &str, dir: &Path) -> Result<Scene, SceneError> {
    let raw: RawFile = toml::from_str(text).map_err(|e| SceneError::Parse {
        path: None,
        message: e.to_string().trim_end().to_string(),
    })?;
    validate(raw, dir)
}

/// Validates the parts of an edited scene exactly as a file is validated: they
/// are written back in the file's terms (the values a file gives, not the
/// derived ones) and read again.
pub(super) fn revalidate(parts: SceneParts) -> Result<Scene, SceneError> {
    validate(RawFile::from(parts), Path::new(""))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::Channel;

    /// A scene from text, relative paths in the current directory.
    fn parse(text: &str) -> Result<Scene, SceneError> {
        super::parse(text, Path::new(""))
    }

    const BASE: &str = r#"
[wall]
center = [0.0, 0.0, 0.0]
normal = [0.0, 0.0, 2.0]
u_axis = [1.0, 0.0, 0.1]
size = [0.3, 0.3]
grid = [4, 3]
roughness = 0.3
ior = 1.5

[scene]
center = [-0.374, 0.0, 0.25]
normal = [0.831365691684, 0.0, -0.555725729736]
u_axis = [0.0, 1.0, 0.0]
size = [0.2, 0.2]
grid = [2, 2]

[[pose]]
name = "A"
camera = [0.416, 0.0, 0.277]
polarizer_deg = [0.0, 90.0]
"#;

    fn with(from: &str, to: &str) -> Result<Scene, SceneError> {
        assert!(BASE.contains(from), "{from}");
        parse(&BASE.replacen(from, to, 1))
    }

    #[test]
    fn wall_sampling_is_read_checked_and_what_was_left_out_is_kept() {
        let s = parse(BASE).unwrap();
        assert_eq!(s.wall.sampling, WallSampling::Uniform);
        let all = LeftOut {
            wall_supersample: true,
            scene_supersample: true,
            sampling: true,
        };
        assert_eq!(s.left_out, all);
        // An edit keeps what the file left out left out.
        assert_eq!(s.clone().edit(|_| {}).unwrap().left_out, all);
        let h = "polarizer_deg = [0.0, 90.0]\nhomography = [[-425.5, 1220.5, 255.5], [250.9, 0, 255.5], [-1.665, 0, 1]]";
        let text = BASE
            .replace(
                "ior = 1.5",
                "ior = 1.5\nsampling = \"pixels\"\nsupersample = 2",
            )
            .replace("polarizer_deg = [0.0, 90.0]", h);
        let p = parse(&text).unwrap();
        assert_eq!(p.wall.sampling, WallSampling::Pixels);
        assert!(
            !p.left_out.sampling && !p.left_out.wall_supersample && p.left_out.scene_supersample
        );
        // "pixels" needs every pose's homography; an unknown value is named.
        let e = with("ior = 1.5", "ior = 1.5\nsampling = \"pixels\"").unwrap_err();
        assert_eq!(e.key(), Some("pose[0].homography"), "{e}");
        assert!(e.to_string().contains("wall.sampling = \"pixels\""), "{e}");
        let e = with("ior = 1.5", "ior = 1.5\nsampling = \"centre\"").unwrap_err();
        assert_eq!(e.key(), Some("wall.sampling"), "{e}");
    }

    #[test]
    fn defaults_and_normalization() {
        let s = parse(BASE).unwrap();
        assert_eq!(s.wall.plane.normal, Vec3::z());
        // u_axis made orthogonal to the normal.
        assert_eq!(s.wall.plane.u, Vec3::x());
        assert_eq!(s.wall.plane.v, Vec3::y());
        assert_eq!(s.wall.brdf.ks, 1.0);
        assert_eq!(s.wall.brdf.kd, 0.0);
        assert_eq!(s.wall.brdf.diffuse, DiffuseModel::Fresnel);
        assert_eq!(s.polarizer, PolarizerModel::Absorbing);
        assert_eq!(s.wall.plane.supersample, 1);
        assert_eq!(s.hidden.emitter, Emitter::Lambertian);
        assert!(s.occluders.is_empty());
        assert_eq!(s.rows(), 24);
        assert_eq!(s.cols(), 4);
    }

    #[test]
    fn a_mosaic_pose_has_four_micro_polarizers_and_survives_an_edit() {
        let s = with(
            "polarizer_deg = [0.0, 90.0]",
            "analyzer = \"mosaic\"\nsensor_deg = 10.0\nextinction = 300.0",
        )
        .unwrap();
        let p = &s.poses[0];
        let m = p.mosaic.expect("a mosaic");
        assert_eq!((m.sensor_deg, m.extinction), (10.0, Some(300.0)));
        assert_eq!(p.channels(), Channel::mosaic().to_vec());
        let psi: Vec<f64> = p.analyzers.iter().map(|a| a.angle_deg).collect();
        assert_eq!(psi, [10.0, 55.0, 100.0, 145.0]);
        assert_eq!(p.analyzers[0].cell, Some([1, 1]));
        let again = s.clone().edit(|_| {}).unwrap();
        assert_eq!(again.poses, s.poses);
    }

    #[test]
    fn crossed_axis_is_normal_to_the_s_direction_and_rotates() {
        let s = parse(BASE).unwrap();
        let p = &s.poses[0];
        let q0 = p.analyzers[0].axis;
        let q90 = p.analyzers[1].axis;
        // The bench's plane of incidence is x-z, so e_s0 is +-y and q(0) has no y part.
        assert!(q0.y.abs() < 1e-12);
        assert!((q90.y.abs() - 1.0).abs() < 1e-12);
        assert!(q0.dot(&q90).abs() < 1e-12);
    }

    #[test]
    fn errors_name_the_key() {
        let cases = [
            ("roughness = 0.3", "roughness = 0", "wall.roughness"),
            ("roughness = 0.3", "roughness = 1.5", "wall.roughness"),
            ("ior = 1.5", "ior = 1.0", "wall.ior"),
            ("ior = 1.5", "ior = 1e308", "wall.ior"),
            (
                "polarizer_deg = [0.0, 90.0]",
                "polarizer_deg = [1e308]",
                "pose[0].polarizer_deg",
            ),
            (
                "polarizer_deg = [0.0, 90.0]",
                "polarizer_deg = [0, 0, 360]",
                "pose[0].polarizer_deg",
            ),
            (
                "polarizer_deg = [0.0, 90.0]",
                "polarizer_deg = [45, 225]",
                "pose[0].polarizer_deg",
            ),
            (
                "polarizer_deg = [0.0, 90.0]",
                "polarizer_deg = [0.0]\nregion = [-1, 0, 10, 10]",
                "pose[0].region",
            ),
            (
                "polarizer_deg = [0.0, 90.0]",
                "polarizer_deg = [0.0]\nregion = [0, 0, 0, 10]",
                "pose[0].region",
            ),
            (
                "polarizer_deg = [0.0, 90.0]",
                "polarizer_deg = [0.0]\nbinning = [2, 2]",
                "pose[0].binning",
            ),
            (
                "polarizer_deg = [0.0, 90.0]",
                "polarizer_deg = [0.0]\nregion = [0, 0, 512, 512]\nbinning = [0, 1]",
                "pose[0].binning",
            ),
            (
                "polarizer_deg = [0.0, 90.0]",
                "polarizer_deg = [0.0]\nanalyzer = \"mosaic\"",
                "pose[0].analyzer and pose[0].polarizer_deg",
            ),
            (
                "polarizer_deg = [0.0, 90.0]",
                "analyzer = \"mosaic\"\nlayout = \"bayer\"",
                "pose[0].layout",
            ),
            (
                "polarizer_deg = [0.0, 90.0]",
                "analyzer = \"mosaic\"\nextinction = 1.0",
                "pose[0].extinction",
            ),
            (
                "polarizer_deg = [0.0, 90.0]",
                "analyzer = \"mosaic\"\nsensor_deg = 400.0",
                "pose[0].sensor_deg",
            ),
            (
                "polarizer_deg = [0.0, 90.0]",
                "analyzer = \"sheet\"",
                "pose[0].analyzer",
            ),
            (
                "polarizer_deg = [0.0, 90.0]",
                "polarizer_deg = [0.0]\nextinction = 300.0",
                "pose[0].extinction",
            ),
            (
                "polarizer_deg = [0.0, 90.0]",
                "analyzer = \"mosaic\"\nregion = [0, 0, 512, 512]\nbinning = [2, 2]",
                "pose[0].binning",
            ),
            ("grid = [4, 3]", "grid = [0, 3]", "wall.grid"),
            ("grid = [2, 2]", "grid = [2, -1]", "scene.grid"),
            (
                "normal = [0.0, 0.0, 2.0]",
                "normal = [0.0, 0.0, 0.0]",
                "wall.normal",
            ),
            (
                "u_axis = [1.0, 0.0, 0.1]",
                "u_axis = [0.0, 0.0, 1.0]",
                "wall.u_axis",
            ),
            (
                "camera = [0.416, 0.0, 0.277]",
                "camera = [0.416, 0.0, -0.1]",
                "pose[0].camera",
            ),
            (
                "center = [-0.374, 0.0, 0.25]",
                "center = [-0.374, 0.0, 0.0]",
                "scene.center",
            ),
            (
                "normal = [0.831365691684, 0.0, -0.555725729736]",
                "normal = [-0.83, 0.0, 0.55]",
                "scene.normal",
            ),
            ("size = [0.2, 0.2]", "size = [0.2, 0.0]", "scene.size"),
            (
                "camera = [0.416, 0.0, 0.277]",
                "camera = [-0.748, 0.0, 0.5]",
                "pose[0].polarizer_deg",
            ),
        ];
        for (from, to, key) in cases {
            let e = with(from, to).unwrap_err();
            assert_eq!(e.key(), Some(key), "{to}: {e}");
        }
        let e = with("roughness = 0.3", "roughness = 0").unwrap_err();
        assert_eq!(e.to_string(), "wall.roughness = 0.0: must be in (0, 1]");
    }

    #[test]
    fn revision_2_keys_are_read_and_wrong_ones_named() {
        let s = parse(&format!(
            "{}\n[polarizer]\nmodel = \"transmitting\"\n",
            BASE.replace("ior = 1.5", "ior = 1.5\ndiffuse = \"lambert\"")
        ))
        .unwrap();
        assert_eq!(s.polarizer, PolarizerModel::Transmitting);
        assert_eq!(s.wall.brdf.diffuse, DiffuseModel::Lambert);
        let cases = [
            ("[polarizer]\nmodel = \"absorbant\"", "polarizer.model"),
            ("[polarizer]\nmodel = 1", "polarizer.model"),
            ("[polarizer]\nmodle = \"absorbing\"", "polarizer.modle"),
            (
                "[polarizer]\nmodel = \"absorbing\"\nextinction = 1e4",
                "polarizer.extinction",
            ),
        ];
        for (extra, key) in cases {
            let e = parse(&format!("{BASE}\n{extra}\n")).unwrap_err();
            assert_eq!(e.key(), Some(key), "{extra}: {e}");
        }
        for bad in ["\"lambertian\"", "0.5", "\"Fresnel\""] {
            let e = with("ior = 1.5", &format!("ior = 1.5\ndiffuse = {bad}")).unwrap_err();
            assert_eq!(e.key(), Some("wall.diffuse"), "{bad}: {e}");
            assert!(e.to_string().contains("lambert"), "{e}");
        }
        // An empty [polarizer] table is the default.
        let s = parse(&format!("{BASE}\n[polarizer]\n")).unwrap();
        assert_eq!(s.polarizer, PolarizerModel::Absorbing);
    }

    #[test]
    fn scene_shadows_are_auto_unless_the_file_says_and_survive_an_edit() {
        let bare = parse(BASE).unwrap();
        assert_eq!(bare.hidden.shadows, ShadowModel::Auto);
        assert_eq!(bare.shadow_choice().model, ShadowModel::Point);
        let edited = bare
            .clone()
            .edit(|p| p.hidden.plane.supersample = 2)
            .unwrap();
        assert_eq!(edited.hidden().shadows, ShadowModel::Auto);
        let auto = with("grid = [2, 2]", "grid = [2, 2]\nshadows = \"auto\"").unwrap();
        assert_eq!(auto.hidden.shadows, ShadowModel::Auto);
        let area = "grid = [2, 2]\nshadows = \"area\"";
        let s = with("grid = [2, 2]", area).unwrap();
        assert_eq!(s.hidden.shadows, ShadowModel::Area);
        let scene = Scene::from_toml_str(&BASE.replace("grid = [2, 2]", area)).unwrap();
        let edited = scene.edit(|p| p.hidden.plane.supersample = 2).unwrap();
        assert_eq!(edited.hidden().shadows, ShadowModel::Area);
        let e = with("grid = [2, 2]", "grid = [2, 2]\nshadows = \"soft\"").unwrap_err();
        assert!(
            e.to_string().contains("shadows") && e.to_string().contains("area"),
            "{e}"
        );
    }

    /// A wall at z = 0 and a screen of one 0.2 m element at z = 1 facing
    /// it, a 0.3 m wall of 4 x 3 elements, a rect at z = 0.25.
    const PARALLEL: &str = r#"
[wall]
center = [0.0, 0.0, 0.0]
normal = [0.0, 0.0, 1.0]
u_axis = [1.0, 0.0, 0.0]
size = [0.3, 0.3]
grid = [4, 3]
roughness = 0.3
ior = 1.5

[scene]
center = [0.0, 0.0, 1.0]
normal = [0.0, 0.0, -1.0]
u_axis = [1.0, 0.0, 0.0]
size = [0.2, 0.2]
grid = [1, 1]

[[pose]]
name = "A"
camera = [0.0, 0.3, 0.5]
polarizer_deg = []

[[occluder]]
rect = { center = [0.0, 0.0, 0.25], half_u = [0.01, 0.0, 0.0], half_v = [0.0, 0.01, 0.0] }
"#;

    #[test]
    fn the_penumbra_is_the_cell_over_the_wall_pitch_through_the_occluder() {
        // 0.2 m x 0.25 / 0.75 over the wall's finer pitch, 0.3 / 4 m.
        let s = parse(PARALLEL).unwrap();
        let w = 0.2 * 0.25 / 0.75 / 0.075;
        assert!(
            (s.penumbra().unwrap() - w).abs() < 1e-12,
            "{:?}",
            s.penumbra()
        );
        let c = s.shadow_choice();
        assert_eq!((c.model, c.open), (ShadowModel::Point, true));
        assert!(c.reason.contains("0.89 wall samples"), "{}", c.reason);
        // Four samples a side: a quarter of it, negligible.
        let fine = s.edit(|p| p.hidden.plane.supersample = 4).unwrap();
        let c = fine.shadow_choice();
        assert_eq!((c.model, c.open), (ShadowModel::Point, false));
        // An isotropic screen facing away casts the same penumbra.
        let away = PARALLEL.replace(
            "normal = [0.0, 0.0, -1.0]",
            "normal = [0.0, 0.0, 1.0]\nemitter = \"isotropic\"",
        );
        let a = parse(&away).unwrap();
        assert!((a.penumbra().unwrap() - w).abs() < 1e-12);
        // The file's word stands; no occluder, nothing to choose.
        let area =
            parse(&PARALLEL.replace("grid = [1, 1]", "grid = [1, 1]\nshadows = \"area\"")).unwrap();
        let c = area.shadow_choice();
        assert_eq!((c.model, c.open), (ShadowModel::Area, false));
        assert!(c.reason.contains("says shadows = \"area\""), "{}", c.reason);
        let open = parse(PARALLEL.split("[[occluder]]").next().unwrap()).unwrap();
        assert_eq!(open.penumbra(), None);
        assert_eq!(open.shadow_choice().model, ShadowModel::Point);
    }

    #[test]
    fn missing_and_unknown_keys_are_parse_errors() {
        let e = with("ior = 1.5\n", "").unwrap_err();
        assert!(e.to_string().contains("ior"), "{e}");
        let e = with("ior = 1.5", "ior = 1.5\nroughnes = 0.2").unwrap_err();
        assert!(e.to_string().contains("roughnes"), "{e}");
        let e = with(
            "[[pose]]\nname = \"A\"\ncamera = [0.416, 0.0, 0.277]\npolarizer_deg = [0.0, 90.0]\n",
            "",
        )
        .unwrap_err();
        assert_eq!(e.key(), Some("pose"));
    }

    #[test]
    fn a_pose_records_the_frame_its_homography_maps_to() {
        let s = with(
            "polarizer_deg = [0.0, 90.0]",
            "polarizer_deg = [0.0, 90.0]\nregion = [8, 0, 512, 256]\nbinning = [2, 2]",
        )
        .unwrap();
        let f = s.poses[0].frame.unwrap();
        assert_eq!(f.region, [8, 0, 512, 256]);
        assert_eq!(f.binning, [2, 2]);
        assert_eq!(parse(BASE).unwrap().poses[0].frame, None);
        let e = with("polarizer_deg = [0.0, 90.0]", "polarizer_deg = [0, 180]").unwrap_err();
        assert!(e.to_string().contains("same polarizer setting"), "{e}");
    }

    #[test]
    fn duplicate_pose_names_are_rejected() {
        let twice = format!("{BASE}\n[[pose]]\nname = \"A\"\ncamera = [0.4, 0.1, 0.3]\n");
        assert_eq!(parse(&twice).unwrap_err().key(), Some("pose[1].name"));
    }

    #[test]
    fn an_edit_is_validated_again_and_recomputes_what_follows() {
        let s = parse(BASE).unwrap();
        let same = s.clone().edit(|_| {}).unwrap();
        assert_eq!(same.rows(), s.rows());
        assert!((same.poses[0].analyzers[1].axis - s.poses[0].analyzers[1].axis).norm() < 1e-12);

        let finer = s
            .clone()
            .edit(|p| p.hidden.plane.grid = Grid { nu: 5, nv: 6 })
            .unwrap();
        assert_eq!(finer.cols(), 30);

        // A moved camera gets its own crossed sheet, as in a file.
        let camera = Vec3::new(0.3, 0.2, 0.3);
        let moved = s.clone().edit(|p| p.poses[0].camera = camera).unwrap();
        let from_file = with("camera = [0.416, 0.0, 0.277]", "camera = [0.3, 0.2, 0.3]").unwrap();
        assert!(
            (moved.poses[0].analyzers[0].axis - from_file.poses[0].analyzers[0].axis).norm()
                < 1e-12
        );

        type Change = Box<dyn FnOnce(&mut SceneParts)>;
        let cases: [(&str, Change); 4] = [
            ("scene.grid", Box::new(|p| p.hidden.plane.grid.nu = 0)),
            ("wall.roughness", Box::new(|p| p.wall.brdf.alpha = 2.0)),
            ("pose[0].camera", Box::new(|p| p.poses[0].camera.z = -1.0)),
            ("pose", Box::new(|p| p.poses.clear())),
        ];
        for (key, change) in cases {
            let e = s.clone().edit(change).unwrap_err();
            assert_eq!(e.key(), Some(key), "{e}");
        }
    }

    /// BASE with one mesh occluder line `occluder` in a scene file written
    /// to a temporary folder beside `files` (name, content).
    fn with_mesh(occluder: &str, files: Files) -> Result<Scene, SceneError> {
        let dir = tempfile::tempdir().unwrap();
        for (name, bytes) in files {
            std::fs::write(dir.path().join(name), bytes).unwrap();
        }
        let path = dir.path().join("scene.toml");
        std::fs::write(&path, format!("{BASE}\n[[occluder]]\n{occluder}\n")).unwrap();
        Scene::load(&path)
    }

    /// Files (name, content) written beside a scene file.
    type Files<'a> = &'a [(&'a str, &'a [u8])];

    const TRIANGLE: &[u8] = b"v -0.2 -0.05 0.1\nv -0.2 0.05 0.1\nv -0.15 0.0 0.12\nf 1 2 3\n";

    #[test]
    fn a_mesh_is_read_beside_the_scene_file_and_survives_an_edit() {
        let s = with_mesh(
            "mesh = \"sub/tri.obj\"\nscale = 2.0\noffset = [0.1, 0.0, 0.0]",
            &[],
        );
        let e = s.unwrap_err();
        assert_eq!(e.key(), Some("occluder[0].mesh"), "{e}");
        assert!(e.to_string().contains("sub/tri.obj"), "{e}");

        let s = with_mesh(
            "mesh = \"tri.obj\"\nscale = 2.0\noffset = [0.1, 0.0, 0.0]",
            &[("tri.obj", TRIANGLE)],
        )
        .unwrap();
        let Occluder::Mesh(m) = &s.occluders()[0] else {
            panic!("a mesh")
        };
        assert_eq!(m.triangles().len(), 1);
        assert!((m.triangles()[0][0] - Vec3::new(-0.3, -0.1, 0.2)).norm() < 1e-15);
        assert_eq!(m.source().path, "tri.obj");
        // An edit keeps the triangles without the file (the folder is gone).
        let again = s.clone().edit(|_| {}).unwrap();
        assert_eq!(again.occluders(), s.occluders());
    }

    #[test]
    fn what_a_mesh_gets_wrong_is_named() {
        let binary_short = {
            let mut b = vec![0u8; 80];
            b.extend(3u32.to_le_bytes());
            b.extend([0u8; 60]);
            b
        };
        let far = b"v 1e5 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\n";
        // (occluder keys, files beside the scene, key named, words in the message)
        let cases: [(&str, Files, &str, &str); 11] = [
            ("mesh = \"none.obj\"", &[], "occluder[0].mesh", "none.obj"),
            (
                "mesh = \"e.obj\"",
                &[("e.obj", b"v 0 0 0\n")],
                "occluder[0].mesh",
                "no triangles",
            ),
            (
                "mesh = \"i.obj\"",
                &[("i.obj", b"v 0 0 0\nf 1 2 3\n")],
                "occluder[0].mesh",
                "out of range",
            ),
            (
                "mesh = \"n.obj\"",
                &[("n.obj", b"v nan 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\n")],
                "occluder[0].mesh",
                "finite",
            ),
            (
                "mesh = \"f.obj\"",
                &[("f.obj", far)],
                "occluder[0].mesh",
                "within",
            ),
            (
                "mesh = \"s.stl\"",
                &[("s.stl", &binary_short)],
                "occluder[0].mesh",
                "binary STL",
            ),
            (
                "mesh = \"t.ply\"",
                &[("t.ply", TRIANGLE)],
                "occluder[0].mesh",
                ".obj",
            ),
            (
                "mesh = \"t.obj\"\nscale = 0.0",
                &[("t.obj", TRIANGLE)],
                "occluder[0].scale",
                "> 0",
            ),
            (
                "mesh = \"t.obj\"\noffset = [0.0, 1e400, 0.0]",
                &[("t.obj", TRIANGLE)],
                "",
                "offset",
            ),
            (
                "sphere = { center = [0.0, 0.0, 0.1], radius = 0.01 }\nscale = 2.0",
                &[],
                "occluder[0].scale",
                "mesh",
            ),
            (
                "sphere = { center = [0.0, 0.0, 0.1], radius = 0.01 }\nmesh = \"t.obj\"",
                &[("t.obj", TRIANGLE)],
                "occluder[0].",
                "exactly one",
            ),
        ];
        for (occluder, files, key, says) in cases {
            let e = with_mesh(occluder, files).unwrap_err();
            if !key.is_empty() {
                assert_eq!(e.key(), Some(key), "{occluder}: {e}");
            }
            assert!(e.to_string().contains(says), "{occluder}: {e}");
        }
        // A directory is no mesh.
        let dir = tempfile::tempdir().unwrap();
        std::fs::create_dir(dir.path().join("d.obj")).unwrap();
        let text = format!("{BASE}\n[[occluder]]\nmesh = \"d.obj\"\n");
        let e = Scene::from_toml_str_in(&text, dir.path()).unwrap_err();
        assert_eq!(e.key(), Some("occluder[0].mesh"), "{e}");
    }

    proptest::proptest! {
        #[test]
        fn arbitrary_text_never_panics(s in "\\PC{0,400}") {
            let _ = parse(&s);
        }

        #[test]
        fn arbitrary_values_in_a_valid_frame_never_panic(
            key in proptest::sample::select(vec!["roughness", "ior", "ks", "kd", "supersample", "grid", "size", "normal", "u_axis", "camera", "polarizer_deg", "homography", "region", "binning", "diffuse", "model"]),
            value in proptest::sample::select(vec!["0", "-1", "1e308", "nan", "inf", "[]", "[0,0]", "[1e-300, 0, 0]", "\"x\"", "[[1,2,3],[4,5,6],[7,8,9]]", "[0, 0, 0]", "{ a = 1 }", "9999999999999"]),
        ) {
            let base = format!(
                "{}region = [0, 0, 64, 64]\nbinning = [1, 1]\n[polarizer]\nmodel = \"absorbing\"\n",
                BASE.replace("ior = 1.5", "ior = 1.5\ndiffuse = \"fresnel\"")
            );
            let text = base
                .lines()
                .map(|l| if l.starts_with(&format!("{key} =")) { format!("{key} = {value}") } else { l.to_string() })
                .collect::<Vec<_>>()
                .join("\n");
            let _ = parse(&text);
        }

        #[test]
        fn arbitrary_mosaic_values_never_panic_and_what_is_accepted_builds(
            key in proptest::sample::select(vec!["analyzer", "sensor_deg", "extinction", "layout", "polarizer_deg", "region", "binning"]),
            value in proptest::sample::select(vec!["0", "-1", "1", "1.0000001", "1e308", "nan", "inf", "-inf", "[]", "[0.0]", "[1, 0, 64, 64]", "[2, 2]", "\"mosaic\"", "\"polarsens\"", "\"x\"", "{ a = 1 }", "360", "-360.5"]),
        ) {
            let base = format!(
                "{}region = [0, 0, 64, 64]\nbinning = [1, 1]\npolarizer_deg = []\n",
                BASE.replace(
                    "polarizer_deg = [0.0, 90.0]",
                    "analyzer = \"mosaic\"\nsensor_deg = 10.0\nextinction = 300.0\nlayout = \"polarsens\"",
                )
            );
            let valid: Vec<&str> = base.lines().filter(|l| !l.starts_with("polarizer_deg =")).collect();
            proptest::prop_assert!(parse(&valid.join("\n")).is_ok(), "the unmutated mosaic pose parses");
            let text = base
                .lines()
                .filter(|l| key == "polarizer_deg" || !l.starts_with("polarizer_deg ="))
                .map(|l| if l.starts_with(&format!("{key} =")) { format!("{key} = {value}") } else { l.to_string() })
                .collect::<Vec<_>>()
                .join("\n");
            if let Ok(scene) = parse(&text) {
                let t = crate::transport::build(&scene, crate::transport::MemoryBudget::DEFAULT);
                let t = t.expect("an accepted scene builds");
                proptest::prop_assert!(t.col_major().iter().all(|v| v.is_finite()));
            }
        }
    }
}
