//! GenICam cameras through Aravis (libaravis 0.8).
//!
//! Features are set by their SFNC names with the older names as fallback
//! (`ExposureTime`/`ExposureTimeAbs`, `Gain`/`GainRaw`,
//! `AcquisitionFrameRate`/`AcquisitionFrameRateAbs`), so the same code drives
//! real cameras and Aravis's fake camera. Cameras are opened by explicit id or
//! address only: polnlos never broadcasts a GigE Vision discovery.

use std::time::{Duration, SystemTime, UNIX_EPOCH};

use aravis::prelude::*;
use aravis::{AcquisitionMode, BufferStatus, Camera};

use super::device::{CameraDevice, CameraError, CameraInfo, Counters, RawFrame};
use super::settings::{CameraSettings, PixelFormat, TriggerMode};

/// Buffers queued on the stream at most.
const MAX_BUFFERS: usize = 16;

/// A camera opened through Aravis.
pub struct AravisCamera {
    id: String,
    camera: Camera,
    exposure_feature: &'static str,
    gain_feature: &'static str,
    gain_is_integer: bool,
    frame_rate_feature: Option<&'static str>,
    settings: CameraSettings,
    counters: Counters,
    /// Frame period of the previous acquisition: the first frame after a
    /// change can take up to one old period.
    last_period_s: f64,
}

fn driver(e: aravis::glib::Error) -> CameraError {
    CameraError::Driver(e.message().to_string())
}

fn feature_err(feature: &str) -> impl Fn(aravis::glib::Error) -> CameraError + '_ {
    move |e| CameraError::Feature {
        feature: feature.to_string(),
        reason: e.message().to_string(),
    }
}

impl AravisCamera {
    /// Opens the camera with this device id or IP address (unicast; no discovery).
    pub fn open(id: &str) -> Result<Self, CameraError> {
        let camera = Camera::new(Some(id)).map_err(|e| CameraError::Open {
            id: id.to_string(),
            reason: e.message().to_string(),
        })?;
        let available = |name: &str| {
            camera
                .device()
                .map(|d| d.is_feature_available(name).unwrap_or(false))
                .unwrap_or(false)
        };
        let exposure_feature = ["ExposureTime", "ExposureTimeAbs"]
            .into_iter()
            .find(|n| available(n))
            .ok_or_else(|| CameraError::MissingFeature {
                names: "ExposureTime or ExposureTimeAbs".into(),
            })?;
        let (gain_feature, gain_is_integer) = if available("Gain") {
            ("Gain", false)
        } else if available("GainRaw") {
            ("GainRaw", true)
        } else {
            return Err(CameraError::MissingFeature {
                names: "Gain or GainRaw".into(),
            });
        };
        let frame_rate_feature = ["AcquisitionFrameRate", "AcquisitionFrameRateAbs"]
            .into_iter()
            .find(|n| available(n));
        let mut cam = Self {
            id: id.to_string(),
            camera,
            exposure_feature,
            gain_feature,
            gain_is_integer,
            frame_rate_feature,
            settings: CameraSettings::default(),
            counters: Counters {
                connects: 1,
                ..Counters::default()
            },
            last_period_s: 1.0,
        };
        cam.configure(&CameraSettings::default())?;
        Ok(cam)
    }

    /// The current value of a string or enumeration feature (for diagnostics).
    pub fn string_feature(&self, name: &str) -> Result<String, CameraError> {
        self.device()?
            .string_feature_value(name)
            .map(|g| g.to_string())
            .map_err(feature_err(name))
    }

    fn device(&self) -> Result<aravis::Device, CameraError> {
        self.camera
            .device()
            .ok_or_else(|| CameraError::Disconnected(format!("{} has no device", self.id)))
    }

    fn float_bounds(&self, feature: &str) -> Result<(f64, f64), CameraError> {
        self.device()?
            .float_feature_bounds(feature)
            .map_err(feature_err(feature))
    }

