//! The static leveling estimator of Kim et al. (IEEE Access, 2023), sans I/O.
//!
//! Feed it timestamped wheel speeds and IMU samples in time order; it calls back
//! with [`Event`]s and keeps the current [`Estimate`]. Nothing here reads a clock,
//! a file or a socket, and after construction the per-sample path does not allocate.
//!
//! Pipeline per the paper: standstill detection (III-C1) gated on IMU stillness,
//! gyro-bias low-pass while stopped (eq. 7-8), IMU attitude from standstill gravity
//! (eq. 9), gyro propagation (eq. 10-11) and dead reckoning (eq. 12-13) over T_d of
//! travel after a stop (forward in time) and before it (backward over buffered
//! samples), road slope (eq. 14-15) with chord and turning rejection, road-to-body
//! pitch (eq. 16) combined over windows (eq. 17 or a Huber average).

pub mod attitude;
pub mod average;
pub mod config;
mod ring;
pub mod types;
pub mod window;

pub use average::{Averager, Combined};
pub use config::{Averaging, ConfigError, EstimatorConfig};
pub use types::{ImuSample, WheelSpeeds};
pub use window::RejectReason;

use attitude::{attitude_from_gravity, pitch_of};
use nalgebra::{UnitQuaternion, Vector3};
use ring::Ring;
use serde::{Deserialize, Serialize};
use window::{Step, WindowIntegrator, WindowSetup};

/// Which operating condition of Fig. 7 a window used.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Condition {
    /// Integrated forward from the end of a stop.
    AccelAfterStop,
    /// Integrated backward from the start of a stop.
    DecelBeforeStop,
}

/// Current road-to-body pitch estimate.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Estimate {
    /// Road-to-body (road-to-IMU) pitch, deg, positive nose-up.
    pub road_to_body_deg: f64,
    /// Standard error of `road_to_body_deg`, deg.
    pub std_err_deg: f64,
    /// Windows accepted under the current load.
    pub windows: u64,
    /// Effective number of windows behind the value (a load-change prior counts too).
    pub weight: f64,
}

/// One accepted slope window.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct WindowReport {
    pub t_s: f64,
    pub condition: Condition,
    /// IMU pitch at the stop from gravity (eq. 9), deg.
    pub imu_pitch_deg: f64,
    /// Road slope along body x over the window (eq. 14), deg, positive rising ahead.
    pub road_slope_deg: f64,
    /// imu_pitch - road_slope (eq. 16), deg.
    pub road_to_body_deg: f64,
    pub distance_m: f64,
    pub duration_s: f64,
    pub chord_deviation_m: f64,
}

