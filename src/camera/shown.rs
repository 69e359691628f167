//! The hidden scene as a demo bench shows it: the wall image of every
//! (pose, polarizer angle) block, which block the bench has selected, and
//! whether the scene is lit. Both demo cameras expose frames from it: Aravis's
//! fake camera ([`super::fake`]) and the in-process one ([`super::synthetic`]).
//!
//! A bench with a moving object also holds the object's wall images at
//! points equally spaced in time round its closed path; a frame exposed at
//! Unix time `t` adds the blend of the two points `t` falls between (the
//! wall image is linear in the scene, so the blend is the image of the
//! blended scene, whose centroid is the blend of the two centroids).

use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use crate::measure::colour::BayerPattern;
use crate::optics::polarizer::IntensityLaw;
use crate::scene::{Frame, MosaicLayout, MOSAIC_DEGREES};

/// What a colour sensor's red, green and blue pixels record of the demo's
/// grey scene, relative to a monochrome pixel: a colour CMOS sensor's
/// typical response to white light through its filters.
pub const BAYER_RESPONSE: [f64; 3] = [0.55, 1.0, 0.7];

/// Key of a block: pose name and polarizer angle in millidegrees (None: no polarizer).
fn key(pose: &str, deg: Option<f64>) -> String {
    match deg {
        Some(d) => format!("{pose}@{}", (d * 1000.0).round() as i64),
        None => format!("{pose}@none"),
    }
}

/// What a demo bench can show, per (pose, polarizer angle) block, in
/// fractions of full scale at the reference exposure.
#[derive(Debug, Clone, Default)]
pub struct BenchImages {
    /// The wall lit by the hidden scene.
    pub scene: Vec<(String, Option<f64>, Frame)>,
    /// The calibration target on the wall (for geometry calibration).
    pub target: Vec<(String, Option<f64>, Frame)>,
    /// The wall lit by a point source (for wall calibration).
    pub source: Vec<(String, Option<f64>, Frame)>,
    /// The wall lit by a moving object (added to `scene`), per point of its
    /// closed path: point `k` of `n` is where it is at phase `k / n` of a
    /// turn (empty: nothing moves).
    pub path: Vec<Vec<(String, Option<f64>, Frame)>>,
    /// Seconds the moving object takes round its path; at Unix time `t` it
    /// is at phase `(t / period_s) mod 1`.
    pub period_s: f64,
}

/// One kind of image (the lit wall, the target, the point source) per block.
struct Images {
    /// Per block key.
    by_key: HashMap<String, Arc<Frame>>,
    /// Per pose: its polarizer angles (degrees) and their images.
    by_pose: HashMap<String, Vec<(f64, Arc<Frame>)>>,
}

impl Images {
    fn new(v: Vec<(String, Option<f64>, Frame)>) -> Self {
        let mut by_key = HashMap::new();
        let mut by_pose: HashMap<String, Vec<(f64, Arc<Frame>)>> = HashMap::new();
        for (pose, deg, frame) in v {
            let frame = Arc::new(frame);
            if let Some(d) = deg {
                by_pose
                    .entry(pose.clone())
                    .or_default()
                    .push((d, frame.clone()));
            }
            by_key.insert(key(&pose, deg), frame);
        }
        Self { by_key, by_pose }
    }

