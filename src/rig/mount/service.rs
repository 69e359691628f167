//! The rotation mount that turns the polarizer: opened from `[mount]`,
//! turned by a capture to its polarizer angle before the first frame, and
//! shown by `GET /mount`.
//!
//! Why here: a capture records the angle its polarizer was *measured* at,
//! so a mount that slipped or was unplugged fails the capture with the
//! angles named instead of labelling frames with an angle they were not
//! taken at. Without a mount (`kind = "none"`) the daemon trusts the
//! request's `polarizer_deg`, as a bench turned by hand must.

use std::sync::Mutex;

use serde::{Deserialize, Serialize};

use crate::rig::mount::elliptec::Elliptec;
use crate::rig::mount::simulated::SimulatedEll14;
use crate::rig::mount::{wrap_degrees, MountError, RotationMount};

/// Which mount turns the polarizer (`[mount]`).
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MountConfig {
    /// `none` (turned by hand), `simulated` (an ELL14 on a pseudo-terminal,
    /// for the fake bench) or `elliptec` (a Thorlabs ELL14/ELL18 on `port`).
    #[serde(default)]
    pub kind: MountKind,
    /// Serial port of an `elliptec` mount, e.g. `/dev/ttyUSB0`.
    pub port: Option<String>,
    /// Its device address (`0` unless it was changed).
    #[serde(default = "default_address")]
    pub address: char,
    /// Mount angle, degrees, at which the polarizer is crossed
    /// (`polarizer_deg` 0); a capture at `polarizer_deg` θ turns the mount
    /// to `zero_deg + θ`.
    #[serde(default)]
    pub zero_deg: f64,
    /// Mount angle at which the *simulated* polarizer is really crossed
    /// (`kind = "simulated"` only): the fake bench shows the light of that
    /// truth, so a `zero_deg` that differs from it (an uncalibrated mount)
    /// shows in the frames; `POST /mount/zero` finds it.
    #[serde(default)]
    pub simulated_zero_deg: f64,
}

fn default_address() -> char {
    '0'
}

impl Default for MountConfig {
    fn default() -> Self {
        Self {
            kind: MountKind::None,
            port: None,
            address: default_address(),
            zero_deg: 0.0,
            simulated_zero_deg: 0.0,
        }
    }
}

/// The kinds of mount.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize, Serialize, utoipa::ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum MountKind {
    /// No mount: the polarizer is turned by hand.
    #[default]
    None,
    /// A simulated ELL14 on a pseudo-terminal (the fake bench's).
    Simulated,
    /// A Thorlabs Elliptec ELL14/ELL18 on a serial port.
    Elliptec,
}

impl MountConfig {
    /// Checks the values a config file gave, naming the key.
    pub fn check(&self) -> Result<(), crate::rig::RigConfigError> {
        let bad = |key: String, reason: &str| crate::rig::RigConfigError::new("mount", key, reason);
        if self.kind == MountKind::Elliptec && self.port.as_deref().unwrap_or("").is_empty() {
            return Err(bad(
                "kind = \"elliptec\"".into(),
                "needs port (e.g. \"/dev/ttyUSB0\")",
            ));
        }
        if !self.address.is_ascii_hexdigit() {
            return Err(bad(
                format!("address = {:?}:", self.address),
                "must be one hexadecimal digit, 0-F",
            ));
        }
        for (key, v) in [
            ("zero_deg", self.zero_deg),
            ("simulated_zero_deg", self.simulated_zero_deg),
        ] {
            if !(v.is_finite() && v.abs() <= 360.0) {
                return Err(bad(
                    format!("{key} = {v}:"),
                    "must be degrees from -360 to 360",
                ));
            }
        }
        Ok(())
    }
}

/// The mount now, as `GET /mount` shows it.
#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct MountView {
    /// Which mount is configured.
    pub kind: MountKind,
    /// Its serial port (the pseudo-terminal of a simulated one).
    pub port: Option<String>,
    /// Whether it answered the last command.
    pub connected: bool,
    /// Mount angle last read back, degrees in [0, 360).
    pub position_deg: Option<f64>,
    /// The polarizer angle that is, from crossed (`position_deg - zero_deg`, in (-180, 180]).
    pub polarizer_deg: Option<f64>,
    /// Mount angle at which the polarizer is crossed, in force now.
    pub zero_deg: f64,
    /// Where `zero_deg` comes from: `config` (`[mount] zero_deg`), or
    /// `calibrated <time>` (`POST /mount/zero`, kept in the data directory).
    pub zero_source: String,
    /// What went wrong last, if the last command failed.
    pub last_error: Option<String>,
}

/// The open mount and what it last said.
struct State {
    device: Option<Box<dyn RotationMount>>,
    position_deg: Option<f64>,
    last_error: Option<String>,
}

