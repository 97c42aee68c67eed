//! Persistence of the estimator between runs, and the end-of-line seed.

use super::Estimator;
use super::average::Averager;
use super::grade::GradePitch;
use super::gravity::GravityFilter;
use super::lever::LeverFit;
use super::mode::PitchModeFit;
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

/// What the daemon persists between runs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EstimatorState {
    pub format: u32,
    pub averager: Averager,
    pub gyro_bias_dps: Option<[f64; 3]>,
    /// Standstill IMU pitch of the current load, deg: the load baseline.
    pub baseline_pitch_deg: Option<f64>,
    pub last_road_slope_deg: Option<f64>,
    /// Settled specific-force magnitude (bias along z included), m/s^2.
    #[serde(default)]
    pub gravity_mps2: Option<f64>,
    /// Accelerometer bias along body x and y as seen in the standstill magnitude, m/s^2.
    #[serde(default)]
    pub accel_bias_xy_mps2: Option<[f64; 2]>,
    /// Lever-arm fit from the rocking at stops (see `lever`).
    #[serde(default)]
    pub lever_fit: Option<LeverFit>,
    /// The stop-by-stop magnitude fit the windows take their accelerometer bias from:
    /// magnitude (bias along z included), bias along x and y, m/s^2.
    #[serde(default)]
    pub stop_gravity_mps2: Option<[f64; 3]>,
    /// The body's pitch against braking learnt from deceleration windows (see `grade`).
    #[serde(default)]
    pub grade_pitch: Option<GradePitch>,
    /// The body's pitch against the drivetrain's force, from acceleration windows.
    #[serde(default)]
    pub squat_pitch: Option<GradePitch>,
    /// How well the stops knew the bias along x and y (1 sigma), m/s^2; a state
    /// written before it was kept reads as known to 0.02.
    #[serde(default)]
    pub stop_bias_sd_mps2: Option<[f64; 2]>,
    /// Mean travel yaw of the accepted windows in the IMU's frame, rad, and how many.
    #[serde(default)]
    pub travel_yaw: Option<(f64, u32)>,
    /// The body's pitch mode as the stops' swings showed it (see `mode`).
    #[serde(default)]
    pub pitch_mode_fit: Option<PitchModeFit>,
}

impl EstimatorState {
    pub const FORMAT: u32 = 1;
}

/// A restored state that cannot be used.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum StateError {
    #[error(
        "state format {found} is not supported (expected {expected}); the file was written by another version"
    )]
    Format { found: u32, expected: u32 },
    #[error("state holds a non-finite or implausible value in `{0}`")]
    Implausible(&'static str),
}

impl Estimator {
    /// End-of-line calibration on a level floor: the IMU pitch there, raw, is the
    /// road-to-body pitch but for the accelerometer bias (see `level_reference_deg`).
    /// Seeds the estimate with it, worth `weight` windows at most and no more than the
    /// bias known so far allows (a bias of 0.2 m/s^2 is 1.2 deg of pitch: then the seed
    /// is worth a few hundredths of a window and the windows decide), and makes it the
    /// baseline of load changes at rest (raw against raw).
    pub fn seed_calibration(&mut self, floor_pitch_deg: f64, weight: f64) {
        let value = self.level_reference_deg(floor_pitch_deg);
        let bias_sd_deg = (self.acc_bias_sd_mps2()[0] / super::STANDARD_GRAVITY_MPS2).to_degrees();
        let known = (self.cfg.window_sigma_prior_deg / bias_sd_deg.max(1e-6)).powi(2);
        self.avg.restore_prior(value, weight.min(known), 0);
        self.baseline_pitch_rad = Some(floor_pitch_deg.to_radians());
        self.refresh_estimate();
    }

    /// The road-to-body pitch that an end-of-line reference stands for, deg: the IMU's
    /// pitch read raw on the level floor (`standstill_pitch` there; with its roll from
    /// `set_floor_roll_deg`), less what the accelerometer bias learnt since adds to
    /// such a reading. A window measures the angle between the IMU and the road, which
    /// no bias moves; the floor's raw pitch carries the x bias as bias / g (0.2 m/s^2 is
    /// 1.2 deg), and a level correction taken against it would be off by that much for
    /// the life of the car. What is left is what the stops have not learnt of the bias
    /// and its drift since the floor.
    pub fn level_reference_deg(&self, floor_pitch_deg: f64) -> f64 {
        if !floor_pitch_deg.is_finite() {
            return floor_pitch_deg;
        }
        let roll = self.floor_roll_rad.unwrap_or(0.0);
        self.unbiased_pitch_rad(floor_pitch_deg.to_radians(), roll)
            .to_degrees()
    }

    /// Snapshot for persistence.
    pub fn state(&self) -> EstimatorState {
        EstimatorState {
            format: EstimatorState::FORMAT,
            averager: self.avg.clone(),
            gyro_bias_dps: self.gyro_bias_dps(),
            baseline_pitch_deg: self.baseline_pitch_rad.map(f64::to_degrees),
            last_road_slope_deg: self.last_road_slope_deg(),
            gravity_mps2: self.gravity.map(|g| g.x.x),
            accel_bias_xy_mps2: self.gravity.map(|g| [g.x.y, g.x.z]),
            lever_fit: Some(self.lever_fit),
            pitch_mode_fit: Some(self.mode_fit),
            stop_gravity_mps2: self.stop_bias.map(|g| [g.x.x, g.x.y, g.x.z]),
            grade_pitch: Some(self.grade),
            squat_pitch: Some(self.squat),
            stop_bias_sd_mps2: self.stop_bias.map(|_| self.acc_bias_sd_mps2()),
            travel_yaw: (self.travel_yaw.1 > 0).then(|| {
                (
                    self.travel_yaw.0 / f64::from(self.travel_yaw.1),
                    self.travel_yaw.1,
                )
            }),
        }
    }

