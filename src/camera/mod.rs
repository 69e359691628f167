//! Camera frames and (with the daemon) the camera driver.
//!
//! [`Frame`] is the type every room that handles images agrees on: the
//! simulator renders frames, the measurement code samples them, the driver
//! fills them from the sensor.

mod frame;

pub use frame::Frame;
