//! GenICam cameras through Aravis (libaravis 0.8).
//!
//! Features are set by their SFNC names with the older names as fallback
//! (the ranged settings' names in `RANGED`, and
//! `AcquisitionFrameRate`/`AcquisitionFrameRateAbs`), so the same code drives
//! real cameras and Aravis's fake camera. Cameras are opened by explicit id or
//! address only: polnlos never broadcasts a GigE Vision discovery.

use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use aravis::glib::object::Cast;
use aravis::prelude::*;
use aravis::{AcquisitionMode, BufferStatus, Camera};

use super::device::{
    BrokenLog, CameraDevice, CameraError, CameraInfo, Counters, FrameCounts, FrameIds, FrameSink,
    RawFrame,
};
use super::settings::{
    Acquisition, CameraRanges, FeatureKind, PixelFormat, SensorLimits, TriggerMode, RANGED,
};

/// Buffers queued on the stream: at least this many whatever the frame
/// count, so that frames arriving while earlier ones are decoded and handed
/// on find a free buffer (a 2-frame capture used to queue 2)...
const MIN_BUFFERS: usize = 8;
/// ...and at most this many...
const MAX_BUFFERS: usize = 32;
/// ...within this much memory (the daemon's memory must not grow with a
/// capture's frame count: tests/daemon/hostile.rs holds it to 64 MiB).
const BUFFER_BYTES: usize = 16 << 20;

/// Seconds a first frame may be late beyond its period (AcquisitionStart,
/// a period change, a busy host) before the camera counts as lost.
const FIRST_FRAME_SLACK_S: f64 = 5.0;
/// Seconds a later frame may be late beyond its period.
const FRAME_SLACK_S: f64 = 3.0;

/// How long a GigE Vision frame may wait for its missing packets before
/// Aravis gives it up as broken: Aravis's 100 ms broke frames whenever a busy
/// host (a solve on both cores) held the stream thread off mid-frame, and a
/// bench of long exposures has no use for the lower latency.
const FRAME_RETENTION_US: u32 = 1_000_000;

/// Frames of socket buffer asked for a GigE Vision stream: packets wait
/// there while the stream thread is held off, and the kernel drops what
/// does not fit. One frame (Aravis's `Auto`) broke 2 of 200 1 ms frames
/// under the test suite's load, since a camera that cannot resend (Aravis's
/// fake) loses every packet that overflows.
const SOCKET_BUFFER_FRAMES: usize = 4;
/// The socket buffer asked for is at least this (small frames arrive fast)...
const MIN_SOCKET_BUFFER: usize = 4 << 20;
/// ...and at most this (the kernel caps it at `net.core.rmem_max` anyway).
const MAX_SOCKET_BUFFER: usize = 64 << 20;

/// The receive buffer asked for a stream of frames of `payload` bytes.
fn socket_buffer_bytes(payload: usize) -> usize {
    payload
        .saturating_mul(SOCKET_BUFFER_FRAMES)
        .clamp(MIN_SOCKET_BUFFER, MAX_SOCKET_BUFFER)
}

/// The kernel's cap on a socket's receive buffer, when this is Linux.
fn read_rmem_max() -> Option<usize> {
    std::fs::read_to_string("/proc/sys/net/core/rmem_max")
        .ok()?
        .trim()
        .parse()
        .ok()
}

/// What to tell the operator when the kernel caps the stream's socket
/// buffer below two frames: why is in [`SOCKET_BUFFER_FRAMES`].
fn rmem_max_warning(asked: usize, payload: usize, rmem_max: Option<usize>) -> Option<String> {
    let cap = rmem_max?;
    // Linux doubles the value set (half is its bookkeeping).
    (cap < asked && cap < 2 * payload).then(|| {
        format!(
            "net.core.rmem_max is {cap} bytes, less than two {payload}-byte frames: packets that arrive while the stream thread is busy can be lost and their frames broken; as root, `sysctl -w net.core.rmem_max={asked}` (and in /etc/sysctl.d/ to keep it)"
        )
    })
}

