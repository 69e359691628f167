//! Checking a capture request against its scene, the camera and the bench.

use super::{invalid, CameraContext, RequestError};
use crate::camera::settings::check_ranges;
use crate::camera::{Acquisition, CameraSettings, PixelFormat};
use crate::daemon::requests::{AutoExposure, CaptureBody};
use crate::measure::exposure::BlockExposure;
use crate::scene::{Channel, FrameGeometry, PixelMap, Pose, Scene};
use crate::store::{CaptureKind, CaptureRecord, CaptureRequest, JobState};

/// Checks a capture request against its scene, the camera and the bench,
/// and resolves every camera setting it will use. `plan` is called only for
/// `"exposure": "auto"`; `capture` looks up the `dark_capture`.
pub fn capture(
    b: &CaptureBody,
    scene: &Scene,
    cam: &CameraContext,
    plan: impl FnOnce() -> Result<Vec<BlockExposure>, RequestError>,
    capture: impl Fn(i64) -> Result<Option<CaptureRecord>, RequestError>,
) -> Result<CaptureRequest, RequestError> {
    let pose = pose_of(&b.scene, scene, &b.pose)?;
    let kind = b.kind.unwrap_or(CaptureKind::Light);
    let planned = planned_exposure(b, plan)?;
    // A planned exposure stands for a stated one; what neither states
    // inherits the defaults, as every setting does.
    let stated = CameraSettings {
        exposure_us: planned
            .as_ref()
            .map(|p| p.exposure_us)
            .or(b.settings.exposure_us),
        ..b.settings
    };
    let acquisition = stated.over(&cam.defaults).complete().map_err(|e| {
        RequestError::Unavailable(format!(
            "the camera has not reported its settings yet ({e}): give them, or retry when GET /camera shows it connected"
        ))
    })?;
    check_ranges(&acquisition, cam.ranges.as_ref()).map_err(|e| invalid(e.to_string()))?;
    let frames = b
        .frames
        .unwrap_or_else(|| planned.as_ref().map_or(1, |p| p.frames));
    check_frames(b, kind, frames, cam)?;
    if let Some(limits) = &cam.sensor {
        limits
            .check(acquisition.region, acquisition.binning)
            .map_err(|e| invalid(e.to_string()))?;
    }
    check_pixel_format(acquisition.pixel_format, cam)?;
    let channels = channels(&b.scene, pose, b.polarizer_deg, &acquisition)?;
    if kind == CaptureKind::Light {
        check_reconstructable(&b.scene, scene, pose, &acquisition)?;
    }
    let request = CaptureRequest {
        kind,
        scene: b.scene.clone(),
        pose: b.pose.clone(),
        channels,
        acquisition,
        frames,
        dark_frames: b.dark_frames,
        dark_capture: b.dark_capture,
    };
    if let Some(id) = b.dark_capture {
        let record = capture(id)?.ok_or_else(|| {
            RequestError::NotFound(format!("dark_capture {id}: no capture with that id"))
        })?;
        check_dark_capture(&record, &request)?;
    }
    Ok(request)
}

