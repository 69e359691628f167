//! Motorized polarizer rotation mounts: the [`RotationMount`] the daemon
//! turns between the blocks of a plan, the Thorlabs Elliptec driver
//! ([`elliptec`]) and a simulated Elliptec on a pseudo-terminal
//! ([`simulated`]) that the driver's real serial code talks to in tests
//! and on the fake bench.
//!
//! Why read back: a mount that slipped or skipped a command would put the
//! polarizer at another angle than the capture records; every move reads
//! the position back, and the angle recorded is the one measured.

pub mod elliptec;
mod service;
pub mod simulated;

pub use service::MountService;
pub(crate) use service::{MountConfig, MountKind, MountView};

/// A mount that turns the polarizer to an angle and says where it is.
pub trait RotationMount: Send {
    /// Finds the mount's home (its zero); returns the angle read back, degrees.
    fn home(&mut self) -> Result<f64, MountError>;
    /// Turns to `deg` (any real number; taken modulo 360) and returns the
    /// angle read back, degrees in [0, 360).
    fn move_to(&mut self, deg: f64) -> Result<f64, MountError>;
    /// The angle now, degrees in [0, 360).
    fn position(&mut self) -> Result<f64, MountError>;
}

/// What went wrong with a mount, naming the command and the port.
#[derive(Debug, thiserror::Error)]
pub enum MountError {
    /// The serial port could not be opened.
    #[error("cannot open the rotation mount at {port}: {reason}; check the cable, the path (e.g. /dev/ttyUSB0) and that the polnlos user is in the dialout group")]
    Open {
        /// The port's path.
        port: String,
        /// The system's reason.
        reason: String,
    },
    /// No (complete) reply within the timeout.
    #[error("the rotation mount at {port} did not answer {command:?} within {timeout_ms} ms (unplugged, powered off, or another address?)")]
    NoReply {
        /// The port's path.
        port: String,
        /// The command sent.
        command: String,
        /// How long it waited.
        timeout_ms: u64,
    },
    /// The port failed while talking (the adaptor was unplugged).
    #[error("the rotation mount at {port} stopped answering during {command:?}: {reason}")]
    Io {
        /// The port's path.
        port: String,
        /// The command sent.
        command: String,
        /// The system's reason.
        reason: String,
    },
    /// The device answered with an error status.
    #[error("the rotation mount at {port} answered {command:?} with error {code}: {meaning}")]
    Device {
        /// The port's path.
        port: String,
        /// The command sent.
        command: String,
        /// The device's status code.
        code: u8,
        /// What the code means (the protocol manual's words).
        meaning: &'static str,
    },
    /// A reply that does not follow the protocol.
    #[error("the rotation mount at {port} answered {command:?} with {reply:?}, which is not a reply polnlos reads: {why}")]
    Reply {
        /// The port's path.
        port: String,
        /// The command sent.
        command: String,
        /// The reply, as received.
        reply: String,
        /// What is wrong with it.
        why: String,
    },
    /// The position read back is not the one asked for.
    #[error("the rotation mount at {port} was sent to {wanted:.3}° but reads {got:.3}° (more than {tolerance:.3}° off): it slipped or skipped the move")]
    Missed {
        /// The port's path.
        port: String,
        /// The angle asked for, degrees.
        wanted: f64,
        /// The angle read back, degrees.
        got: f64,
        /// The tolerance, degrees.
        tolerance: f64,
    },
}

/// `deg` taken into [0, 360).
pub(crate) fn wrap_degrees(deg: f64) -> f64 {
    let w = deg.rem_euclid(360.0);
    if w >= 360.0 {
        0.0
    } else {
        w
    }
}

/// The smallest angle between two angles, degrees in [0, 180].
pub fn angle_between(a: f64, b: f64) -> f64 {
    let d = wrap_degrees(a - b);
    d.min(360.0 - d)
}
