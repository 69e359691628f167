//! The daemon's configuration: `config/polnlos.toml` embedded as the default,
//! an optional file on top, command-line flags last.

use std::collections::BTreeMap;
use std::net::SocketAddr;
use std::path::{Path, PathBuf};

use serde::Deserialize;

/// The embedded default configuration (runs against Aravis's fake camera).
pub const DEFAULT_TOML: &str = include_str!("../../../config/polnlos.toml");

/// Full configuration.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Config {
    /// HTTP bind address.
    pub bind: SocketAddr,
    /// Data directory.
    pub data_dir: PathBuf,
    /// Bearer token ("" = none).
    #[serde(default)]
    pub token: String,
    /// File holding the bearer token.
    pub token_file: Option<PathBuf>,
    /// Extra scene files.
    #[serde(default)]
    pub scene_files: Vec<PathBuf>,
    /// Camera selection.
    pub camera: CameraConfig,
    /// Demo scene of the fake camera.
    pub demo: DemoConfig,
    /// Queue limits.
    pub queue: QueueConfig,
    /// HTTP limits and who may talk to the daemon.
    #[serde(default)]
    pub http: HttpConfig,
    /// Fraction of full scale per microsecond per unit of `T l`, per scene.
    #[serde(default)]
    pub calibration: BTreeMap<String, f64>,
    /// What the daemon deletes by itself (nothing unless set).
    #[serde(default)]
    pub retention: RetentionConfig,
    /// The rotation mount that turns the polarizer (none unless set).
    #[serde(default)]
    pub mount: crate::rig::mount::MountConfig,
    /// The stage that moves the camera between poses (none unless set).
    #[serde(default)]
    pub stage: crate::rig::stage::StageConfig,
    /// The relay that switches the hidden scene's light (none unless set).
    #[serde(default)]
    pub light: crate::rig::relay::LightConfig,
}

/// A retention policy: the oldest finished captures (with the
/// reconstructions that use them) are deleted beyond an age or a total size;
/// jobs that are queued or running, and what they need, are never touched.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RetentionConfig {
    /// Captures older than this many days are deleted (0: no age limit).
    pub max_age_days: f64,
    /// The oldest captures are deleted while captures and reconstructions
    /// take more than this many MiB (0: no size limit).
    pub max_total_mib: u64,
    /// Seconds between two applications of the policy.
    pub check_every_s: f64,
}

impl Default for RetentionConfig {
    fn default() -> Self {
        Self {
            max_age_days: 0.0,
            max_total_mib: 0,
            check_every_s: 60.0,
        }
    }
}

impl RetentionConfig {
    /// The policy the store applies.
    pub fn policy(&self) -> crate::store::Retention {
        crate::store::Retention {
            max_age: (self.max_age_days > 0.0)
                .then(|| std::time::Duration::from_secs_f64(self.max_age_days * 86_400.0)),
            max_bytes: (self.max_total_mib > 0).then_some(self.max_total_mib << 20),
        }
    }
}

/// Which camera to open.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraConfig {
    /// Start Aravis's GigE Vision fake camera on `address`.
    #[serde(default)]
    pub fake: bool,
    /// The sensor the fake camera plays: `"mono"`, `"polarsens"` (a
    /// polarizer-mosaic camera presenting Lucid's PolarizeMono8/16 formats)
    /// or `"bayer"` (a colour camera, raw BayerRG16).
    #[serde(default)]
    pub fake_sensor: crate::camera::fake::FakeSensor,
    /// IP address to open the camera at.
    pub address: Option<String>,
    /// Aravis device id to open the camera by.
    pub id: Option<String>,
    /// Full-well capacity in electrons (the datasheet's), for exposure planning.
    #[serde(default = "full_well")]
    pub full_well_e: f64,
    /// Read noise in electrons RMS (the datasheet's), for exposure planning.
    #[serde(default = "read_noise")]
    pub read_noise_e: f64,
    /// What a capture that lost frames (dropped or broken) does.
    #[serde(default)]
    pub lost_frames: LostFrames,
    /// Seconds an acquisition may run beyond twice its frames' time before
    /// its capture fails as stalled (and the queue goes on).
    #[serde(default = "stall_slack")]
    pub stall_slack_s: f64,
    /// What a capture does whose frames have more than `saturated_share` of
    /// a frame's pixels at full scale.
    #[serde(default)]
    pub saturated: Saturated,
    /// The share of one frame's pixels at full scale (0..1) above which
    /// `saturated` applies; 0: any saturated pixel.
    #[serde(default)]
    pub saturated_share: f64,
}