/// Checks that a light capture of `pose` at `a`'s region and binning can be
/// measured: the pose has a homography, and the frame holds every wall element.
///
/// Why: such a capture used the bench for nothing and failed only at its
/// reconstruction (issue 47); target captures, which find the homography,
/// are not held to it.
fn check_reconstructable(
    scene_name: &str,
    scene: &Scene,
    pose: &Pose,
    a: &Acquisition,
) -> Result<(), RequestError> {
    let Some(h) = &pose.homography else {
        return Err(invalid(format!(
            "pose {:?} of scene {scene_name:?} has no homography, so a light capture of it could not be reconstructed: capture the dot target at this pose (\"kind\": \"target\"), fit the pose's homography with POST /calibrations, load the scene file it returns, then capture again",
            pose.name
        )));
    };
    // A pose that names its frame is measured only at that frame
    // (validate::reconstruction refuses any other).
    if let Some(f) = pose
        .frame
        .filter(|f| (f.region, f.binning) != (a.region, a.binning))
    {
        return Err(invalid(format!(
            "region = {:?}, binning = {:?}: pose {:?}'s homography maps the wall into region {:?} binning {:?} (scene {scene_name:?}), so a light capture at another frame could not be reconstructed: capture at that region and binning, or fit the pose's homography for this frame with POST /calibrations (from a \"kind\": \"target\" capture at it)",
            a.region, a.binning, pose.name, f.region, f.binning
        )));
    }
    // The frame as a reconstruction reads it (measure::load).
    let geometry = FrameGeometry {
        offset: [a.region[0], a.region[1]],
        size: [a.region[2] as usize, a.region[3] as usize],
        binning: a.binning,
    };
    // Cheap first: a frame that holds the wall's whole image needs no map;
    // only a frame the wall may leave is mapped pixel by pixel.
    let wall = &scene.wall().plane;
    if let Ok(true) = geometry.holds_wall(h, wall, &pose.name) {
        return Ok(());
    }
    PixelMap::frame(h, wall, geometry, &pose.name)
        .map(|_| ())
        .map_err(|e| {
            invalid(format!(
                "region = {:?}, binning = {:?}: {e}, so this capture could not be reconstructed; GET /scenes/{scene_name}/wall gives where pose {:?} sees the wall (if the wall or camera moved, fit the pose's homography again with POST /calibrations)",
                a.region, a.binning, pose.name
            ))
        })
}

/// Checks that the camera lists the pixel format (when it lists any): a
/// format it cannot deliver is a 422 now, not a failed capture later.
fn check_pixel_format(format: PixelFormat, cam: &CameraContext) -> Result<(), RequestError> {
    let Some(listed) = cam.pixel_formats.as_ref().filter(|l| !l.is_empty()) else {
        return Ok(());
    };
    if listed.iter().any(|n| n == format.name()) {
        return Ok(());
    }
    let usable: Vec<&str> = listed
        .iter()
        .filter_map(|n| PixelFormat::from_name(n))
        .map(PixelFormat::name)
        .collect();
    Err(invalid(format!(
        "pixel_format = {:?}: the camera does not offer it; it offers {} of the formats polnlos decodes",
        format.name(),
        if usable.is_empty() {
            "none".to_string()
        } else {
            usable.join(", ")
        }
    )))
}

/// The pose a request names, or an error listing the scene's poses.
fn pose_of<'a>(scene_name: &str, scene: &'a Scene, pose: &str) -> Result<&'a Pose, RequestError> {
    scene.pose(pose).ok_or_else(|| {
        let names: Vec<&str> = scene.poses().iter().map(|p| p.name.as_str()).collect();
        invalid(format!(
            "scene {scene_name:?} has no pose {pose:?}; its poses: {}",
            names.join(", ")
        ))
    })
}

/// The blocks a capture of `pose` yields: the pose's four micro-polarizer
/// channels from a polarizer-mosaic camera (which states no angle and reads
/// its mosaic whole: unbinned, at an even offset), else the one sheet
/// setting `polarizer_deg` names (absent for a pose without polarizer).
fn channels(
    scene_name: &str,
    pose: &Pose,
    polarizer_deg: Option<f64>,
    a: &Acquisition,
) -> Result<Vec<Channel>, RequestError> {
    let format = a.pixel_format.name();
    match (pose.mosaic, a.pixel_format.mosaic()) {
        (Some(_), Some(_)) => {
            if let Some(deg) = polarizer_deg {
                return Err(invalid(format!(
                    "polarizer_deg = {deg}: pose {:?} of scene {scene_name:?} sees through the camera's polarizer mosaic (analyzer = \"mosaic\"), which gives all four angles in one frame; leave polarizer_deg out",
                    pose.name
                )));
            }
            check_whole_cells(
                a,
                "polarizer-mosaic camera",
                "the four micro-polarizers of its 2x2 cell",
            )?;
            Ok(Channel::mosaic().to_vec())
        }
        (Some(_), None) => Err(invalid(format!(
            "pose {:?} of scene {scene_name:?} has a polarizer mosaic (analyzer = \"mosaic\"), but pixel_format = {format:?} is not a polarization camera's raw mosaic; set a polarization format ({}) or capture a scene whose pose has a polarizer sheet",
            pose.name,
            crate::camera::PixelFormat::ALL
                .iter()
                .filter(|f| f.mosaic().is_some())
                .map(|f| f.name())
                .collect::<Vec<_>>()
                .join(", ")
        ))),
        (None, Some(_)) => Err(invalid(format!(
            "pixel_format = {format:?} reads a polarizer mosaic, but pose {:?} of scene {scene_name:?} {}: its scene must say analyzer = \"mosaic\" for this pose, or set a monochrome pixel_format",
            pose.name,
            if pose.analyzers.is_empty() {
                "has no polarizer".to_string()
            } else {
                "has a polarizer sheet (polarizer_deg)".to_string()
            }
        ))),
        (None, None) => {
            check_sheet(scene_name, pose, polarizer_deg)?;
            if a.pixel_format.bayer().is_some() {
                check_whole_cells(a, "colour (Bayer) camera", "its 2x2 cell's colours")?;
            }
            Ok(vec![Channel::sheet(polarizer_deg)])
        }
    }
}

