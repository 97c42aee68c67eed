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
use nalgebra::{Matrix3, UnitQuaternion, Vector3};
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
    /// The wheels have read zero for `zero_speed_time_s` (no IMU needed for this).
    WheelsStopped {
        t_s: f64,
    },
    /// The wheels read a speed again.
    WheelsMoving {
        t_s: f64,
    },
    /// Wheels stopped and the IMU still: the standstill reference is being taken.
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
    /// A pitch step at the first standstill after a restart or wheel-speed outage:
    /// the load may have changed, or the car moved unseen. The next accepted window
    /// decides; until then nothing changes.
    LoadChangeSuspected {
        t_s: f64,
        delta_deg: f64,
    },
    /// A step in standstill IMU pitch: the load changed while the road could not.
    LoadChanged {
        t_s: f64,
        delta_deg: f64,
        estimate: Option<Estimate>,
    },
    /// `shift_windows` windows in a row sat beyond `shift_deg` on one side of the
    /// estimate: the pitch moved unseen, and the average restarted from them.
    PitchShifted {
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
    /// Settled specific-force magnitude (bias along z included), m/s^2.
    #[serde(default)]
    pub gravity_mps2: Option<f64>,
    /// Accelerometer bias along body x and y as seen in the standstill magnitude, m/s^2.
    #[serde(default)]
    pub accel_bias_xy_mps2: Option<[f64; 2]>,
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
    /// Where the car came to rest (start of the deceleration walk).
    t_rest_s: f64,
    /// Specific-force sums of the settled samples of the current load segment.
    seg_sum: Vector3<f64>,
    seg_n: u64,
    seg_first_s: f64,
    seg_last_s: f64,
    block_sum: Vector3<f64>,
    block_n: u64,
    block_t0_s: f64,
    /// A block that differed from the segment, waiting for a second one to confirm.
    pending: Option<(Vector3<f64>, u64)>,
    /// The car drove since the previous standstill.
    moved: bool,
    /// Nothing watched the wheels between the load baseline and this standstill.
    motion_unknown: bool,
    /// The settled reference exists and the baseline and deceleration window were handled.
    settled_done: bool,
}