/// What a capture with saturated pixels does: their values are lower
/// bounds, so its measurement is biased low where they fall (issue 38).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Saturated {
    /// Keep the capture; its record counts them, the log and the
    /// reconstructions that use it warn.
    #[default]
    Warn,
    /// Fail the capture, naming the count, so that it is taken again.
    Fail,
}

fn stall_slack() -> f64 {
    60.0
}

/// What a capture that lost frames does: the mean of the frames received is
/// still unbiased in free run, but a loss says the link or the host cannot
/// keep up, and a user may want such captures refused.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum LostFrames {
    /// Keep the capture; its record counts the losses and the log warns.
    #[default]
    Warn,
    /// Fail the capture, naming the losses.
    Fail,
}

fn full_well() -> f64 {
    10_000.0
}

fn read_noise() -> f64 {
    5.0
}

/// The fake camera's hidden scene.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DemoConfig {
    /// Scene name.
    pub scene: String,
    /// `disk`, `bars`, `letter` or `flat` (a white field, for a colour calibration).
    pub pattern: String,
    /// Whether the fake bench switches the hidden scene off for dark frames
    /// by itself (false: it plays a bench switched by hand).
    #[serde(default = "yes")]
    pub bench_switches_scene: bool,
    /// Whether the fake camera's frames carry the shot and read noise of
    /// `[camera] full_well_e` and `read_noise_e` (else only ±0.5 DN dither).
    #[serde(default = "yes")]
    pub sensor_noise: bool,
    /// A disk that moves over the pattern along a known closed path (none
    /// unless set): live view's difference mode and its tracker are tested
    /// against it (issue 49).
    #[serde(default)]
    pub motion: Option<MotionConfig>,
    /// How far the fake bench stands off its scene files, by freedom
    /// (`occluder-x` ... `wall-v`, `polnlos calibrate scene --free`; metres,
    /// degrees for `occluder-yaw`): the camera shows the bench so placed,
    /// and a scene calibration has a known truth to find (none unless set).
    #[serde(default)]
    pub bench_offset: std::collections::BTreeMap<String, f64>,
}

impl DemoConfig {
    /// [`DemoConfig::bench_offset`] as a placement, or which entry is wrong.
    pub fn placement(&self) -> Result<crate::calibrate::scene::Placement, ConfigError> {
        use crate::calibrate::scene::{Freedom, Placement};
        let mut p = Placement::default();
        for (name, &v) in &self.bench_offset {
            let f = Freedom::parse(name).ok_or_else(|| {
                ConfigError::Invalid(format!(
                    "demo.bench_offset.{name}: not a freedom; they are {}",
                    Freedom::ALL.map(Freedom::name).join(", ")
                ))
            })?;
            let most = if f.angular() { 30.0 } else { 0.1 };
            if !(v.is_finite() && v.abs() <= most) {
                return Err(ConfigError::Invalid(format!(
                    "demo.bench_offset.{name} = {v}: give at most {most} {} either way",
                    if f.angular() { "degrees" } else { "metres" }
                )));
            }
            p.set(f, v);
        }
        Ok(p)
    }
}

fn yes() -> bool {
    true
}

fn one() -> f64 {
    1.0
}

/// A bright disk the fake bench's hidden scene carries round a circle at a
/// steady speed, on top of the pattern: where it is at any moment is known,
/// so a tracker's answer can be checked against the truth.
///
/// The path's clock is the Unix time: at Unix time `t` seconds the disk's
/// centre is at `center_m + radius_m (cos 2 pi t / period_s, sin 2 pi t /
/// period_s)` on the hidden-scene plane (metres along its u and v axes,
/// MODEL.md "Geometry of a scene file"), so anyone holding a frame's time
/// computes where it was, with no state shared with the bench.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MotionConfig {
    /// The circle's centre on the hidden-scene plane, metres along (u, v)
    /// from the plane's centre (default the centre).
    #[serde(default)]
    pub center_m: [f64; 2],
    /// The circle's radius, metres (0: the disk stands still).
    pub radius_m: f64,
    /// Seconds per turn (anticlockwise, from +u towards +v).
    pub period_s: f64,
    /// The disk's radius, metres.
    pub disk_radius_m: f64,
    /// The disk's radiance, in units of the pattern's lit elements (default 1).
    #[serde(default = "one")]
    pub level: f64,
}