/// Checks that a camera with a 2x2 pattern on its sensor (a `kind` whose
/// cell holds `cell`) reads whole cells: unbinned, at an even offset.
///
/// Why: a binned pixel mixes the cell's pixels, and an odd offset starts
/// the pattern on another of them.
fn check_whole_cells(a: &Acquisition, kind: &str, cell: &str) -> Result<(), RequestError> {
    let format = a.pixel_format.name();
    if a.binning != [1, 1] {
        return Err(invalid(format!(
            "binning = {:?}: a binned pixel of a {kind} ({format}) mixes {cell}; use binning [1, 1]",
            a.binning
        )));
    }
    if !a.region[0].is_multiple_of(2) || !a.region[1].is_multiple_of(2) {
        return Err(invalid(format!(
            "region = {:?}: on a {kind} ({format}) the region's x and y offsets must be even, or the 2x2 pattern starts on another pixel of {cell}; use [{}, {}, ...]",
            a.region,
            a.region[0] & !1,
            a.region[1] & !1
        )));
    }
    Ok(())
}

/// Checks that `polarizer_deg` is a setting of the pose's sheet (or absent
/// for a pose without polarizer).
fn check_sheet(
    scene_name: &str,
    pose: &Pose,
    polarizer_deg: Option<f64>,
) -> Result<(), RequestError> {
    let angles: Vec<f64> = pose.analyzers.iter().map(|a| a.angle_deg).collect();
    let list = || {
        let a: Vec<String> = angles.iter().map(|a| a.to_string()).collect();
        a.join(", ")
    };
    match (polarizer_deg, angles.is_empty()) {
        (None, true) => Ok(()),
        (Some(a), false) if angles.iter().any(|x| (x - a).abs() < 1e-6) => Ok(()),
        (None, false) => Err(invalid(format!(
            "pose {:?} of scene {scene_name:?} has a polarizer: give polarizer_deg, one of {}",
            pose.name,
            list()
        ))),
        (Some(a), true) => Err(invalid(format!(
            "pose {:?} of scene {scene_name:?} has no polarizer, but polarizer_deg = {a} was given",
            pose.name
        ))),
        (Some(a), false) => Err(invalid(format!(
            "polarizer_deg = {a} is not an angle of pose {:?} (scene {scene_name:?}): {}",
            pose.name,
            list()
        ))),
    }
}