impl Standstill {
    fn mean(&self) -> Vector3<f64> {
        self.seg_sum / self.seg_n.max(1) as f64
    }
    fn settled_s(&self) -> f64 {
        if self.seg_n == 0 {
            0.0
        } else {
            self.seg_last_s - self.seg_first_s
        }
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
    wheels_stopped: bool,
    /// The wheels have not been watched since the load baseline (start, restore, outage).
    motion_unknown: bool,
    /// A load step seen when motion was unknown, waiting for a window: (delta rad, new pitch rad).
    pending_load: Option<(f64, f64)>,
    /// Accepted windows in a row beyond `shift_deg` from the estimate: (side, count).
    shift_run: (f64, usize),
    quiet_since: Option<f64>,
    /// Odometry since the last standstill ended, m.
    travelled_m: f64,
    standstill: Option<Standstill>,
    bias_rps: Option<Vector3<f64>>,
    /// Settled specific-force magnitude, the g of eq. 12-13: measured rather than
    /// nominal so that an accelerometer bias along z cancels.
    gravity: Option<GravityFilter>,
    /// Settled samples waiting one stillness window before they join the reference.
    settle_queue: std::collections::VecDeque<ImuSample>,
    /// The last stillness window was close enough to the bias to update it.
    bias_window_ok: bool,
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
            wheels_stopped: false,
            motion_unknown: true,
            pending_load: None,
            shift_run: (0.0, 0),
            quiet_since: None,
            travelled_m: 0.0,
            standstill: None,
            bias_rps: None,
            bias_window_ok: false,
            settle_queue: std::collections::VecDeque::with_capacity(
                (4.0 * cfg.still_window_s * MAX_RATE_HZ).ceil() as usize + 2,
            ),
            gravity: None,
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

    /// Settled standstill reference: IMU pitch from gravity (deg) and the seconds of
    /// settled samples behind it. `None` while moving or before anything settled.
    pub fn standstill_pitch(&self) -> Option<(f64, f64)> {
        let st = self.standstill?;
        if st.seg_n < 5 {
            return None;
        }
        Some((pitch_from(&st.mean())?.to_degrees(), st.settled_s()))
    }

    /// End-of-line calibration on a level floor: the IMU pitch is the road-to-body
    /// pitch. Seeds the estimate with it, worth `weight` windows, and makes it the load
    /// baseline.
    pub fn seed_calibration(&mut self, road_to_body_deg: f64, weight: f64) {
        self.avg.restore_prior(road_to_body_deg, weight, 0);
        self.baseline_pitch_rad = Some(road_to_body_deg.to_radians());
        self.refresh_estimate();
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
        if let Some(g) = st.gravity_mps2 {
            if !(g.is_finite() && (5.0..15.0).contains(&g)) {
                return Err(StateError::Implausible("gravity_mps2"));
            }
        }
        if let Some(b) = st.accel_bias_xy_mps2 {
            if b.iter().any(|x| !x.is_finite() || x.abs() > 2.0) {
                return Err(StateError::Implausible("accel_bias_xy_mps2"));
            }
        }
        self.last_slope_rad = st.last_road_slope_deg.map(f64::to_radians);
        self.motion_unknown = true;
        // A restored magnitude is as uncertain as a few seconds of standstill; new stops
        // refine it.
        self.gravity = st.gravity_mps2.map(|g| {
            let bias = st.accel_bias_xy_mps2.unwrap_or([0.0; 2]);
            GravityFilter::new(g, 1e-5, bias, 0.01)
        });
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
            let since = *self.wheels_zero_since.get_or_insert(w.t_s);
            if !self.wheels_stopped && w.t_s - since >= self.cfg.zero_speed_time_s {
                self.wheels_stopped = true;
                emit(Event::WheelsStopped { t_s: w.t_s });
            }
        } else {
            self.wheels_zero_since = None;
            if self.wheels_stopped {
                self.wheels_stopped = false;
                emit(Event::WheelsMoving { t_s: w.t_s });
            }
        }
        self.wheels = Some(w);
    }

    /// End of input (end of a log, shutdown): evaluate what is still waiting, such as
    /// the deceleration window of a stop that has not settled for `settle_time_s` yet.
    pub fn finish(&mut self, t_s: f64, emit: &mut dyn FnMut(Event)) {
        if let Some(st) = self.standstill {
            if !st.settled_done && st.seg_n >= 5 {
                self.on_settled(t_s, emit);
            }
        }
    }

