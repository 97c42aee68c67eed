//! Baseline pitch estimators from the literature, behind the same interface as
//! leveld's estimator, for the accuracy benchmark. Both are reimplementations from
//! the published ideas, tuned reasonably and not to lose.

use crate::estimator::{Estimator, EstimatorConfig, Event, ImuSample, WheelSpeeds};

/// A road-to-body pitch estimator fed with the same samples as leveld.
pub trait PitchMethod {
    fn name(&self) -> &'static str;
    fn push_wheels(&mut self, w: WheelSpeeds);
    fn push_imu(&mut self, s: ImuSample);
    fn finish(&mut self, t_s: f64);
    /// Current estimate (deg) and whether the method calls it converged.
    fn estimate(&self) -> Option<(f64, bool)>;
    /// Single-window (single-update) estimates so far: (time s the value holds at,
    /// road-to-body deg).
    fn windows(&self) -> &[(f64, f64)];
    fn rejected(&self) -> u64 {
        0
    }
    /// The IMU's roll an end-of-line station read on the level floor, deg.
    fn calibrate_floor_roll(&mut self, _roll_deg: f64) {}
}

/// leveld's estimator as a [`PitchMethod`]; converged = VALID (standard error and
/// window count within the given bounds).
/// The benchmark's converged rule for leveld (the reference config's VALID): standard
/// error at most this, deg ...
pub const VALID_MAX_STD_ERR_DEG: f64 = 0.06;
/// ... with at least this many windows' weight behind the estimate.
pub const VALID_MIN_WEIGHT: f64 = 4.0;

pub struct Leveld {
    est: Estimator,
    windows: Vec<(f64, f64)>,
    rejected: u64,
    max_std_err_deg: f64,
    min_windows: f64,
    name: &'static str,
    /// Take the end-of-line roll (off: a car calibrated for pitch only).
    floor_roll: bool,
}

impl Leveld {
    pub fn new(cfg: EstimatorConfig, name: &'static str) -> Self {
        Self {
            est: Estimator::new(cfg).expect("valid config"),
            windows: Vec::new(),
            rejected: 0,
            max_std_err_deg: VALID_MAX_STD_ERR_DEG,
            min_windows: VALID_MIN_WEIGHT,
            name,
            floor_roll: true,
        }
    }

    /// The same without the end-of-line roll: windows keep a lane's roll in.
    pub fn without_floor_roll(mut self) -> Self {
        self.floor_roll = false;
        self
    }
    fn take(&mut self, e: Event) {
        match e {
            Event::WindowAccepted { window, .. } => self
                .windows
                .push((window.reference_s, window.road_to_body_deg)),
            // A window the estimator took back out is not counted as accepted.
            Event::WindowWithdrawn {
                road_to_body_deg, ..
            } if self.windows.last().is_some_and(|w| w.1 == road_to_body_deg) => {
                self.windows.pop();
            }
            Event::WindowRejected { .. } => self.rejected += 1,
            _ => {}
        }
    }
}

impl PitchMethod for Leveld {
    fn name(&self) -> &'static str {
        self.name
    }
    fn calibrate_floor_roll(&mut self, roll_deg: f64) {
        if self.floor_roll {
            self.est.set_floor_roll_deg(Some(roll_deg));
        }
    }
    fn push_wheels(&mut self, w: WheelSpeeds) {
        let mut buf = Vec::new();
        self.est.push_wheels(w, &mut |e| buf.push(e));
        buf.into_iter().for_each(|e| self.take(e));
    }
    fn push_imu(&mut self, s: ImuSample) {
        let mut buf = Vec::new();
        self.est.push_imu(s, &mut |e| buf.push(e));
        buf.into_iter().for_each(|e| self.take(e));
    }
    fn finish(&mut self, t_s: f64) {
        let mut buf = Vec::new();
        self.est.finish(t_s, &mut |e| buf.push(e));
        buf.into_iter().for_each(|e| self.take(e));
    }
    fn estimate(&self) -> Option<(f64, bool)> {
        self.est.estimate().map(|e| {
            (
                e.road_to_body_deg,
                e.std_err_deg <= self.max_std_err_deg && e.weight >= self.min_windows,
            )
        })
    }
    fn windows(&self) -> &[(f64, f64)] {
        &self.windows
    }
    fn rejected(&self) -> u64 {
        self.rejected
    }
}

/// First-order low-pass with time constant `tau_s`.
#[derive(Debug, Clone, Copy, Default)]
struct Lpf {
    y: Option<f64>,
}