impl MotionConfig {
    /// The disk's centre at Unix time `unix_s`: (u, v) metres on the hidden-scene plane.
    /// Why: the bench renders it and a test computes the truth from it.
    pub fn position(&self, unix_s: f64) -> [f64; 2] {
        let angle = std::f64::consts::TAU * (unix_s / self.period_s).rem_euclid(1.0);
        [
            self.center_m[0] + self.radius_m * angle.cos(),
            self.center_m[1] + self.radius_m * angle.sin(),
        ]
    }

    /// Refuses a value that is not a finite length, period or level, naming it.
    fn check(&self) -> Result<(), ConfigError> {
        let bad = |name: &str, v: f64, want: &str| {
            Err(ConfigError::Invalid(format!(
                "demo.motion.{name} = {v}: give {want}"
            )))
        };
        for (k, &c) in ["center_m[0]", "center_m[1]"].iter().zip(&self.center_m) {
            if !c.is_finite() {
                return bad(k, c, "a finite offset in metres");
            }
        }
        if !(self.radius_m.is_finite() && self.radius_m >= 0.0) {
            return bad("radius_m", self.radius_m, "a radius >= 0 in metres");
        }
        if !(self.period_s.is_finite() && self.period_s >= 0.1 && self.period_s <= 86_400.0) {
            return bad("period_s", self.period_s, "0.1 to 86400 seconds a turn");
        }
        if !(self.disk_radius_m.is_finite() && self.disk_radius_m > 0.0) {
            return bad(
                "disk_radius_m",
                self.disk_radius_m,
                "a radius > 0 in metres",
            );
        }
        if !(self.level.is_finite() && self.level > 0.0 && self.level <= 100.0) {
            return bad("level", self.level, "a radiance above 0, up to 100");
        }
        Ok(())
    }
}

/// Queue limits.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct QueueConfig {
    /// Captures waiting.
    pub captures: usize,
    /// Reconstructions waiting.
    pub reconstructions: usize,
    /// Reconstructions running at once.
    pub reconstruction_workers: usize,
    /// Largest request body, bytes.
    pub max_body_bytes: usize,
    /// Frames (light + dark) one capture may take.
    #[serde(default = "max_frames")]
    pub max_frames_per_capture: usize,
    /// Disk space captures must leave free, MiB.
    #[serde(default = "reserve_free")]
    pub reserve_free_mib: u64,
    /// Largest file `POST /captures/import` takes, MiB (1 to 4096).
    #[serde(default = "max_import")]
    pub max_import_mib: u64,
}

fn max_import() -> u64 {
    512
}

fn max_frames() -> usize {
    1000
}

fn reserve_free() -> u64 {
    64
}

/// HTTP limits and who may talk to the daemon.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct HttpConfig {
    /// Connections served at once.
    pub max_connections: usize,
    /// Connections served at once from one client address (at most
    /// `max_connections`): one client cannot fill `max_connections` and lock
    /// everyone else out.
    pub max_connections_per_peer: usize,
    /// Seconds to send a request's headers.
    pub header_timeout_s: f64,
    /// Seconds to send a request's body.
    pub body_timeout_s: f64,
    /// Host names requests may be addressed to, besides the bound address and loopback names.
    pub allowed_hosts: Vec<String>,
    /// With a token, GET requests need none.
    pub public_reads: bool,
}

impl Default for HttpConfig {
    fn default() -> Self {
        Self {
            max_connections: 256,
            max_connections_per_peer: 64,
            header_timeout_s: 10.0,
            body_timeout_s: 30.0,
            allowed_hosts: Vec::new(),
            public_reads: false,
        }
    }
}

/// A configuration that cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    /// The file could not be read.
    #[error("cannot read config {path}: {source}")]
    Read {
        /// File.
        path: PathBuf,
        /// Cause.
        source: std::io::Error,
    },
    /// The file is not valid.
    #[error("config {path} is not valid: {message}")]
    Parse {
        /// File (or "embedded default").
        path: String,
        /// Parser message naming the key.
        message: String,
    },
    /// A value is not acceptable.
    #[error("config: {0}")]
    Invalid(String),
    /// A `[mount]`, `[stage]` or `[light]` value is not acceptable.
    #[error("config: {0}")]
    Rig(#[from] crate::rig::RigConfigError),
}

impl Config {
    /// The embedded default.
    pub fn embedded() -> Self {
        toml::from_str(DEFAULT_TOML).expect("the embedded config/polnlos.toml is valid")
    }

