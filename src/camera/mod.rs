//! The camera: the small trait the daemon sees, the Aravis driver
//! behind it, the Aravis fake camera bench used by default and in tests, and
//! the thread that owns the camera.
//!
//! Aravis objects are `Send` but not `Sync`, so one dedicated thread owns the
//! camera (`worker`); everyone else talks to it through a channel. That
//! thread only configures, triggers and pops buffers: averaging and disk I/O
//! happen elsewhere.

pub(crate) mod aravis;
mod device;
pub mod fake;
pub(crate) mod hotplug;
mod pixel;
pub(crate) mod settings;
mod shown;
pub use aravis::AravisCamera;
pub use hotplug::Hotplug;
pub use shown::BenchImages;
pub use worker::CameraHandle;
pub(crate) mod synthetic;
pub(crate) mod worker;

pub(crate) use device::FrameIds;
pub use device::{
    frames_between, CameraDevice, CameraError, CameraInfo, Counters, FrameCounts, FrameSink,
    RawFrame, SinkClosed,
};
pub(crate) use pixel::DecodeError;
pub(crate) use settings::GeometryError;
pub use settings::{
    Acquisition, CameraRanges, CameraSettings, PixelFormat, SensorLimits, TriggerMode,
};
