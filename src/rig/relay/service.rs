//! The relay that switches the hidden scene's light: opened from `[light]`,
//! switched off by a capture around its dark frames (and a dark capture),
//! and shown by `GET /light`.
//!
//! Why here: a bench with a relay takes its darks unattended, so a plan
//! needs no "switch the hidden scene off" step; a relay that does not read
//! back what it was sent fails the capture instead of labelling lit frames
//! dark. Without one (`kind = "none"`) the bench's own switch (the fake
//! bench's) or the operator does it.

use std::sync::Mutex;

use serde::{Deserialize, Serialize};

use crate::rig::relay::devantech::Devantech;
use crate::rig::relay::simulated::SimulatedRelay;
use crate::rig::relay::{LightSwitch, RelayError};

/// Which relay switches the hidden scene's light (`[light]`).
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LightConfig {
    /// `none`, `simulated` (a USB-RLY02 on a pseudo-terminal, for the fake
    /// bench) or `devantech` (a Devantech USB-RLY02/08/16 on `port`).
    #[serde(default)]
    pub kind: LightKind,
    /// Serial port of a `devantech` module, e.g. `/dev/ttyACM0`.
    pub port: Option<String>,
    /// The relay the scene's light is wired through (normally open: energized is lit), 1-8.
    #[serde(default = "first_relay")]
    pub relay: u8,
}

fn first_relay() -> u8 {
    1
}

impl Default for LightConfig {
    fn default() -> Self {
        Self {
            kind: LightKind::None,
            port: None,
            relay: first_relay(),
        }
    }
}

/// The kinds of light switch.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize, Serialize, utoipa::ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum LightKind {
    /// No relay: the bench's own switch, or the operator.
    #[default]
    None,
    /// A simulated Devantech USB-RLY02 on a pseudo-terminal.
    Simulated,
    /// A Devantech USB-RLY02/08/16 relay module on a serial port.
    Devantech,
}

impl LightConfig {
    /// Checks the values a config file gave, naming the key.
    pub fn check(&self) -> Result<(), crate::rig::RigConfigError> {
        let bad = |key: String, reason: &str| crate::rig::RigConfigError::new("light", key, reason);
        if self.kind == LightKind::Devantech && self.port.as_deref().unwrap_or("").is_empty() {
            return Err(bad(
                "kind = \"devantech\"".into(),
                "needs port (e.g. \"/dev/ttyACM0\")",
            ));
        }
        if !(1..=8).contains(&self.relay) {
            return Err(bad(format!("relay = {}:", self.relay), "must be 1 to 8"));
        }
        Ok(())
    }
}

/// The light switch now, as `GET /light` shows it.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct LightView {
    /// Which switch is configured.
    pub kind: LightKind,
    /// Its serial port (the pseudo-terminal of a simulated one).
    pub port: Option<String>,
    /// The relay the light is wired through.
    pub relay: u8,
    /// Whether the light was on when last read.
    pub on: Option<bool>,
    /// What went wrong last, if the last command failed.
    pub last_error: Option<String>,
}

/// The open module and what it last said.
struct State {
    device: Option<Box<dyn LightSwitch>>,
    on: Option<bool>,
    last_error: Option<String>,
}

/// Owns the relay (and, on the fake bench, the simulated module it talks
/// to); one command at a time behind its lock.
pub struct LightService {
    config: LightConfig,
    port: Option<String>,
    state: Mutex<State>,
    simulated: Option<SimulatedRelay>,
}

impl LightService {
    /// Starts the configured switch; a module that cannot be opened now is
    /// opened again at the next switch (its error is shown meanwhile).
    pub fn start(config: &LightConfig) -> Result<Self, RelayError> {
        let simulated = match config.kind {
            LightKind::Simulated => {
                Some(SimulatedRelay::start().map_err(|e| RelayError::Open {
                    port: "a pseudo-terminal".into(),
                    reason: e.to_string(),
                })?)
            }
            _ => None,
        };
        let port = match config.kind {
            LightKind::None => None,
            LightKind::Simulated => simulated.as_ref().map(|s| s.path().to_string()),
            LightKind::Devantech => config.port.clone(),
        };
        let service = Self {
            config: config.clone(),
            port,
            state: Mutex::new(State {
                device: None,
                on: None,
                last_error: None,
            }),
            simulated,
        };
        // The scene is lit between captures.
        if service.present() {
            let _ = service.set(true);
        }
        Ok(service)
    }

    /// Whether a relay switches the scene's light.
    pub fn present(&self) -> bool {
        self.config.kind != LightKind::None
    }

    /// Whether dark frames need no operator on a bench with this switch:
    /// a relay, or `bench`'s own switch (the fake bench's).
    pub fn switches_scene(&self, bench: &dyn crate::rig::bench::Bench) -> bool {
        self.present() || bench.switches_scene()
    }

    /// Switches the light and returns the state read back, or why it could
    /// not (blocking: serial I/O of up to a second). A failure closes the
    /// module, to be opened again at the next switch.
    pub fn set(&self, on: bool) -> Result<bool, RelayError> {
        let mut s = self.state.lock().unwrap_or_else(|e| e.into_inner());
        let result = match s.device.as_mut() {
            Some(d) => d.set(on),
            None => self.open().and_then(|mut d| {
                let r = d.set(on);
                s.device = Some(d);
                r
            }),
        };
        match &result {
            Ok(read) => {
                s.on = Some(*read);
                s.last_error = None;
            }
            Err(e) => {
                s.device = None;
                s.on = None;
                s.last_error = Some(e.to_string());
            }
        }
        result
    }

    fn open(&self) -> Result<Box<dyn LightSwitch>, RelayError> {
        let port = self.port.clone().unwrap_or_default();
        Ok(Box::new(Devantech::open(&port, self.config.relay)?))
    }

    /// The simulated module, to play faults in tests (`None` for a real one).
    pub fn simulated(&self) -> Option<&SimulatedRelay> {
        self.simulated.as_ref()
    }

    /// The switch as last seen (no I/O).
    pub fn view(&self) -> LightView {
        let s = self.state.lock().unwrap_or_else(|e| e.into_inner());
        LightView {
            kind: self.config.kind,
            port: self.port.clone(),
            relay: self.config.relay,
            on: s.on,
            last_error: s.last_error.clone(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rig::relay::simulated::Fault;

    #[test]
    fn the_simulated_relay_lights_the_scene_and_a_stuck_one_is_named() {
        let simulated = LightConfig {
            kind: LightKind::Simulated,
            ..LightConfig::default()
        };
        let l = LightService::start(&simulated).unwrap();
        assert!(l.present());
        let sim = l.simulated().expect("simulated");
        // Lit from the start.
        assert!(sim.is_on(1));
        assert!(!l.set(false).unwrap());
        assert!(!sim.is_on(1));
        assert_eq!(l.view().on, Some(false));
        sim.set_fault(Fault::Stuck);
        let e = l.set(true).unwrap_err().to_string();
        assert!(e.contains("switched on but reads off"), "{e}");
        assert!(l.view().last_error.is_some_and(|m| m.contains("relay 1")));
        sim.set_fault(Fault::None);
        assert!(l.set(true).unwrap());
        assert!(LightConfig {
            kind: LightKind::Devantech,
            ..LightConfig::default()
        }
        .check()
        .unwrap_err()
        .to_string()
        .contains("needs port"));
        assert!(LightConfig {
            relay: 9,
            ..LightConfig::default()
        }
        .check()
        .unwrap_err()
        .to_string()
        .contains("relay = 9"));
    }
}