/// What the estimator observed and why.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(tag = "event", rename_all = "snake_case")]
pub enum Event {
    StandstillStarted {
        t_s: f64,
        imu_pitch_deg: f64,
    },
    StandstillEnded {
        t_s: f64,
        duration_s: f64,
    },
    WindowAccepted {
        window: WindowReport,
        estimate: Estimate,
    },
    WindowRejected {
        t_s: f64,
        condition: Condition,
        reason: RejectReason,
    },
    /// A step in standstill IMU pitch: the load changed while the road could not.
    LoadChanged {
        t_s: f64,
        delta_deg: f64,
        estimate: Option<Estimate>,
    },
    /// An input sample was dropped (non-finite value or time going backwards).
    SampleDropped {
        t_s: f64,
        reason: DropReason,
    },
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum DropReason {
    NonFinite,
    TimeNotIncreasing,
}

/// What the daemon persists between runs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EstimatorState {
    pub format: u32,
    pub averager: Averager,
    pub gyro_bias_dps: Option<[f64; 3]>,
    /// Standstill IMU pitch of the current load, deg: the load baseline.
    pub baseline_pitch_deg: Option<f64>,
    pub last_road_slope_deg: Option<f64>,
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

#[derive(Debug, Clone, Copy)]
struct Standstill {
    t_start_s: f64,
    /// Specific force sums of the current load segment.
    seg_sum: Vector3<f64>,
    seg_n: u64,
    block_sum: Vector3<f64>,
    block_n: u64,
    block_t0_s: f64,
    /// A block that differed from the segment, waiting for a second one to confirm.
    pending: Option<(Vector3<f64>, u64)>,
}

impl Standstill {
    fn mean(&self) -> Vector3<f64> {
        self.seg_sum / self.seg_n.max(1) as f64
    }
}

#[derive(Debug, Clone, Copy)]
struct ForwardCtx {
    imu_pitch_rad: f64,
}

/// The estimator. See the module documentation.
#[derive(Debug, Clone)]
pub struct Estimator {
    cfg: EstimatorConfig,
    hist: Ring<ImuSample>,
    last_t_s: Option<f64>,
    wheels: Option<WheelSpeeds>,
    wheels_zero_since: Option<f64>,
    quiet_since: Option<f64>,
    /// Odometry since the last standstill ended, m.
    travelled_m: f64,
    standstill: Option<Standstill>,
    bias_rps: Option<Vector3<f64>>,
    fwd: WindowIntegrator,
    fwd_ctx: Option<ForwardCtx>,
    bwd: WindowIntegrator,
    avg: Averager,
    baseline_pitch_rad: Option<f64>,
    last_slope_rad: Option<f64>,
    estimate: Option<Estimate>,
}

const MAX_RATE_HZ: f64 = 200.0;

impl Estimator {
    pub fn new(cfg: EstimatorConfig) -> Result<Self, ConfigError> {
        cfg.validate()?;
        let hist_cap = (cfg.history_s * MAX_RATE_HZ).ceil() as usize;
        let win_cap = (cfg.max_window_time_s * MAX_RATE_HZ).ceil() as usize + 2;
        Ok(Self {
            hist: Ring::with_capacity(hist_cap),
            last_t_s: None,
            wheels: None,
            wheels_zero_since: None,
            quiet_since: None,
            travelled_m: 0.0,
            standstill: None,
            bias_rps: None,
            fwd: WindowIntegrator::with_capacity(win_cap),
            fwd_ctx: None,
            bwd: WindowIntegrator::with_capacity(win_cap),
            avg: Averager::new(
                cfg.averaging,
                cfg.average_capacity,
                cfg.window_sigma_prior_deg,
            ),
            baseline_pitch_rad: None,
            last_slope_rad: None,
            estimate: None,
            cfg,
        })
    }

    pub fn config(&self) -> &EstimatorConfig {
        &self.cfg
    }

    /// Current estimate, `None` before the first accepted window.
    pub fn estimate(&self) -> Option<Estimate> {
        self.estimate
    }

    /// Road slope of the last accepted window, deg.
    pub fn last_road_slope_deg(&self) -> Option<f64> {
        self.last_slope_rad.map(f64::to_degrees)
    }

    pub fn is_standstill(&self) -> bool {
        self.standstill.is_some()
    }

    /// Gyro bias estimate, deg/s.
    pub fn gyro_bias_dps(&self) -> Option<[f64; 3]> {
        self.bias_rps.map(|b| b.map(f64::to_degrees).into())
    }