    /// Reads a config file (a complete file: start from config/polnlos.toml).
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Read {
            path: path.to_path_buf(),
            source,
        })?;
        toml::from_str(&text).map_err(|e| ConfigError::Parse {
            path: path.display().to_string(),
            message: e.to_string().trim_end().to_string(),
        })
    }

    /// The token in force ("" for none): `token`, or the contents of
    /// `token_file` (trimmed; an empty or whitespace-only file is an error,
    /// not "no token").
    pub fn resolved_token(&self) -> Result<String, ConfigError> {
        if self.token.trim() != self.token {
            return Err(ConfigError::Invalid(
                "token has leading or trailing whitespace; remove it".into(),
            ));
        }
        match &self.token_file {
            Some(p) if self.token.is_empty() => {
                let t = std::fs::read_to_string(p).map_err(|source| ConfigError::Read {
                    path: p.clone(),
                    source,
                })?;
                let t = t.trim();
                if t.is_empty() {
                    return Err(ConfigError::Invalid(format!(
                        "token_file {} is empty or only whitespace; write the token into it, or remove token_file",
                        p.display()
                    )));
                }
                Ok(t.to_string())
            }
            _ => Ok(self.token.clone()),
        }
    }

    /// Checks the combinations that would be unsafe or cannot work.
    pub fn validate(&self) -> Result<(), ConfigError> {
        let token = self.resolved_token()?;
        if !self.bind.ip().is_loopback() && token.is_empty() {
            return Err(ConfigError::Invalid(format!(
                "bind = {} is beyond loopback, so a token is required: set token or token_file",
                self.bind
            )));
        }
        let slack = self.camera.stall_slack_s;
        if !(slack.is_finite() && (0.0..=86_400.0).contains(&slack)) {
            return Err(ConfigError::Invalid(format!(
                "camera.stall_slack_s = {slack}: give 0 to 86400 seconds"
            )));
        }
        let share = self.camera.saturated_share;
        if !(share.is_finite() && (0.0..=1.0).contains(&share)) {
            return Err(ConfigError::Invalid(format!(
                "camera.saturated_share = {share}: give a share of a frame's pixels from 0 (any saturated pixel) to 1"
            )));
        }
        let r = &self.retention;
        if !(r.max_age_days.is_finite() && (0.0..=36_500.0).contains(&r.max_age_days)) {
            return Err(ConfigError::Invalid(format!(
                "retention.max_age_days = {}: give 0 (no age limit) up to 36500 days",
                r.max_age_days
            )));
        }
        if r.max_total_mib > (1 << 40) {
            return Err(ConfigError::Invalid(format!(
                "retention.max_total_mib = {}: at most 2^40 MiB; 0 means no size limit",
                r.max_total_mib
            )));
        }
        if !(r.check_every_s.is_finite() && (0.1..=86_400.0).contains(&r.check_every_s)) {
            return Err(ConfigError::Invalid(format!(
                "retention.check_every_s = {}: give 0.1 to 86400 seconds",
                r.check_every_s
            )));
        }
        self.demo.placement()?;
        if let Some(m) = &self.demo.motion {
            m.check()?;
        }
        self.mount.check()?;
        self.stage.check()?;
        self.light.check()?;
        if self.camera.address.is_none() && self.camera.id.is_none() {
            return Err(ConfigError::Invalid(
                "[camera] needs address or id (polnlos never runs a broadcast discovery)".into(),
            ));
        }
        if self.camera.fake
            && !self
                .camera
                .address
                .as_deref()
                .map(|a| a.starts_with("127."))
                .unwrap_or(false)
        {
            return Err(ConfigError::Invalid(
                "[camera] fake = true needs a loopback address (127.x.y.z)".into(),
            ));
        }
        let c = &self.camera;
        let sensor_ok = c.full_well_e > 0.0
            && c.full_well_e.is_finite()
            && c.read_noise_e >= 0.0
            && c.read_noise_e.is_finite();
        if !sensor_ok {
            return Err(ConfigError::Invalid(format!(
                "[camera] full_well_e = {} and read_noise_e = {}: need a positive full well and a read noise >= 0 (electrons, from the camera's datasheet)",
                c.full_well_e, c.read_noise_e
            )));
        }
        let q = &self.queue;
        if q.captures == 0
            || q.reconstructions == 0
            || q.reconstruction_workers == 0
            || q.max_body_bytes < 1024
            || !(1..=4096).contains(&q.max_import_mib)
            || q.max_frames_per_capture == 0
        {
            return Err(ConfigError::Invalid(
                "[queue] sizes must be at least 1 (max_body_bytes at least 1024, max_import_mib 1 to 4096)".into(),
            ));
        }
        let h = &self.http;
        let seconds = |v: f64| v > 0.0 && v <= 3600.0;
        if h.max_connections == 0 || !seconds(h.header_timeout_s) || !seconds(h.body_timeout_s) {
            return Err(ConfigError::Invalid(format!(
                "[http] max_connections = {}, header_timeout_s = {}, body_timeout_s = {}: need at least 1 connection and timeouts from 0 to 3600 s",
                h.max_connections, h.header_timeout_s, h.body_timeout_s
            )));
        }
        if h.max_connections_per_peer == 0 {
            return Err(ConfigError::Invalid(
                "[http] max_connections_per_peer = 0: need at least 1 (and well below max_connections, so that one client cannot lock the others out)".into(),
            ));
        }
        Ok(())
    }
}