impl Lpf {
    fn step(&mut self, x: f64, dt: f64, tau_s: f64) -> f64 {
        let y = match self.y {
            None => x,
            Some(y) => y + (x - y) * (dt / (tau_s + dt)),
        };
        self.y = Some(y);
        y
    }
}

/// Kasaba-style estimation from the direction of the acceleration vector.
///
/// During straight longitudinal acceleration and braking the acceleration lies along
/// the road, so in body axes `delta AccZ = -tan(pitch) * delta AccX`, where pitch is
/// the road-to-body pitch. The method regresses low-passed AccZ on AccX (a Huber
/// regression over 10 Hz points taken while moving straight) and reports
/// `atan(-slope)`. Assumptions: the grade is constant while AccX varies, so grade
/// changes, which move AccX through gravity without the matching AccZ, bias it; in
/// effect the road is taken as level on average. Gyro and wheel speeds only gate.
pub struct Kasaba {
    fx: Lpf,
    fz: Lpf,
    last_t: Option<f64>,
    v_mps: f64,
    yaw_dps: f64,
    next_pick: f64,
    pts: Vec<(f64, f64)>,
    windows: Vec<(f64, f64)>,
    est: Option<f64>,
    next_fit: f64,
}

impl Default for Kasaba {
    fn default() -> Self {
        Self::new()
    }
}

impl Kasaba {
    pub fn new() -> Self {
        Self {
            fx: Lpf::default(),
            fz: Lpf::default(),
            last_t: None,
            v_mps: 0.0,
            yaw_dps: 0.0,
            next_pick: 0.0,
            pts: Vec::new(),
            windows: Vec::new(),
            est: None,
            next_fit: 0.0,
        }
    }

    fn fit(&self) -> Option<f64> {
        if self.pts.len() < 50 {
            return None;
        }
        let n = self.pts.len() as f64;
        let (mx, mz) = self
            .pts
            .iter()
            .fold((0.0, 0.0), |a, p| (a.0 + p.0 / n, a.1 + p.1 / n));
        let sxx: f64 = self.pts.iter().map(|p| (p.0 - mx).powi(2)).sum();
        if sxx / n < 0.05 {
            return None; // not enough acceleration variety yet
        }
        // Huber IRLS for the slope.
        let mut b = self
            .pts
            .iter()
            .map(|p| (p.0 - mx) * (p.1 - mz))
            .sum::<f64>()
            / sxx;
        let mut a = mz - b * mx;
        for _ in 0..8 {
            let r: Vec<f64> = self.pts.iter().map(|p| p.1 - a - b * p.0).collect();
            let mut sorted: Vec<f64> = r.iter().map(|x| x.abs()).collect();
            sorted.sort_by(f64::total_cmp);
            let s = (1.4826 * sorted[sorted.len() / 2]).max(1e-4);
            let w: Vec<f64> = r
                .iter()
                .map(|x| {
                    if x.abs() <= 1.5 * s {
                        1.0
                    } else {
                        1.5 * s / x.abs()
                    }
                })
                .collect();
            let sw: f64 = w.iter().sum();
            let (wx, wz) = self.pts.iter().zip(&w).fold((0.0, 0.0), |acc, (p, w)| {
                (acc.0 + w * p.0 / sw, acc.1 + w * p.1 / sw)
            });
            let num: f64 = self
                .pts
                .iter()
                .zip(&w)
                .map(|(p, w)| w * (p.0 - wx) * (p.1 - wz))
                .sum();
            let den: f64 = self
                .pts
                .iter()
                .zip(&w)
                .map(|(p, w)| w * (p.0 - wx).powi(2))
                .sum();
            b = num / den;
            a = wz - b * wx;
        }
        Some((-b).atan().to_degrees())
    }
}