/// Owns the mount (and, on the fake bench, the simulated device it talks
/// to); one command at a time behind its lock.
pub struct MountService {
    config: MountConfig,
    port: Option<String>,
    /// The zero in force and where it comes from.
    zero: Mutex<(f64, String)>,
    /// Where a calibrated zero is kept (`None`: not kept).
    zero_file: Option<std::path::PathBuf>,
    state: Mutex<State>,
    /// The simulated device, kept running while the daemon is.
    simulated: Option<SimulatedEll14>,
}

impl MountService {
    /// Starts the configured mount; one that cannot be opened now is opened
    /// again at the next capture (its error is shown meanwhile). A zero
    /// calibrated earlier and kept in `zero_file` overrides `[mount] zero_deg`.
    pub fn start(
        config: &MountConfig,
        zero_file: Option<std::path::PathBuf>,
    ) -> Result<Self, MountError> {
        let simulated = match config.kind {
            MountKind::Simulated => {
                Some(SimulatedEll14::start().map_err(|e| MountError::Open {
                    port: "a pseudo-terminal".into(),
                    reason: e.to_string(),
                })?)
            }
            _ => None,
        };
        let port = match config.kind {
            MountKind::None => None,
            MountKind::Simulated => simulated.as_ref().map(|s| s.path().to_string()),
            MountKind::Elliptec => config.port.clone(),
        };
        let kept = zero_file
            .as_deref()
            .and_then(|f| std::fs::read_to_string(f).ok())
            .and_then(|t| serde_json::from_str::<KeptZero>(&t).ok())
            .filter(|k| k.zero_deg.is_finite() && k.zero_deg.abs() <= 360.0);
        let zero = match kept {
            Some(k) => {
                tracing::info!(
                    "rotation mount: crossed at {:.3}° (calibrated {}; [mount] zero_deg = {} is not used)",
                    k.zero_deg,
                    k.calibrated_at,
                    config.zero_deg
                );
                (k.zero_deg, format!("calibrated {}", k.calibrated_at))
            }
            None => (config.zero_deg, "config".to_string()),
        };
        let service = Self {
            config: config.clone(),
            port,
            zero: Mutex::new(zero),
            zero_file,
            state: Mutex::new(State {
                device: None,
                position_deg: None,
                last_error: None,
            }),
            simulated,
        };
        let _ = service.read();
        Ok(service)
    }

    /// Whether a mount turns the polarizer (else the request's angle is trusted).
    pub fn present(&self) -> bool {
        self.config.kind != MountKind::None
    }

    /// Turns the polarizer to `polarizer_deg` from crossed and returns the
    /// angle measured after the move (same convention), or why it could not.
    /// Blocking: serial I/O of up to a few seconds.
    pub fn turn_to(&self, polarizer_deg: f64) -> Result<f64, MountError> {
        let zero = self.zero_deg();
        let position = self.with_device(|d| d.move_to(zero + polarizer_deg))?;
        Ok(from_crossed(position, zero))
    }

    /// Mount angle at which the polarizer is crossed, in force now.
    pub fn zero_deg(&self) -> f64 {
        self.zero.lock().unwrap_or_else(|e| e.into_inner()).0
    }

    /// Makes `zero_deg` the crossed setting from now on and keeps it in the
    /// data directory (written to a new file, then renamed over the old).
    pub fn set_zero(&self, zero_deg: f64, calibrated_at: &str) -> std::io::Result<()> {
        if let Some(f) = &self.zero_file {
            let kept = KeptZero {
                zero_deg,
                calibrated_at: calibrated_at.to_string(),
            };
            let text = serde_json::to_string_pretty(&kept).map_err(std::io::Error::other)?;
            let tmp = f.with_extension("json.new");
            std::fs::write(&tmp, text)?;
            std::fs::File::open(&tmp)?.sync_all()?;
            std::fs::rename(&tmp, f)?;
        }
        *self.zero.lock().unwrap_or_else(|e| e.into_inner()) =
            (zero_deg, format!("calibrated {calibrated_at}"));
        Ok(())
    }

    /// Where the simulated polarizer really is, degrees from its true
    /// crossed setting (`None` for a real mount or none: only the bench
    /// knows). What the fake bench shows.
    pub fn simulated_truth_deg(&self) -> Option<f64> {
        let sim = self.simulated.as_ref()?;
        Some(from_crossed(sim.angle(), self.config.simulated_zero_deg))
    }

    /// Reads the position (blocking, a fraction of a second).
    pub fn read(&self) -> Result<f64, MountError> {
        self.with_device(|d| d.position())
    }

