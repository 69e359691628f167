//! Relays that switch the hidden scene's light, so that a bench takes its
//! dark frames unattended: the [`LightSwitch`] a capture switches around its
//! dark frames, the Devantech USB-RLY02/08/16 driver ([`devantech`]) and a
//! simulated USB-RLY02 on a pseudo-terminal ([`simulated`]) that the
//! driver's real serial code talks to in tests and on the fake bench.
//!
//! Why read back: a relay that did not switch would label frames of the lit
//! scene as dark (or the reverse); every switch reads the relay states
//! back, and a relay that reads otherwise fails the capture.

pub mod devantech;
mod service;
pub mod simulated;

pub use service::LightService;
pub(crate) use service::{LightConfig, LightKind, LightView};

/// A switch for the hidden scene's light.
pub trait LightSwitch: Send {
    /// Switches the light on or off; returns the state read back.
    fn set(&mut self, on: bool) -> Result<bool, RelayError>;
    /// Whether the light is switched on now.
    fn state(&mut self) -> Result<bool, RelayError>;
}

/// What went wrong with a relay, naming the command and the port.
#[derive(Debug, thiserror::Error)]
pub enum RelayError {
    /// The serial port could not be opened.
    #[error("cannot open the relay at {port}: {reason}; check the cable, the path (e.g. /dev/ttyACM0) and that the polnlos user is in the dialout group")]
    Open {
        /// The port's path.
        port: String,
        /// The system's reason.
        reason: String,
    },
    /// No (complete) reply within the timeout.
    #[error("the relay at {port} did not answer command 0x{command:02X} within {timeout_ms} ms (unplugged, or not a Devantech USB-RLY module?)")]
    NoReply {
        /// The port's path.
        port: String,
        /// The command byte sent.
        command: u8,
        /// How long it waited.
        timeout_ms: u64,
    },
    /// The port failed while talking (the module was unplugged).
    #[error("the relay at {port} stopped answering during command 0x{command:02X}: {reason}")]
    Io {
        /// The port's path.
        port: String,
        /// The command byte sent.
        command: u8,
        /// The system's reason.
        reason: String,
    },
    /// The relay number is not one the module has.
    #[error("the relay module at {port} ({module}) has relays 1 to {count}; [light] relay = {relay} is not one of them")]
    NoSuchRelay {
        /// The port's path.
        port: String,
        /// The module, as it named itself.
        module: String,
        /// Its relays.
        count: u8,
        /// The relay asked for.
        relay: u8,
    },
    /// The relay reads back in the other state.
    #[error("relay {relay} at {port} was switched {} but reads {}: it is stuck or its module lost power; check the module, then press Continue", on_off(*.wanted), on_off(!*.wanted))]
    Stuck {
        /// The port's path.
        port: String,
        /// The relay.
        relay: u8,
        /// The state asked for.
        wanted: bool,
    },
}

/// "on" or "off".
fn on_off(on: bool) -> &'static str {
    if on {
        "on"
    } else {
        "off"
    }
}
