//! A simulated Devantech USB-RLY02 on a pseudo-terminal: it answers the
//! module's command bytes on the pty's master side, and the driver opens
//! the slave's path like any serial port, so the real serial code runs. It
//! keeps its relay states (the fake bench shows the scene lit or dark from
//! relay 1) and can play faults: no reply, a relay that does not switch, a
//! cable pulled.

use std::sync::{Arc, Mutex};

use crate::rig::serial::PtyDevice;

/// The module id a USB-RLY02 answers (`0x5A`'s first byte).
pub(crate) const MODULE_ID: u8 = 10;

/// How the simulated module misbehaves.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Fault {
    /// It answers as the documentation says.
    #[default]
    None,
    /// It answers nothing.
    Silent,
    /// Its relays keep their states whatever they are sent.
    Stuck,
}

struct State {
    /// Bit k: relay k + 1 energized.
    relays: u8,
    fault: Fault,
}

/// A running simulated USB-RLY02; stops (the cable pulled) when dropped or
/// [`SimulatedRelay::unplug`]ged.
pub struct SimulatedRelay {
    device: PtyDevice,
    state: Arc<Mutex<State>>,
}

impl SimulatedRelay {
    /// Starts the module on a new pseudo-terminal, its relays off.
    pub fn start() -> std::io::Result<Self> {
        let state = Arc::new(Mutex::new(State {
            relays: 0,
            fault: Fault::None,
        }));
        let st = state.clone();
        let device = PtyDevice::start("sim-usb-rly02", move |bytes| {
            bytes.iter().flat_map(|&c| answer(c, &st)).collect()
        })?;
        Ok(Self { device, state })
    }

    /// The serial port's path to open (`/dev/pts/N`).
    pub fn path(&self) -> &str {
        self.device.path()
    }

    /// Whether relay `relay` (1 or 2) is energized.
    pub fn is_on(&self, relay: u8) -> bool {
        let bits = self.state.lock().map(|s| s.relays).unwrap_or(0);
        (1..=2).contains(&relay) && bits & (1 << (relay - 1)) != 0
    }

    /// Makes the module misbehave from now on (or behave again).
    pub fn set_fault(&self, fault: Fault) {
        if let Ok(mut s) = self.state.lock() {
            s.fault = fault;
        }
    }

    /// Pulls the cable: the module stops and its pty closes.
    pub fn unplug(&mut self) {
        self.device.unplug();
    }
}

/// The reply to one command byte (empty for a switch, or a silent module).
fn answer(command: u8, state: &Mutex<State>) -> Vec<u8> {
    let Ok(mut s) = state.lock() else {
        return Vec::new();
    };
    if s.fault == Fault::Silent {
        return Vec::new();
    }
    let stuck = s.fault == Fault::Stuck;
    match command {
        0x5A => vec![MODULE_ID, 1],
        0x5B => vec![s.relays],
        0x64 if !stuck => {
            s.relays = 0b11;
            Vec::new()
        }
        0x65 | 0x66 if !stuck => {
            s.relays |= 1 << (command - 0x65);
            Vec::new()
        }
        0x6E if !stuck => {
            s.relays = 0;
            Vec::new()
        }
        0x6F | 0x70 if !stuck => {
            s.relays &= !(1 << (command - 0x6F));
            Vec::new()
        }
        _ => Vec::new(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_module_switches_each_relay_by_its_byte_and_reports_the_states() {
        let st = Mutex::new(State {
            relays: 0,
            fault: Fault::None,
        });
        assert_eq!(answer(0x5A, &st), [MODULE_ID, 1]);
        assert!(answer(0x66, &st).is_empty());
        assert_eq!(answer(0x5B, &st), [0b10]);
        answer(0x65, &st);
        answer(0x70, &st);
        assert_eq!(answer(0x5B, &st), [0b01]);
        st.lock().unwrap().fault = Fault::Stuck;
        answer(0x6E, &st);
        assert_eq!(answer(0x5B, &st), [0b01]);
        st.lock().unwrap().fault = Fault::Silent;
        assert!(answer(0x5A, &st).is_empty());
    }
}