/// The plan's block for a capture asking `"exposure": "auto"` (None when
/// it does not), refusing an exposure both stated and planned.
fn planned_exposure(
    b: &CaptureBody,
    plan: impl FnOnce() -> Result<Vec<BlockExposure>, RequestError>,
) -> Result<Option<BlockExposure>, RequestError> {
    match (b.settings.exposure_us, b.exposure) {
        (Some(_), Some(_)) => Err(invalid(
            "give either exposure_us or \"exposure\": \"auto\", not both",
        )),
        (_, None) if b.target.is_some() => {
            Err(invalid("target is only for \"exposure\": \"auto\""))
        }
        (_, None) => Ok(None),
        // A mosaic frame holds its pose's four blocks: the shortest
        // exposure keeps the brightest of them within full scale.
        (None, Some(AutoExposure::Auto)) => plan()?
            .into_iter()
            .filter(|p| {
                p.pose == b.pose
                    && (Channel::sheet(b.polarizer_deg).same(p.channel)
                        || matches!(p.channel, Channel::Mosaic { .. }))
            })
            .min_by(|x, y| x.exposure_us.total_cmp(&y.exposure_us))
            .map(Some)
            .ok_or_else(|| {
                invalid(format!(
                    "the exposures of scene {:?} have no block for pose {:?}",
                    b.scene, b.pose
                ))
            }),
    }
}

/// Frame counts within the cap; dark frames only where the bench can take them.
fn check_frames(
    b: &CaptureBody,
    kind: CaptureKind,
    frames: usize,
    cam: &CameraContext,
) -> Result<(), RequestError> {
    let max = cam.max_frames;
    if frames == 0 || frames.saturating_add(b.dark_frames) > max {
        return Err(invalid(format!(
            "frames = {frames}, dark_frames = {}: need at least 1 frame and at most {max} in all ([queue] max_frames_per_capture)",
            b.dark_frames
        )));
    }
    if b.dark_frames > 0 && !cam.bench_switches_scene {
        return Err(invalid(
            "this bench cannot switch the hidden scene off by itself, so dark frames cannot be taken within a capture: switch the scene off, POST a capture with \"kind\": \"dark\", switch it back on, and give that capture's id as dark_capture",
        ));
    }
    if kind == CaptureKind::Dark && (b.dark_frames > 0 || b.dark_capture.is_some()) {
        return Err(invalid(
            "a dark capture takes no dark_frames and no dark_capture of its own",
        ));
    }
    if b.dark_frames > 0 && b.dark_capture.is_some() {
        return Err(invalid("give dark_frames or dark_capture, not both"));
    }
    Ok(())
}

