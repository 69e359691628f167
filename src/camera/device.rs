//! The small interface the daemon needs from a camera.

use serde::Serialize;

use super::settings::{Acquisition, CameraRanges, GeometryError, SensorLimits, RANGED};

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

/// What one acquisition received, lost and could not use: recorded with
/// each capture, so that a user can tell which capture lost frames.
#[derive(
    Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, serde::Deserialize, utoipa::ToSchema,
)]
pub struct FrameCounts {
    /// Frames delivered whole.
    pub received: u64,
    /// Frames the camera sent that never arrived while the acquisition
    /// waited for them (gaps in the frame ids between the first and the
    /// last frame it saw: no free buffer, or every packet lost).
    pub dropped: u64,
    /// Frames that arrived incomplete or undecodable (missing packets, a
    /// payload that does not match the format).
    pub broken: u64,
}

impl FrameCounts {
    /// Frames lost to this acquisition: dropped and broken ones.
    pub fn lost(&self) -> u64 {
        self.dropped + self.broken
    }

    /// The losses in words, `None` when there were none: one text for the
    /// capture's log or failure and for the reconstructions that use it.
    ///
    /// Why: a lost frame is replaced by a later one, so the capture still
    /// keeps every frame it asked for; the sentence says so instead of
    /// calling the lost frames part of those received.
    pub fn losses(&self) -> Option<String> {
        (self.lost() > 0).then(|| {
            format!(
                "lost {} frames ({} dropped, {} broken) besides the {} received whole",
                self.lost(),
                self.dropped,
                self.broken,
                self.received
            )
        })
    }
}

impl std::ops::Add for FrameCounts {
    type Output = Self;
    fn add(self, o: Self) -> Self {
        Self {
            received: self.received + o.received,
            dropped: self.dropped + o.dropped,
            broken: self.broken + o.broken,
        }
    }
}

/// Follows the frame ids of one acquisition and says how many frames never
/// arrived before each one.
#[derive(Debug, Default)]
pub(crate) struct FrameIds {
    last: Option<u64>,
    /// Broken frames without an id since the last id: they are among the
    /// ids skipped, and counted broken, not dropped.
    unnamed: u64,
}

impl FrameIds {
    /// The frames lost just before the frame with id `id` (whole or broken).
    /// Id 0 (a frame broken before its leader told its id) counts nothing
    /// now; a late frame (an id behind the last one) counts nothing.
    pub fn next(&mut self, id: u64) -> u64 {
        if id == 0 {
            self.unnamed += 1;
            return 0;
        }
        let Some(last) = self.last else {
            self.last = Some(id);
            return 0;
        };
        match frames_between(last, id) {
            Some(gap) => {
                self.last = Some(id);
                let gap = gap.saturating_sub(self.unnamed);
                self.unnamed = 0;
                gap
            }
            None => 0,
        }
    }
}

/// What the log says about one acquisition's broken buffers: the first in
/// full, the rest once, summed, when the acquisition ends.
///
/// Why: a lossy link breaks buffers in bursts; one line per buffer (28
/// identical "frame 0 arrived broken" lines in one idle burst) buries the
/// line that matters.
#[derive(Debug, Default)]
pub struct BrokenLog {
    count: u64,
    /// The statuses of the buffers after the first, in the order first seen.
    statuses: Vec<String>,
}

impl BrokenLog {
    /// Notes a broken buffer; returns the line to log for the first one.
    pub fn note(&mut self, frame_id: u64, status: &str) -> Option<String> {
        self.count += 1;
        if self.count == 1 {
            return Some(format!(
                "frame {frame_id} arrived broken ({status}); waiting for the next (later ones are summed when the acquisition ends)"
            ));
        }
        if !self.statuses.iter().any(|s| s == status) {
            self.statuses.push(status.to_string());
        }
        None
    }

    /// The line to log when the acquisition ends, when more than one broke.
    pub fn summary(&self) -> Option<String> {
        (self.count > 1).then(|| {
            format!(
                "{} more buffers of this acquisition arrived broken ({})",
                self.count - 1,
                self.statuses.join(", ")
            )
        })
    }
}