    /// Forget the wheel speeds (input lost): no standstill is declared until they return.
    pub fn wheels_lost(&mut self) {
        self.wheels = None;
        self.wheels_zero_since = None;
        self.wheels_stopped = false;
        self.motion_unknown = true;
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

    /// IMU stillness over the trailing `still_window_s`. Also records whether the
    /// window may feed the bias filter.
    fn imu_still(&mut self, t_now: f64) -> bool {
        let n = self.hist.len();
        let (mut k, mut oldest) = (0usize, t_now);
        let (mut sa, mut qa, mut sg, mut qg) = (
            Vector3::zeros(),
            Vector3::zeros(),
            Vector3::zeros(),
            Vector3::zeros(),
        );
        for i in (0..n).rev() {
            let x = self.hist.get(i);
            if t_now - x.t_s > self.cfg.still_window_s {
                break;
            }
            let (a, w) = (x.acc(), x.gyro_rps());
            sa += a;
            qa += a.component_mul(&a);
            sg += w;
            qg += w.component_mul(&w);
            oldest = x.t_s;
            k += 1;
        }
        self.bias_window_ok = false;
        if k < 5 || t_now - oldest < 0.75 * self.cfg.still_window_s {
            return false;
        }
        let kf = k as f64;
        let std_max = |s: Vector3<f64>, q: Vector3<f64>| {
            let m = s / kf;
            (q / kf - m.component_mul(&m))
                .map(|v| v.max(0.0).sqrt())
                .max()
        };
        let acc_ok = std_max(sa, qa) <= self.cfg.still_acc_std_mps2;
        let gyro_ok = std_max(sg, qg).to_degrees() <= self.cfg.still_gyro_std_dps;
        let offset_dps = self.bias_rps.map(|b| (sg / kf - b).norm().to_degrees());
        let mean_ok = offset_dps.is_none_or(|o| o <= self.cfg.still_gyro_dps);

        self.bias_window_ok = offset_dps.is_none_or(|o| o <= self.cfg.bias_gate_dps);
        acc_ok && gyro_ok && mean_ok
    }

    /// Walking back from the newest sample, the index of the earliest sample of the
    /// trailing run whose 5-sample mean specific force matches `f_rest` (not before `floor`).
    fn rest_edge(&self, f_rest: &Vector3<f64>, floor: usize) -> usize {
        const AVG: usize = 5;
        let n = self.hist.len();
        let tol = self.cfg.rest_acc_tol_mps2;
        let mut edge = n - 1;
        let mut i = n;
        while i >= floor + AVG {
            let mut m = Vector3::zeros();
            for j in i - AVG..i {
                m += self.hist.get(j).acc();
            }
            if ((m / AVG as f64) - f_rest).amax() > tol {
                break;
            }
            edge = i - AVG;
            i -= 1;
        }
        edge
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

    /// Index of the first history sample at or after `t`.
    fn index_at(&self, t: f64) -> usize {
        let (mut lo, mut hi) = (0, self.hist.len());
        while lo < hi {
            let mid = (lo + hi) / 2;
            if self.hist.get(mid).t_s < t {
                lo = mid + 1
            } else {
                hi = mid
            }
        }
        lo
    }

    /// Where the car came to rest, found walking back from the settled sample `from`
    /// with the attitude carried by the gyro: a body rocking on its suspension at rest
    /// only tilts gravity along x (its lever-arm acceleration is mostly vertical),
    /// while braking shows fully in x. Returns the edge and the attitude there. The
    /// search goes back at most 2 s before `floor`, the first quiet sample.
    fn rocking_rest_edge(
        &self,
        q_ref: UnitQuaternion<f64>,
        from: usize,
        floor: usize,
        g: f64,
    ) -> (usize, UnitQuaternion<f64>) {
        const AVG: usize = 5;
        let tol = self.cfg.rest_acc_tol_mps2;
        let lowest = floor.saturating_sub(200);
        let bias = self.bias_rps.unwrap_or_else(Vector3::zeros);
        let up = Vector3::new(0.0, 0.0, g);
        let mut q = q_ref;
        let mut res = [0.0f64; AVG];
        // Attitudes of the last AVG samples visited, the one at `edge` among them.
        let mut qs = [q_ref; AVG];
        let (mut edge, mut q_edge) = (from, q_ref);
        let mut i = from;
        let mut k = 0usize;
        loop {
            let x = self.hist.get(i);
            // The IMU rides the rocking body at the lever arm: remove that acceleration.
            let lever_acc = self.lever_acc_at(i);
            res[k % AVG] = x.acc_mps2[0] - (q.inverse() * up).x - lever_acc.x;
            qs[k % AVG] = q;
            k += 1;
            if k >= AVG {
                if (res.iter().sum::<f64>() / AVG as f64).abs() > tol {
                    break;
                }
                // The newest sample of this window is certainly at rest; its attitude
                // was visited AVG - 1 steps ago.
                edge = i + AVG - 1;
                q_edge = qs[k % AVG];
            }
            if i == 0 || i <= lowest {
                break;
            }
            let (a, b) = (self.hist.get(i - 1), x);
            let w = (a.gyro_rps() + b.gyro_rps()) * 0.5 - bias;
            q = attitude::propagate(&q, &w, a.t_s - b.t_s);
            i -= 1;
        }
        (edge.min(from), q_edge)
    }

    /// Velocity of the IMU at sample `i` (frame of its attitude `q_i`, m/s) while the
    /// pitch centre is at rest but the body may still rock on its suspension. Each rest
    /// sample j on the `later` side gives omega_j x lever arm, carried to `i` by the
    /// integrated acceleration between them; the mean over `REST_VELOCITY_S` averages
    /// out gyro noise (a single sample's noise times a 2 m lever arm costs about 0.1 deg
    /// of slope). Smoothing the rate at `i` itself instead is biased right at the stop,
    /// where the rocking starts with a kink. The first `SKIP` samples are left out in
    /// case `i` is a step early.
    fn rest_velocity(
        &self,
        q_i: UnitQuaternion<f64>,
        i: usize,
        later: bool,
        g: f64,
    ) -> Vector3<f64> {
        const REST_VELOCITY_S: f64 = 0.25;
        const SKIP: usize = 2;
        let bias = self.bias_rps.unwrap_or_else(Vector3::zeros);
        let lever = Vector3::from(self.cfg.lever_arm_m);
        let up = Vector3::new(0.0, 0.0, g);
        let n = self.hist.len();
        let t_i = self.hist.get(i).t_s;
        let (mut q, mut dv) = (q_i, Vector3::zeros());
        let (mut sum, mut count) = (Vector3::zeros(), 0usize);
        let mut j = i;
        loop {
            let next = if later { j + 1 } else { j.wrapping_sub(1) };
            if next >= n {
                break;
            }
            let (a, b) = (self.hist.get(j), self.hist.get(next));
            if (b.t_s - t_i).abs() > REST_VELOCITY_S {
                break;
            }
            let dt = b.t_s - a.t_s;
            let q_next = attitude::propagate(&q, &((a.gyro_rps() + b.gyro_rps()) * 0.5 - bias), dt);
            // dv = v_next - v_i, in time order whichever way the walk goes.
            dv += ((q * a.acc() - up) + (q_next * b.acc() - up)) * (0.5 * dt);
            q = q_next;
            j = next;
            if j.abs_diff(i) > SKIP {
                sum += q * (b.gyro_rps() - bias).cross(&lever) - dv;
                count += 1;
            }
        }
        if count == 0 {
            return q_i * (self.hist.get(i).gyro_rps() - bias).cross(&lever);
        }
        sum / count as f64
    }

    /// Carry an attitude along the history from sample `from` to sample `to` with the
    /// bias-corrected gyro (eq. 10-11), in either direction.
    fn carry(&self, mut q: UnitQuaternion<f64>, from: usize, to: usize) -> UnitQuaternion<f64> {
        let bias = self.bias_rps.unwrap_or_else(Vector3::zeros);
        let step = |q: UnitQuaternion<f64>, i: usize, sign: f64| {
            let (a, b) = (self.hist.get(i), self.hist.get(i + 1));
            let w = (a.gyro_rps() + b.gyro_rps()) * 0.5 - bias;
            attitude::propagate(&q, &w, sign * (b.t_s - a.t_s))
        };
        if from < to {
            for i in from..to {
                q = step(q, i, 1.0);
            }
        } else {
            for i in (to..from).rev() {
                q = step(q, i, -1.0);
            }
        }
        q
    }

    fn begin_standstill(&mut self, q0_t: f64, t_now: f64, emit: &mut dyn FnMut(Event)) {
        let n = self.hist.len();
        let first_quiet = self.index_at(q0_t).min(n - 1);
        // Reference at rest: the most recent quarter second, surely stopped by now.
        let mut f_rest = Vector3::zeros();
        let mut w_mean = Vector3::zeros();
        let mut k = 0;
        for i in (first_quiet..n).rev() {
            let x = self.hist.get(i);
            if t_now - x.t_s > 0.25 && k >= 5 {
                break;
            }
            f_rest += x.acc();
            w_mean += x.gyro_rps();
            k += 1;
        }
        f_rest /= k.max(1) as f64;
        if self.bias_rps.is_none() {
            // First standstill ever: start eq. 7 from the mean rate.
            self.bias_rps = Some(w_mean / k.max(1) as f64);
        }
        // The car came to rest where the specific force settled; constant braking
        // has no variance, so the stillness test alone would start too early.
        let rest = self
            .rest_edge(&f_rest, 0)
            .max(first_quiet.saturating_sub(100))
            .min(n - 1);
        let moved = self.travelled_m > 0.5;
        // From here on the wheels are watched; before, motion may have gone unseen.
        let motion_unknown = self.motion_unknown && !moved;
        self.motion_unknown = false;
        self.settle_queue.clear();
        self.standstill = Some(Standstill {
            t_rest_s: self.hist.get(rest).t_s,
            seg_sum: Vector3::zeros(),
            seg_n: 0,
            seg_first_s: t_now,
            seg_last_s: t_now,
            block_sum: Vector3::zeros(),
            block_n: 0,
            block_t0_s: t_now,
            pending: None,
            moved,
            motion_unknown,
            settled_done: false,
        });
        let pitch = pitch_from(&f_rest).unwrap_or(0.0);
        emit(Event::StandstillStarted {
            t_s: t_now,
            imu_pitch_deg: pitch.to_degrees(),
        });
        // The drive stopped before a forward window covered its distance.
        if self.fwd.is_active() {
            let step = self.fwd.exhausted();
            self.finish_forward(step, t_now, emit);
        }
    }

    fn update_gravity(&mut self, t_s: f64, f: &Vector3<f64>) {
        let q = self.cfg.gravity_walk_mps2_rts;
        let k = self.gravity.get_or_insert_with(|| {
            GravityFilter::new(f.norm(), 1e-3, [0.0; 2], GravityFilter::BIAS_PRIOR_MPS2)
        });
        k.update(t_s, f, q);
    }

    /// Gravity magnitude for a window whose reference is the standstill mean `f_mean`.
    fn gravity_mps2(&self, f_mean: &Vector3<f64>) -> f64 {
        let m = f_mean.norm();
        match self.gravity {
            Some(g) if m > 0.0 => g.magnitude(&(f_mean / m)),
            _ => m,
        }
    }

    fn update_standstill(&mut self, s: &ImuSample, emit: &mut dyn FnMut(Event)) {
        if !self.bias_window_ok {
            return;
        }
        // Samples join the reference only once a further stillness window has passed:
        // the last ones before a drive-off are already moving.
        if self.settle_queue.len() == self.settle_queue.capacity() {
            self.settle_queue.pop_front();
        }
        self.settle_queue.push_back(*s);
        let lag = 2.0 * self.cfg.still_window_s;
        while let Some(x) = self.settle_queue.front().copied() {
            if s.t_s - x.t_s < lag {
                break;
            }
            self.settle_queue.pop_front();
            self.commit_settled(&x, emit);
        }
    }

    /// Acceleration of the IMU at history sample `i` from the body still rocking about
    /// the pitch centre (angular acceleration and rate from smoothed gyro readings), in
    /// body axes, m/s^2. Mounted 2 m ahead of the pitch centre, the IMU sees a rocking
    /// tail of 0.1 deg/s as 1 mm/s^2 in the standstill mean: 0.05 deg of slope over a
    /// gentle 2 s window.
    fn lever_acc_at(&self, i: usize) -> Vector3<f64> {
        const H: usize = 5;
        let lever = Vector3::from(self.cfg.lever_arm_m);
        if i < 2 * H || i + 2 * H >= self.hist.len() || lever == Vector3::zeros() {
            return Vector3::zeros();
        }
        let rate = |c: usize| {
            let mut w = Vector3::zeros();
            for j in c - H..=c + H {
                w += self.hist.get(j).gyro_rps();
            }
            w / (2 * H + 1) as f64
        };
        let span = self.hist.get(i + H).t_s - self.hist.get(i - H).t_s;
        if span <= 0.0 {
            return Vector3::zeros();
        }
        let alpha = (rate(i + H) - rate(i - H)) / span;
        let w = rate(i) - self.bias_rps.unwrap_or_else(Vector3::zeros);
        alpha.cross(&lever) + w.cross(&w.cross(&lever))
    }

    fn commit_settled(&mut self, s: &ImuSample, emit: &mut dyn FnMut(Event)) {
        self.update_bias(s);
        // The gravity reference is the specific force of the pitch centre: what the IMU
        // would read without the rocking tail.
        let f = s.acc() - self.lever_acc_at(self.index_at(s.t_s));
        self.update_gravity(s.t_s, &f);
        let block_s = self.cfg.load_block_s;
        let settle_s = self.cfg.settle_time_s;
        let deadline_s = self.cfg.history_s - self.cfg.max_window_time_s - 1.0;
        let thr = self.cfg.load_change_deg.to_radians();
        let Some(st) = self.standstill.as_mut() else {
            return;
        };
        let s = *s;
        if st.seg_n == 0 {
            st.seg_first_s = s.t_s;
            st.block_t0_s = s.t_s;
        }
        if !st.settled_done {
            st.seg_sum += f;
            st.seg_n += 1;
            st.seg_last_s = s.t_s;
            // Wait for a long gravity average, but not so long that the history loses
            // the samples before the stop.
            if st.settled_s() >= settle_s || s.t_s - st.t_rest_s >= deadline_s {
                self.on_settled(s.t_s, emit);
            }
            return;
        }
        st.seg_last_s = s.t_s;
        st.block_sum += f;
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

    /// The standstill has a settled gravity reference: check the load baseline and
    /// evaluate the deceleration window.
    fn on_settled(&mut self, t_now: f64, emit: &mut dyn FnMut(Event)) {
        let Some(st) = self.standstill.as_mut() else {
            return;
        };
        st.settled_done = true;
        let st = *st;
        let Some(q_ref) = attitude_from_gravity(&st.mean()) else {
            return;
        };
        let pitch = pitch_of(&q_ref);
        // Stopped or parked without driving since the last baseline: a pitch step is a load change.
        match self.baseline_pitch_rad {
            Some(base) if !st.moved => {
                let delta = pitch - base;
                if delta.abs().to_degrees() > self.cfg.load_change_deg {
                    if st.motion_unknown {
                        // After a restart or a wheel-speed outage the car may have moved
                        // to another grade: let the next accepted window decide.
                        self.pending_load = Some((delta, pitch));
                        emit(Event::LoadChangeSuspected {
                            t_s: t_now,
                            delta_deg: delta.to_degrees(),
                        });
                    } else {
                        self.apply_load_change(delta, pitch, t_now, emit);
                    }
                }
            }
            _ => self.baseline_pitch_rad = Some(pitch),
        }
        // The baseline now stands here: odometry counts from this stop. (A standstill
        // that never settles, such as one declared while still rolling below the
        // wheel sensors' dead zone, must not reset it.)
        self.travelled_m = 0.0;
        if !st.moved {
            return;
        }
        // Deceleration condition: carry the settled attitude back to the rest edge, then
        // walk the history backwards from there.
        if self.hist.get(0).t_s > st.t_rest_s {
            let r = Err(RejectReason::TooShort { distance_m: 0.0 });
            self.report_window(r, Condition::DecelBeforeStop, pitch, st.t_rest_s, emit);
            return;
        }
        let g = self.gravity_mps2(&st.mean());
        let (rest, q0) = self.rocking_rest_edge(
            q_ref,
            self.index_at(st.seg_first_s),
            self.index_at(st.t_rest_s),
            g,
        );
        let setup = self.window_setup(q0, g);
        let v0 = self.rest_velocity(q0, rest, true, g);
        self.bwd.start(setup, v0);
        let mut result = None;
        for i in (0..=rest).rev() {
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
        self.report_window(r, Condition::DecelBeforeStop, pitch, st.t_rest_s, emit);
    }

    /// Count windows in a row that sit beyond `shift_deg` on the same side of the
    /// estimate; true when `shift_windows` of them (this one included) agree.
    fn track_shift(&mut self, window_deg: f64) -> bool {
        let (k, thr) = (self.cfg.shift_windows, self.cfg.shift_deg);
        let Some(e) = self.estimate.filter(|_| k >= 2) else {
            self.shift_run = (0.0, 0);
            return false;
        };
        let d = window_deg - e.road_to_body_deg;
        self.shift_run = if d.abs() <= thr {
            (0.0, 0)
        } else if d.signum() == self.shift_run.0 {
            (self.shift_run.0, self.shift_run.1 + 1)
        } else {
            (d.signum(), 1)
        };
        self.shift_run.1 >= k
    }

    fn apply_load_change(
        &mut self,
        delta_rad: f64,
        new_pitch_rad: f64,
        t_s: f64,
        emit: &mut dyn FnMut(Event),
    ) {
        self.baseline_pitch_rad = Some(new_pitch_rad);
        self.shift_run = (0.0, 0);
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
        let Some(st) = self.standstill else { return };
        if !st.settled_done && st.seg_n >= 5 {
            // A short stop: use what settled.
            self.on_settled(t_now, emit);
        }
        self.standstill = None;
        emit(Event::StandstillEnded {
            t_s: t_now,
            duration_s: t_now - st.t_rest_s,
        });
        let q_ref = if st.seg_n >= 5 {
            attitude_from_gravity(&st.mean())
        } else {
            None
        };
        let Some(q_ref) = q_ref else {
            if st.moved {
                let r = Err(RejectReason::NotStill);
                self.report_window(r, Condition::DecelBeforeStop, 0.0, t_now, emit);
            }
            let r = Err(RejectReason::NotStill);
            self.report_window(r, Condition::AccelAfterStop, 0.0, t_now, emit);
            return;
        };
        // Start the walk at the last sample that still matched the standstill: from
        // there the car moves. The current sample is pushed by the caller.
        let n = self.hist.len();
        let floor = self.index_at(st.t_rest_s);
        let g_mean = st.mean();
        let mut first = n - 1;
        let mut i = n - 1;
        while i >= floor + 5 {
            let mut m = Vector3::zeros();
            for j in i - 4..=i {
                m += self.hist.get(j).acc();
            }
            if ((m / 5.0) - g_mean).amax() <= self.cfg.rest_acc_tol_mps2 {
                first = i;
                break;
            }
            i -= 1;
        }
        // Two samples of margin: a sample straddling the drive-off can still match.
        let first = first.saturating_sub(2).max(floor);
        let last_settled = self.index_at(st.seg_last_s).min(n - 1);
        let q0 = self.carry(q_ref, last_settled, first);
        let setup = self.window_setup(q0, self.gravity_mps2(&g_mean));
        // A stop that settled ends with the body at rest: its rate is zero, not noise.
        let settled_at_start = st.seg_n >= 5 && self.hist.get(first).t_s - st.seg_last_s < 1.0;
        let v0 = if settled_at_start {
            Vector3::zeros()
        } else {
            self.rest_velocity(q0, first, false, setup.gravity_mps2)
        };
        self.fwd.start(setup, v0);
        self.fwd_ctx = Some(ForwardCtx {
            imu_pitch_rad: pitch_of(&q_ref),
        });
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
            check_extra_m: c.chord_check_extra_m,
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
                if let Some((delta, new_pitch)) = self.pending_load.take() {
                    // Keep the suspected load change only if this window agrees with it.
                    let shifted_closer = self.estimate.is_none_or(|e| {
                        let w = r2b.to_degrees();
                        (w - (e.road_to_body_deg + delta.to_degrees())).abs()
                            < (w - e.road_to_body_deg).abs()
                    });
                    if shifted_closer {
                        self.apply_load_change(delta, new_pitch, t_s, emit);
                    }
                }
                let shifted = self.track_shift(r2b.to_degrees());
                self.avg.push(r2b.to_degrees());
                self.last_slope_rad = Some(g.slope_rad);
                self.refresh_estimate();
                if shifted {
                    let before = self.estimate.map_or(0.0, |e| e.road_to_body_deg);
                    self.avg.restart_from_newest(self.cfg.shift_windows);
                    self.refresh_estimate();
                    self.shift_run = (0.0, 0);
                    let after = self.estimate.map_or(before, |e| e.road_to_body_deg);
                    emit(Event::PitchShifted {
                        t_s,
                        delta_deg: after - before,
                        estimate: self.estimate,
                    });
                }
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

/// Kalman filter on the standstill specific-force magnitude. An accelerometer bias `b`
/// makes the magnitude depend on where gravity points in the body: |g u + b| is about
/// c + b_x u_x + b_y u_y for the unit gravity direction u (b_z folds into c). A window
/// cancels the bias only with the magnitude of its own stop (the reference the attitude
/// came from); a single short stop measures it noisily, a plain average over stops
/// misses the bias term by up to |b| sin(pitch), 4 mm/s^2 for 0.05 m/s^2 at 5 deg:
/// 0.25 deg of slope over a 2 s window. So the state is (c, b_x, b_y), each a random
/// walk of `gravity_walk_mps2_rts` (the bias drifts with temperature); each settled
/// sample measures the magnitude with a noise learnt from the innovations.
#[derive(Debug, Clone, Copy)]
struct GravityFilter {
    x: Vector3<f64>,
    /// Covariance of `x`.
    p: Matrix3<f64>,
    /// Per-sample measurement variance, (m/s^2)^2.
    r: f64,
    last_t: Option<f64>,
}

impl GravityFilter {
    /// Prior spread of the horizontal bias terms, m/s^2 (a MEMS accelerometer offset).
    const BIAS_PRIOR_MPS2: f64 = 0.1;

    fn new(c: f64, c_var: f64, bias: [f64; 2], bias_sd: f64) -> Self {
        let b2 = bias_sd * bias_sd;
        Self {
            x: Vector3::new(c, bias[0], bias[1]),
            p: Matrix3::from_diagonal(&Vector3::new(c_var, b2, b2)),
            r: 1e-3,
            last_t: None,
        }
    }

    fn regressor(u: &Vector3<f64>) -> Vector3<f64> {
        Vector3::new(1.0, u.x, u.y)
    }

    /// Expected magnitude for gravity along the body direction `u` (unit), m/s^2.
    fn magnitude(&self, u: &Vector3<f64>) -> f64 {
        Self::regressor(u).dot(&self.x)
    }

    fn update(&mut self, t_s: f64, f: &Vector3<f64>, q: f64) {
        let m = f.norm();
        if m <= 0.0 {
            return;
        }
        if let Some(t0) = self.last_t {
            let walk = q * q * (t_s - t0).max(0.0);
            self.p += Matrix3::from_diagonal_element(walk);
        }
        self.last_t = Some(t_s);
        let h = Self::regressor(&(f / m));
        let y = m - h.dot(&self.x);
        self.r = (0.995 * self.r + 0.005 * y * y).max(1e-8);
        let ph = self.p * h;
        let k = ph / (h.dot(&ph) + self.r);
        self.x += k * y;
        self.p -= k * ph.transpose();
    }
}
