//! The commands behind the CLI: each takes plain arguments, does its IO and returns
//! the process exit code. `cli` parses and dispatches; nothing here knows about clap.

pub mod calibrate;
pub mod check_config;
pub mod replay;
pub mod status;

#[cfg(feature = "sim")]
pub mod bench;
#[cfg(feature = "sim")]
pub mod simulate;
