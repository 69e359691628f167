//! The parsers a file or a client can reach, as fuzz entry points: each takes
//! arbitrary bytes and must return (a value or a named error), never panic,
//! abort or allocate by a size it was told. Shared by the cargo-fuzz targets
//! in this folder and by `tests/daemon/fuzz.rs`, which runs them over the corpus and
//! a fixed-seed batch of mutations in the ordinary test suite.

#![allow(dead_code)]

use polnlos::camera::{Acquisition, CameraSettings, SensorLimits};
use polnlos::daemon::{validate_capture, validate_reconstruction, CameraContext};
use polnlos::measure::exposure::CameraLimits;
use polnlos::scene::Scene;

/// Aravis's fake camera: the limits region and binning are checked against.
const LIMITS: SensorLimits = SensorLimits {
    sensor: [2048, 2048],
    min_size: [1, 1],
    size_increment: [1, 1],
    offset_increment: [1, 1],
    max_binning: [16, 16],
};

/// A scene file.
pub fn scene_toml(data: &[u8]) {
    if let Ok(text) = std::str::from_utf8(data) {
        if let Ok(scene) = polnlos::scene::Scene::from_toml_str(text) {
            // An accepted scene has a sane shape.
            assert!(scene.rows() > 0 && scene.cols() > 0);
        }
    }
}

/// An `.npy` measurement or matrix.
pub fn npy(data: &[u8]) {
    if let Ok(a) = polnlos::files::npy::decode(data) {
        assert_eq!(a.data.len(), a.shape.iter().product::<usize>());
    }
}

/// Camera frames as `polnlos measure` reads them (multi-page grey TIFF).
pub fn frames_tiff(data: &[u8]) {
    if let Ok(f) = polnlos::files::frames::decode_frames(data) {
        let st = &f.stack;
        assert!(st.count >= 1 && st.mean.len() == st.width * st.height);
        assert!(st.width as u64 * st.height as u64 <= polnlos::files::frames::MAX_PIXELS);
    }
}

/// The polarization-camera bench (pose A through a Polarsens mosaic).
fn mosaic_scene() -> &'static Scene {
    static SCENE: std::sync::OnceLock<Scene> = std::sync::OnceLock::new();
    SCENE.get_or_init(|| match Scene::builtin("brewster-mosaic-3x3") {
        Some(Ok(s)) => s,
        _ => panic!("the built-in scene brewster-mosaic-3x3 must parse"),
    })
}

/// The scene bodies are checked against (the reference bench, two poses).
fn scene() -> &'static Scene {
    static SCENE: std::sync::OnceLock<Scene> = std::sync::OnceLock::new();
    SCENE.get_or_init(|| match Scene::builtin("brewster-multi-3x3") {
        Some(Ok(s)) => s,
        _ => panic!("the built-in scene brewster-multi-3x3 must parse"),
    })
}

/// A `POST /captures` body, through the whole validation the daemon runs
/// (against a connected camera with the fake camera's limits).
pub fn capture_json(data: &[u8]) {
    if let Ok(b) = serde_json::from_slice::<polnlos::api::bodies::CaptureBody>(data) {
        let cam = CameraContext {
            limits: CameraLimits {
                exposure_us: (10.0, 1e7),
                max_frames: 1000,
                full_well_e: 1e4,
                read_noise_e: 5.0,
            },
            ranges: Some(polnlos::camera::CameraRanges {
                exposure_us: (10.0, 1e7),
                ..polnlos::camera::CameraRanges::synthetic()
            }),
            sensor: Some(LIMITS),
            defaults: CameraSettings {
                region: Some([0, 0, 512, 512]),
                ..CameraSettings::builtin()
            },
            pixel_formats: Some(vec![
                "Mono8".into(),
                "Mono16".into(),
                "PolarizeMono16".into(),
            ]),
            bench_switches_scene: true,
            max_frames: 1000,
        };
        let plan = || Ok(Vec::new());
        // The mosaic bench when the body names it, else the two-pose bench.
        let scene = if b.scene == "brewster-mosaic-3x3" {
            mosaic_scene()
        } else {
            scene()
        };
        if let Ok(r) = validate_capture(&b, scene, &cam, plan, |_| Ok(None)) {
            // What is accepted fits the sensor and the frame cap.
            assert!(LIMITS
                .check(r.acquisition.region, r.acquisition.binning)
                .is_ok());
            assert!(r.frames >= 1 && r.frames + r.dark_frames <= 1000);
            // ... and is a pixel format the camera lists.
            assert!(matches!(
                r.acquisition.pixel_format.name(),
                "Mono8" | "Mono16" | "PolarizeMono16"
            ));
            // A mosaic capture yields its pose's four blocks, from an
            // unbinned frame at an even offset; any other capture one.
            let mosaic = scene.pose(&r.pose).is_some_and(|p| p.mosaic.is_some());
            assert_eq!(mosaic, r.acquisition.pixel_format.mosaic().is_some());
            if mosaic {
                let [x, y, ..] = r.acquisition.region;
                assert!(r.channels.len() == 4 && r.acquisition.binning == [1, 1]);
                assert!(x % 2 == 0 && y % 2 == 0);
            } else {
                assert_eq!(r.channels.len(), 1);
            }
        }
    }
}

