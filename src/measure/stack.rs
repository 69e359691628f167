//! Frames to the measurement vector `i` (MODEL.md "From camera frames to i"):
//! each wall element the footprint-weighted mean of the pixels that image it
//! through its pose's homography, in fractions of full scale per
//! microsecond, stacked in block order, with the variance of each element
//! (propagated from its pixels') when every block has one.
//!
//! The variance of a mean of frames is not the frame-to-frame variance over
//! the frame count alone: where the noise per frame is below one DN the
//! digitizer does not dither, every frame rounds the same way, and the mean
//! keeps a bias of up to half a DN that no number of frames averages away
//! (and that the sample variance does not see). Each element's variance
//! therefore adds that bias's variance, per pixel before the pixels are averaged, `(1/12) exp(-2 pi^2 s^2)` DN² for a
//! per-frame noise of `s` DN (the residual of Gaussian-dithered rounding:
//! the first Fourier term of the quantizer's error, Widrow & Kollár 2008).

use std::collections::HashMap;
use std::sync::{Arc, Mutex};

use super::MeasureError;
use crate::scene::{Cells, Frame, FrameGeometry, Homography, PixelMap, Plane};

/// One (pose, polarizer angle) block's frames, as a capture gives them.
#[derive(Debug, Clone, Copy)]
pub struct BlockFrames<'a> {
    /// Pose name (for errors and the map cache).
    pub pose: &'a str,
    /// The pose's camera→wall homography.
    pub homography: &'a Homography,
    /// The pixels it averages: a mosaic block's micro-polarizer, or
    /// [`Cells::ALL`].
    pub cells: Cells,
    /// For one colour of a Bayer sensor, that colour's pixels: every pixel
    /// of the element then takes its value from them by interpolation
    /// ([`PixelMap::interpolated`]).
    pub colour: Option<Cells>,
    /// Mean dark-subtracted frame, DN.
    pub mean: &'a Frame,
    /// Variance of the mean frame, DN², when the capture had 2 frames or more.
    pub variance: Option<&'a Frame>,
    /// Frames averaged into the mean (for the quantization floor of the variance).
    pub frames: usize,
    /// Full scale of the pixel format, DN.
    pub full_scale: f64,
    /// Exposure per frame, microseconds.
    pub exposure_us: f64,
    /// The frame's region offset on the sensor, unbinned pixels.
    pub offset: [u32; 2],
    /// The frame's binning.
    pub binning: [u32; 2],
}

impl BlockFrames<'_> {
    /// Where the frame's pixels lie on the sensor.
    pub fn geometry(&self) -> FrameGeometry {
        FrameGeometry {
            offset: self.offset,
            size: [self.mean.width, self.mean.height],
            binning: self.binning,
        }
    }
}

/// What a pixel map is made for: pose, frame and the cells it averages.
type MapKey = (String, FrameGeometry, Cells, Option<Cells>);

/// A stacked measurement.
#[derive(Debug, Clone, PartialEq)]
pub struct Measurement {
    /// `i`, fractions of full scale per microsecond, MODEL.md row order.
    pub i: Vec<f64>,
    /// Variance of each element of `i`, when every block had one.
    pub variance: Option<Vec<f64>>,
}

impl Measurement {
    /// Its rows that were not measured (NaN) set to 0 with variance 0
    /// (`crate::solve::zero_unmeasured`); returns their indices.
    pub fn zero_unmeasured(&mut self) -> Vec<usize> {
        crate::solve::zero_unmeasured(&mut self.i, self.variance.as_deref_mut())
    }
}

/// The pixel maps of a scene's poses, made once per (pose, frame geometry,
/// mosaic cell) and shared: a map costs a pass over the wall's image, a measurement
/// with it one pass over the frame (MODEL.md "From camera frames to i").
#[derive(Debug, Default)]
pub struct PixelMaps {
    maps: Mutex<HashMap<MapKey, Arc<PixelMap>>>,
}

