//! leveld: automatic static headlamp leveling from wheel speeds and a 6-axis IMU.
//!
//! - [`estimator`]: the sans-IO estimator (Kim et al., IEEE Access 2023).
//! - [`can`]: DBC-driven codecs, checksums and the candump log format.
//! - [`daemon`]: the one pipeline (frames in, LEVELING out) with its live and replay
//!   frame sources, config, state and clock.
//! - [`commands`]: what each `leveld` subcommand does; [`cli`] only parses.
//! - [`sim`], [`bench`] (feature `sim`): a vehicle and IMU simulator with ground truth,
//!   and the accuracy benchmark against the paper's baselines.

#[cfg(feature = "sim")]
pub mod bench;
pub mod can;
pub mod cli;
pub mod commands;
pub mod daemon;
pub mod estimator;
#[cfg(feature = "sim")]
pub mod sim;
