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

    /// The format of a GenICam name (as [`PixelFormat::name`] writes it).
    pub fn from_name(name: &str) -> Option<Self> {
        [PixelFormat::Mono8, PixelFormat::Mono12, PixelFormat::Mono16]
            .into_iter()
            .find(|f| f.name() == name)
    }

    /// Largest digital number, `2^bits - 1`.
    pub fn full_scale(self) -> f64 {
        f64::from((1u32 << self.bits()) - 1)
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip_and_full_scale_follows_the_bits() {
        for f in [PixelFormat::Mono8, PixelFormat::Mono12, PixelFormat::Mono16] {
            assert_eq!(PixelFormat::from_name(f.name()), Some(f));
        }
        assert_eq!(PixelFormat::from_name("RGB8"), None);
        assert_eq!(PixelFormat::Mono8.full_scale(), 255.0);
        assert_eq!(PixelFormat::Mono12.full_scale(), 4095.0);
        assert_eq!(PixelFormat::Mono16.full_scale(), 65535.0);
    }
}