/// Stream buffers for frames of `payload` bytes (see [`MIN_BUFFERS`]).
fn buffer_count(payload: usize) -> usize {
    (BUFFER_BYTES / payload.max(1)).clamp(MIN_BUFFERS, MAX_BUFFERS)
}

/// A camera opened through Aravis.
pub struct AravisCamera {
    id: String,
    camera: Camera,
    /// The feature found for each entry of [`RANGED`], in its order.
    ranged: Vec<(&'static str, FeatureKind)>,
    frame_rate_feature: Option<&'static str>,
    limits: SensorLimits,
    /// Settings read back after the last configure (what the camera has).
    settings: Acquisition,
    counters: Counters,
    /// Frame period of the previous acquisition: the first frame after a
    /// change can take up to one old period.
    last_period_s: f64,
    /// Whether the kernel's socket-buffer cap was checked (once per camera).
    warned_rmem: bool,
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
        let ranged = RANGED
            .iter()
            .map(|r| {
                r.features
                    .iter()
                    .copied()
                    .find(|(n, _)| available(n))
                    .ok_or_else(|| CameraError::MissingFeature {
                        names: r.feature_names(),
                    })
            })
            .collect::<Result<Vec<_>, _>>()?;
        let frame_rate_feature = ["AcquisitionFrameRate", "AcquisitionFrameRateAbs"]
            .into_iter()
            .find(|n| available(n));
        let limits = read_limits(&camera)?;
        let mut cam = Self {
            id: id.to_string(),
            camera,
            ranged,
            frame_rate_feature,
            limits,
            settings: Acquisition::defaults_at([0, 0, 0, 0], [1, 1]),
            counters: Counters {
                connects: 1,
                ..Counters::default()
            },
            last_period_s: 1.0,
            warned_rmem: false,
        };
        // Keep the camera's own region and binning (the pose homographies are
        // calibrated on them); everything else from the defaults.
        let (x, y, w, h) = cam
            .camera
            .region()
            .map_err(feature_err("OffsetX/OffsetY/Width/Height"))?;
        let binning = match cam.camera.is_binning_available() {
            Ok(true) => cam
                .camera
                .binning()
                .map(|(bx, by)| [to_u32(bx), to_u32(by)])
                .map_err(feature_err("BinningHorizontal/BinningVertical"))?,
            _ => [1, 1],
        };
        let mut current =
            Acquisition::defaults_at([to_u32(x), to_u32(y), to_u32(w), to_u32(h)], binning);
        // A polarization or colour camera keeps its raw-mosaic format: the
        // default monochrome one would read the same mosaic (or a grey the
        // camera made of it) under a name that hides it.
        if let Some(own) = cam
            .camera
            .pixel_format_as_string()
            .ok()
            .and_then(|f| PixelFormat::from_name(f.as_str()))
            .filter(|f| f.mosaic().is_some() || f.bayer().is_some())
        {
            current.pixel_format = own;
        }
        cam.configure(&current)?;
        Ok(cam)
    }