    /// The mount as last seen (no I/O).
    pub fn view(&self) -> MountView {
        let (zero_deg, zero_source) = self.zero.lock().unwrap_or_else(|e| e.into_inner()).clone();
        let s = self.state.lock().unwrap_or_else(|e| e.into_inner());
        MountView {
            kind: self.config.kind,
            port: self.port.clone(),
            connected: s.device.is_some() && s.last_error.is_none(),
            position_deg: s.position_deg,
            polarizer_deg: s.position_deg.map(|p| from_crossed(p, zero_deg)),
            zero_deg,
            zero_source,
            last_error: s.last_error.clone(),
        }
    }

    /// Runs `f` on the device, opening it first when it is not open; a
    /// failure closes it (the next command opens it again) and is kept for
    /// the view.
    fn with_device(
        &self,
        f: impl FnOnce(&mut dyn RotationMount) -> Result<f64, MountError>,
    ) -> Result<f64, MountError> {
        let mut s = self.state.lock().unwrap_or_else(|e| e.into_inner());
        let result = self.open(&mut s).and_then(f);
        match &result {
            Ok(p) => {
                s.position_deg = Some(*p);
                s.last_error = None;
            }
            Err(e) => {
                s.device = None;
                s.last_error = Some(e.to_string());
            }
        }
        result
    }

    fn open<'a>(&self, s: &'a mut State) -> Result<&'a mut dyn RotationMount, MountError> {
        if s.device.is_none() {
            let Some(port) = self.port.as_deref() else {
                return Err(MountError::Open {
                    port: "(none)".into(),
                    reason: "no rotation mount is configured ([mount] kind = \"none\")".into(),
                });
            };
            s.device = Some(Box::new(Elliptec::open(port, self.config.address)?));
        }
        match s.device.as_deref_mut() {
            Some(d) => Ok(d),
            None => Err(MountError::Open {
                port: self.port.clone().unwrap_or_default(),
                reason: "not open".into(),
            }),
        }
    }
}

/// A calibrated zero as the data directory keeps it (`mount-zero.json`).
#[derive(Debug, Serialize, Deserialize)]
struct KeptZero {
    zero_deg: f64,
    calibrated_at: String,
}

/// A mount angle as a polarizer angle from crossed, in (-180, 180].
fn from_crossed(position_deg: f64, zero_deg: f64) -> f64 {
    let d = wrap_degrees(position_deg - zero_deg);
    if d > 180.0 {
        d - 360.0
    } else {
        d
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mount_angles_read_as_polarizer_angles_from_crossed() {
        assert_eq!(from_crossed(30.0, 0.0), 30.0);
        assert_eq!(from_crossed(350.0, 0.0), -10.0);
        assert_eq!(from_crossed(10.0, 20.0), -10.0);
        assert_eq!(from_crossed(200.0, 20.0), 180.0);
    }

    #[test]
    fn a_config_without_what_its_kind_needs_is_refused_by_key() {
        let elliptec = MountConfig {
            kind: MountKind::Elliptec,
            ..MountConfig::default()
        };
        assert!(elliptec
            .check()
            .unwrap_err()
            .to_string()
            .contains("needs port"));
        let far = MountConfig {
            zero_deg: 400.0,
            ..MountConfig::default()
        };
        assert!(far
            .check()
            .unwrap_err()
            .to_string()
            .contains("zero_deg = 400"));
        let bad = MountConfig {
            address: 'x',
            ..MountConfig::default()
        };
        assert!(bad.check().unwrap_err().to_string().contains("address"));
        MountConfig::default().check().unwrap();
    }

    #[test]
    fn the_simulated_mount_turns_and_reads_back_through_the_driver() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("mount-zero.json");
        let config = MountConfig {
            kind: MountKind::Simulated,
            zero_deg: 12.0,
            ..MountConfig::default()
        };
        let m = MountService::start(&config, Some(file.clone())).unwrap();
        assert!(m.present());
        let got = m.turn_to(45.0).unwrap();
        assert!((got - 45.0).abs() < 0.05, "{got}");
        let v = m.view();
        assert!(v.connected, "{v:?}");
        assert!((v.position_deg.unwrap() - 57.0).abs() < 0.05, "{v:?}");
        assert!((v.polarizer_deg.unwrap() - 45.0).abs() < 0.05, "{v:?}");
        assert_eq!(v.zero_source, "config");
        // A calibrated zero is used at once and kept across a restart.
        m.set_zero(20.0, "2026-11-24T00:00:00Z").unwrap();
        assert!((m.turn_to(0.0).unwrap()).abs() < 0.05);
        assert!((m.view().position_deg.unwrap() - 20.0).abs() < 0.05);
        drop(m);
        let again = MountService::start(&config, Some(file)).unwrap();
        assert_eq!(again.zero_deg(), 20.0);
        assert!(again
            .view()
            .zero_source
            .starts_with("calibrated 2026-11-24"));
    }
}
