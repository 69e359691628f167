//! An in-process camera with no Aravis behind it: the same demo bench as
//! [`super::fake`], exposed straight into [`RawFrame`]s.
//!
//! It lets the daemon and its HTTP routes be tested in-process (no UDP
//! socket, no GigE Vision), and lets a library user drive polnlos from any
//! frame source. The camera path itself is tested through Aravis's fake camera.

use std::sync::{Arc, Mutex};
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use super::device::{FrameCounts, FrameSink};
use super::settings::{CameraRanges, SensorLimits};
use super::shown::{BenchImages, Shown};
use super::worker::Opener;
use super::{Acquisition, CameraDevice, CameraError, CameraInfo, Counters, RawFrame};
use crate::rig::bench::Bench;

/// Sensor width and height of the synthetic camera.
const SENSOR: u32 = 512;

/// A demo bench whose camera runs in this process.
pub(crate) struct SyntheticBench {
    shown: Arc<Shown>,
    /// Settings of the camera, kept across reopenings like a real camera's.
    settings: Arc<Mutex<Acquisition>>,
}

impl SyntheticBench {
    /// A bench showing `frames` (per pose and polarizer angle, in fractions
    /// of full scale at `reference_exposure_us`).
    pub fn new(images: BenchImages, reference_exposure_us: f64) -> Self {
        Self {
            shown: Arc::new(Shown::new(images, reference_exposure_us)),
            settings: Arc::new(Mutex::new(Acquisition::defaults_at(
                [0, 0, SENSOR, SENSOR],
                [1, 1],
            ))),
        }
    }

    /// Gives the camera a sensor's shot and read noise (see
    /// `Shown::set_sensor_noise`); without it its frames carry only dither.
    pub fn with_sensor_noise(self, full_well_e: f64, read_noise_e: f64) -> Self {
        self.shown.set_sensor_noise(full_well_e, read_noise_e);
        self
    }

    /// Opens this bench's camera (what [`super::worker::CameraHandle::spawn`] takes).
    pub fn opener(&self) -> Opener {
        let shown = self.shown.clone();
        let settings = self.settings.clone();
        Box::new(move || {
            Ok(Box::new(SyntheticCamera {
                shown: shown.clone(),
                settings: settings.clone(),
                counters: Counters {
                    connects: 1,
                    ..Counters::default()
                },
                frame_id: 0,
            }) as Box<dyn CameraDevice>)
        })
    }
}

impl Bench for SyntheticBench {
    fn select(&self, pose: &str, polarizer_deg: Option<f64>) {
        self.shown.select(pose, polarizer_deg);
    }
    fn scene_on(&self, on: bool) {
        self.shown.scene_on(on);
    }
    fn show_target(&self, on: bool) {
        self.shown.show_target(on);
    }
    fn show_source(&self, on: bool) {
        self.shown.show_source(on);
    }
    fn switches_scene(&self) -> bool {
        true
    }
}

/// The camera of a [`SyntheticBench`].
struct SyntheticCamera {
    shown: Arc<Shown>,
    settings: Arc<Mutex<Acquisition>>,
    counters: Counters,
    frame_id: u64,
}

impl SyntheticCamera {
    fn limits() -> SensorLimits {
        SensorLimits {
            sensor: [SENSOR, SENSOR],
            min_size: [1, 1],
            size_increment: [1, 1],
            offset_increment: [1, 1],
            max_binning: [1, 1],
        }
    }

    fn settings(&self) -> Acquisition {
        self.settings
            .lock()
            .map(|s| *s)
            .unwrap_or_else(|e| *e.into_inner())
    }
}

impl CameraDevice for SyntheticCamera {
    fn describe(&mut self) -> Result<CameraInfo, CameraError> {
        Ok(CameraInfo {
            id: "polnlos-Synthetic-POLNLOS-DEMO".into(),
            address: "in-process".into(),
            vendor: "polnlos".into(),
            model: "Synthetic".into(),
            serial: "POLNLOS-DEMO".into(),
            sensor: (SENSOR as i32, SENSOR as i32),
            ranges: CameraRanges::synthetic(),
            frame_rate: None,
            pixel_formats: vec!["Mono8".into(), "Mono16".into()],
            mosaic: None,
            bayer: None,
            limits: Self::limits(),
            settings: self.settings(),
        })
    }

    fn configure(&mut self, s: &Acquisition) -> Result<(), CameraError> {
        Self::limits().check(s.region, s.binning)?;
        CameraError::check_ranges(s, &CameraRanges::synthetic())?;
        *self.settings.lock().unwrap_or_else(|e| e.into_inner()) = *s;
        Ok(())
    }

    fn acquire(&mut self, n: usize, sink: &mut FrameSink<'_>) -> Result<FrameCounts, CameraError> {
        let s = self.settings();
        let [ox, oy, w, h] = s.region;
        let (w, h) = (w as usize, h as usize);
        let full = s.pixel_format.full_scale();
        for _ in 0..n {
            // A real camera takes its exposure's time per frame.
            std::thread::sleep(Duration::from_secs_f64(s.exposure_us * 1e-6));
            let mut pixels = vec![0u16; w * h];
            self.shown.expose(
                (w, h, ox as usize, oy as usize),
                full,
                s.exposure_us,
                s.gain,
                |i, v| {
                    if let Some(p) = pixels.get_mut(i) {
                        *p = v as u16;
                    }
                },
            );
            self.frame_id += 1;
            self.counters.completed += 1;
            let system_timestamp_ns = SystemTime::now()
                .duration_since(UNIX_EPOCH)
                .map_or(0, |d| d.as_nanos() as u64);
            sink(RawFrame {
                width: w,
                height: h,
                bits: s.pixel_format.bits(),
                pixels,
                frame_id: self.frame_id & 0xffff,
                system_timestamp_ns,
            })
            .map_err(CameraError::Stopped)?;
        }
        Ok(FrameCounts {
            received: n as u64,
            ..FrameCounts::default()
        })
    }

    fn counters(&self) -> Counters {
        self.counters
    }
}
