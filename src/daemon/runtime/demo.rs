//! The fake camera's demo: the wall image of a test pattern behind every
//! (pose, angle) block of the demo scene and of the scenes on the same bench,
//! rendered by the numeric core through each pose's homography; with
//! `[demo] motion`, also the wall images of a disk at [`PATH_POSITIONS`]
//! points of its path, which the bench blends by the clock.

use super::scenes::Scenes;
use crate::daemon::{runtime::config, DaemonError, DEMO_PEAK_FRACTION, DEMO_REFERENCE_EXPOSURE_US};
use crate::scene::{Frame, FrameGeometry, Plane};
use crate::simulate::camera::render;
use crate::simulate::patterns::Pattern;

type DemoFrames = crate::camera::BenchImages;

/// Points of the moving disk's path whose wall images are rendered, equally
/// spaced in time round the circle; a frame between two shows their blend.
/// Why 16: a blend moves the disk's centroid along the chord between two
/// points, within `r (1 - cos(pi / 16))` = 1.9 % of the circle's radius of
/// the circle (1 mm on a 5 cm circle, a twenty-fifth of the demo scene's
/// 25 mm cell), and each point costs a frame per block of the demo scene
/// (1 MiB at 512 x 512).
const PATH_POSITIONS: usize = 16;

/// Sub-samples per element edge the disk's coverage is averaged over.
const DISK_SAMPLES: usize = 8;

/// Brightness of the calibration target's dots, fraction of full scale at the
/// reference exposure.
const TARGET_LEVEL: f32 = 0.8;

/// Where the demo bench's calibration point source sits on the hidden-scene
/// plane (unit radiance: its fitted gain is the demo calibration).
pub(crate) const DEMO_SOURCE: crate::calibrate::wall::PointSource =
    crate::calibrate::wall::PointSource { u: 0.03, v: -0.02 };

/// Area shadows where the scene file leaves the choice open (`Auto`).
fn area_shadows(p: &mut crate::scene::SceneParts) {
    if p.hidden.shadows == crate::scene::ShadowModel::Auto {
        p.hidden.shadows = crate::scene::ShadowModel::Area;
    }
}

/// Renders the fake camera's frame for every block of the demo scene (and of
/// every other scene on the same bench with poses of their own), normalized so
/// that the unpolarized peak is 80 % of full scale at the reference exposure.
/// Returns the frames and the calibration they imply (fraction of full scale
/// per microsecond per unit of T l).
pub(in crate::daemon) fn frames(
    scenes: &Scenes,
    demo: &config::DemoConfig,
) -> Result<(DemoFrames, f64), DaemonError> {
    let err = |m: String| DaemonError::Demo(m);
    let pattern = Pattern::from_name(&demo.pattern).ok_or_else(|| {
        err(format!(
            "pattern {:?} is not disk, bars, letter or flat",
            demo.pattern
        ))
    })?;
    let scene = scenes
        .get(&demo.scene)
        .ok_or_else(|| err(format!("no scene {:?}", demo.scene)))?;
    let t = scenes
        .transport(&demo.scene)
        .map_err(|e| err(e.to_string()))?;
    let l = pattern.render(t.scene_grid());
    // The moving disk's scenes, on the pattern: the brightest sets the scale.
    let path = match &demo.motion {
        Some(m) => disks(&scene.hidden().plane, m, &demo.scene)?,
        None => Vec::new(),
    };
    let lit: Vec<Vec<f64>> = std::iter::once(l.clone())
        .chain(
            path.iter()
                .map(|d| l.iter().zip(d).map(|(a, b)| a + b).collect()),
        )
        .collect();
    let lit: Vec<&[f64]> = lit.iter().map(Vec::as_slice).collect();
    let peak = crate::simulate::brightest_unpolarized(&scene, &t, &lit, scenes.budget())
        .map_err(|e| err(e.to_string()))?;
    if peak <= 0.0 {
        return Err(err("the demo scene lights no wall element".into()));
    }
    let norm = DEMO_PEAK_FRACTION / peak;
    let placed = demo.placement().map_err(|e| err(e.to_string()))?;
    let mut frames: DemoFrames = DemoFrames::default();
    let target = crate::calibrate::geometry::Target::default_target();
    // The demo scene first; then same-bench scenes add blocks it lacks (B, C, angles).
    let mut names = vec![demo.scene.clone()];
    names.extend(scenes.names().into_iter().filter(|n| {
        n != &demo.scene && same_bench(&scene, &scenes.get(n).unwrap_or_else(|| scene.clone()))
    }));
    let sensor = FrameGeometry::plain(512, 512);
    let scaled = |f: Option<Frame>| {
        f.map(|mut f| {
            f.pixels.iter_mut().for_each(|p| *p *= norm as f32);
            f
        })
    };
    for name in names {
        let Some(s) = scenes.get(&name) else {
            continue;
        };
        let shown = |frames: &DemoFrames, p: &str, a: Option<f64>| {
            frames.scene.iter().any(|(q, b, _)| q == p && *b == a)
        };
        let blocks = crate::transport::blocks_of(&s);
        if blocks
            .iter()
            .all(|b| shown(&frames, &b.pose, bench_angle(&s, b)))
        {
            continue;
        }
        // The bench as it stands ([demo] bench_offset), which its file may not say.
        // A monitor's cell is an area, not a point: its shadows are the
        // visible fraction of the cell, unless the scene file says otherwise.
        let s = placed
            .moved(&s)
            .and_then(|s| s.edit(area_shadows))
            .map_err(|e| err(format!("scene {name:?} moved by demo.bench_offset: {e}")))?;
        // Each pixel at its own wall point: the camera a measurement must average.
        let l = pattern.render(s.hidden().plane.grid);
        let lit = render(&s, &l, sensor);
        let point = crate::calibrate::wall::point_scene(&s, &DEMO_SOURCE, &material(&s))
            .map_err(|e| err(e.to_string()))?;
        let source = render(&point, &[1.0], sensor);
        for ((block, frame), (_, source)) in lit.into_iter().zip(source) {
            let angle = bench_angle(&s, &block);
            if shown(&frames, &block.pose, angle) {
                continue;
            }
            let (Some(frame), Some(source), Some(h)) = (
                scaled(frame),
                scaled(source),
                s.pose(&block.pose).and_then(|p| p.homography),
            ) else {
                continue;
            };
            frames.scene.push((block.pose.clone(), angle, frame));
            frames.source.push((block.pose.clone(), angle, source));
            let mut dots = crate::calibrate::geometry::render(&target, &h, 512, 512);
            dots.pixels.iter_mut().for_each(|p| *p *= TARGET_LEVEL);
            frames.target.push((block.pose, angle, dots));
        }
    }
    if let Some(m) = &demo.motion {
        let moved = placed
            .moved(&scene)
            .and_then(|s| s.edit(area_shadows))
            .map_err(|e| err(e.to_string()))?;
        frames.path = path
            .iter()
            .map(|d| {
                render(&moved, d, sensor)
                    .into_iter()
                    .filter_map(|(block, frame)| {
                        let angle = bench_angle(&scene, &block);
                        scaled(frame).map(|f| (block.pose, angle, f))
                    })
                    .collect()
            })
            .collect();
        frames.period_s = m.period_s;
    }
    // Frame value v = norm T l at the reference exposure, as a fraction of full scale.
    let c = norm / DEMO_REFERENCE_EXPOSURE_US;
    Ok((frames, c))
}

