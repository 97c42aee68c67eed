//! Vehicle and IMU simulator with ground truth. The estimator does not depend on it.

pub mod canlog;
pub mod drive;
pub mod noise;
pub mod paper;
pub mod presets;
pub mod roughness;
pub mod scenario;

pub use drive::{Drive, Input, Truth, floor_attitude_deg, floor_roll_deg, simulate};
pub use scenario::{Road, Scenario, Sensors, SpeedProfile, Vehicle};