    fn gain_bounds(&self) -> Result<(f64, f64), CameraError> {
        let d = self.device()?;
        if self.gain_is_integer {
            let (a, b) = d
                .integer_feature_bounds(self.gain_feature)
                .map_err(feature_err(self.gain_feature))?;
            Ok((a as f64, b as f64))
        } else {
            d.float_feature_bounds(self.gain_feature)
                .map_err(feature_err(self.gain_feature))
        }
    }

    /// Sets the frame rate to match the exposure (free run) and returns the period.
    fn match_frame_rate(&mut self) -> Result<f64, CameraError> {
        let Some(feature) = self.frame_rate_feature else {
            return Ok((self.settings.exposure_us * 1e-6).max(0.001));
        };
        let d = self.device()?;
        let _ = d.set_boolean_feature_value("AcquisitionFrameRateEnable", true);
        let (lo, hi) = d
            .float_feature_bounds(feature)
            .map_err(feature_err(feature))?;
        let want = (1e6 / self.settings.exposure_us).clamp(lo, hi);
        d.set_float_feature_value(feature, want)
            .map_err(feature_err(feature))?;
        let got = d
            .float_feature_value(feature)
            .map_err(feature_err(feature))?;
        Ok(1.0 / got.max(1e-6))
    }

    fn check(feature: &str, value: f64, (min, max): (f64, f64)) -> Result<(), CameraError> {
        if !(value >= min && value <= max) {
            return Err(CameraError::OutOfRange {
                feature: feature.to_string(),
                value,
                min,
                max,
            });
        }
        Ok(())
    }
}

impl CameraDevice for AravisCamera {
    fn describe(&mut self) -> Result<CameraInfo, CameraError> {
        let c = &self.camera;
        let s = |r: Result<aravis::glib::GString, aravis::glib::Error>| {
            r.map(|g| g.to_string()).unwrap_or_default()
        };
        Ok(CameraInfo {
            id: self.id.clone(),
            vendor: s(c.vendor_name()),
            model: s(c.model_name()),
            serial: s(c.device_serial_number()),
            sensor: c.sensor_size().map_err(driver)?,
            exposure_us: self.float_bounds(self.exposure_feature)?,
            exposure_feature: self.exposure_feature.into(),
            gain: self.gain_bounds()?,
            gain_feature: self.gain_feature.into(),
            frame_rate: self
                .frame_rate_feature
                .and_then(|f| self.float_bounds(f).ok()),
            pixel_formats: c
                .dup_available_pixel_formats_as_strings()
                .map(|v| v.into_iter().map(|g| g.to_string()).collect())
                .unwrap_or_default(),
            settings: self.settings.clone(),
        })
    }

    fn configure(&mut self, s: &CameraSettings) -> Result<(), CameraError> {
        let d = self.device()?;
        let eb = self.float_bounds(self.exposure_feature)?;
        Self::check(self.exposure_feature, s.exposure_us, eb)?;
        let gb = self.gain_bounds()?;
        Self::check(self.gain_feature, s.gain, gb)?;
        let c = &self.camera;
        c.set_pixel_format_from_string(s.pixel_format.name())
            .map_err(feature_err("PixelFormat"))?;
        if let Some([bx, by]) = s.binning {
            c.set_binning(bx, by)
                .map_err(feature_err("BinningHorizontal/BinningVertical"))?;
        }
        // No region: keep the camera's own (the pose homographies are calibrated on it).
        if let Some([x, y, w, h]) = s.region {
            c.set_region(x, y, w, h)
                .map_err(feature_err("OffsetX/OffsetY/Width/Height"))?;
        }
        d.set_float_feature_value(self.exposure_feature, s.exposure_us)
            .map_err(feature_err(self.exposure_feature))?;
        if self.gain_is_integer {
            d.set_integer_feature_value(self.gain_feature, s.gain.round() as i64)
                .map_err(feature_err(self.gain_feature))?;
        } else {
            d.set_float_feature_value(self.gain_feature, s.gain)
                .map_err(feature_err(self.gain_feature))?;
        }
        match s.trigger {
            TriggerMode::Free => {
                if d.is_feature_available("TriggerMode").unwrap_or(false) {
                    d.set_string_feature_value("TriggerMode", "Off")
                        .map_err(feature_err("TriggerMode"))?;
                }
            }
            TriggerMode::Software => c
                .set_trigger("Software")
                .map_err(feature_err("TriggerMode/TriggerSource"))?,
        }
        self.settings = s.clone();
        Ok(())
    }

