//! Inputs of the estimator.

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

/// One 6-axis IMU sample as the sensor reports it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ImuSample {
    /// Sample time, s (receive timestamp live, log timestamp in replay).
    pub t_s: f64,
    /// Specific force in body axes (x fwd, y left, z up), m/s^2; +9.81 on z at rest on level ground.
    pub acc_mps2: [f64; 3],
    /// Angular rate about body x, y, z, right-handed, deg/s.
    pub gyro_dps: [f64; 3],
}

impl ImuSample {
    pub fn new(t_s: f64, acc_mps2: [f64; 3], gyro_dps: [f64; 3]) -> Self {
        Self {
            t_s,
            acc_mps2,
            gyro_dps,
        }
    }
    pub fn acc(&self) -> Vector3<f64> {
        Vector3::from(self.acc_mps2)
    }
    pub fn gyro_rps(&self) -> Vector3<f64> {
        Vector3::from(self.gyro_dps).map(f64::to_radians)
    }
}

/// Four wheel speeds as the ESC reports them (unsigned, km/h).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct WheelSpeeds {
    pub t_s: f64,
    /// Front-left, front-right, rear-left, rear-right, km/h.
    pub kmh: [f64; 4],
}

impl WheelSpeeds {
    /// Mean of the four wheels (eq. 6), km/h.
    pub fn mean_kmh(&self) -> f64 {
        self.kmh.iter().sum::<f64>() / 4.0
    }
    /// Mean of the wheels that read more than `zero_kmh`, km/h (0 when none does). At
    /// the edge of the wheel sensors' dead zone the inner wheels of a turn, or a wheel
    /// whose sensor cuts out a little higher, still read zero while the car moves: the
    /// mean of all four then reads the speed halved.
    pub fn moving_mean_kmh(&self, zero_kmh: f64) -> f64 {
        let (sum, n) = self
            .kmh
            .iter()
            .filter(|&&v| v > zero_kmh)
            .fold((0.0, 0u32), |(s, n), &v| (s + v, n + 1));
        if n == 0 { 0.0 } else { sum / f64::from(n) }
    }
    /// Largest wheel speed, km/h.
    pub fn max_kmh(&self) -> f64 {
        self.kmh.iter().copied().fold(0.0, f64::max)
    }
}