    /// The image of `pose` with its polarizer at `deg`: the rendered one at
    /// that angle, else the nearest rendered angle's moved by the change of
    /// the polarizer's intensity law fitted to the pose's rendered angles
    /// (with fewer than three angles, the nearest rendered angle's as is).
    ///
    /// Why: a rotation mount stops where it stops, and a bench that shows
    /// the angle the mount is really at makes a mis-set mount show in the
    /// data. Through a linear polarizer turned by θ the intensity of every
    /// pixel is `a + b cos 2θ + c sin 2θ` (the Stokes parameters of its
    /// light, exact for a sheet seen head-on; the bench's off-axis rays
    /// bend it by less than the fit's residual at the rendered angles).
    fn at(&self, pose: &str, deg: Option<f64>) -> Option<Arc<Frame>> {
        if let Some(f) = self.by_key.get(&key(pose, deg)) {
            return Some(f.clone());
        }
        let (deg, rendered) = (deg?, self.by_pose.get(pose)?);
        let gap = |d: f64| {
            let g = (d - deg).rem_euclid(180.0);
            g.min(180.0 - g)
        };
        let (near_deg, near) = rendered
            .iter()
            .min_by(|a, b| gap(a.0).total_cmp(&gap(b.0)))?;
        // The nearest rendered image, moved by the law's change from its
        // angle to `deg`: exact at every rendered angle, the law between.
        let Some(law) = IntensityLaw::over(rendered.iter().map(|(d, _)| *d)) else {
            return Some(near.clone());
        };
        let (at, from) = (law.weights(deg), law.weights(*near_deg));
        let mut pixels = near.pixels.clone();
        for ((a, b), (_, f)) in at.iter().zip(&from).zip(rendered) {
            let w = (a - b) as f32;
            for (p, &v) in pixels.iter_mut().zip(&f.pixels) {
                *p += w * v;
            }
        }
        // Light through a polarizer is never negative.
        pixels.iter_mut().for_each(|p| *p = p.max(0.0));
        Some(Arc::new(Frame {
            width: near.width,
            height: near.height,
            pixels,
        }))
    }
}

impl Images {
    /// The image a polarizer-mosaic sensor at `pose` records: each pixel
    /// through its own micro-polarizer (`layout`, the sensor's 0-degree one
    /// at crossed, ideal), i.e. the image at that angle (MODEL.md "On-chip
    /// polarizer mosaic"); `None` when an angle has no image.
    fn mosaic(&self, pose: &str, layout: MosaicLayout) -> Option<Arc<Frame>> {
        let at: Vec<Arc<Frame>> = MOSAIC_DEGREES
            .iter()
            .map(|&deg| self.at(pose, Some(deg)))
            .collect::<Option<_>>()?;
        let (width, height) = (at[0].width, at[0].height);
        if at.iter().any(|f| (f.width, f.height) != (width, height)) {
            return None;
        }
        let mut pixels = vec![0.0; width * height];
        for (k, p) in pixels.iter_mut().enumerate() {
            *p = at[layout.block_at((k % width) as i64, (k / width) as i64)].pixels[k];
        }
        Some(Arc::new(Frame {
            width,
            height,
            pixels,
        }))
    }
}

/// The images of the selected block.
#[derive(Default)]
struct Selected {
    scene: Option<Arc<Frame>>,
    target: Option<Arc<Frame>>,
    source: Option<Arc<Frame>>,
    /// The moving object's image at each point of its path (empty when
    /// nothing moves, or the block has no image of it).
    path: Vec<Arc<Frame>>,
}

/// A moving object's wall images round its closed path, and its period.
struct Path {
    /// Per point of the path, equally spaced in time.
    points: Vec<Images>,
    /// Seconds a turn.
    period_s: f64,
}

impl Path {
    /// The two path images a moment at Unix time `unix_s` falls between and
    /// the second's weight; `None` when nothing moves.
    /// Why: the moment's image is their blend, exact at every point.
    fn at(images: &[Arc<Frame>], period_s: f64, unix_s: f64) -> Option<(&Frame, &Frame, f32)> {
        let n = images.len();
        if n == 0 || period_s.is_nan() || period_s <= 0.0 {
            return None;
        }
        let phase = (unix_s / period_s).rem_euclid(1.0) * n as f64;
        let k = (phase.floor() as usize).min(n - 1);
        let w = (phase - k as f64).clamp(0.0, 1.0) as f32;
        Some((&images[k], &images[(k + 1) % n], w))
    }
}

