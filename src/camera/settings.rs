//! Camera settings a capture asks for, checked before they reach the camera.

use serde::{Deserialize, Serialize};

/// Monochrome pixel formats polnlos reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, utoipa::ToSchema)]
pub enum PixelFormat {
    /// 8 bits.
    Mono8,
    /// 12 bits in 16-bit words.
    Mono12,
    /// 16 bits, little-endian.
    Mono16,
}

impl PixelFormat {
    /// The GenICam name.
    pub fn name(self) -> &'static str {
        match self {
            PixelFormat::Mono8 => "Mono8",
            PixelFormat::Mono12 => "Mono12",
            PixelFormat::Mono16 => "Mono16",
        }
    }

    /// Significant bits.
    pub fn bits(self) -> u32 {
        match self {
            PixelFormat::Mono8 => 8,
            PixelFormat::Mono12 => 12,
            PixelFormat::Mono16 => 16,
        }
    }
}

/// Free running or one frame per software trigger.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum TriggerMode {
    /// The camera streams at its frame rate.
    Free,
    /// One frame per `TriggerSoftware` command.
    Software,
}

/// Everything a capture sets on the camera.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct CameraSettings {
    /// Exposure, microseconds.
    pub exposure_us: f64,
    /// Gain in the camera's units (dB for `Gain`, raw steps for `GainRaw`).
    pub gain: f64,
    /// Pixel format.
    pub pixel_format: PixelFormat,
    /// Region of interest `[x, y, width, height]`; the camera's current one when absent.
    pub region: Option<[i32; 4]>,
    /// Binning `[x, y]`, none when absent.
    pub binning: Option<[i32; 2]>,
    /// Trigger mode.
    pub trigger: TriggerMode,
}

impl Default for CameraSettings {
    fn default() -> Self {
        Self {
            exposure_us: 20_000.0,
            gain: 0.0,
            pixel_format: PixelFormat::Mono16,
            region: None,
            binning: None,
            trigger: TriggerMode::Free,
        }
    }
}

/// Exposure polnlos accepts at all: 10 us to one hour.
pub const EXPOSURE_RANGE_US: (f64, f64) = (10.0, 3.6e9);
