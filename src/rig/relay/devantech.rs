//! The Devantech USB-RLY02, USB-RLY08 and USB-RLY16 relay modules: a USB
//! CDC serial port (the baud rate is not used), one command byte each,
//! replies only to the queries (the module's technical documentation):
//! `0x5A` version (2 bytes: module id, firmware), `0x5B` relay states (one
//! byte, bit k = relay k + 1), `0x65`+k-1 relay k on, `0x6F`+k-1 relay k off.
//!
//! Why this module: the documented byte protocol reads the relay states
//! back, so a relay that did not switch is caught before a dark frame is
//! taken with the scene lit.

use std::io::{Read, Write};
use std::time::{Duration, Instant};

use super::{LightSwitch, RelayError};

/// Line settings (ignored by the USB module, needed by the tty).
pub(crate) const BAUD: u32 = 9600;

/// How long a query may take to answer.
pub const QUERY_TIMEOUT: Duration = Duration::from_millis(500);

/// Get the module id and firmware version (2 bytes).
const VERSION: u8 = 0x5A;
/// Get the relay states (1 byte).
const STATES: u8 = 0x5B;
/// Relay 1 on; relay k is `ON + k - 1`.
const ON: u8 = 0x65;
/// Relay 1 off; relay k is `OFF + k - 1`.
const OFF: u8 = 0x6F;

/// A module's name and relay count from its id (`0x5A`'s first byte).
pub fn module(id: u8) -> Option<(&'static str, u8)> {
    match id {
        8 => Some(("USB-RLY08", 8)),
        9 => Some(("USB-RLY16", 8)),
        10 => Some(("USB-RLY02", 2)),
        _ => None,
    }
}

/// A Devantech relay module on a serial port (or anything that reads and
/// writes like one), switching the scene's light on relay `relay`.
pub struct Devantech<P> {
    port: P,
    path: String,
    relay: u8,
    module: &'static str,
}

impl Devantech<Box<dyn serialport::SerialPort>> {
    /// Opens the module at `path` (e.g. `/dev/ttyACM0`), reads which module
    /// it is, and checks that it has relay `relay` (1-8).
    pub fn open(path: &str, relay: u8) -> Result<Self, RelayError> {
        let port = crate::rig::serial::open(path, BAUD).map_err(|e| RelayError::Open {
            port: path.to_string(),
            reason: e.to_string(),
        })?;
        Self::with_port(port, path, relay)
    }
}

impl<P: Read + Write + Send> Devantech<P> {
    /// The module on `port` (its reads time out after a short while), named
    /// `path` in errors.
    pub fn with_port(port: P, path: &str, relay: u8) -> Result<Self, RelayError> {
        let mut m = Self {
            port,
            path: path.to_string(),
            relay,
            module: "",
        };
        let mut version = [0u8; 2];
        m.query(VERSION, &mut version)?;
        let (name, count) = module(version[0]).ok_or_else(|| RelayError::NoSuchRelay {
            port: path.to_string(),
            module: format!("unknown module id {}", version[0]),
            count: 0,
            relay,
        })?;
        if relay == 0 || relay > count {
            return Err(RelayError::NoSuchRelay {
                port: path.to_string(),
                module: name.to_string(),
                count,
                relay,
            });
        }
        m.module = name;
        Ok(m)
    }

