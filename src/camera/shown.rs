//! The hidden scene as a demo bench shows it: the wall image of every
//! (pose, polarizer angle) block, which block the bench has selected, and
//! whether the scene is lit. Both demo cameras expose frames from it: Aravis's
//! fake camera ([`super::fake`]) and the in-process one ([`super::synthetic`]).

use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Mutex;

use super::Frame;

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
}

/// Wall images per block and the bench's state.
pub struct Shown {
    /// Wall frames per block, in fractions of full scale at the reference exposure.
    frames: HashMap<String, Frame>,
    /// The target's image per block.
    targets: HashMap<String, Frame>,
    /// The point source's image per block.
    sources: HashMap<String, Frame>,
    source_on: AtomicBool,
    selected: Mutex<Option<String>>,
    scene_on: AtomicBool,
    target_on: AtomicBool,
    reference_exposure_us: f64,
    /// Dark level, fraction of full scale at the reference exposure.
    dark_level: f64,
    counter: AtomicU64,
}

impl Shown {
    /// A bench showing `images` (scaled to `reference_exposure_us`), the
    /// scene lit, the target away, nothing selected.
    pub fn new(images: BenchImages, reference_exposure_us: f64) -> Self {
        let keyed = |v: Vec<(String, Option<f64>, Frame)>| {
            v.into_iter()
                .map(|(p, d, f)| (key(&p, d), f))
                .collect::<HashMap<_, _>>()
        };
        Self {
            frames: keyed(images.scene),
            targets: keyed(images.target),
            sources: keyed(images.source),
            source_on: AtomicBool::new(false),
            selected: Mutex::new(None),
            scene_on: AtomicBool::new(true),
            target_on: AtomicBool::new(false),
            reference_exposure_us,
            dark_level: 0.01,
            counter: AtomicU64::new(0),
        }
    }

    /// Moves the bench to a block.
    pub fn select(&self, pose: &str, polarizer_deg: Option<f64>) {
        if let Ok(mut s) = self.selected.lock() {
            *s = Some(key(pose, polarizer_deg));
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
    /// and with `1 + 0.1 gain`.
    pub fn expose(
        &self,
        (w, h, ox, oy): (usize, usize, usize, usize),
        full: f64,
        exposure_us: f64,
        gain: f64,
        mut put: impl FnMut(usize, f64),
    ) {
        let scale = exposure_us / self.reference_exposure_us * (1.0 + 0.1 * gain);
        let selected = self.selected.lock().ok().and_then(|s| s.clone());
        let frame = if self.target_on.load(Ordering::SeqCst) {
            selected.and_then(|k| self.targets.get(&k))
        } else if self.source_on.load(Ordering::SeqCst) {
            selected.and_then(|k| self.sources.get(&k))
        } else if self.scene_on.load(Ordering::SeqCst) {
            selected.and_then(|k| self.frames.get(&k))
        } else {
            None
        };
        let mut seed = self
            .counter
            .fetch_add(1, Ordering::Relaxed)
            .wrapping_mul(0x9E37_79B9_7F4A_7C15)
            | 1;
        for y in 0..h {
            for x in 0..w {
                let signal = frame
                    .and_then(|f| {
                        let (fx, fy) = (x.checked_add(ox)?, y.checked_add(oy)?);
                        (fx < f.width && fy < f.height)
                            .then(|| f.pixels.get(fy * f.width + fx))
                            .flatten()
                            .map(|&p| f64::from(p))
                    })
                    .unwrap_or(0.0);
                seed ^= seed << 13;
                seed ^= seed >> 7;
                seed ^= seed << 17;
                let dither = (seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5;
                let v = ((self.dark_level + signal) * scale * full + dither)
                    .round()
                    .clamp(0.0, full);
                put(y * w + x, v);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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
        // Nothing selected: the dark level only (0.01 of full scale).
        assert!((mean(&s, 1000.0) - 10.0).abs() <= 0.5);
        s.select("A", Some(0.0));
        assert!((mean(&s, 1000.0) - 510.0).abs() <= 0.5);
        assert!((mean(&s, 500.0) - 255.0).abs() <= 0.5);
        s.scene_on(false);
        assert!((mean(&s, 1000.0) - 10.0).abs() <= 0.5);
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
