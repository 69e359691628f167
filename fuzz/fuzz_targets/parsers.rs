//! The parsers a file or a client can reach, as fuzz entry points: each takes
//! arbitrary bytes and must return (a value or a named error), never panic,
//! abort or allocate by a size it was told. Shared by the cargo-fuzz targets
//! in this folder and by `tests/fuzz.rs`, which runs them over the corpus and
//! a fixed-seed batch of mutations in the ordinary test suite.

#![allow(dead_code)]

use polnlos::camera::{CameraSettings, SensorLimits};

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

/// A `POST /captures` body, and the geometry check it reaches.
pub fn capture_json(data: &[u8]) {
    if let Ok(b) = serde_json::from_slice::<polnlos::daemon::CaptureBody>(data) {
        let _ = LIMITS.check(
            b.region.unwrap_or([0, 0, 512, 512]),
            b.binning.unwrap_or([1, 1]),
        );
    }
}

/// A `POST /reconstructions` body.
pub fn reconstruction_json(data: &[u8]) {
    let _ = serde_json::from_slice::<polnlos::daemon::ReconstructionBody>(data);
}

/// A `PUT /camera/settings` body, and the geometry check it reaches.
pub fn settings_json(data: &[u8]) {
    if let Ok(s) = serde_json::from_slice::<CameraSettings>(data) {
        if LIMITS
            .check(
                s.region.unwrap_or([0, 0, 512, 512]),
                s.binning.unwrap_or([1, 1]),
            )
            .is_ok()
        {
            let [x, y, w, h] = s.region.unwrap_or([0, 0, 512, 512]);
            assert!(x + w <= 2048 && y + h <= 2048);
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