/// The moving disk at each of the [`PATH_POSITIONS`] points of its path
/// (point `k` where it is at phase `k / PATH_POSITIONS` of a turn), on
/// `plane`; refused when it would leave the plane.
fn disks(
    plane: &Plane,
    m: &config::MotionConfig,
    scene: &str,
) -> Result<Vec<Vec<f64>>, DaemonError> {
    let reach = m.radius_m + m.disk_radius_m;
    let [hu, hv] = [plane.size[0] / 2.0, plane.size[1] / 2.0];
    if m.center_m[0].abs() + reach > hu || m.center_m[1].abs() + reach > hv {
        return Err(DaemonError::Demo(format!(
            "demo.motion: a disk of {} m on a circle of {} m about ({}, {}) m leaves the hidden-scene plane of scene {scene:?} ({hu} m either side along u, {hv} m along v)",
            m.disk_radius_m, m.radius_m, m.center_m[0], m.center_m[1]
        )));
    }
    Ok((0..PATH_POSITIONS)
        .map(|k| {
            let at = m.position(k as f64 / PATH_POSITIONS as f64 * m.period_s);
            disk(plane, at, m.disk_radius_m, m.level)
        })
        .collect())
}

/// A disk of `radius` metres centred at `(u, v)` metres on `plane`, at
/// `level`: each element's covered fraction ([`DISK_SAMPLES`] squared
/// sub-samples) times `level`, row-major as the scene's unknowns.
fn disk(plane: &Plane, [cu, cv]: [f64; 2], radius: f64, level: f64) -> Vec<f64> {
    let [su, sv] = plane.size;
    let inside = |x: f64, y: f64| (x * su - su / 2.0 - cu).hypot(y * sv - sv / 2.0 - cv) <= radius;
    crate::simulate::patterns::coverage(plane.grid, DISK_SAMPLES, inside)
        .into_iter()
        .map(|c| level * c)
        .collect()
}

/// The angle from crossed of the polarizer a block's light passes, as the
/// bench shows it (a sheet's, or a mosaic micro-polarizer's `sensor_deg +
/// theta`); `None` without one.
fn bench_angle(s: &crate::scene::Scene, block: &crate::transport::Block) -> Option<f64> {
    s.pose(&block.pose)?
        .analyzer(block.channel)
        .map(|a| a.angle_deg)
}

/// The scene's wall material as wall calibration fits it, with a unit source.
fn material(s: &crate::scene::Scene) -> crate::calibrate::wall::WallParams {
    crate::calibrate::wall::WallParams {
        alpha: s.wall().brdf.alpha,
        ior: s.wall().brdf.eta,
        kd: s.wall().brdf.kd,
        gain: 1.0,
    }
}

/// Same wall, same hidden-scene plane, no occluder difference: frames can be shared.
fn same_bench(a: &crate::scene::Scene, b: &crate::scene::Scene) -> bool {
    a.wall().plane.center == b.wall().plane.center
        && a.wall().plane.size == b.wall().plane.size
        && a.wall().plane.grid == b.wall().plane.grid
        && a.wall().brdf == b.wall().brdf
        && a.hidden().plane.center == b.hidden().plane.center
        && a.hidden().plane.size == b.hidden().plane.size
        && a.occluders() == b.occluders()
}