impl PixelMaps {
    /// The map of `pose` (homography `h`) for frames of `geometry`, made on first use.
    pub fn get(
        &self,
        pose: &str,
        h: &Homography,
        wall: &Plane,
        geometry: FrameGeometry,
        cells: Cells,
        colour: Option<Cells>,
    ) -> Result<Arc<PixelMap>, MeasureError> {
        let key = (pose.to_string(), geometry, cells, colour);
        if let Some(m) = self.lock().get(&key) {
            return Ok(Arc::clone(m));
        }
        let map = PixelMap::cell_frame(h, wall, geometry, cells, pose)?;
        let map = Arc::new(match colour {
            None => map,
            Some(colour) => map.interpolated(colour).ok_or_else(|| MeasureError::Capture {
                capture: format!("pose {pose:?}"),
                reason: format!(
                    "its frames are binned {:?}: a binned pixel of a colour sensor mixes its colours; capture with binning [1, 1]",
                    geometry.binning
                ),
            })?,
        });
        self.lock().insert(key, Arc::clone(&map));
        Ok(map)
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, HashMap<MapKey, Arc<PixelMap>>> {
        // A panic while inserting leaves at worst a missing entry: the map stays usable.
        self.maps
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }
}

/// Stacks `blocks` (in MODEL.md block order) into a measurement: each wall
/// element the footprint-weighted mean of its pixels, its variance propagated
/// from theirs; dividing by full scale and exposure makes captures of
/// different exposures and pixel formats comparable, and variances scale by
/// the square of the same factor.
pub fn stack(
    blocks: &[BlockFrames<'_>],
    wall: &Plane,
    maps: &PixelMaps,
) -> Result<Measurement, MeasureError> {
    let mut i = Vec::with_capacity(blocks.len() * wall.grid.count());
    let mut variance = Some(Vec::with_capacity(i.capacity()));
    for b in blocks {
        let map = maps.get(b.pose, b.homography, wall, b.geometry(), b.cells, b.colour)?;
        if let Some(v) = b.variance {
            if (v.width, v.height) != (b.mean.width, b.mean.height) {
                return Err(MeasureError::VarianceSize {
                    pose: b.pose.to_string(),
                    variance: [v.width, v.height],
                    mean: [b.mean.width, b.mean.height],
                });
            }
        }
        let n = b.frames.max(1) as f64;
        let var_of = b
            .variance
            .map(|v| move |p: usize| with_rounding_bias(f64::from(v.pixels[p]), n));
        let (values, vars) = map.average(
            &b.mean.pixels,
            var_of.as_ref().map(|f| f as &(dyn Fn(usize) -> f64 + Sync)),
        );
        let to_units = 1.0 / b.full_scale / b.exposure_us;
        i.extend(values.into_iter().map(|v| v * to_units));
        match (vars, variance.as_mut()) {
            (Some(v), Some(acc)) => acc.extend(v.into_iter().map(|v| v * to_units * to_units)),
            _ => variance = None,
        }
    }
    Ok(Measurement { i, variance })
}

/// The variance of a mean of `n` frames, `var_mean` DN² as measured, plus the
/// variance of the rounding bias the mean keeps when the per-frame noise
/// `s = sqrt(n var_mean)` does not dither the digitizer (module docs).
pub fn with_rounding_bias(var_mean: f64, n: f64) -> f64 {
    let var_mean = var_mean.max(0.0);
    let s2 = n * var_mean;
    var_mean + (-2.0 * std::f64::consts::PI.powi(2) * s2).exp() / 12.0
}

#[cfg(test)]
mod tests {
    use super::*;

    fn wall() -> Plane {
        match crate::scene::Scene::builtin("brewster-multi-3x3") {
            Some(Ok(s)) => s.wall().plane.clone(),
            _ => panic!("built-in scene"),
        }
    }

    fn flat(value: f32) -> Frame {
        Frame {
            width: 512,
            height: 512,
            pixels: vec![value; 512 * 512],
        }
    }

    fn homography() -> Homography {
        match crate::scene::Scene::builtin("brewster-multi-3x3") {
            Some(Ok(s)) => s.poses()[0].homography.expect("pose B has a homography"),
            _ => panic!("built-in scene"),
        }
    }

    #[test]
    fn blocks_stack_in_order_in_units_of_full_scale_per_microsecond() {
        let (w, h) = (wall(), homography());
        let (a, b, var) = (flat(1000.0), flat(500.0), flat(4.0));
        let block = |mean, variance, exposure_us| BlockFrames {
            pose: "B",
            homography: &h,
            cells: Cells::ALL,
            colour: None,
            mean,
            variance,
            frames: 8,
            full_scale: 1000.0,
            exposure_us,
            offset: [0, 0],
            binning: [1, 1],
        };
        let maps = PixelMaps::default();
        let m = stack(
            &[block(&a, Some(&var), 10.0), block(&b, Some(&var), 5.0)],
            &w,
            &maps,
        )
        .expect("inside the frame");
        let n = w.grid.nu * w.grid.nv;
        assert_eq!(m.i.len(), 2 * n);
        // 1000 DN of 1000 in 10 us and 500 DN in 5 us: both 0.1 per us.
        assert!(m.i.iter().all(|v| (v - 0.1).abs() < 1e-12), "{:?}", m.i);
        // 4 DN² per pixel, averaged over element 0's pixels: 4 sum w_p².
        let map = maps
            .get(
                "B",
                &h,
                &w,
                FrameGeometry::plain(512, 512),
                Cells::ALL,
                None,
            )
            .expect("cached");
        let w2: f64 = map.weights()[map.range(0)].iter().map(|w| w * w).sum();
        assert!(w2 < 1.0 / 20.0, "element 0 has dozens of pixels: {w2}");
        let var = m.variance.expect("both blocks have a variance");
        assert!((var[0] - 4.0 * w2 / 1e8).abs() < 1e-20);
        assert!((var[n] - 4.0 * w2 / 1e6 / 25.0).abs() < 1e-20);
        // One block without a variance: the measurement has none.
        let m = stack(
            &[block(&a, Some(&var_frame()), 10.0), block(&b, None, 5.0)],
            &w,
            &maps,
        );
        assert_eq!(m.expect("inside").variance, None);
    }

    /// A frame of seeded values, smooth plus a checker, and its variance.
    fn textured(seed: u64) -> (Frame, Frame) {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let mut f = flat(0.0);
        let mut v = flat(0.0);
        for y in 0..512 {
            for x in 0..512 {
                let k = y * 512 + x;
                f.pixels[k] =
                    (100.0 + 0.3 * x as f64 + 50.0 * ((x + y) % 2) as f64 + rng.random::<f64>())
                        as f32;
                v.pixels[k] = (1.0 + rng.random::<f64>() * 9.0) as f32;
            }
        }
        (f, v)
    }

    #[test]
    fn each_element_is_the_footprint_weighted_mean_of_its_pixels() {
        let (w, h) = (wall(), homography());
        let (f, var) = textured(3);
        let b = BlockFrames {
            pose: "B",
            homography: &h,
            cells: Cells::ALL,
            colour: None,
            mean: &f,
            variance: Some(&var),
            frames: 1,
            full_scale: 1.0,
            exposure_us: 1.0,
            offset: [0, 0],
            binning: [1, 1],
        };
        let m = stack(&[b], &w, &PixelMaps::default()).expect("inside");
        let var_m = m.variance.expect("variance given");
        // MODEL.md's sums, written out pixel by pixel.
        let inv = h.inverse_matrix();
        let n = w.grid.count();
        let (mut ax, mut a, mut a2v) = (vec![0.0; n], vec![0.0; n], vec![0.0; n]);
        for y in 0..512 {
            for x in 0..512 {
                let (u, v) = h.invert(x as f64, y as f64).expect("finite");
                let fu = (u / w.size[0] + 0.5) * w.grid.nu as f64;
                let fv = (v / w.size[1] + 0.5) * w.grid.nv as f64;
                if !(fu >= 0.0 && fv >= 0.0 && fu < w.grid.nu as f64 && fv < w.grid.nv as f64) {
                    continue;
                }
                let j = w.grid.index(fu as usize, fv as usize);
                let ww = inv[2][0] * x as f64 + inv[2][1] * y as f64 + inv[2][2];
                let ap = h.inverse_determinant().abs() / ww.abs().powi(3);
                let k = y * 512 + x;
                ax[j] += ap * f64::from(f.pixels[k]);
                a[j] += ap;
                a2v[j] += ap * ap * with_rounding_bias(f64::from(var.pixels[k]), 1.0);
            }
        }
        for j in 0..n {
            let (want, want_var) = (ax[j] / a[j], a2v[j] / (a[j] * a[j]));
            assert!(
                (m.i[j] - want).abs() <= 1e-9 * want,
                "{j}: {} {want}",
                m.i[j]
            );
            assert!((var_m[j] - want_var).abs() <= 1e-9 * want_var, "{j}");
        }
    }

    #[test]
    fn flat_frames_keep_every_pixels_photons_and_say_their_true_noise() {
        use rand::SeedableRng;
        use rand_distr::{Distribution, Normal};
        let (w, h) = (wall(), homography());
        let sigma = 200.0;
        let noise = Normal::new(0.0, sigma).expect("a normal");
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let var = flat((sigma * sigma) as f32);
        let maps = PixelMaps::default();
        let reps = 48;
        let n = w.grid.count();
        let (mut s1, mut s2) = (vec![0.0; n], vec![0.0; n]);
        let mut reported = Vec::new();
        for _ in 0..reps {
            let mut f = flat(5000.0);
            f.pixels
                .iter_mut()
                .for_each(|p| *p += noise.sample(&mut rng) as f32);
            let b = BlockFrames {
                pose: "B",
                homography: &h,
                cells: Cells::ALL,
                colour: None,
                mean: &f,
                variance: Some(&var),
                frames: 1,
                full_scale: 1.0,
                exposure_us: 1.0,
                offset: [0, 0],
                binning: [1, 1],
            };
            let m = stack(&[b], &w, &maps).expect("inside");
            for j in 0..n {
                s1[j] += m.i[j];
                s2[j] += m.i[j] * m.i[j];
            }
            reported = m.variance.expect("given");
        }
        let map = maps
            .get(
                "B",
                &h,
                &w,
                FrameGeometry::plain(512, 512),
                Cells::ALL,
                None,
            )
            .expect("cached");
        let (mut ratio, mut worst) = (0.0, 0.0f64);
        for j in 0..n {
            let mean = s1[j] / reps as f64;
            let observed = (s2[j] - reps as f64 * mean * mean) / (reps as f64 - 1.0);
            ratio += observed / reported[j] / n as f64;
            // Against the ideal of averaging the element's pixels equally.
            let ideal = sigma / (map.range(j).len() as f64).sqrt();
            worst = worst.max(reported[j].sqrt() / ideal);
        }
        // The reported variance is the scatter observed (48 repeats: 0.6 % over the elements).
        assert!((ratio - 1.0).abs() < 0.05, "observed / reported {ratio}");
        // The footprint weights cost almost nothing against equal weights.
        assert!(worst <= 1.3, "worst element noise {worst} x the ideal");
    }

    #[test]
    fn the_variance_keeps_the_rounding_bias_that_frames_do_not_average() {
        // Noiseless frames: the mean is known to the digitizer's 1/12 DN², not 0.
        assert!((with_rounding_bias(0.0, 32.0) - 1.0 / 12.0).abs() < 1e-15);
        // 0.2 DN of noise per frame dithers a little: part of the floor remains.
        let b = with_rounding_bias(0.04 / 32.0, 32.0) - 0.04 / 32.0;
        assert!(b > 0.01 && b < 1.0 / 12.0, "{b}");
        // 2 DN per frame dithers fully: the measured variance stands.
        let v = 4.0 / 32.0;
        assert!((with_rounding_bias(v, 32.0) - v).abs() < 1e-30);
    }

    fn var_frame() -> Frame {
        flat(1.0)
    }

    #[test]
    fn a_frame_too_small_for_the_homography_is_an_error_naming_the_pose() {
        let (w, h) = (wall(), homography());
        let small = Frame {
            width: 16,
            height: 16,
            pixels: vec![0.0; 256],
        };
        let block = BlockFrames {
            pose: "B",
            homography: &h,
            cells: Cells::ALL,
            colour: None,
            mean: &small,
            variance: None,
            frames: 1,
            full_scale: 1.0,
            exposure_us: 1.0,
            offset: [0, 0],
            binning: [1, 1],
        };
        let e = stack(&[block], &w, &PixelMaps::default()).expect_err("outside");
        assert!(e.to_string().starts_with("pose \"B\""), "{e}");
    }
}