    /// Snapshot for persistence.
    pub fn state(&self) -> EstimatorState {
        EstimatorState {
            format: EstimatorState::FORMAT,
            averager: self.avg.clone(),
            gyro_bias_dps: self.gyro_bias_dps(),
            baseline_pitch_deg: self.baseline_pitch_rad.map(f64::to_degrees),
            last_road_slope_deg: self.last_road_slope_deg(),
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
        if let Some(b) = st.gyro_bias_dps {
            if b.iter().any(|x| !x.is_finite() || x.abs() > 50.0) {
                return Err(StateError::Implausible("gyro_bias_dps"));
            }
        }
        let mut avg = Averager::new(
            self.cfg.averaging,
            self.cfg.average_capacity,
            self.cfg.window_sigma_prior_deg,
        );
        let mut stored = st.averager.clone();
        if let Some(c) = stored.combined() {
            if !(c.value_deg.is_finite() && c.value_deg.abs() < 45.0 && c.weight.is_finite()) {
                return Err(StateError::Implausible("averager"));
            }
            // Carry the stored evidence as a prior worth its full weight.
            avg.restore_prior(c.value_deg, c.weight, stored.accepted());
        }
        self.avg = avg;
        self.bias_rps = st
            .gyro_bias_dps
            .map(|b| Vector3::from(b).map(f64::to_radians));
        self.baseline_pitch_rad = st.baseline_pitch_deg.map(f64::to_radians);
        self.last_slope_rad = st.last_road_slope_deg.map(f64::to_radians);
        self.refresh_estimate();
        Ok(())
    }

    /// Feed a wheel-speed message.
    pub fn push_wheels(&mut self, w: WheelSpeeds, emit: &mut dyn FnMut(Event)) {
        if !w.t_s.is_finite() || w.kmh.iter().any(|v| !v.is_finite()) {
            emit(Event::SampleDropped {
                t_s: w.t_s,
                reason: DropReason::NonFinite,
            });
            return;
        }
        if let Some(prev) = self.wheels {
            if w.t_s < prev.t_s {
                emit(Event::SampleDropped {
                    t_s: w.t_s,
                    reason: DropReason::TimeNotIncreasing,
                });
                return;
            }
            let dt = (w.t_s - prev.t_s).min(0.2);
            self.travelled_m += 0.5 * (prev.mean_kmh() + w.mean_kmh()) / 3.6 * dt;
        }
        if w.max_kmh() <= self.cfg.zero_speed_kmh {
            self.wheels_zero_since.get_or_insert(w.t_s);
        } else {
            self.wheels_zero_since = None;
        }
        self.wheels = Some(w);
    }

    /// Forget the wheel speeds (input lost): no standstill is declared until they return.
    pub fn wheels_lost(&mut self) {
        self.wheels = None;
        self.wheels_zero_since = None;
    }

    /// Feed an IMU sample.
    pub fn push_imu(&mut self, s: ImuSample, emit: &mut dyn FnMut(Event)) {
        if !s.t_s.is_finite()
            || s.acc_mps2
                .iter()
                .chain(s.gyro_dps.iter())
                .any(|v| !v.is_finite())
        {
            emit(Event::SampleDropped {
                t_s: s.t_s,
                reason: DropReason::NonFinite,
            });
            return;
        }
        if let Some(t) = self.last_t_s {
            if s.t_s <= t {
                emit(Event::SampleDropped {
                    t_s: s.t_s,
                    reason: DropReason::TimeNotIncreasing,
                });
                return;
            }
            if s.t_s - t > self.cfg.max_imu_gap_s {
                // A hole in the data: nothing before it can be trusted as still.
                self.quiet_since = None;
            }
        }
        self.last_t_s = Some(s.t_s);
        self.hist.push(s);

        let still = self.imu_still(s.t_s);
        let wheels_zero = self.wheels_zero_since.is_some();
        let quiet = still && wheels_zero;
        if quiet {
            self.quiet_since.get_or_insert(s.t_s);
        } else {
            self.quiet_since = None;
        }

        if self.standstill.is_some() {
            if quiet {
                self.update_standstill(&s, emit);
            } else {
                self.end_standstill(s.t_s, emit);
            }
        } else if let (Some(q0), Some(w0)) = (self.quiet_since, self.wheels_zero_since) {
            if s.t_s - q0 >= self.cfg.still_time_s && s.t_s - w0 >= self.cfg.zero_speed_time_s {
                self.begin_standstill(q0, s.t_s, emit);
            }
        }

        if self.fwd.is_active() {
            let step = self.fwd.push(&s);
            self.finish_forward(step, s.t_s, emit);
        }
    }

    /// IMU stillness over the trailing `still_window_s`.
    fn imu_still(&self, t_now: f64) -> bool {
        let n = self.hist.len();
        let bias = self.bias_rps.unwrap_or_else(Vector3::zeros);
        let (mut k, mut sum, mut sq, mut gyro) = (0usize, Vector3::zeros(), Vector3::zeros(), 0.0);
        let mut oldest = t_now;
        for i in (0..n).rev() {
            let x = self.hist.get(i);
            if t_now - x.t_s > self.cfg.still_window_s {
                break;
            }
            let a = x.acc();
            sum += a;
            sq += a.component_mul(&a);
            gyro += (x.gyro_rps() - bias).norm();
            oldest = x.t_s;
            k += 1;
        }
        if k < 5 || t_now - oldest < 0.75 * self.cfg.still_window_s {
            return false;
        }
        let kf = k as f64;
        let mean = sum / kf;
        let var = sq / kf - mean.component_mul(&mean);
        let std_max = var.map(|v| v.max(0.0).sqrt()).max();
        std_max <= self.cfg.still_acc_std_mps2
            && (gyro / kf).to_degrees() <= self.cfg.still_gyro_dps
    }

    fn update_bias(&mut self, s: &ImuSample) {
        let w = s.gyro_rps();
        let a = self.cfg.gyro_bias_alpha;
        // Eq. 7: first-order low-pass of the gyro output while stopped.
        self.bias_rps = Some(match self.bias_rps {
            Some(b) => w * a + b * (1.0 - a),
            None => w,
        });
    }

    fn begin_standstill(&mut self, q0_t: f64, t_now: f64, emit: &mut dyn FnMut(Event)) {
        // Everything since the quiet run began is standstill: average it.
        let mut sum = Vector3::zeros();
        let mut n = 0u64;
        let mut first_idx = None;
        for i in 0..self.hist.len() {
            let x = self.hist.get(i);
            if x.t_s >= q0_t {
                first_idx.get_or_insert(i);
                sum += x.acc();
                n += 1;
                self.update_bias(&x);
            }
        }
        let Some(first_idx) = first_idx else { return };
        let st = Standstill {
            t_start_s: q0_t,
            seg_sum: sum,
            seg_n: n,
            block_sum: Vector3::zeros(),
            block_n: 0,
            block_t0_s: t_now,
            pending: None,
        };
        self.standstill = Some(st);
        let g_mean = st.mean();
        let Some(q0) = attitude_from_gravity(&g_mean) else {
            return;
        };
        let pitch = pitch_of(&q0);
        emit(Event::StandstillStarted {
            t_s: t_now,
            imu_pitch_deg: pitch.to_degrees(),
        });

        // The drive stopped before a forward window covered its distance.
        if self.fwd.is_active() {
            let step = self.fwd.exhausted();
            self.finish_forward(step, t_now, emit);
        }

        // Parked or stopped without driving since the last baseline: a pitch step is a load change.
        let moved = self.travelled_m > 0.5;
        match self.baseline_pitch_rad {
            Some(base) if !moved => {
                let delta = pitch - base;
                if delta.abs().to_degrees() > self.cfg.load_change_deg {
                    self.apply_load_change(delta, pitch, t_now, emit);
                }
            }
            _ => self.baseline_pitch_rad = Some(pitch),
        }

        // Deceleration condition: walk the history backwards from the first still sample.
        if moved {
            let setup = self.window_setup(q0, g_mean.norm());
            self.bwd.start(setup);
            let mut result = None;
            for i in (0..=first_idx).rev() {
                if let Step::Done(r) = self.bwd.push(&self.hist.get(i)) {
                    result = Some(r);
                    break;
                }
            }
            let r = match result {
                Some(r) => r,
                None => match self.bwd.exhausted() {
                    Step::Done(r) => r,
                    Step::Continue => return,
                },
            };
            self.report_window(r, Condition::DecelBeforeStop, pitch, q0_t, emit);
        }
        self.travelled_m = 0.0;
    }

    fn update_standstill(&mut self, s: &ImuSample, emit: &mut dyn FnMut(Event)) {
        self.update_bias(s);
        let block_s = self.cfg.load_block_s;
        let thr = self.cfg.load_change_deg.to_radians();
        let Some(st) = self.standstill.as_mut() else {
            return;
        };
        st.block_sum += s.acc();
        st.block_n += 1;
        if s.t_s - st.block_t0_s < block_s {
            return;
        }
        let block_mean = st.block_sum / st.block_n as f64;
        let (block, block_n) = (st.block_sum, st.block_n);
        st.block_sum = Vector3::zeros();
        st.block_n = 0;
        st.block_t0_s = s.t_s;
        let (Some(bp), Some(sp)) = (pitch_from(&block_mean), pitch_from(&st.mean())) else {
            return;
        };
        if (bp - sp).abs() <= thr {
            st.seg_sum += block;
            st.seg_n += block_n;
            st.pending = None;
            return;
        }
        match st.pending.take() {
            Some((psum, pn))
                if pitch_from(&(psum / pn as f64))
                    .is_some_and(|pp| (pp - bp).abs() <= thr / 2.0) =>
            {
                // Two blocks agree on a new pitch: the load changed.
                st.seg_sum = psum + block;
                st.seg_n = pn + block_n;
                let new_pitch = pitch_from(&st.mean()).unwrap_or(bp);
                let delta = new_pitch - sp;
                self.apply_load_change(delta, new_pitch, s.t_s, emit);
            }
            _ => st.pending = Some((block, block_n)),
        }
    }

    fn apply_load_change(
        &mut self,
        delta_rad: f64,
        new_pitch_rad: f64,
        t_s: f64,
        emit: &mut dyn FnMut(Event),
    ) {
        self.baseline_pitch_rad = Some(new_pitch_rad);
        self.avg
            .restart_shifted(delta_rad.to_degrees(), self.cfg.load_prior_windows);
        self.refresh_estimate();
        emit(Event::LoadChanged {
            t_s,
            delta_deg: delta_rad.to_degrees(),
            estimate: self.estimate,
        });
    }

    fn end_standstill(&mut self, t_now: f64, emit: &mut dyn FnMut(Event)) {
        let Some(st) = self.standstill.take() else {
            return;
        };
        emit(Event::StandstillEnded {
            t_s: t_now,
            duration_s: t_now - st.t_start_s,
        });
        self.travelled_m = 0.0;
        let g_mean = st.mean();
        let Some(q0) = attitude_from_gravity(&g_mean) else {
            return;
        };
        // Start the walk where the IMU was certainly still: motion began inside the
        // last stillness window, so go back two windows (still samples add nothing).
        let t_start = (t_now - 2.0 * self.cfg.still_window_s).max(st.t_start_s);
        let setup = self.window_setup(q0, g_mean.norm());
        self.fwd.start(setup);
        self.fwd_ctx = Some(ForwardCtx {
            imu_pitch_rad: pitch_of(&q0),
        });
        // Catch up on the history up to (not including) the current sample; the
        // caller pushes the current one.
        let n = self.hist.len();
        let mut first = n - 1;
        while first > 0 && self.hist.get(first - 1).t_s >= t_start {
            first -= 1;
        }
        for i in first..n - 1 {
            let step = self.fwd.push(&self.hist.get(i));
            if let Step::Done(_) = step {
                self.finish_forward(step, t_now, emit);
                return;
            }
        }
    }

    fn finish_forward(&mut self, step: Step, t_now: f64, emit: &mut dyn FnMut(Event)) {
        let Step::Done(r) = step else { return };
        let Some(ctx) = self.fwd_ctx.take() else {
            return;
        };
        self.report_window(r, Condition::AccelAfterStop, ctx.imu_pitch_rad, t_now, emit);
    }

    fn window_setup(&self, q0: UnitQuaternion<f64>, g: f64) -> WindowSetup {
        let c = &self.cfg;
        WindowSetup {
            q0,
            gyro_bias_rps: self.bias_rps.unwrap_or_else(Vector3::zeros),
            gravity_mps2: g,
            lever_arm_m: Vector3::from(c.lever_arm_m),
            distance_m: c.window_distance_m,
            max_time_s: c.max_window_time_s,
            max_gap_s: c.max_imu_gap_s,
            max_yaw_rate_rps: c.max_yaw_rate_dps.to_radians(),
            max_lateral_acc_mps2: c.max_lateral_acc_mps2,
            max_chord_deviation_m: c.max_chord_deviation_m,
        }
    }

    fn report_window(
        &mut self,
        r: Result<window::WindowGeometry, RejectReason>,
        condition: Condition,
        imu_pitch_rad: f64,
        t_s: f64,
        emit: &mut dyn FnMut(Event),
    ) {
        match r {
            Ok(g) => {
                let r2b = imu_pitch_rad - g.slope_rad;
                self.avg.push(r2b.to_degrees());
                self.last_slope_rad = Some(g.slope_rad);
                self.refresh_estimate();
                let window = WindowReport {
                    t_s,
                    condition,
                    imu_pitch_deg: imu_pitch_rad.to_degrees(),
                    road_slope_deg: g.slope_rad.to_degrees(),
                    road_to_body_deg: r2b.to_degrees(),
                    distance_m: g.distance_m,
                    duration_s: g.duration_s,
                    chord_deviation_m: g.chord_deviation_m,
                };
                if let Some(estimate) = self.estimate {
                    emit(Event::WindowAccepted { window, estimate });
                }
            }
            Err(reason) => emit(Event::WindowRejected {
                t_s,
                condition,
                reason,
            }),
        }
    }

    fn refresh_estimate(&mut self) {
        let accepted = self.avg.accepted();
        self.estimate = self.avg.combined().map(|c| Estimate {
            road_to_body_deg: c.value_deg,
            std_err_deg: c.std_err_deg,
            windows: accepted,
            weight: c.weight,
        });
    }
}

fn pitch_from(f: &Vector3<f64>) -> Option<f64> {
    attitude::pitch_roll_from_gravity(f).map(|(p, _)| p)
}