/// How many frame ids lie strictly between two frames' ids, or None when
/// `id` does not come after `previous` (a late frame, or a count that
/// restarted). GigE Vision 1 block ids are 16-bit and wrap from 65535 to 1
/// (0 is never used), and are compared as Aravis does, within half the
/// cycle; larger ids (GigE Vision 2, USB3 Vision) do not wrap.
pub fn frames_between(previous: u64, id: u64) -> Option<u64> {
    const WRAP: u64 = 0xffff;
    if (1..=WRAP).contains(&previous) && (1..=WRAP).contains(&id) {
        let ahead = if id > previous {
            id - previous
        } else {
            id + WRAP - previous
        };
        (ahead > 0 && ahead <= WRAP / 2).then(|| ahead - 1)
    } else {
        (id > previous).then(|| id - previous - 1)
    }
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
    /// Stream packets that found no free buffer (Aravis 0.8 counts
    /// `n_underruns` per packet, and counts the frames a free-running camera
    /// sends after a capture had its frames): not a capture's frame losses,
    /// which [`FrameCounts`] gives per capture.
    pub underruns: u64,
    /// GigE Vision packets missing.
    pub missing_packets: u64,
    /// GigE Vision packets resent.
    pub resent_packets: u64,
    /// Streams replaced because stray packets reached them before or
    /// instead of the camera's frames (they can throw off Aravis's frame
    /// count: `camera/aravis.rs`).
    pub stream_restarts: u64,
    /// Times the camera was (re)opened.
    pub connects: u64,
}

/// What the camera is and what it can do.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
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
    /// Each ranged setting's range and the feature that sets it
    /// (`exposure_us` and `exposure_feature`, ...: one pair per entry of
    /// `super::settings::RANGED`).
    #[serde(flatten)]
    pub ranges: CameraRanges,
    /// Frame-rate range, frames per second, when the camera has one.
    pub frame_rate: Option<(f64, f64)>,
    /// Pixel formats the camera offers.
    pub pixel_formats: Vec<String>,
    /// The sensor's polarizer mosaic (`"polarsens"`), when the camera
    /// offers or uses a polarization camera's raw-mosaic format; null for a
    /// plain sensor. A capture of a mosaic pose needs such a format.
    #[schema(value_type = Option<String>)]
    pub mosaic: Option<crate::scene::MosaicLayout>,
    /// The Bayer filter of a colour camera reading out its raw frames
    /// (the pattern its current pixel format names); null otherwise.
    #[schema(value_type = Option<String>)]
    pub bayer: Option<crate::measure::colour::BayerPattern>,
    /// Region and binning limits, read from the feature nodes.
    pub limits: SensorLimits,
    /// Settings read back from the camera (not what was asked for).
    pub settings: Acquisition,
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
    #[error("no frame within {timeout_ms} ms (frame {got} of {wanted}; the stream received {packets} packets in this acquisition); the camera may have stopped or been unplugged")]
    Timeout {
        /// Timeout used.
        timeout_ms: u64,
        /// Frames received so far.
        got: usize,
        /// Frames asked for.
        wanted: usize,
        /// Packets the stream received in this acquisition, whole frames or
        /// not: 0 says the camera sent nothing to this host.
        packets: u64,
    },
    /// The camera is not connected (lost, or never opened).
    #[error("camera is not connected ({0}); it is reconnected automatically when it comes back")]
    Disconnected(String),
    /// A region or binning the sensor cannot deliver (checked before Aravis sees it).
    #[error(transparent)]
    Geometry(#[from] GeometryError),
    /// The receiver of the frames stopped the acquisition.
    #[error("acquisition stopped: {0}")]
    Stopped(SinkClosed),
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

    /// `Ok` when every ranged setting of `s` is within the camera's
    /// `ranges`, else [`CameraError::OutOfRange`] naming the first feature out.
    pub fn check_ranges(s: &Acquisition, ranges: &CameraRanges) -> Result<(), Self> {
        for r in RANGED {
            let (range, feature) = (r.range)(ranges);
            Self::check_range(feature, (r.value)(s), range)?;
        }
        Ok(())
    }

    /// Whether the error means the camera is gone and must be reopened.
    pub fn is_connection_loss(&self) -> bool {
        matches!(
            self,
            CameraError::Timeout { .. } | CameraError::Disconnected(_) | CameraError::Open { .. }
        )
    }
}

/// Where acquired frames go, one at a time; an `Err` stops the acquisition.
pub type FrameSink<'a> = dyn FnMut(RawFrame) -> Result<(), SinkClosed> + 'a;

