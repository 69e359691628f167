//! The small interface the daemon needs from a camera.

use serde::Serialize;

use super::settings::{CameraSettings, GeometryError, SensorLimits};

/// One frame as the sensor delivered it (no arithmetic done yet).
#[derive(Debug, Clone)]
pub struct RawFrame {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Significant bits per pixel (8, 12 or 16).
    pub bits: u32,
    /// Pixel values, row-major.
    pub pixels: Vec<u16>,
    /// Camera frame id (16-bit on GigE Vision; it wraps).
    pub frame_id: u64,
    /// Host time the buffer arrived, nanoseconds since the Unix epoch.
    pub system_timestamp_ns: u64,
}

/// Acquisition counters, as areaDetector's ADAravis reports them.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, utoipa::ToSchema)]
pub struct Counters {
    /// Buffers completed successfully.
    pub completed: u64,
    /// Buffers that arrived broken.
    pub failed: u64,
    /// Pops that timed out.
    pub timeouts: u64,
    /// Frames dropped because no buffer was free.
    pub underruns: u64,
    /// GigE Vision packets missing.
    pub missing_packets: u64,
    /// GigE Vision packets resent.
    pub resent_packets: u64,
    /// Times the camera was (re)opened.
    pub connects: u64,
}

/// What the camera is and what it can do.
#[derive(Debug, Clone, Default, Serialize, utoipa::ToSchema)]
pub struct CameraInfo {
    /// GenICam identity, `vendor-model-serial`.
    pub id: String,
    /// Id or address the camera was opened by (from the config).
    pub address: String,
    /// Vendor name.
    pub vendor: String,
    /// Model name.
    pub model: String,
    /// Serial number.
    pub serial: String,
    /// Sensor size (width, height).
    pub sensor: (i32, i32),
    /// Exposure range in microseconds and the feature that sets it.
    pub exposure_us: (f64, f64),
    /// Feature used for exposure (`ExposureTime` or `ExposureTimeAbs`).
    pub exposure_feature: String,
    /// Gain range and the feature that sets it.
    pub gain: (f64, f64),
    /// Feature used for gain (`Gain` or `GainRaw`).
    pub gain_feature: String,
    /// Frame-rate range, frames per second, when the camera has one.
    pub frame_rate: Option<(f64, f64)>,
    /// Pixel formats the camera offers.
    pub pixel_formats: Vec<String>,
    /// Region and binning limits, read from the feature nodes.
    pub limits: SensorLimits,
    /// Settings read back from the camera (not what was asked for).
    pub settings: CameraSettings,
}

/// What went wrong with the camera, naming the feature or the device.
#[derive(Debug, Clone, thiserror::Error)]
pub enum CameraError {
    /// No camera could be opened at that id or address.
    #[error("cannot open camera {id:?}: {reason}; check the id/address in the config and that the camera is powered and reachable")]
    Open {
        /// Id or address asked for.
        id: String,
        /// Aravis's message.
        reason: String,
    },
    /// The camera has no feature by any of the expected names.
    #[error(
        "camera has no feature {names}; it is not a GenICam SFNC camera polnlos knows how to drive"
    )]
    MissingFeature {
        /// The names tried.
        names: String,
    },
    /// A value outside the feature's range.
    #[error("camera feature {feature} = {value}: out of range [{min}, {max}]")]
    OutOfRange {
        /// Feature name.
        feature: String,
        /// Asked value.
        value: f64,
        /// Minimum.
        min: f64,
        /// Maximum.
        max: f64,
    },
    /// A feature write or read that the camera refused.
    #[error("camera feature {feature}: {reason}")]
    Feature {
        /// Feature name.
        feature: String,
        /// Aravis's message.
        reason: String,
    },
    /// No frame arrived in time.
    #[error("no frame within {timeout_ms} ms (frame {got} of {wanted}); the camera may have stopped or been unplugged")]
    Timeout {
        /// Timeout used.
        timeout_ms: u64,
        /// Frames received so far.
        got: usize,
        /// Frames asked for.
        wanted: usize,
    },
    /// The camera is not connected (lost, or never opened).
    #[error("camera is not connected ({0}); it is reconnected automatically when it comes back")]
    Disconnected(String),
    /// A region or binning the sensor cannot deliver (checked before Aravis sees it).
    #[error(transparent)]
    Geometry(#[from] GeometryError),
    /// The receiver of the frames stopped the acquisition (its reason).
    #[error("acquisition stopped: {0}")]
    Stopped(String),
    /// Anything else from the driver.
    #[error("camera error: {0}")]
    Driver(String),
}

impl CameraError {
    /// `Ok` when `value` is within `(min, max)`, else [`CameraError::OutOfRange`]
    /// naming the feature.
    pub fn check_range(feature: &str, value: f64, (min, max): (f64, f64)) -> Result<(), Self> {
        if value >= min && value <= max {
            Ok(())
        } else {
            Err(CameraError::OutOfRange {
                feature: feature.to_string(),
                value,
                min,
                max,
            })
        }
    }

    /// Whether the error means the camera is gone and must be reopened.
    pub fn is_connection_loss(&self) -> bool {
        matches!(
            self,
            CameraError::Timeout { .. } | CameraError::Disconnected(_) | CameraError::Open { .. }
        )
    }
}

/// Where acquired frames go, one at a time; `Err(reason)` stops the acquisition.
pub type FrameSink<'a> = dyn FnMut(RawFrame) -> Result<(), String> + 'a;

/// A camera as the daemon uses it. Implementations are owned by one thread.
pub trait CameraDevice: Send {
    /// Identity, ranges and current settings.
    fn describe(&mut self) -> Result<CameraInfo, CameraError>;
    /// Applies settings (validated against the camera's ranges).
    fn configure(&mut self, settings: &CameraSettings) -> Result<(), CameraError>;
    /// Acquires `n` frames with the current settings, handing each to `sink`
    /// as it arrives (nothing is kept here); an `Err` from the sink stops the
    /// acquisition with [`CameraError::Stopped`].
    fn acquire(&mut self, n: usize, sink: &mut FrameSink<'_>) -> Result<(), CameraError>;
    /// Counters since the camera was opened.
    fn counters(&self) -> Counters;
}