/// Wall images per block and the bench's state.
pub struct Shown {
    /// Wall frames per block, in fractions of full scale at the reference exposure.
    frames: Images,
    /// The target's image per block.
    targets: Images,
    /// The point source's image per block.
    sources: Images,
    /// The moving object's images round its path (none when nothing moves).
    path: Path,
    source_on: AtomicBool,
    selected: Mutex<Selected>,
    scene_on: AtomicBool,
    target_on: AtomicBool,
    reference_exposure_us: f64,
    /// Dark level, fraction of full scale at the reference exposure.
    dark_level: f64,
    counter: AtomicU64,
    /// The sensor's polarizer mosaic, when the bench's camera has one.
    mosaic: Option<MosaicLayout>,
    /// The sensor's Bayer filter, when the bench's camera is a colour one.
    bayer: Option<BayerPattern>,
    /// Shot and read noise of the sensor, when set ([`Shown::set_sensor_noise`]).
    noise: std::sync::OnceLock<SensorNoise>,
}

/// A sensor's noise: photon shot noise from its full well, and read noise.
#[derive(Debug, Clone, Copy, PartialEq)]
struct SensorNoise {
    /// Electrons at full scale.
    full_well_e: f64,
    /// Read noise, electrons RMS.
    read_noise_e: f64,
}

impl Shown {
    /// A bench showing `images` (scaled to `reference_exposure_us`), the
    /// scene lit, the target away, its first block selected.
    ///
    /// Why a block from the start: an idle camera on a real bench sees the
    /// lit wall, and the live view is for aiming before the first capture
    /// (with nothing selected it showed the dark level, a flat grey).
    pub fn new(images: BenchImages, reference_exposure_us: f64) -> Self {
        let first = images
            .scene
            .first()
            .map(|(pose, deg, _)| (pose.clone(), *deg));
        let shown = Self {
            frames: Images::new(images.scene),
            targets: Images::new(images.target),
            sources: Images::new(images.source),
            path: Path {
                points: images.path.into_iter().map(Images::new).collect(),
                period_s: images.period_s,
            },
            source_on: AtomicBool::new(false),
            selected: Mutex::new(Selected::default()),
            scene_on: AtomicBool::new(true),
            target_on: AtomicBool::new(false),
            reference_exposure_us,
            dark_level: 0.01,
            counter: AtomicU64::new(0),
            mosaic: None,
            bayer: None,
            noise: std::sync::OnceLock::new(),
        };
        if let Some((pose, deg)) = first {
            shown.select(&pose, deg);
        }
        shown
    }

    /// The same bench seen by a camera whose sensor has a polarizer mosaic:
    /// a block without a sheet shows each pixel through its micro-polarizer.
    pub fn with_mosaic(mut self, layout: Option<MosaicLayout>) -> Self {
        self.mosaic = layout;
        self
    }

    /// The same bench seen by a colour camera: each pixel through its
    /// colour's filter of `pattern` ([`BAYER_RESPONSE`]).
    pub fn with_bayer(mut self, pattern: Option<BayerPattern>) -> Self {
        self.bayer = pattern;
        self
    }

    /// Gives the camera a sensor's noise: each pixel's electrons
    /// (`full_well_e` at full scale) with their shot noise, plus
    /// `read_noise_e`, as a real camera's frames have (the first call wins).
    ///
    /// Why: without it a frame's only noise is the ±0.5 DN dither, a
    /// thousand times less than a real sensor's shot noise at half scale,
    /// and the model check then measures the rendering's quadrature instead
    /// of the model (issue 38: the demo's rotating plan left 24.6x the noise).
    pub fn set_sensor_noise(&self, full_well_e: f64, read_noise_e: f64) {
        if full_well_e.is_finite()
            && full_well_e > 0.0
            && read_noise_e.is_finite()
            && read_noise_e >= 0.0
        {
            let _ = self.noise.set(SensorNoise {
                full_well_e,
                read_noise_e,
            });
        }
    }

