//! The daemon side: configuration, the frame pipeline shared by live runs and
//! replays, persisted state.

pub mod calibrate;
pub mod calibration;
pub mod clock;
pub mod config;
pub mod frame_loop;
pub mod inputs;
pub mod live;
pub mod log_bus;
pub mod pipeline;
pub mod replay;
pub mod saver;
pub mod sink;
pub mod socket;
pub mod state;
pub mod status;

use crate::can::dbc::Database;
use anyhow::{Context, Result};
use config::Config;
use std::path::{Path, PathBuf};

/// Where the default config is looked for before the built-in one is used.
pub const SYSTEM_CONFIG: &str = "/etc/leveld/leveld.toml";

/// The reference DBC, built in for the built-in config.
pub const DEFAULT_DBC: &str = include_str!("../../dbc/leveld.dbc");

/// Which config was used.
#[derive(Debug, Clone)]
pub enum ConfigSource {
    File(PathBuf),
    BuiltIn,
}

impl std::fmt::Display for ConfigSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::File(p) => write!(f, "{}", p.display()),
            Self::BuiltIn => write!(f, "built-in default (config/leveld.toml)"),
        }
    }
}

/// Load the config (the given file, else the system one, else the built-in) and its DBC.
pub fn load(config: Option<&Path>) -> Result<(Config, Database, ConfigSource)> {
    let (cfg, src) = match config {
        Some(p) => (Config::load(p)?, ConfigSource::File(p.into())),
        None if Path::new(SYSTEM_CONFIG).exists() => (
            Config::load(Path::new(SYSTEM_CONFIG))?,
            ConfigSource::File(SYSTEM_CONFIG.into()),
        ),
        None => (
            Config::parse(Path::new("config/leveld.toml"), config::DEFAULT_TOML)?,
            ConfigSource::BuiltIn,
        ),
    };
    let db = match (&src, cfg.can.dbc.exists()) {
        (ConfigSource::BuiltIn, false) => {
            Database::parse(Path::new("built-in leveld.dbc"), DEFAULT_DBC)?
        }
        _ => Database::load(&cfg.can.dbc)
            .with_context(|| format!("loading the DBC named by {src}"))?,
    };
    Ok((cfg, db, src))
}