/// Region and binning, stated or inherited, within the sensor's limits.
/// A dark capture fits a light one when it is done, dark, and taken with the
/// same settings ([`Acquisition::same_dark_as`]).
fn check_dark_capture(c: &CaptureRecord, r: &CaptureRequest) -> Result<(), RequestError> {
    let id = c.id;
    if !c.is_dark() || c.state != JobState::Done {
        return Err(invalid(format!(
            "dark_capture {id} is a {} capture in state {}; it must be a done dark capture",
            c.kind.name(),
            c.state.name()
        )));
    }
    let dark = Acquisition::try_from(c).map_err(|e| invalid(format!("dark_capture {id}: {e}")))?;
    let r = &r.acquisition;
    if !dark.same_dark_as(r) {
        return Err(invalid(format!(
            "dark_capture {id} was taken at {}; this capture asks for {}: take a dark capture with the same settings",
            dark.dark_settings(),
            r.dark_settings()
        )));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::super::fixtures::{record, scene};
    use super::*;
    use crate::camera::{CameraSettings, PixelFormat, SensorLimits, TriggerMode};
    use crate::measure::exposure::CameraLimits;

    fn cam() -> CameraContext {
        CameraContext {
            limits: CameraLimits {
                exposure_us: (10.0, 1e6),
                max_frames: 100,
                full_well_e: 1e4,
                read_noise_e: 5.0,
            },
            ranges: Some(crate::camera::CameraRanges {
                exposure_us: (10.0, 1e6),
                gain: (0.0, 10.0),
                ..crate::camera::CameraRanges::synthetic()
            }),
            sensor: Some(SensorLimits {
                sensor: [512, 512],
                ..SensorLimits::default()
            }),
            defaults: CameraSettings {
                region: Some([0, 0, 512, 512]),
                ..CameraSettings::builtin()
            },
            pixel_formats: Some(vec!["Mono8".into(), "Mono16".into(), "BayerRG8".into()]),
            bench_switches_scene: false,
            max_frames: 100,
        }
    }

    fn body(json: serde_json::Value) -> CaptureBody {
        serde_json::from_value(json).expect("a well-formed body")
    }

    fn no_plan() -> Result<Vec<BlockExposure>, RequestError> {
        panic!("the plan is built only for \"exposure\": \"auto\"")
    }

    fn check(json: serde_json::Value) -> Result<CaptureRequest, RequestError> {
        capture(&body(json), &scene(), &cam(), no_plan, |_| Ok(None))
    }

    fn message(r: Result<CaptureRequest, RequestError>) -> String {
        match r {
            Err(RequestError::Invalid(m)) => m,
            other => panic!("expected a 422, got {other:?}"),
        }
    }

    #[test]
    fn a_capture_inherits_every_setting_it_does_not_state() {
        // A target capture: a light one must be at the pose's frame.
        let r = check(serde_json::json!({
            "scene": "brewster-multi-3x3", "pose": "B", "polarizer_deg": 0.0, "kind": "target",
            "exposure_us": 5000.0, "frames": 3, "region": [0, 0, 256, 128]
        }))
        .expect("accepted");
        assert_eq!(r.kind, CaptureKind::Target);
        assert_eq!((r.acquisition.exposure_us, r.frames), (5000.0, 3));
        assert_eq!(r.acquisition.region, [0, 0, 256, 128]);
        assert_eq!(r.acquisition.binning, [1, 1]);
        assert_eq!(r.acquisition.pixel_format, PixelFormat::Mono16);
        assert_eq!(r.acquisition.trigger, TriggerMode::Free);
    }

    #[test]
    fn a_pixel_format_the_camera_does_not_list_is_refused_with_what_it_offers() {
        let with = |format: &str| {
            check(serde_json::json!({
                "scene": "brewster-multi-3x3", "pose": "B", "polarizer_deg": 0.0,
                "exposure_us": 5000.0, "pixel_format": format
            }))
        };
        let m = message(with("Mono12p"));
        assert!(m.contains("\"Mono12p\""), "{m}");
        assert!(
            m.contains("it offers Mono8, Mono16, BayerRG8 of the formats"),
            "{m}"
        );
        assert_eq!(
            with("Mono8").expect("listed").acquisition.pixel_format,
            PixelFormat::Mono8
        );
        // A camera that lists nothing (or no camera yet) checks nothing here.
        let mut open = cam();
        open.pixel_formats = Some(Vec::new());
        let b = body(serde_json::json!({
            "scene": "brewster-multi-3x3", "pose": "B", "polarizer_deg": 0.0,
            "exposure_us": 5000.0, "pixel_format": "Mono12p"
        }));
        assert!(capture(&b, &scene(), &open, no_plan, |_| Ok(None)).is_ok());
    }

    #[test]
    fn a_bayer_capture_reads_whole_colour_cells() {
        let with = |extra: serde_json::Value| {
            let mut b = serde_json::json!({
                "scene": "brewster-multi-3x3", "pose": "B", "polarizer_deg": 0.0,
                "exposure_us": 5000.0, "pixel_format": "BayerRG8"
            });
            b.as_object_mut()
                .unwrap()
                .extend(extra.as_object().unwrap().clone());
            let mut c = cam();
            c.sensor = Some(SensorLimits {
                sensor: [512, 512],
                max_binning: [4, 4],
                ..SensorLimits::default()
            });
            capture(&body(b), &scene(), &c, no_plan, |_| Ok(None))
        };
        assert!(with(serde_json::json!({})).is_ok());
        let m = message(with(
            serde_json::json!({ "binning": [2, 2], "region": [0, 0, 256, 256] }),
        ));
        assert!(
            m.contains("colour (Bayer) camera (BayerRG8) mixes its 2x2 cell's colours"),
            "{m}"
        );
        let m = message(with(serde_json::json!({ "region": [1, 0, 256, 256] })));
        assert!(m.contains("offsets must be even"), "{m}");
    }

    /// The built-in crossed bench with its one pose's text changed by `edits`.
    fn crossed(edits: &[(&str, &str)]) -> Scene {
        let mut text = crate::scene::builtin::text("brewster-crossed")
            .expect("built in")
            .to_string();
        for (from, to) in edits {
            assert!(text.contains(from), "{from}");
            text = text.replacen(from, to, 1);
        }
        Scene::from_toml_str(&text).expect("scene")
    }

    fn check_on(scene: &Scene, json: serde_json::Value) -> Result<CaptureRequest, RequestError> {
        capture(&body(json), scene, &cam(), no_plan, |_| Ok(None))
    }

    #[test]
    fn a_light_capture_that_could_not_be_reconstructed_is_refused_and_a_target_one_is_not() {
        let light = |region: [u32; 4], kind: &str| {
            serde_json::json!({ "scene": "brewster-crossed", "pose": "A", "polarizer_deg": 0.0,
                "exposure_us": 5000.0, "region": region, "kind": kind })
        };
        let whole = [0, 0, 512, 512];
        // No homography: refused, naming the route that fits one.
        let bare = crossed(&[("homography = ", "# homography = ")]);
        let m = message(check_on(&bare, light(whole, "light")));
        assert!(
            m.contains("pose \"A\" of scene \"brewster-crossed\" has no homography"),
            "{m}"
        );
        assert!(
            m.contains("POST /calibrations,") && !m.contains("/calibrations/wall"),
            "{m}"
        );
        // The target capture that finds it stays allowed, as do darks.
        assert!(check_on(&bare, light(whole, "target")).is_ok());
        assert!(check_on(&bare, light(whole, "dark")).is_ok());
        // A region other than the frame the pose names.
        let framed = crossed(&[]);
        let m = message(check_on(&framed, light([0, 0, 256, 256], "light")));
        assert!(
            m.contains("maps the wall into region [0, 0, 512, 512]"),
            "{m}"
        );
        assert!(check_on(&framed, light(whole, "light")).is_ok());
        // A pose that names no frame: the wall must lie in the region.
        let free = crossed(&[("region = [0, 0, 512, 512]", "")]);
        let m = message(check_on(&free, light([0, 0, 256, 256], "light")));
        assert!(m.contains("imaged partly outside the frame"), "{m}");
        assert!(m.contains("GET /scenes/brewster-crossed/wall"), "{m}");
        assert!(check_on(&free, light(whole, "light")).is_ok());
        // Shifted 200 pixels right, the wall leaves the 512-pixel frame.
        let shifted = crossed(&[
            ("region = [0, 0, 512, 512]", ""),
            (
                "[-425.517945, 1220.52494, 255.5]",
                "[-758.604399, 1220.52494, 455.5]",
            ),
        ]);
        let m = message(check_on(&shifted, light(whole, "light")));
        assert!(m.contains("imaged partly outside the frame"), "{m}");
        assert!(check_on(&shifted, light(whole, "target")).is_ok());
    }

    #[test]
    fn the_block_must_be_one_of_the_pose() {
        let base = |pose: &str, deg: Option<f64>| {
            serde_json::json!({ "scene": "brewster-multi-3x3", "pose": pose,
                "polarizer_deg": deg, "exposure_us": 5000.0 })
        };
        assert!(message(check(base("Z", None))).contains("its poses: B, C"));
        assert!(message(check(base("B", None))).contains("give polarizer_deg, one of 0"));
        assert!(message(check(base("B", Some(45.0)))).contains("not an angle of pose \"B\""));
        assert!(check(base("C", Some(0.0))).is_ok());
    }

    #[test]
    fn exposure_gain_and_frames_are_held_to_the_camera_and_the_cap() {
        let with = |extra: serde_json::Value| {
            let mut v = serde_json::json!({ "scene": "brewster-multi-3x3", "pose": "B",
                "polarizer_deg": 0.0, "exposure_us": 5000.0 });
            if let (Some(o), serde_json::Value::Object(e)) = (v.as_object_mut(), extra) {
                o.extend(e);
            }
            check(v)
        };
        assert!(message(with(serde_json::json!({ "exposure_us": 5.0 })))
            .contains("must be from 10 to 1000000"));
        // An exposure not given inherits the defaults, as every setting does.
        let r = with(serde_json::json!({ "exposure_us": null })).expect("the default exposure");
        assert_eq!(r.acquisition.exposure_us, 20_000.0);
        assert!(message(with(serde_json::json!({ "exposure": "auto" }))).contains("not both"));
        assert!(message(with(serde_json::json!({ "gain": 11.0 }))).contains("gain = 11"));
        assert!(message(with(serde_json::json!({ "frames": 0 }))).contains("at least 1 frame"));
        assert!(message(with(serde_json::json!({ "frames": 101 }))).contains("at most 100"));
        // This bench is set by hand: no dark frames within a capture.
        assert!(
            message(with(serde_json::json!({ "dark_frames": 2 }))).contains("\"kind\": \"dark\"")
        );
        assert!(message(with(serde_json::json!({ "region": [0, 0, 600, 16] }))).contains("600"));
    }

    #[test]
    fn an_automatic_exposure_takes_the_plan_of_its_block() {
        let b = body(
            serde_json::json!({ "scene": "brewster-multi-3x3", "pose": "C",
            "polarizer_deg": 0.0, "exposure": "auto" }),
        );
        let block = |pose: &str, exposure_us: f64, frames: usize| BlockExposure {
            pose: pose.into(),
            channel: Channel::Sheet { deg: 0.0 },
            peak_rate_per_us: 1e-4,
            exposure_us,
            frames,
            peak_fraction: 0.8,
            snr: 100.0,
            limited_by: None,
        };
        let plan = || Ok(vec![block("B", 1000.0, 4), block("C", 2500.0, 7)]);
        let r = capture(&b, &scene(), &cam(), plan, |_| Ok(None)).expect("accepted");
        assert_eq!((r.acquisition.exposure_us, r.frames), (2500.0, 7));
    }

    #[test]
    fn a_camera_that_has_not_reported_its_region_makes_the_request_wait() {
        let mut c = cam();
        c.defaults.region = None;
        let b = body(
            serde_json::json!({ "scene": "brewster-multi-3x3", "pose": "B",
            "polarizer_deg": 0.0, "exposure_us": 5000.0 }),
        );
        let r = capture(&b, &scene(), &c, no_plan, |_| Ok(None));
        assert!(matches!(r, Err(RequestError::Unavailable(_))), "{r:?}");
    }

    #[test]
    fn a_dark_capture_must_exist_and_match() {
        let b = body(
            serde_json::json!({ "scene": "brewster-multi-3x3", "pose": "B",
            "polarizer_deg": 0.0, "exposure_us": 5000.0, "dark_capture": 7 }),
        );
        let r = capture(&b, &scene(), &cam(), no_plan, |_| Ok(None));
        assert!(matches!(r, Err(RequestError::NotFound(_))), "{r:?}");
        let dark = |exposure_us: f64| record(7, "dark", exposure_us, JobState::Done);
        let r = capture(&b, &scene(), &cam(), no_plan, |_| Ok(Some(dark(5000.0))));
        assert_eq!(r.expect("a matching dark").dark_capture, Some(7));
        let r = capture(&b, &scene(), &cam(), no_plan, |_| Ok(Some(dark(4000.0))));
        assert!(message(r).contains("take a dark capture with the same settings"));
        let light = record(7, "light", 5000.0, JobState::Done);
        let r = capture(&b, &scene(), &cam(), no_plan, |_| Ok(Some(light.clone())));
        assert!(message(r).contains("must be a done dark capture"));
        // A dark row from before region and trigger were recorded cannot
        // vouch for its settings.
        let mut old = dark(5000.0);
        (old.settings.region, old.settings.trigger) = (None, None);
        let r = capture(&b, &scene(), &cam(), no_plan, |_| Ok(Some(old.clone())));
        assert!(
            message(r).contains("capture 7 records no region, trigger"),
            "{old:?}"
        );
    }
}