    /// Moves the bench to `pose` with the polarizer at `polarizer_deg`
    /// (any angle: see [`Images::at`]).
    pub fn select(&self, pose: &str, polarizer_deg: Option<f64>) {
        let pick = |images: &Images| match (self.mosaic, polarizer_deg) {
            (Some(layout), None) => images.mosaic(pose, layout),
            _ => images.at(pose, polarizer_deg),
        };
        let chosen = Selected {
            scene: pick(&self.frames),
            target: pick(&self.targets),
            source: pick(&self.sources),
            // Every point of the path, or none.
            path: self
                .path
                .points
                .iter()
                .map(pick)
                .collect::<Option<Vec<_>>>()
                .unwrap_or_default(),
        };
        if let Ok(mut s) = self.selected.lock() {
            *s = chosen;
        }
    }

    /// Lights the hidden scene or switches it off.
    pub fn scene_on(&self, on: bool) {
        self.scene_on.store(on, Ordering::SeqCst);
    }

    /// Puts the calibration target up (it hides the scene) or takes it down.
    pub fn show_target(&self, on: bool) {
        self.target_on.store(on, Ordering::SeqCst);
    }

    /// Puts the point source in place of the hidden scene, or back.
    pub fn show_source(&self, on: bool) {
        self.source_on.store(on, Ordering::SeqCst);
    }

    /// Exposes one frame of the region `(w, h, ox, oy)`: hands `put` each
    /// pixel's index (row-major in the region) and value in DN, rounded and
    /// clamped to `[0, full]`, with +-0.5 DN of dither so that averaging
    /// frames means something. Signal and dark level scale with the exposure
    /// and with `1 + 0.1 gain`. A moving object is where the clock says.
    pub fn expose(
        &self,
        region: (usize, usize, usize, usize),
        full: f64,
        exposure_us: f64,
        gain: f64,
        put: impl FnMut(usize, f64),
    ) {
        let now = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0.0, |d| d.as_secs_f64());
        self.expose_at(now, region, full, exposure_us * (1.0 + 0.1 * gain), put);
    }

    /// [`Shown::expose`] at Unix time `unix_s`, `exposure_us` already scaled by the gain.
    /// Why: a test sets the moment a moving object is exposed at.
    fn expose_at(
        &self,
        unix_s: f64,
        (w, h, ox, oy): (usize, usize, usize, usize),
        full: f64,
        exposure_us: f64,
        mut put: impl FnMut(usize, f64),
    ) {
        let scale = exposure_us / self.reference_exposure_us;
        let (frame, path) = self
            .selected
            .lock()
            .ok()
            .map(|s| {
                if self.target_on.load(Ordering::SeqCst) {
                    (s.target.clone(), Vec::new())
                } else if self.source_on.load(Ordering::SeqCst) {
                    (s.source.clone(), Vec::new())
                } else if self.scene_on.load(Ordering::SeqCst) {
                    (s.scene.clone(), s.path.clone())
                } else {
                    (None, Vec::new())
                }
            })
            .unwrap_or_default();
        let frame = frame.as_deref();
        let moving = Path::at(&path, self.path.period_s, unix_s);
        // Electrons per DN and the read noise in DN², when the sensor is noisy.
        let noise = self.noise.get().map(|n| {
            (
                n.full_well_e / full,
                (n.read_noise_e * full / n.full_well_e).powi(2),
            )
        });
        // Xorshift64, seeded per frame.
        let mut rng = XorShift(
            self.counter
                .fetch_add(1, Ordering::Relaxed)
                .wrapping_mul(0x9E37_79B9_7F4A_7C15)
                | 1,
        );
        // Each colour's response along a row (the filter repeats every two
        // columns), and one row of values at a time.
        let mut row = vec![0.0; w];
        let mut blend: Vec<f32> = Vec::new();
        let pixel = Pixel {
            dark: self.dark_level,
            scale: scale * full,
            full,
            noise,
        };
        for y in 0..h {
            let response = |x: usize| {
                self.bayer.map_or(1.0, |p| {
                    BAYER_RESPONSE[p.colour_at((ox + x) as i64, (oy + y) as i64) as usize]
                })
            };
            let parity = [response(0), response(1)];
            // The block's pixels this row sees (none past its edge), with
            // the moving object's where it is now.
            let fy = oy.saturating_add(y);
            let fixed = frame.map_or(&[][..], |f| row_of(f, fy, ox));
            let signal = match moving {
                None => fixed,
                Some((a, b, wb)) => {
                    let (a, b) = (row_of(a, fy, ox), row_of(b, fy, ox));
                    let at = |r: &[f32], x: usize| r.get(x).copied().unwrap_or(0.0);
                    blend.clear();
                    blend.extend(
                        (0..w).map(|x| at(fixed, x) + (1.0 - wb) * at(a, x) + wb * at(b, x)),
                    );
                    &blend[..]
                }
            };
            expose_row(&mut row, signal, parity, &pixel, &mut rng);
            for (x, &v) in row.iter().enumerate() {
                put(y * w + x, v);
            }
        }
    }
}

