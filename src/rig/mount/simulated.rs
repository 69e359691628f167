//! A simulated Elliptec ELL14 on a pseudo-terminal: it speaks the device's
//! protocol on the pty's master side, and the driver opens the slave's path
//! (`/dev/pts/N`) like any serial port, so the real serial code runs. It
//! keeps the angle it is at (the fake bench renders there) and can play
//! faults: no reply, an error reply, a move that lands off target, a
//! cable pulled.

use std::sync::{Arc, Mutex};

use crate::rig::serial::PtyDevice;

/// Pulses per turn of the simulated ELL14 (the real one's).
pub const PULSES: u32 = 143_360;

/// The simulated device's `in` reply data (after `0IN`).
const INFO: &str = "0E1140051720231701016800023000";

/// How the simulated device misbehaves.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Fault {
    /// It answers as the manual says.
    #[default]
    None,
    /// It answers nothing.
    Silent,
    /// Moves and homing answer this status code (2: mechanical timeout).
    Error(u8),
    /// Moves land this many pulses off target.
    Slip(i32),
}

struct State {
    pulses: i32,
    fault: Fault,
}

/// A running simulated ELL14; stops (the cable pulled) when dropped or
/// [`SimulatedEll14::unplug`]ged.
pub struct SimulatedEll14 {
    device: PtyDevice,
    state: Arc<Mutex<State>>,
}

impl SimulatedEll14 {
    /// Starts the device on a new pseudo-terminal at address `0`.
    pub fn start() -> std::io::Result<Self> {
        let state = Arc::new(Mutex::new(State {
            pulses: 0,
            fault: Fault::None,
        }));
        let st = state.clone();
        let mut pending = String::new();
        let device = PtyDevice::start("sim-ell14", move |bytes| {
            pending.extend(bytes.iter().map(|&b| b as char));
            let mut out = Vec::new();
            while let Some((cmd, rest)) = take_command(&pending) {
                if let Some(r) = answer(&cmd, &st) {
                    out.extend_from_slice(format!("{r}\r\n").as_bytes());
                }
                pending = rest;
            }
            out
        })?;
        Ok(Self { device, state })
    }

    /// The serial port's path to open (`/dev/pts/N`).
    pub fn path(&self) -> &str {
        self.device.path()
    }

    /// The angle the device is at, degrees in [0, 360).
    pub fn angle(&self) -> f64 {
        let p = self.state.lock().map(|s| s.pulses).unwrap_or(0);
        super::wrap_degrees(f64::from(p) * 360.0 / f64::from(PULSES))
    }

    /// Makes the device misbehave from now on (or behave again).
    pub fn set_fault(&self, fault: Fault) {
        if let Ok(mut s) = self.state.lock() {
            s.fault = fault;
        }
    }

    /// Pulls the cable: the device stops and its pty closes.
    pub fn unplug(&mut self) {
        self.device.unplug();
    }
}

/// The first whole command in `input` (address, two letters, data of the
/// command's length), and what follows it; line ends and noise before a
/// command are skipped.
fn take_command(input: &str) -> Option<(String, String)> {
    let s = input.trim_start_matches(|c: char| !c.is_ascii_hexdigit());
    let cmd = s.get(1..3)?;
    let data = match cmd {
        "ho" => 1,
        "ma" | "mr" => 8,
        _ => 0,
    };
    let end = 3 + data;
    let whole = s.get(..end)?;
    Some((whole.to_string(), s[end..].to_string()))
}

/// The reply to one command, or none (a silent device).
fn answer(cmd: &str, state: &Mutex<State>) -> Option<String> {
    let mut s = state.lock().ok()?;
    let addr = cmd.get(..1)?;
    if addr != "0" || s.fault == Fault::Silent {
        return None;
    }
    let position = |p: i32| format!("0PO{:08X}", p as u32);
    match cmd.get(1..3)? {
        "in" => Some(format!("0IN{INFO}")),
        "gs" => Some("0GS00".into()),
        "gp" => Some(position(s.pulses)),
        "ho" | "ma" => {
            if let Fault::Error(code) = s.fault {
                return Some(format!("0GS{code:02X}"));
            }
            let target = if &cmd[1..3] == "ho" {
                0
            } else {
                u32::from_str_radix(cmd.get(3..11)?, 16).ok()? as i32
            };
            let slip = match s.fault {
                Fault::Slip(p) => p,
                _ => 0,
            };
            s.pulses = (target + slip).rem_euclid(PULSES as i32);
            Some(position(s.pulses))
        }
        _ => Some("0GS03".into()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn commands_are_cut_by_their_length_and_noise_is_skipped() {
        assert_eq!(
            take_command("0gp0ma00004600"),
            Some(("0gp".into(), "0ma00004600".into()))
        );
        assert_eq!(
            take_command("\r\n0ho0"),
            Some(("0ho0".into(), String::new()))
        );
        assert_eq!(take_command("0ma0000"), None);
        let st = Mutex::new(State {
            pulses: 0,
            fault: Fault::None,
        });
        assert_eq!(answer("0ma00004600", &st).as_deref(), Some("0PO00004600"));
        assert_eq!(answer("0gp", &st).as_deref(), Some("0PO00004600"));
        assert_eq!(answer("0xx", &st).as_deref(), Some("0GS03"));
        assert_eq!(answer("1gp", &st), None);
    }
}
