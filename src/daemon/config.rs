//! leveld configuration (TOML): interfaces, DBC, the role of each signal, checks,
//! timeouts, output, actuator and estimator parameters, state file.

pub use crate::can::checks::ChecksumKind;
pub use crate::can::codec::{InputMessage, OutputMessage};
use crate::estimator::EstimatorConfig;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CanConfig {
    /// Interfaces to read (live). Replays read every interface unless told otherwise.
    pub input_interfaces: Vec<String>,
    pub output_interface: String,
    /// DBC file; relative paths are taken from the config file's folder.
    pub dbc: PathBuf,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Leveling {
    /// Road-to-body pitch measured at end-of-line on a level floor, deg. A calibration
    /// stored in the state file takes precedence.
    pub reference_pitch_deg: f64,
    pub actuator_min_deg: f64,
    pub actuator_max_deg: f64,
    /// VALID needs a standard error at or below this, deg.
    pub valid_max_std_err_deg: f64,
    /// VALID needs at least this many windows (a load-change prior counts).
    pub valid_min_windows: f64,
    /// Consecutive failed frames before a message is marked invalid.
    pub invalid_after: u32,
    /// Consecutive good frames before an invalid message is valid again.
    pub valid_after: u32,
    /// A frame timestamp further ahead than this of the newest one is a clock step,
    /// not time that passed (see `daemon::clock`), s.
    pub max_clock_step_s: f64,
}

impl Default for Leveling {
    fn default() -> Self {
        Self {
            reference_pitch_deg: 0.0,
            actuator_min_deg: -3.0,
            actuator_max_deg: 3.0,
            valid_max_std_err_deg: 0.06,
            valid_min_windows: 4.0,
            invalid_after: 3,
            valid_after: 3,
            max_clock_step_s: 5.0,
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StateConfig {
    pub path: PathBuf,
    /// Where the running daemon publishes its status for `leveld status`; its folder
    /// must exist (the unit's RuntimeDirectory). Empty: publish nothing.
    #[serde(default = "default_status_path")]
    pub status_path: PathBuf,
    /// The end-of-line calibration, written only by `leveld calibrate`. Default:
    /// `calibration.json` next to the state file.
    #[serde(default)]
    pub calibration_path: PathBuf,
}

fn default_status_path() -> PathBuf {
    PathBuf::from("/run/leveld/status.json")
}

/// The whole configuration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Config {
    pub can: CanConfig,
    pub wheels: InputMessage,
    pub acc: InputMessage,
    pub gyro: InputMessage,
    pub output: OutputMessage,
    #[serde(default)]
    pub leveling: Leveling,
    pub state: StateConfig,
    #[serde(default)]
    pub estimator: EstimatorConfig,
}

/// A configuration problem, naming the file and the field or line.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error("cannot read config {path}: {source}")]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("config {path}: {msg}")]
    Parse { path: PathBuf, msg: String },
    #[error("config {path}: `{field}`: {msg}")]
    Field {
        path: PathBuf,
        field: String,
        msg: String,
    },
}

/// Keys earlier versions read, and what to write instead.
const RENAMED_KEYS: [(&str, &str, &str); 1] = [(
    "estimator",
    "gyro_bias_alpha",
    "replaced by `gyro_bias_time_constant_s` in seconds, which holds at any IMU rate: \
     an alpha of 0.01 at 100 Hz is 1 s (the IMU's sample interval over alpha)",
)];

/// A config that failed to parse because it still uses a key of an earlier version:
/// the error names the key and what replaced it.
fn renamed_key(path: &Path, text: &str) -> Option<ConfigError> {
    let table: toml::Table = toml::from_str(text).ok()?;
    RENAMED_KEYS.iter().find_map(|&(section, key, msg)| {
        table.get(section)?.get(key)?;
        Some(ConfigError::Field {
            path: path.into(),
            field: format!("{section}.{key}"),
            msg: msg.into(),
        })
    })
}

/// The configuration shipped in `config/leveld.toml`, built in.
pub const DEFAULT_TOML: &str = include_str!("../../config/leveld.toml");

impl Config {
    /// Read and check a config file; relative paths inside it are resolved against its folder.
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Read {
            path: path.into(),
            source,
        })?;
        Self::parse(path, &text)
    }

    pub fn parse(path: &Path, text: &str) -> Result<Self, ConfigError> {
        let mut cfg: Config = toml::from_str(text).map_err(|e| {
            renamed_key(path, text).unwrap_or_else(|| ConfigError::Parse {
                path: path.into(),
                msg: e.to_string(),
            })
        })?;
        let base = path.parent().unwrap_or(Path::new("."));
        let names_no_file = |p: &Path| {
            let b = p.as_os_str().as_encoded_bytes();
            b.is_empty() || b.ends_with(b"/") || p.file_name().is_none()
        };
        if names_no_file(&cfg.state.path) {
            return Err(ConfigError::Field {
                path: path.into(),
                field: "state.path".into(),
                msg: format!(
                    "{:?} names no file; give a file path such as /var/lib/leveld/state.json",
                    cfg.state.path
                ),
            });
        }
        let status = cfg.state.status_path.clone();
        if !status.as_os_str().is_empty() && names_no_file(&status) {
            return Err(ConfigError::Field {
                path: path.into(),
                field: "state.status_path".into(),
                msg: format!(
                    "{status:?} names no file; give a file path such as /run/leveld/status.json, or \"\" to publish none"
                ),
            });
        }
        if cfg.state.calibration_path.as_os_str().is_empty() {
            cfg.state.calibration_path = cfg.state.path.with_file_name("calibration.json");
        } else if names_no_file(&cfg.state.calibration_path)
            || cfg.state.calibration_path == cfg.state.path
        {
            return Err(ConfigError::Field {
                path: path.into(),
                field: "state.calibration_path".into(),
                msg: format!(
                    "{:?} must name a file other than state.path, such as /var/lib/leveld/calibration.json",
                    cfg.state.calibration_path
                ),
            });
        }
        if cfg.state.calibration_path.is_relative() {
            cfg.state.calibration_path = base.join(&cfg.state.calibration_path);
        }
        if cfg.can.dbc.is_relative() {
            cfg.can.dbc = base.join(&cfg.can.dbc);
        }
        if cfg.state.path.is_relative() {
            cfg.state.path = base.join(&cfg.state.path);
        }
        if !status.as_os_str().is_empty() && cfg.state.status_path.is_relative() {
            cfg.state.status_path = base.join(&cfg.state.status_path);
        }
        cfg.validate(path)?;
        Ok(cfg)
    }

    fn validate(&self, path: &Path) -> Result<(), ConfigError> {
        let field = |f: &str, msg: String| ConfigError::Field {
            path: path.into(),
            field: f.into(),
            msg,
        };
        for (name, m, n) in [
            ("wheels", &self.wheels, 4),
            ("acc", &self.acc, 3),
            ("gyro", &self.gyro, 3),
        ] {
            if m.signals.len() != n {
                return Err(field(
                    &format!("{name}.signals"),
                    format!("needs {n} signal names, found {}", m.signals.len()),
                ));
            }
            if m.counter.len() > 2 || m.checksum.len() > 2 {
                return Err(field(
                    &format!("{name}.counter/checksum"),
                    "at most two parts each".into(),
                ));
            }
            if m.checksum_kind != ChecksumKind::None && m.checksum.is_empty() {
                return Err(field(
                    &format!("{name}.checksum"),
                    "name the checksum signal(s) for this checksum_kind".into(),
                ));
            }
            if m.timeout_ms == Some(0) {
                return Err(field(
                    &format!("{name}.timeout_ms"),
                    "must be greater than 0".into(),
                ));
            }
        }
        if self.can.input_interfaces.is_empty() {
            return Err(field(
                "can.input_interfaces",
                "name at least one interface".into(),
            ));
        }
        if !matches!(
            self.output.checksum_kind,
            ChecksumKind::Crc8SaeJ1850 | ChecksumKind::Crc8Autosar
        ) {
            return Err(field(
                "output.checksum_kind",
                "choose crc8_sae_j1850 or crc8_autosar (the LEVELING checksum is a CRC over bytes 0-6)".into(),
            ));
        }
        if !(10..=10_000).contains(&self.output.period_ms) {
            return Err(field("output.period_ms", "choose 10..10000 ms".into()));
        }
        let l = &self.leveling;
        if !(l.actuator_min_deg < l.actuator_max_deg)
            || !l.actuator_min_deg.is_finite()
            || !l.actuator_max_deg.is_finite()
        {
            return Err(field(
                "leveling.actuator_min_deg",
                "must be finite and below actuator_max_deg".into(),
            ));
        }
        if !l.reference_pitch_deg.is_finite() || l.reference_pitch_deg.abs() > 10.0 {
            return Err(field(
                "leveling.reference_pitch_deg",
                "must be within +-10 deg".into(),
            ));
        }
        if l.invalid_after == 0 || l.valid_after == 0 {
            return Err(field("leveling.invalid_after", "must be at least 1".into()));
        }
        if !(l.valid_max_std_err_deg > 0.0 && l.valid_max_std_err_deg <= 1.0) {
            return Err(field(
                "leveling.valid_max_std_err_deg",
                "must be above 0 and at most 1 deg (R48 leaves about 0.2 deg)".into(),
            ));
        }
        if !(l.valid_min_windows >= 1.0 && l.valid_min_windows <= 100.0) {
            return Err(field(
                "leveling.valid_min_windows",
                "must be 1..100: VALID could never be reached otherwise".into(),
            ));
        }
        if l.valid_min_windows > self.estimator.average_capacity as f64 {
            return Err(field(
                "leveling.valid_min_windows",
                format!(
                    "{} windows can never be reached: the average keeps estimator.average_capacity = {}",
                    l.valid_min_windows, self.estimator.average_capacity
                ),
            ));
        }
        if !(l.max_clock_step_s >= 0.5 && l.max_clock_step_s <= 3600.0) {
            return Err(field(
                "leveling.max_clock_step_s",
                "choose 0.5..3600 s (longer than any input timeout)".into(),
            ));
        }
        for (name, iface) in self
            .can
            .input_interfaces
            .iter()
            .map(|i| ("can.input_interfaces", i))
            .chain([("can.output_interface", &self.can.output_interface)])
        {
            if iface.is_empty() || iface.len() > 15 || iface.contains(['/', ' ', '\0']) {
                return Err(field(
                    name,
                    format!("{iface:?} is not an interface name (1..15 bytes, no '/' or spaces)"),
                ));
            }
        }

        self.estimator
            .validate()
            .map_err(|e| field(&format!("estimator.{}", e.field), e.to_string()))?;
        Ok(())
    }
}