impl PitchMethod for Kasaba {
    fn name(&self) -> &'static str {
        "kasaba"
    }
    fn push_wheels(&mut self, w: WheelSpeeds) {
        self.v_mps = w.mean_kmh() / 3.6;
    }
    fn push_imu(&mut self, s: ImuSample) {
        let dt = self.last_t.map_or(0.01, |t| (s.t_s - t).clamp(1e-4, 0.1));
        self.last_t = Some(s.t_s);
        let fx = self.fx.step(s.acc_mps2[0], dt, 0.3);
        let fz = self.fz.step(s.acc_mps2[2], dt, 0.3);
        self.yaw_dps = s.gyro_dps[2];
        if s.t_s >= self.next_pick {
            self.next_pick = s.t_s + 0.1;
            if self.v_mps > 2.0 && self.yaw_dps.abs() < 2.0 {
                self.pts.push((fx, fz));
            }
        }
        if s.t_s >= self.next_fit && !self.pts.is_empty() {
            self.next_fit = s.t_s + 10.0;
            if let Some(e) = self.fit() {
                self.est = Some(e);
                self.windows.push((s.t_s, e));
            }
        }
    }
    fn finish(&mut self, t_s: f64) {
        if let Some(e) = self.fit() {
            self.est = Some(e);
            self.windows.push((t_s, e));
        }
    }
    fn estimate(&self) -> Option<(f64, bool)> {
        // Called converged once it has seen enough driving (2 minutes of points).
        self.est.map(|e| (e, self.pts.len() >= 1200))
    }
    fn windows(&self) -> &[(f64, f64)] {
        &self.windows
    }
}

/// Nilsson-style Kalman filter on body pitch.
///
/// While moving straight, `asin((AccX - dv/dt) / g)` is the total pitch, road grade
/// plus road-to-body pitch; dv/dt comes from the wheel speeds. A scalar Kalman filter
/// with a slow random walk tracks the road-to-body pitch and treats the grade as
/// zero-mean measurement noise: the method assumes the road is level on average.
pub struct Nilsson {
    x_deg: Option<f64>,
    p: f64,
    v_lpf: Lpf,
    ax_lpf: Lpf,
    prev_v: Option<(f64, f64)>,
    dvdt: f64,
    last_imu_t: Option<f64>,
    next_update: f64,
    updates: u64,
    windows: Vec<(f64, f64)>,
    yaw_dps: f64,
}

impl Default for Nilsson {
    fn default() -> Self {
        Self::new()
    }
}

impl Nilsson {
    pub fn new() -> Self {
        Self {
            x_deg: None,
            p: 25.0,
            v_lpf: Lpf::default(),
            ax_lpf: Lpf::default(),
            prev_v: None,
            dvdt: 0.0,
            last_imu_t: None,
            next_update: 0.0,
            updates: 0,
            windows: Vec::new(),
            yaw_dps: 0.0,
        }
    }
}

impl PitchMethod for Nilsson {
    fn name(&self) -> &'static str {
        "nilsson"
    }
    fn push_wheels(&mut self, w: WheelSpeeds) {
        let dt = self
            .prev_v
            .map_or(0.02, |(t, _)| (w.t_s - t).clamp(1e-3, 0.2));
        let v = self.v_lpf.step(w.mean_kmh() / 3.6, dt, 0.1);
        if let Some((_, pv)) = self.prev_v {
            self.dvdt = 0.8 * self.dvdt + 0.2 * (v - pv) / dt;
        }
        self.prev_v = Some((w.t_s, v));
    }
    fn push_imu(&mut self, s: ImuSample) {
        let dt = self
            .last_imu_t
            .map_or(0.01, |t| (s.t_s - t).clamp(1e-4, 0.1));
        self.last_imu_t = Some(s.t_s);
        let ax = self.ax_lpf.step(s.acc_mps2[0], dt, 0.1);
        self.yaw_dps = s.gyro_dps[2];
        let v = self.prev_v.map_or(0.0, |p| p.1);
        if s.t_s < self.next_update || v < 3.0 || self.yaw_dps.abs() > 2.0 {
            return;
        }
        self.next_update = s.t_s + 0.1;
        let g = 9.80665;
        let z = ((ax - self.dvdt) / g).clamp(-1.0, 1.0).asin().to_degrees();
        // Measurement noise: the grade (a few degrees) and the dv/dt error.
        let r = 3.0f64.powi(2);
        let q = 1e-5;
        let x = self.x_deg.unwrap_or(z);
        let p = self.p + q;
        let k = p / (p + r);
        self.x_deg = Some(x + k * (z - x));
        self.p = (1.0 - k) * p;
        self.updates += 1;
        if self.updates.is_multiple_of(50) {
            self.windows.push((s.t_s, self.x_deg.unwrap_or(0.0)));
        }
    }
    fn finish(&mut self, _t_s: f64) {}
    fn estimate(&self) -> Option<(f64, bool)> {
        self.x_deg.map(|x| (x, self.p.sqrt() < 0.2))
    }
    fn windows(&self) -> &[(f64, f64)] {
        &self.windows
    }
}