    /// Restore a persisted snapshot. The averaging mode and capacity of the running
    /// configuration win over the stored ones.
    pub fn restore(&mut self, st: &EstimatorState) -> Result<(), StateError> {
        if st.format != EstimatorState::FORMAT {
            return Err(StateError::Format {
                found: st.format,
                expected: EstimatorState::FORMAT,
            });
        }
        let ok_angle = |v: Option<f64>| v.is_none_or(|x| x.is_finite() && x.abs() < 45.0);
        if !ok_angle(st.baseline_pitch_deg) {
            return Err(StateError::Implausible("baseline_pitch_deg"));
        }
        if !ok_angle(st.last_road_slope_deg) {
            return Err(StateError::Implausible("last_road_slope_deg"));
        }
        if let Some(b) = st.gyro_bias_dps
            && b.iter().any(|x| !x.is_finite() || x.abs() > 50.0)
        {
            return Err(StateError::Implausible("gyro_bias_dps"));
        }
        let mut avg = Averager::new(
            self.cfg.averaging,
            self.cfg.average_capacity,
            self.cfg.window_sigma_prior_deg,
        );
        let mut stored = st.averager.clone();
        stored.sanitize_learnt();
        if let Some(c) = stored.combined() {
            if !(c.value_deg.is_finite() && c.value_deg.abs() < 45.0 && c.weight.is_finite()) {
                return Err(StateError::Implausible("averager"));
            }
            // Carry the stored evidence, its spread and what it learnt of the grade.
            avg.restore_from(&mut stored);
        }
        self.avg = avg;
        self.bias_rps = st
            .gyro_bias_dps
            .map(|b| Vector3::from(b).map(f64::to_radians));
        self.bias_taught = self.bias_rps.is_some();
        self.baseline_pitch_rad = st.baseline_pitch_deg.map(f64::to_radians);
        if let Some(g) = st.gravity_mps2
            && !(g.is_finite() && (5.0..15.0).contains(&g))
        {
            return Err(StateError::Implausible("gravity_mps2"));
        }
        if let Some(f) = &st.lever_fit
            && (!f.is_finite() || f.mtm.iter().step_by(4).any(|d| *d < 0.0))
        {
            return Err(StateError::Implausible("lever_fit"));
        }
        if let Some(b) = st.accel_bias_xy_mps2
            && b.iter().any(|x| !x.is_finite() || x.abs() > 2.0)
        {
            return Err(StateError::Implausible("accel_bias_xy_mps2"));
        }
        if let Some([c, bx, by]) = st.stop_gravity_mps2
            && !(c.is_finite()
                && (5.0..15.0).contains(&c)
                && [bx, by].iter().all(|b| b.is_finite() && b.abs() <= 2.0))
        {
            return Err(StateError::Implausible("stop_gravity_mps2"));
        }
        if st
            .stop_bias_sd_mps2
            .is_some_and(|b| b.iter().any(|x| !x.is_finite() || !(0.0..=2.0).contains(x)))
        {
            return Err(StateError::Implausible("stop_bias_sd_mps2"));
        }
        if st
            .travel_yaw
            .is_some_and(|(y, _)| !y.is_finite() || y.abs() > 0.1)
        {
            return Err(StateError::Implausible("travel_yaw"));
        }
        if st.grade_pitch.is_some_and(|g| !g.is_plausible()) {
            return Err(StateError::Implausible("grade_pitch"));
        }
        if st.squat_pitch.is_some_and(|g| !g.is_plausible()) {
            return Err(StateError::Implausible("squat_pitch"));
        }
        if st.pitch_mode_fit.is_some_and(|f| !f.is_plausible()) {
            return Err(StateError::Implausible("pitch_mode_fit"));
        }
        self.mode_fit = st.pitch_mode_fit.unwrap_or_default();
        self.grade = st.grade_pitch.unwrap_or_default();
        self.squat = st.squat_pitch.unwrap_or_default();
        self.last_slope_rad = st.last_road_slope_deg.map(f64::to_radians);
        let prior = Vector3::from(self.cfg.lever_arm_m);
        self.lever_fit = st.lever_fit.unwrap_or_default();
        self.lever_arm = if self.cfg.learn_lever_arm && prior != Vector3::zeros() {
            self.lever_fit.solve(&prior)
        } else {
            prior
        };
        self.motion_unknown = true;
        // A restored magnitude is as uncertain as a few seconds of standstill; new stops
        // refine it.
        self.gravity = st.gravity_mps2.map(|g| {
            let bias = st.accel_bias_xy_mps2.unwrap_or([0.0; 2]);
            GravityFilter::new(g, 1e-5, bias, 0.01)
        });
        // The bias stands as learnt, as well known as it was (what no stop showed stays
        // unknown) but no better than a bias that drifted while the car was parked.
        let [sx, sy] = st
            .stop_bias_sd_mps2
            .unwrap_or([0.0; 2])
            .map(|s| s.max(0.02));
        self.stop_bias = st.stop_gravity_mps2.map(|[c, bx, by]| {
            let mut f = GravityFilter::new(c, 1e-4, [bx, by], 0.02);
            f.p[(1, 1)] = sx * sx;
            f.p[(2, 2)] = sy * sy;
            f
        });
        self.travel_yaw = st
            .travel_yaw
            .map_or((0.0, 0), |(y, n)| (y * f64::from(n), n));
        self.refresh_estimate();
        Ok(())
    }
}