/// The pixels of row `fy` of `f` from column `ox` on (empty past its edges).
fn row_of(f: &Frame, fy: usize, ox: usize) -> &[f32] {
    if fy >= f.height {
        return &[];
    }
    let end = (fy * f.width + f.width).min(f.pixels.len());
    let start = (fy * f.width).saturating_add(ox).min(end);
    &f.pixels[start..end]
}

/// Xorshift64: a fake sensor's noise, cheap and fixed by its seed.
struct XorShift(u64);

impl XorShift {
    /// Uniform in [0, 1).
    #[inline(always)]
    fn uniform(&mut self) -> f64 {
        let s = &mut self.0;
        *s ^= *s << 13;
        *s ^= *s >> 7;
        *s ^= *s << 17;
        (*s >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// What turns a pixel's signal into DN: the dark level, the scale to DN
/// (exposure, gain and full scale), the full scale and, on a noisy sensor,
/// electrons per DN and the read noise in DN².
struct Pixel {
    dark: f64,
    scale: f64,
    full: f64,
    noise: Option<(f64, f64)>,
}

/// One row of a frame: `signal` (fractions of full scale; 0 past its end)
/// times the colour filter's response, in DN with shot and read noise,
/// dithered by +-0.5 DN, rounded and clamped to `[0, full]`.
#[multiversion::multiversion(targets("x86_64+avx2+fma"))]
fn expose_row(row: &mut [f64], signal: &[f32], parity: [f64; 2], p: &Pixel, rng: &mut XorShift) {
    for (x, out) in row.iter_mut().enumerate() {
        let s = signal.get(x).map_or(0.0, |&v| f64::from(v)) * parity[x % 2];
        let dither = rng.uniform() - 0.5;
        let mean = (p.dark + s) * p.scale;
        // Shot noise (variance = electrons, in DN²: mean / e_per_dn) and
        // read noise, Gaussian (Box-Muller); the electrons are many.
        let shot = p.noise.map_or(0.0, |(e_per_dn, read_dn2)| {
            let sd = (mean.max(0.0) / e_per_dn + read_dn2).sqrt();
            let (u1, u2) = (rng.uniform().max(f64::MIN_POSITIVE), rng.uniform());
            sd * (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
        });
        *out = (mean + shot + dither).round().clamp(0.0, p.full);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_polarizer_between_rendered_angles_follows_the_intensity_law() {
        // One pixel lit by partly polarized light: a + b cos 2θ + c sin 2θ.
        let law = |d: f64| {
            let t = 2.0 * d.to_radians();
            0.4 + 0.25 * t.cos() - 0.1 * t.sin()
        };
        let frame = |d: f64| Frame {
            width: 1,
            height: 1,
            pixels: vec![law(d) as f32],
        };
        let images = Images::new(
            [0.0, 45.0, 90.0, 135.0]
                .into_iter()
                .map(|d| ("A".to_string(), Some(d), frame(d)))
                .collect(),
        );
        for d in [2.0, -2.0, 30.0, 100.5, 179.0] {
            let got = f64::from(images.at("A", Some(d)).unwrap().pixels[0]);
            assert!((got - law(d)).abs() < 1e-6, "{d}: {got} vs {}", law(d));
        }
        // A rendered angle is itself; two angles cannot fit the law: the nearest.
        assert_eq!(
            images.at("A", Some(45.0)).unwrap().pixels[0],
            law(45.0) as f32
        );
        let two = Images::new(vec![
            ("B".into(), Some(0.0), frame(0.0)),
            ("B".into(), Some(90.0), frame(90.0)),
        ]);
        assert_eq!(two.at("B", Some(80.0)).unwrap().pixels[0], law(90.0) as f32);
        assert_eq!(two.at("B", Some(178.0)).unwrap().pixels[0], law(0.0) as f32);
        assert!(two.at("C", Some(0.0)).is_none());
    }

    #[test]
    fn a_mosaic_sensor_shows_each_pixel_through_its_micro_polarizer() {
        let frame = |v: f32| Frame {
            width: 4,
            height: 2,
            pixels: vec![v; 8],
        };
        let images = BenchImages {
            scene: [0.0, 45.0, 90.0, 135.0]
                .into_iter()
                .map(|d| ("A".to_string(), Some(d), frame(0.1 + d as f32 / 450.0)))
                .collect(),
            ..BenchImages::default()
        };
        let s = Shown::new(images, 1000.0).with_mosaic(Some(MosaicLayout::Polarsens));
        s.select("A", None);
        let mut got = [0.0; 8];
        s.expose((4, 2, 0, 0), 1000.0, 1000.0, 0.0, |i, v| got[i] = v);
        // Row 0: 90, 45, 90, 45; row 1: 135, 0, 135, 0 (plus 10 DN of dark).
        let want = |d: f64| 1000.0 * (0.01 + 0.1 + d / 450.0);
        for (k, d) in [90.0, 45.0, 90.0, 45.0, 135.0, 0.0, 135.0, 0.0]
            .into_iter()
            .enumerate()
        {
            assert!(
                (got[k] - want(d)).abs() <= 0.6,
                "{k}: {} vs {}",
                got[k],
                want(d)
            );
        }
        // A region at an odd offset starts on another micro-polarizer.
        s.expose((2, 1, 1, 1), 1000.0, 1000.0, 0.0, |i, v| got[i] = v);
        assert!((got[0] - want(0.0)).abs() <= 0.6 && (got[1] - want(135.0)).abs() <= 0.6);
    }

    #[test]
    fn a_moving_object_is_the_blend_of_the_two_path_points_the_clock_falls_between() {
        // Four points round a 4 s path: point k lights pixel k of a 4 x 1
        // wall image; the static scene lights every pixel at 0.1.
        let frame = |f: &dyn Fn(usize) -> f32| Frame {
            width: 4,
            height: 1,
            pixels: (0..4).map(f).collect(),
        };
        let images = BenchImages {
            scene: vec![("A".into(), Some(0.0), frame(&|_| 0.1))],
            path: (0..4)
                .map(|k| {
                    let lit = move |x: usize| if x == k { 0.4 } else { 0.0 };
                    vec![("A".to_string(), Some(0.0), frame(&lit))]
                })
                .collect(),
            period_s: 4.0,
            ..BenchImages::default()
        };
        let s = Shown::new(images, 1000.0);
        let at = |t: f64| {
            let mut got = [0.0; 4];
            s.expose_at(t, (4, 1, 0, 0), 1000.0, 1000.0, |i, v| got[i] = v);
            got
        };
        // DN = 1000 (dark 0.01 + scene 0.1 + the blend), +-0.5 of dither.
        let want = |blend: [f64; 4]| blend.map(|b| 1000.0 * (0.11 + b));
        let close = |got: [f64; 4], want: [f64; 4]| {
            got.iter().zip(&want).all(|(g, w)| (g - w).abs() <= 0.6)
        };
        let t0 = 1_700_000_000.0;
        assert!(close(at(t0), want([0.4, 0.0, 0.0, 0.0])), "{:?}", at(t0));
        assert!(close(at(t0 + 1.5), want([0.0, 0.2, 0.2, 0.0])));
        assert!(close(at(t0 + 3.75), want([0.3, 0.0, 0.0, 0.1])));
        assert!(close(at(t0 + 4.25), want([0.3, 0.1, 0.0, 0.0])));
        // Switched off, or behind the target: no moving object either.
        s.scene_on(false);
        assert!(close(at(t0), [10.0; 4]));
        s.scene_on(true);
        // A block the path has no image of shows the static scene alone.
        s.select("B", Some(0.0));
        assert!(close(at(t0), [10.0; 4]));
    }

    fn bench() -> Shown {
        let frame = Frame {
            width: 4,
            height: 2,
            pixels: vec![0.5; 8],
        };
        let images = BenchImages {
            scene: vec![("A".into(), Some(0.0), frame)],
            ..BenchImages::default()
        };
        Shown::new(images, 1000.0)
    }

    fn mean(s: &Shown, exposure_us: f64) -> f64 {
        let mut sum = 0.0;
        s.expose((4, 2, 0, 0), 1000.0, exposure_us, 0.0, |_, v| sum += v);
        sum / 8.0
    }

    #[test]
    fn the_selected_block_is_shown_in_proportion_to_the_exposure() {
        let s = bench();
        // The first block is selected from the start (an idle camera sees
        // the lit wall): 0.5 of full scale plus the dark level's 0.01.
        assert!((mean(&s, 1000.0) - 510.0).abs() <= 0.5);
        // A pose the bench has no image of: the dark level only.
        s.select("Z", Some(0.0));
        assert!((mean(&s, 1000.0) - 10.0).abs() <= 0.5);
        s.select("A", Some(0.0));
        assert!((mean(&s, 1000.0) - 510.0).abs() <= 0.5);
        assert!((mean(&s, 500.0) - 255.0).abs() <= 0.5);
        s.scene_on(false);
        assert!((mean(&s, 1000.0) - 10.0).abs() <= 0.5);
    }

    #[test]
    fn a_sensor_s_noise_is_its_shot_noise_plus_its_read_noise() {
        let s = bench();
        // 4000 DN full scale, 16,000 e- full well: 4 e- per DN. The pixels
        // sit at 0.51 of full scale, 2040 DN = 8160 e-: shot variance
        // 8160 e-² = 510 DN², read noise 40 e- = 10 DN: 100 DN² more.
        s.set_sensor_noise(16_000.0, 40.0);
        let (mut n, mut sum, mut sum2) = (0.0, 0.0, 0.0);
        for _ in 0..400 {
            s.expose((4, 2, 0, 0), 4000.0, 1000.0, 0.0, |_, v| {
                n += 1.0;
                sum += v;
                sum2 += v * v;
            });
        }
        let mean = sum / n;
        let var = sum2 / n - mean * mean;
        assert!((mean - 2040.0).abs() < 2.0, "{mean}");
        // 610 DN² plus the dither's and the rounding's 1/6; 3200 samples
        // give the variance to about 2.5 %.
        assert!((var / 610.2 - 1.0).abs() < 0.1, "{var}");
        // Without it, only the dither and the rounding: under 1 DN².
        let quiet = bench();
        let (mut n, mut sum, mut sum2) = (0.0, 0.0, 0.0);
        for _ in 0..100 {
            quiet.expose((4, 2, 0, 0), 4000.0, 1000.0, 0.0, |_, v| {
                n += 1.0;
                sum += v;
                sum2 += v * v;
            });
        }
        assert!(sum2 / n - (sum / n).powi(2) < 1.0);
    }

    #[test]
    fn pixels_outside_the_wall_image_are_dark_and_values_clamp_at_full_scale() {
        let s = bench();
        s.select("A", Some(0.0));
        let mut values = Vec::new();
        s.expose((2, 2, 3, 1), 1000.0, 4000.0, 0.0, |i, v| {
            values.push((i, v))
        });
        // (3, 1) is in the image (saturated: 0.51 * 4 > 1); (4, 1) is outside it.
        assert_eq!(values[0], (0, 1000.0));
        assert!((values[1].1 - 40.0).abs() <= 0.5);
        assert!(values[2..].iter().all(|&(_, v)| (v - 40.0).abs() <= 0.5));
    }
}