    /// The module, as it named itself.
    pub fn module(&self) -> &'static str {
        self.module
    }

    fn io(&self, command: u8, e: std::io::Error) -> RelayError {
        RelayError::Io {
            port: self.path.clone(),
            command,
            reason: e.to_string(),
        }
    }

    /// Sends `command` (no reply).
    fn send(&mut self, command: u8) -> Result<(), RelayError> {
        self.port
            .write_all(&[command])
            .and_then(|()| self.port.flush())
            .map_err(|e| self.io(command, e))
    }

    /// Sends `command` and reads exactly `reply.len()` bytes within
    /// [`QUERY_TIMEOUT`].
    fn query(&mut self, command: u8, reply: &mut [u8]) -> Result<(), RelayError> {
        self.send(command)?;
        let deadline = Instant::now() + QUERY_TIMEOUT;
        let mut got = 0;
        while got < reply.len() {
            if Instant::now() >= deadline {
                return Err(RelayError::NoReply {
                    port: self.path.clone(),
                    command,
                    timeout_ms: QUERY_TIMEOUT.as_millis() as u64,
                });
            }
            match self.port.read(&mut reply[got..]) {
                Ok(0) => std::thread::sleep(Duration::from_millis(5)),
                Ok(n) => got += n,
                Err(e)
                    if matches!(
                        e.kind(),
                        std::io::ErrorKind::TimedOut
                            | std::io::ErrorKind::WouldBlock
                            | std::io::ErrorKind::Interrupted
                    ) => {}
                Err(e) => return Err(self.io(command, e)),
            }
        }
        Ok(())
    }
}

impl<P: Read + Write + Send> LightSwitch for Devantech<P> {
    fn set(&mut self, on: bool) -> Result<bool, RelayError> {
        let k = self.relay - 1;
        self.send(if on { ON + k } else { OFF + k })?;
        let read = self.state()?;
        if read != on {
            return Err(RelayError::Stuck {
                port: self.path.clone(),
                relay: self.relay,
                wanted: on,
            });
        }
        Ok(read)
    }

    fn state(&mut self) -> Result<bool, RelayError> {
        let mut states = [0u8; 1];
        self.query(STATES, &mut states)?;
        Ok(states[0] & (1 << (self.relay - 1)) != 0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A module whose replies are scripted, recording what it was sent.
    struct Scripted {
        replies: std::collections::VecDeque<u8>,
        sent: Vec<u8>,
    }

    impl Read for Scripted {
        fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
            match (self.replies.pop_front(), buf.first_mut()) {
                (Some(b), Some(slot)) => {
                    *slot = b;
                    Ok(1)
                }
                _ => Err(std::io::ErrorKind::TimedOut.into()),
            }
        }
    }

    impl Write for Scripted {
        fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
            self.sent.extend_from_slice(buf);
            Ok(buf.len())
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }

    fn module_with(replies: &[u8], relay: u8) -> Result<Devantech<Scripted>, RelayError> {
        let port = Scripted {
            replies: replies.iter().copied().collect(),
            sent: Vec::new(),
        };
        Devantech::with_port(port, "/dev/ttyACM0", relay)
    }

    #[test]
    fn relay_k_is_switched_by_its_own_byte_and_read_from_its_own_bit() {
        // Version (USB-RLY08, firmware 3), then the states after the switch.
        let mut m = module_with(&[8, 3, 0b0000_0100], 3).unwrap();
        assert_eq!(m.module(), "USB-RLY08");
        assert!(m.set(true).unwrap());
        assert_eq!(m.port.sent, [VERSION, ON + 2, STATES]);
        let mut m = module_with(&[10, 1, 0b01], 2).unwrap();
        assert!(!m.set(false).unwrap());
        assert_eq!(m.port.sent, [VERSION, OFF + 1, STATES]);
    }

    #[test]
    fn a_relay_the_module_lacks_or_one_that_does_not_switch_is_named() {
        let e = module_with(&[10, 1], 3)
            .err()
            .expect("a USB-RLY02 has 2 relays");
        assert!(
            e.to_string().contains("USB-RLY02") && e.to_string().contains("relay = 3"),
            "{e}"
        );
        let e = module_with(&[42, 1], 1).err().expect("unknown id");
        assert!(e.to_string().contains("unknown module id 42"), "{e}");
        let mut m = module_with(&[10, 1, 0], 1).unwrap();
        let e = m.set(true).unwrap_err().to_string();
        assert!(e.contains("switched on but reads off"), "{e}");
        let e = module_with(&[10], 1).err().expect("half a version reply");
        assert!(
            matches!(
                e,
                RelayError::NoReply {
                    command: VERSION,
                    ..
                }
            ),
            "{e}"
        );
    }
}
