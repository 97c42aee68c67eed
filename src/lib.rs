//! leveld: automatic static headlamp leveling from wheel speeds and a 6-axis IMU.
//!
//! - [`estimator`]: the sans-IO estimator (Kim et al., IEEE Access 2023).
//! - [`sim`]: a vehicle and IMU simulator with ground truth.

pub mod bench;
pub mod can;
pub mod cli;
pub mod daemon;
pub mod estimator;
pub mod report;
pub mod sim;