/// Why a [`FrameSink`] took no more frames: whoever read them stopped (a
/// capture cancelled or failed, a live view ended).
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("the frame writer stopped")]
pub struct SinkClosed;

/// A camera as the daemon uses it. Implementations are owned by one thread.
pub trait CameraDevice: Send {
    /// Identity, ranges and current settings.
    fn describe(&mut self) -> Result<CameraInfo, CameraError>;
    /// Applies settings (validated against the camera's ranges).
    fn configure(&mut self, settings: &Acquisition) -> Result<(), CameraError>;
    /// Acquires `n` frames with the current settings, handing each to `sink`
    /// as it arrives (nothing is kept here); an `Err` from the sink stops the
    /// acquisition with [`CameraError::Stopped`]. Returns what this
    /// acquisition received and lost.
    fn acquire(&mut self, n: usize, sink: &mut FrameSink<'_>) -> Result<FrameCounts, CameraError>;
    /// Counters since the camera was opened.
    fn counters(&self) -> Counters;
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn gaps_in_16_bit_block_ids_wrap_past_zero() {
        assert_eq!(frames_between(5, 6), Some(0));
        assert_eq!(frames_between(5, 9), Some(3));
        assert_eq!(frames_between(65535, 1), Some(0));
        assert_eq!(frames_between(65534, 2), Some(2));
        assert_eq!(frames_between(70_000, 70_003), Some(2));
        // Late frames and a restarted count are no loss.
        assert_eq!(frames_between(3, 65530), None);
        assert_eq!(frames_between(300, 1), None);
        assert_eq!(frames_between(9, 9), None);
    }

    #[test]
    fn a_burst_of_broken_buffers_is_one_line_and_one_summary() {
        let mut log = BrokenLog::default();
        assert_eq!(log.summary(), None);
        let first = log.note(0, "MissingPackets");
        assert_eq!(
            first.as_deref(),
            Some("frame 0 arrived broken (MissingPackets); waiting for the next (later ones are summed when the acquisition ends)")
        );
        assert_eq!(log.summary(), None);
        let rest: Vec<_> = (0..27)
            .map(|k| {
                log.note(
                    0,
                    if k % 9 == 0 {
                        "Timeout"
                    } else {
                        "MissingPackets"
                    },
                )
            })
            .collect();
        assert!(rest.iter().all(Option::is_none));
        assert_eq!(
            log.summary().as_deref(),
            Some("27 more buffers of this acquisition arrived broken (Timeout, MissingPackets)")
        );
    }

    #[test]
    fn a_broken_frame_without_an_id_is_not_also_dropped() {
        let mut ids = FrameIds::default();
        assert_eq!(ids.next(10), 0);
        assert_eq!(ids.next(0), 0);
        assert_eq!(ids.next(13), 1);
        // A late frame neither counts nor moves the count back.
        assert_eq!(ids.next(12), 0);
        assert_eq!(ids.next(14), 0);
    }

    proptest! {
        /// Frames of a wrapping 16-bit count, some left out and some
        /// delivered late (swapped with the next): the gaps add up to the
        /// frames left out.
        #[test]
        fn dropped_frames_are_counted_across_the_wrap(
            start in 1u64..65536,
            keep in proptest::collection::vec(any::<bool>(), 2..300),
            swap in proptest::collection::vec(any::<bool>(), 300),
        ) {
            let id = |k: u64| (start - 1 + k) % 65535 + 1;
            let last = keep.len() - 1;
            // The first and the last are always seen.
            let mut seen: Vec<u64> = (0..keep.len())
                .filter(|&k| keep[k] || k == 0 || k == last)
                .map(|k| id(k as u64))
                .collect();
            let kept = seen.len() as u64;
            // Late frames: a frame arrives after its successor (not the first or last).
            let swapped: Vec<usize> = (1..seen.len().saturating_sub(2)).filter(|&k| swap[k]).collect();
            for &k in &swapped {
                seen.swap(k, k + 1);
            }
            let mut ids = FrameIds::default();
            let dropped: u64 = seen.iter().map(|&i| ids.next(i)).sum();
            // A late frame is counted dropped when its successor arrives
            // first, and not taken back: at most one per swap.
            let swaps = swapped.len() as u64;
            prop_assert!(dropped >= keep.len() as u64 - kept);
            prop_assert!(dropped <= keep.len() as u64 - kept + swaps);
        }
    }
}