/// The log filter `RUST_LOG` asks for (`None`: `info`), and why it could
/// not be read when it could not.
pub fn log_targets(
    var: Option<&str>,
) -> (
    tracing_subscriber::filter::Targets,
    Option<tracing_subscriber::filter::ParseError>,
) {
    let info = || tracing_subscriber::filter::Targets::new().with_default(tracing::Level::INFO);
    match var.map(str::trim).filter(|v| !v.is_empty()) {
        None => (info(), None),
        Some(v) => match v.parse() {
            Ok(t) => (t, None),
            Err(e) => (info(), Some(e)),
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn embedded_default_is_valid_and_loopback() {
        let c = Config::embedded();
        c.validate().unwrap();
        assert!(c.bind.ip().is_loopback());
        assert!(c.camera.fake);
    }

    #[test]
    fn a_whitespace_token_file_is_an_error_not_no_token() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("token");
        std::fs::write(&p, " \n\t\n").unwrap();
        let mut c = Config::embedded();
        c.token_file = Some(p.clone());
        assert!(c
            .resolved_token()
            .unwrap_err()
            .to_string()
            .contains("whitespace"));
        std::fs::write(&p, "s3cret\n").unwrap();
        assert_eq!(c.resolved_token().unwrap(), "s3cret");
        c.token = " padded".into();
        assert!(c.resolved_token().is_err());
    }

    #[test]
    fn retention_is_off_by_default_and_its_values_are_checked() {
        let c = Config::embedded();
        assert_eq!(c.retention.policy(), crate::store::Retention::default());
        let mut c = Config::embedded();
        c.retention.max_age_days = 30.0;
        c.retention.max_total_mib = 1024;
        let p = c.retention.policy();
        assert_eq!(p.max_age, Some(std::time::Duration::from_secs(30 * 86_400)));
        assert_eq!(p.max_bytes, Some(1 << 30));
        c.retention.max_age_days = -1.0;
        let e = c.validate().unwrap_err().to_string();
        assert!(e.contains("retention.max_age_days = -1"), "{e}");
        c.retention.max_age_days = 0.0;
        c.retention.check_every_s = f64::NAN;
        assert!(c
            .validate()
            .unwrap_err()
            .to_string()
            .contains("retention.check_every_s"));
    }

    #[test]
    fn the_camera_policies_default_to_keep_and_a_minute_and_are_checked() {
        let c = Config::embedded();
        assert_eq!(c.camera.lost_frames, LostFrames::Warn);
        assert_eq!(c.camera.stall_slack_s, 60.0);
        for bad in [f64::NAN, -1.0, 1e6] {
            let mut c = Config::embedded();
            c.camera.stall_slack_s = bad;
            let e = c.validate().unwrap_err().to_string();
            assert!(e.contains("camera.stall_slack_s"), "{e}");
        }
        assert_eq!(c.camera.saturated, Saturated::Warn);
        assert_eq!(c.camera.saturated_share, 0.0);
        for bad in [f64::NAN, -0.1, 1.5] {
            let mut c = Config::embedded();
            c.camera.saturated_share = bad;
            let e = c.validate().unwrap_err().to_string();
            assert!(e.contains("camera.saturated_share"), "{e}");
        }
    }

    #[test]
    fn the_moving_disk_goes_round_its_circle_on_the_unix_clock_and_its_values_are_checked() {
        let text = DEFAULT_TOML.replacen(
            "\nsensor_noise = true\n",
            "\nsensor_noise = true\nmotion = { center_m = [0.01, -0.02], radius_m = 0.05, period_s = 4.0, disk_radius_m = 0.03 }\n",
            1,
        );
        let c: Config = toml::from_str(&text).unwrap();
        c.validate().unwrap();
        let m = c.demo.motion.expect("motion");
        assert_eq!(m.level, 1.0);
        let near = |a: [f64; 2], b: [f64; 2]| (a[0] - b[0]).hypot(a[1] - b[1]) < 1e-9;
        // A turn every 4 s, anticlockwise from +u: a quarter turn is +v.
        assert!(near(m.position(1_700_000_000.0), [0.06, -0.02]));
        assert!(near(m.position(1_700_000_001.0), [0.01, 0.03]));
        assert!(near(m.position(1_700_000_002.0), [-0.04, -0.02]));
        assert!(near(
            m.position(1_700_000_004.0),
            m.position(1_700_000_000.0)
        ));
        // The speed is the circumference over the period.
        // (Over 10 ms: the Unix time's f64 resolves 0.24 us.)
        let (a, b) = (m.position(1_700_000_000.0), m.position(1_700_000_000.01));
        let speed = (a[0] - b[0]).hypot(a[1] - b[1]) / 0.01;
        let circumference = std::f64::consts::TAU * 0.05;
        assert!(
            (speed / (circumference / 4.0) - 1.0).abs() < 1e-3,
            "{speed}"
        );
        for (field, bad) in [
            ("radius_m", -0.1),
            ("period_s", 0.0),
            ("period_s", f64::NAN),
            ("disk_radius_m", 0.0),
            ("level", f64::INFINITY),
        ] {
            let mut c = c.clone();
            let m = c.demo.motion.as_mut().unwrap();
            match field {
                "radius_m" => m.radius_m = bad,
                "period_s" => m.period_s = bad,
                "disk_radius_m" => m.disk_radius_m = bad,
                _ => m.level = bad,
            }
            let e = c.validate().unwrap_err().to_string();
            assert!(e.contains(&format!("demo.motion.{field}")), "{e}");
        }
    }

    #[test]
    fn the_fake_bench_offset_is_a_placement_by_freedom_and_refused_out_of_range() {
        use crate::calibrate::scene::Freedom;
        let mut c = Config::embedded();
        c.demo.bench_offset = [("occluder-x".into(), 0.02), ("scene-u".into(), -0.01)].into();
        let p = c.demo.placement().unwrap();
        assert_eq!(p.get(Freedom::OccluderX), 0.02);
        assert_eq!(p.get(Freedom::SceneU), -0.01);
        assert_eq!(p.get(Freedom::Distance), 0.0);
        for (name, v, says) in [
            ("occluder-w", 0.01, "not a freedom; they are occluder-x"),
            ("distance", 0.5, "at most 0.1 metres"),
            ("occluder-yaw", f64::NAN, "at most 30 degrees"),
        ] {
            let mut c = c.clone();
            c.demo.bench_offset = [(name.into(), v)].into();
            let e = c.validate().unwrap_err().to_string();
            assert!(
                e.contains(&format!("demo.bench_offset.{name}")) && e.contains(says),
                "{e}"
            );
        }
    }

    #[test]
    fn beyond_loopback_needs_a_token() {
        let mut c = Config::embedded();
        c.bind = "0.0.0.0:8470".parse().unwrap();
        assert!(c
            .validate()
            .unwrap_err()
            .to_string()
            .contains("token is required"));
        c.token = "secret".into();
        c.validate().unwrap();
    }

    #[test]
    fn rust_log_sets_levels_per_target_and_an_unreadable_one_falls_back_to_info() {
        let (t, e) = super::log_targets(Some("warn,polnlos::daemon=debug"));
        assert!(e.is_none());
        assert!(t.would_enable("polnlos::daemon::jobs", &tracing::Level::DEBUG));
        assert!(!t.would_enable("polnlos::store", &tracing::Level::INFO));
        assert!(t.would_enable("polnlos::store", &tracing::Level::WARN));
        for unset in [None, Some(""), Some("  ")] {
            let (t, e) = super::log_targets(unset);
            assert!(e.is_none());
            assert!(t.would_enable("polnlos", &tracing::Level::INFO));
            assert!(!t.would_enable("polnlos", &tracing::Level::DEBUG));
        }
        let (t, e) = super::log_targets(Some("polnlos=loud"));
        assert!(e.is_some());
        assert!(t.would_enable("polnlos", &tracing::Level::INFO));
        assert!(!t.would_enable("polnlos", &tracing::Level::DEBUG));
    }
}