    fn acquire(
        &mut self,
        n: usize,
        on_frame: &mut dyn FnMut(usize),
    ) -> Result<Vec<RawFrame>, CameraError> {
        let period = self.match_frame_rate()?;
        let exposure_s = self.settings.exposure_us * 1e-6;
        // Long exposures must not time out; the first frame after a period change
        // can take up to one old period.
        let first_timeout =
            Duration::from_secs_f64(2.0 * period.max(exposure_s) + self.last_period_s + 1.0);
        let timeout = Duration::from_secs_f64(2.0 * period.max(exposure_s) + 1.0);
        let c = &self.camera;
        let payload = c.payload().map_err(driver)? as usize;
        let stream = c.create_stream().map_err(driver)?;
        for _ in 0..n.clamp(2, MAX_BUFFERS) {
            stream.push_buffer(aravis::Buffer::new_allocate(payload));
        }
        c.set_acquisition_mode(AcquisitionMode::Continuous)
            .map_err(feature_err("AcquisitionMode"))?;
        c.start_acquisition()
            .map_err(feature_err("AcquisitionStart"))?;
        let software = self.settings.trigger == TriggerMode::Software;
        let bits = self.settings.pixel_format.bits();
        let mut frames = Vec::with_capacity(n);
        let mut failures = 0;
        let result = loop {
            if frames.len() == n {
                break Ok(());
            }
            if software {
                if let Err(e) = c.software_trigger() {
                    break Err(feature_err("TriggerSoftware")(e));
                }
            }
            let wait = if frames.is_empty() {
                first_timeout
            } else {
                timeout
            };
            let Some(buffer) = stream.timeout_pop_buffer(wait.as_micros() as u64) else {
                self.counters.timeouts += 1;
                break Err(CameraError::Timeout {
                    timeout_ms: wait.as_millis() as u64,
                    got: frames.len(),
                    wanted: n,
                });
            };
            if buffer.status() != BufferStatus::Success {
                failures += 1;
                self.counters.failed += 1;
                stream.push_buffer(buffer);
                if failures > 2 * n + 4 {
                    break Err(CameraError::Driver(format!("{failures} broken buffers in a row; check the network or the camera's packet size")));
                }
                continue;
            }
            let (w, h) = (
                buffer.image_width() as usize,
                buffer.image_height() as usize,
            );
            let data = buffer.image_data();
            let pixels: Vec<u16> = if self.settings.pixel_format == PixelFormat::Mono8 {
                data.iter().take(w * h).map(|&b| u16::from(b)).collect()
            } else {
                data.chunks_exact(2)
                    .take(w * h)
                    .map(|p| u16::from_le_bytes([p[0], p[1]]))
                    .collect()
            };
            let frame_id = buffer.frame_id();
            stream.push_buffer(buffer);
            if pixels.len() != w * h {
                failures += 1;
                self.counters.failed += 1;
                continue;
            }
            let now = SystemTime::now()
                .duration_since(UNIX_EPOCH)
                .map(|d| d.as_nanos() as u64)
                .unwrap_or(0);
            frames.push(RawFrame {
                width: w,
                height: h,
                bits,
                pixels,
                frame_id,
                system_timestamp_ns: now,
            });
            self.counters.completed += 1;
            on_frame(frames.len());
        };
        let _ = c.stop_acquisition();
        let (_, _, underruns) = stream.statistics();
        self.counters.underruns += underruns;
        self.counters.missing_packets += stream.info_uint64_by_name("n_missing_packets");
        self.counters.resent_packets += stream.info_uint64_by_name("n_resent_packets");
        self.last_period_s = period;
        result.map(|()| frames)
    }

    fn counters(&self) -> Counters {
        self.counters
    }
}