    /// What the camera has now: every setting read back from its features.
    fn read_settings(&self) -> Result<Acquisition, CameraError> {
        let c = &self.camera;
        let d = self.device()?;
        let format = c
            .pixel_format_as_string()
            .map_err(feature_err("PixelFormat"))?;
        let pixel_format =
            PixelFormat::from_name(format.as_str()).ok_or_else(|| CameraError::Feature {
                feature: "PixelFormat".into(),
                reason: format!(
                    "{format} is not a format polnlos reads ({})",
                    PixelFormat::names()
                ),
            })?;
        let (x, y, w, h) = c
            .region()
            .map_err(feature_err("OffsetX/OffsetY/Width/Height"))?;
        let binning = if c.is_binning_available().unwrap_or(false) {
            let (bx, by) = c
                .binning()
                .map_err(feature_err("BinningHorizontal/BinningVertical"))?;
            [to_u32(bx), to_u32(by)]
        } else {
            [1, 1]
        };
        let trigger_on = d.is_feature_available("TriggerMode").unwrap_or(false)
            && d.string_feature_value("TriggerMode")
                .map(|v| v.as_str() == "On")
                .unwrap_or(false);
        let software = trigger_on
            && c.trigger_source()
                .map(|v| v.as_str() == "Software")
                .unwrap_or(false);
        let mut settings = Acquisition {
            pixel_format,
            trigger: if software {
                TriggerMode::Software
            } else {
                TriggerMode::Free
            },
            ..Acquisition::defaults_at([to_u32(x), to_u32(y), to_u32(w), to_u32(h)], binning)
        };
        for (r, &(feature, kind)) in RANGED.iter().zip(&self.ranged) {
            *(r.value_mut)(&mut settings) = match kind {
                FeatureKind::Integer => d
                    .integer_feature_value(feature)
                    .map_err(feature_err(feature))? as f64,
                FeatureKind::Float => d
                    .float_feature_value(feature)
                    .map_err(feature_err(feature))?,
            };
        }
        Ok(settings)
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

    /// Each ranged setting's range, read from its feature now.
    fn ranges(&self) -> Result<CameraRanges, CameraError> {
        let d = self.device()?;
        let mut found = self.ranged.iter();
        CameraRanges::from_table(|_| {
            let Some(&(feature, kind)) = found.next() else {
                return Err(CameraError::Driver(
                    "a ranged setting without a feature".into(),
                ));
            };
            let range = match kind {
                FeatureKind::Integer => d
                    .integer_feature_bounds(feature)
                    .map(|(a, b)| (a as f64, b as f64)),
                FeatureKind::Float => d.float_feature_bounds(feature),
            };
            Ok((range.map_err(feature_err(feature))?, feature.to_string()))
        })
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
}

/// A feature value Aravis reports as `i32` that cannot be negative (0 if it is).
fn to_u32(v: i32) -> u32 {
    u32::try_from(v).unwrap_or(0)
}

/// Region and binning limits from the feature nodes. Minimum sizes and
/// increments do not depend on the current region; the sensor size is the
/// unbinned one.
fn read_limits(c: &Camera) -> Result<SensorLimits, CameraError> {
    let (sw, sh) = c
        .sensor_size()
        .map_err(feature_err("SensorWidth/SensorHeight"))?;
    let inc = |r: Result<i32, aravis::glib::Error>| r.map(to_u32).unwrap_or(1).max(1);
    let binning = if c.is_binning_available().unwrap_or(false) {
        let bx = c.x_binning_bounds().map(|b| to_u32(b.1)).unwrap_or(1);
        let by = c.y_binning_bounds().map(|b| to_u32(b.1)).unwrap_or(1);
        [bx.max(1), by.max(1)]
    } else {
        [1, 1]
    };
    let limits = SensorLimits {
        sensor: [to_u32(sw), to_u32(sh)],
        min_size: [
            c.width_bounds().map(|b| to_u32(b.0)).unwrap_or(1).max(1),
            c.height_bounds().map(|b| to_u32(b.0)).unwrap_or(1).max(1),
        ],
        size_increment: [inc(c.width_increment()), inc(c.height_increment())],
        offset_increment: [inc(c.x_offset_increment()), inc(c.y_offset_increment())],
        max_binning: binning,
    };
    if limits.sensor[0] == 0 || limits.sensor[1] == 0 {
        return Err(CameraError::Feature {
            feature: "SensorWidth/SensorHeight".into(),
            reason: format!("the camera reports a {sw} x {sh} sensor"),
        });
    }
    Ok(limits)
}

impl CameraDevice for AravisCamera {
    fn describe(&mut self) -> Result<CameraInfo, CameraError> {
        let c = &self.camera;
        let s = |r: Result<aravis::glib::GString, aravis::glib::Error>| {
            r.map(|g| g.to_string()).unwrap_or_default()
        };
        let (vendor, model, serial) = (
            s(c.vendor_name()),
            s(c.model_name()),
            s(c.device_serial_number()),
        );
        let pixel_formats: Vec<String> = c
            .dup_available_pixel_formats_as_strings()
            .map(|v| v.into_iter().map(|g| g.to_string()).collect())
            .unwrap_or_default();
        let settings = self.read_settings()?;
        Ok(CameraInfo {
            id: format!("{vendor}-{model}-{serial}"),
            address: self.id.clone(),
            vendor,
            model,
            serial,
            sensor: c.sensor_size().map_err(driver)?,
            ranges: self.ranges()?,
            frame_rate: self
                .frame_rate_feature
                .and_then(|f| self.float_bounds(f).ok()),
            mosaic: PixelFormat::sensor_mosaic(&pixel_formats, settings.pixel_format),
            bayer: settings.pixel_format.bayer(),
            pixel_formats,
            limits: self.limits,
            settings,
        })
    }

    fn configure(&mut self, s: &Acquisition) -> Result<(), CameraError> {
        // Region and binning are checked against the sensor before Aravis sees them.
        let (region, binning) = (s.region, s.binning);
        self.limits.check(region, binning)?;
        let d = self.device()?;
        CameraError::check_ranges(s, &self.ranges()?)?;
        let c = &self.camera;
        c.set_pixel_format_from_string(s.pixel_format.name())
            .map_err(feature_err("PixelFormat"))?;
        // Checked above: every value is at most the sensor size, so it fits i32.
        let i = |v: u32| i32::try_from(v).unwrap_or(i32::MAX);
        if c.is_binning_available().unwrap_or(false) {
            c.set_binning(i(binning[0]), i(binning[1]))
                .map_err(feature_err("BinningHorizontal/BinningVertical"))?;
        }
        let [x, y, w, h] = region;
        c.set_region(i(x), i(y), i(w), i(h))
            .map_err(feature_err("OffsetX/OffsetY/Width/Height"))?;
        for (r, &(feature, kind)) in RANGED.iter().zip(&self.ranged) {
            let v = (r.value)(s);
            let set = match kind {
                FeatureKind::Integer => d.set_integer_feature_value(feature, v.round() as i64),
                FeatureKind::Float => d.set_float_feature_value(feature, v),
            };
            set.map_err(feature_err(feature))?;
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
        self.settings = self.read_settings()?;
        if (self.settings.region, self.settings.binning) != (region, binning) {
            return Err(CameraError::Feature {
                feature: "OffsetX/OffsetY/Width/Height".into(),
                reason: format!(
                    "asked for region {region:?} at binning {binning:?}, the camera has {:?} at {:?}",
                    self.settings.region, self.settings.binning
                ),
            });
        }
        Ok(())
    }

    fn acquire(&mut self, n: usize, sink: &mut FrameSink<'_>) -> Result<FrameCounts, CameraError> {
        let period = self.match_frame_rate()?;
        let exposure_s = self.settings.exposure_us * 1e-6;
        // Long exposures must not time out; the first frame after a period change
        // can take up to one old period.
        // The slack: a busy host (a solve on every core) can hold the stream
        // thread off for a second; a frame that is only late is not a lost
        // camera (a 1 s slack failed a 20 ms capture under the test suite's load).
        let first_timeout = Duration::from_secs_f64(
            2.0 * period.max(exposure_s) + self.last_period_s + FIRST_FRAME_SLACK_S,
        );
        let timeout = Duration::from_secs_f64(2.0 * period.max(exposure_s) + FRAME_SLACK_S);
        let payload = self.camera.payload().map_err(driver)? as usize;
        let (mut stream, replaced) = start_stream(&self.camera, &mut self.warned_rmem, payload)?;
        self.counters.stream_restarts += replaced;
        // One new stream when the first frame does not come although packets
        // do, every one discarded ([`thrown_off`]).
        let mut restarted = false;
        let c = &self.camera;
        let software = self.settings.trigger == TriggerMode::Software;
        let bits = self.settings.pixel_format.bits();
        let mut taken = 0;
        let mut counts = FrameCounts::default();
        let mut ids = FrameIds::default();
        let mut broken_log = BrokenLog::default();
        // Broken buffers count as frames that did not arrive: the capture
        // fails when no whole frame came within the frame timeout.
        let mut last_whole = Instant::now();
        let result = loop {
            if taken == n {
                break Ok(counts);
            }
            if software {
                if let Err(e) = c.software_trigger() {
                    break Err(feature_err("TriggerSoftware")(e));
                }
            }
            let wait = if taken == 0 { first_timeout } else { timeout };
            let Some(buffer) = stream.timeout_pop_buffer(wait.as_micros() as u64) else {
                // (A frame taken or broken was a buffer completed or failed:
                // not thrown off.)
                if !restarted && thrown_off(&stream) {
                    restarted = true;
                    tracing::warn!(
                        "no frame within {} ms although the stream received {} packets, every one discarded as a late frame (a stray packet first can throw off Aravis's frame counter): starting a new stream",
                        wait.as_millis(),
                        stream.info_uint64_by_name("n_received_packets")
                    );
                    let _ = c.stop_acquisition();
                    drop(stream);
                    let (again, replaced) = start_stream(c, &mut self.warned_rmem, payload)?;
                    self.counters.stream_restarts += 1 + replaced;
                    stream = again;
                    continue;
                }
                self.counters.timeouts += 1;
                break Err(timed_out(&stream, wait, taken, n));
            };
            counts.dropped += ids.next(buffer.frame_id());
            if buffer.status() != BufferStatus::Success {
                counts.broken += 1;
                self.counters.failed += 1;
                if let Some(line) =
                    broken_log.note(buffer.frame_id(), &format!("{:?}", buffer.status()))
                {
                    tracing::warn!("{line}");
                }
                stream.push_buffer(buffer);
                if last_whole.elapsed() > wait {
                    break Err(CameraError::Driver(format!(
                        "{} broken buffers and no whole frame in {} ms; check the network or the camera's packet size",
                        counts.broken,
                        wait.as_millis()
                    )));
                }
                continue;
            }
            let frame = decode(&buffer, self.settings.pixel_format, bits);
            stream.push_buffer(buffer);
            let frame = match frame {
                Ok(frame) => frame,
                Err(e) => {
                    counts.broken += 1;
                    self.counters.failed += 1;
                    tracing::warn!("dropped a frame: {e}");
                    continue;
                }
            };
            self.counters.completed += 1;
            last_whole = Instant::now();
            counts.received += 1;
            taken += 1;
            if let Err(why) = sink(frame) {
                break Err(CameraError::Stopped(why));
            }
        };
        let _ = c.stop_acquisition();
        if let Some(line) = broken_log.summary() {
            tracing::warn!("{line}");
        }
        let (_, _, underruns) = stream.statistics();
        self.counters.underruns += underruns;
        self.counters.missing_packets += stream.info_uint64_by_name("n_missing_packets");
        self.counters.resent_packets += stream.info_uint64_by_name("n_resent_packets");
        self.last_period_s = period;
        result
    }

    fn counters(&self) -> Counters {
        self.counters
    }
}

/// A new stream of `camera` with its buffers, then the acquisition started,
/// and how many streams were replaced on the way: a stream that receives
/// packets before the start (strays, which could throw off its frame count,
/// [`thrown_off`]) is replaced, up to twice.
fn start_stream(
    camera: &Camera,
    warned_rmem: &mut bool,
    payload: usize,
) -> Result<(aravis::Stream, u64), CameraError> {
    let mut tries = 0;
    let stream = loop {
        let stream = camera.create_stream().map_err(driver)?;
        if let Some(gv) = stream.downcast_ref::<aravis::GvStream>() {
            let bytes = socket_buffer_bytes(payload);
            gv.set_socket_buffer(aravis::GvStreamSocketBuffer::Fixed);
            gv.set_socket_buffer_size(i32::try_from(bytes).unwrap_or(i32::MAX));
            gv.set_frame_retention(FRAME_RETENTION_US);
            // The kernel's cap is read once per camera, not at every acquisition.
            if !*warned_rmem {
                *warned_rmem = true;
                if let Some(line) = rmem_max_warning(bytes, payload, read_rmem_max()) {
                    tracing::warn!("{line}");
                }
            }
        }
        for _ in 0..buffer_count(payload) {
            stream.push_buffer(aravis::Buffer::new_allocate(payload));
        }
        let strays = stream.info_uint64_by_name("n_received_packets");
        if strays == 0 || tries == 2 {
            break stream;
        }
        tries += 1;
        tracing::warn!("a new stream received {strays} packets before the acquisition started: starting another");
    };
    camera
        .set_acquisition_mode(AcquisitionMode::Continuous)
        .map_err(feature_err("AcquisitionMode"))?;
    camera
        .start_acquisition()
        .map_err(feature_err("AcquisitionStart"))?;
    Ok((stream, tries))
}

/// Whether `stream` received packets and discarded every one as a late
/// frame: a stray packet (a stale control answer to a port the kernel gave
/// the stream again) taken as the first one sets Aravis 0.8's last frame id
/// to garbage, and the camera's frames are then "late" for up to 100
/// frames; a new stream starts its count afresh.
fn thrown_off(stream: &aravis::Stream) -> bool {
    let received = stream.info_uint64_by_name("n_received_packets");
    received > 0
        && stream.info_uint64_by_name("n_ignored_packets") == received
        && stream.info_uint64_by_name("n_completed_buffers") == 0
        && stream.info_uint64_by_name("n_failures") == 0
}

/// The timeout of an acquisition that got `got` of `wanted` frames, with
/// what the stream received logged: whether the camera sent nothing, or
/// sent packets that found no buffer or made no whole frame.
fn timed_out(stream: &aravis::Stream, wait: Duration, got: usize, wanted: usize) -> CameraError {
    let info = |name: &str| stream.info_uint64_by_name(name);
    let packets = info("n_received_packets");
    tracing::warn!(
        "no frame within {} ms: the stream received {packets} packets ({} ignored, {} with no free buffer), completed {} buffers, failed {}",
        wait.as_millis(),
        info("n_ignored_packets"),
        info("n_underruns"),
        info("n_completed_buffers"),
        info("n_failures"),
    );
    CameraError::Timeout {
        timeout_ms: wait.as_millis() as u64,
        got,
        wanted,
        packets,
    }
}

/// A received buffer as a frame: its pixels decoded by its format (widened
/// to 16 bits), or why the buffer does not hold the frame it says.
fn decode(
    buffer: &aravis::Buffer,
    format: PixelFormat,
    bits: u32,
) -> Result<RawFrame, super::DecodeError> {
    let (w, h) = (
        buffer.image_width() as usize,
        buffer.image_height() as usize,
    );
    let pixels = format.decode(&buffer.image_data(), w, h)?;
    let system_timestamp_ns = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| d.as_nanos() as u64)
        .unwrap_or(0);
    Ok(RawFrame {
        width: w,
        height: h,
        bits,
        pixels,
        frame_id: buffer.frame_id(),
        system_timestamp_ns,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_socket_buffer_holds_four_frames_within_its_bounds() {
        assert_eq!(socket_buffer_bytes(512 * 512 * 2), MIN_SOCKET_BUFFER);
        assert_eq!(socket_buffer_bytes(2048 * 2048 * 2), 32 << 20);
        assert_eq!(socket_buffer_bytes(100), MIN_SOCKET_BUFFER);
        assert_eq!(socket_buffer_bytes(usize::MAX), MAX_SOCKET_BUFFER);
    }

    #[test]
    fn a_kernel_cap_below_two_frames_is_named_with_the_fix() {
        let frame = 2048 * 2048 * 2;
        let asked = socket_buffer_bytes(frame);
        let line = rmem_max_warning(asked, frame, Some(212_992)).expect("a warning");
        assert!(line.contains("212992") && line.contains(&format!("rmem_max={asked}")));
        assert!(rmem_max_warning(asked, frame, Some(4 << 20)).is_some());
        assert_eq!(rmem_max_warning(asked, frame, Some(16 << 20)), None);
        assert_eq!(rmem_max_warning(asked, frame, None), None);
    }
}