/// A `POST /reconstructions` body, through the daemon's validation (no
/// capture exists, so the solver checks and block counting are what it reaches).
pub fn reconstruction_json(data: &[u8]) {
    if let Ok(b) = serde_json::from_slice::<polnlos::api::bodies::ReconstructionBody>(data) {
        let _ = validate_reconstruction(&b, scene(), |_| Ok(None));
    }
}

/// A `PUT /camera/settings` body (a change over the defaults), and the
/// geometry check it reaches.
pub fn settings_json(data: &[u8]) {
    if let Ok(b) = serde_json::from_slice::<polnlos::api::bodies::SettingsBody>(data) {
        let on_camera = Acquisition::defaults_at([0, 0, 512, 512], [1, 1]);
        let s = b.change.over(&on_camera.into()).complete();
        let s = s.expect("every setting is stated or the camera's");
        if LIMITS.check(s.region, s.binning).is_ok() {
            let [x, y, w, h] = s.region;
            assert!(x + w <= 2048 && y + h <= 2048);
        }
    }
}

/// A `POST /plans` body, and the steps it would walk on a bench with and
/// without a mount and a scene switch.
pub fn plan_json(data: &[u8]) {
    if let Ok(b) = serde_json::from_slice::<polnlos::api::bodies::PlanBody>(data) {
        for (mount, stage, switches_scene) in [(true, true, true), (false, false, false)] {
            let bench = polnlos::daemon::Automated {
                mount,
                stage,
                switches_scene,
            };
            let steps = polnlos::daemon::steps_of(scene(), &b, bench);
            assert!(matches!(
                steps.last(),
                Some(polnlos::daemon::PlanStep::Reconstruct)
            ));
            let captures = steps
                .iter()
                .filter(|s| matches!(s, polnlos::daemon::PlanStep::Capture { .. }))
                .count();
            assert!(captures >= scene().block_count());
        }
    }
}

/// A daemon configuration file (token files are not read).
pub fn config_toml(data: &[u8]) {
    if let Ok(text) = std::str::from_utf8(data) {
        if let Ok(c) = toml::from_str::<polnlos::daemon::Config>(text) {
            if c.token_file.is_none() {
                let _ = c.validate();
            }
        }
    }
}

/// A `POST /calibrations/wall` body, through its shape checks.
pub fn wall_calibration_json(data: &[u8]) {
    use polnlos::api::bodies::{WallCalibrationBody, MAX_CAPTURES_PER_POSITION};
    if let Ok(b) = serde_json::from_slice::<WallCalibrationBody>(data) {
        if let Ok(positions) = b.positions() {
            // What is accepted is bounded and each capture is of one position.
            assert!((1..=polnlos::calibrate::wall::MAX_SOURCES).contains(&positions.len()));
            let mut ids = std::collections::HashSet::new();
            for p in &positions {
                assert!(p.source.u.is_finite() && p.source.v.is_finite());
                assert!((1..=MAX_CAPTURES_PER_POSITION).contains(&p.captures.len()));
                assert!(p.captures.iter().all(|id| ids.insert(*id)));
            }
        }
    }
}

/// A `POST /calibrations` body and the dot target it may carry (TOML).
pub fn calibration_json(data: &[u8]) {
    if let Ok(b) = serde_json::from_slice::<polnlos::api::bodies::CalibrationBody>(data) {
        if let Some(text) = b.target {
            target_toml(text.as_bytes());
        }
    }
    target_toml(data);
}

/// A dot-target file.
fn target_toml(data: &[u8]) {
    if let Ok(text) = std::str::from_utf8(data) {
        if let Ok(t) = polnlos::calibrate::geometry::Target::from_toml_str(text) {
            assert!(t.radius_m > 0.0 && t.radius_m.is_finite());
            assert!((5..=10_000).contains(&t.dots.len()));
            assert!(t.dots.iter().flatten().all(|x| x.is_finite()));
        }
    }
}

/// A reply line from a rotation mount (Thorlabs Elliptec), as the serial
/// port delivers it.
pub fn elliptec_reply(data: &[u8]) {
    let line = String::from_utf8_lossy(data);
    if let Ok(polnlos::rig::mount::elliptec::Reply::Info(i)) =
        polnlos::rig::mount::elliptec::parse_reply('0', line.trim_end())
    {
        assert!(i.pulses > 0 && i.travel > 0);
    }
}
