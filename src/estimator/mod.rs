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
mod events;
mod fusion;
mod grade;
mod gravity;
mod history;
mod lever;
mod mode;
mod motion;
mod persist;
mod ring;
mod standstill;
mod stillness;
pub mod types;
mod vibration;
pub mod window;

pub use average::{Averager, Combined, PairHandle};
pub use config::{Averaging, ConfigError, EstimatorConfig};
pub use events::{Condition, DropReason, Estimate, Event, WindowReport};
pub use grade::GradePitch;
pub use lever::LeverFit;
pub use mode::{PitchMode, PitchModeFit};
pub use persist::{EstimatorState, StateError};
pub use types::{ImuSample, WheelSpeeds};
pub use window::RejectReason;

use gravity::{GravityFilter, pitch_from};
use nalgebra::{Matrix3, Vector3};
use ring::Ring;
use standstill::{ForwardCtx, Standstill};
use window::WindowIntegrator;

/// How far a body's squat per m/s^2 pulling away may differ from its dive under
/// braking before the windows show it (1 sigma), as a share of the dive: anti-squat
/// and anti-dive geometry differ, and a car squats by about half to one and a half of
/// what it dives.
const SQUAT_PRIOR_SD: f64 = 0.5;

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
    /// Accepted windows in a row beyond `shift_deg` from the estimate.
    shift_run: fusion::ShiftRun,
    quiet_since: Option<f64>,
    /// Odometry since the last standstill ended, m.
    travelled_m: f64,
    standstill: Option<Standstill>,
    bias_rps: Option<Vector3<f64>>,
    /// Settled specific-force magnitude, the g of eq. 12-13: measured rather than
    /// nominal so that an accelerometer bias along z cancels.
    gravity: Option<GravityFilter>,
    /// Settled samples not yet given to `gravity`.
    gravity_block: gravity::GravityBlock,
    /// Share of the recent settled samples below `rest_swing_gate_mps2` (a running
    /// mean over about 50 samples): under a quarter, the gyro's noise alone exceeds the
    /// gate, and the gravity filter takes every settled sample.
    calm_share: f64,
    /// The same model fed one settled stop at a time with an honest variance: the
    /// accelerometer bias the windows remove (`acc_bias_mps2`).
    stop_bias: Option<GravityFilter>,
    /// Settled samples waiting one stillness window before they join the reference.
    settle_queue: std::collections::VecDeque<ImuSample>,
    /// The IMU's sample interval, s: the walks over the history count samples for
    /// spans given in seconds (`samples_in`); intervals in a row that disagree with it.
    sample_dt_s: (f64, u32),
    /// The gyro's noise learnt at rest; the gyro gates grow with it.
    gyro_noise: stillness::NoiseFloor,
    acc_noise: stillness::NoiseFloor,
    /// The last stillness window was close enough to the bias to update it.
    bias_window_ok: bool,
    /// A settled block has taught `bias_rps` (or it was restored from a saved state).
    bias_taught: bool,
    /// Mean specific force over the last stillness window, m/s^2.
    still_mean_acc: Vector3<f64>,
    /// The IMU saw the car move while the wheels read zero (a creep or a drive-off in
    /// the wheel sensors' dead zone) since the last standstill began.
    imu_moved: bool,
    /// Time (s) and mean speed (m/s) of the last wheel reading with a speed.
    last_wheel_motion: Option<(f64, f64)>,
    /// Earlier wheel readings with a speed, time s and m/s, newest first, one every
    /// `WHEEL_MARK_EVERY_S`: the rest check compares the IMU's speed with them.
    wheel_marks: [Option<(f64, f64)>; WHEEL_MARKS],
    /// Lever-arm fit from the rocking at stops, and the arm in use, m.
    lever_fit: LeverFit,
    lever_arm: Vector3<f64>,
    /// The body's pitch mode, from the swing after each stop.
    mode_fit: mode::PitchModeFit,
    /// Tracker of the motion after the IMU ended a standstill in the dead zone.
    dead_zone_motion: Option<motion::MotionTracker>,
    fwd: WindowIntegrator,
    fwd_ctx: Option<ForwardCtx>,
    bwd: WindowIntegrator,
    avg: Averager,
    /// The deceleration window accepted at the current stop, waiting for the
    /// acceleration window of the same stop to pair with.
    open_pair: Option<PairHandle>,
    /// The deceleration window of the current stop, until the first wheel speed after
    /// the drive-off confirms the stop was at rest.
    stop_window: Option<PairHandle>,
    baseline_pitch_rad: Option<f64>,
    last_slope_rad: Option<f64>,
    /// The body's pitch per m/s^2 of longitudinal force, learnt from braking.
    grade: GradePitch,
    /// Its pitch per m/s^2 of the drivetrain's force, learnt from pulling away (from
    /// a prior of `grade`'s).
    squat: GradePitch,
    /// See [`Estimator::grade_share`].
    grade_share: f64,
    /// Sum and count of the accepted windows' travel yaw in the IMU's frame, rad.
    travel_yaw: (f64, u32),
    /// `cfg.acc_matrix`, unless it is the identity.
    acc_matrix: Option<Matrix3<f64>>,
    /// Roll of the IMU on the level floor of the end-of-line calibration (elevation of
    /// its y axis, raw force), rad: lets the windows take a lane's roll out.
    floor_roll_rad: Option<f64>,
    estimate: Option<Estimate>,
    /// Pitch the body turned at rest since the settled reference, shown in the estimate
    /// until the settled blocks or the drive-off decide on it, rad.
    live_offset_rad: f64,
}

/// While the IMU-seen speed is above this share of `drive_off_speed_mps`, no sample
/// joins the standstill reference: it may be the start of a drive-off.
const MOTION_PAUSE_SHARE: f64 = 0.35;

/// Highest IMU rate the buffers are sized for, Hz.
const MAX_RATE_HZ: f64 = 200.0;
/// Period and number of the wheel readings kept for the rest check (`wheel_marks`):
/// they reach 3 s back, s.
const WHEEL_MARK_EVERY_S: f64 = 0.5;
pub(super) const WHEEL_MARKS: usize = 6;
/// Sample interval assumed until the IMU's own is learnt, s (100 Hz).
const NOMINAL_SAMPLE_DT_S: f64 = 0.01;

/// Standard gravity, m/s^2 (noise densities in ug/sqrt(Hz), the grade's pull).
const STANDARD_GRAVITY_MPS2: f64 = 9.80665;

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
            shift_run: fusion::ShiftRun::default(),
            quiet_since: None,
            travelled_m: 0.0,
            standstill: None,
            bias_rps: None,
            bias_window_ok: false,
            bias_taught: false,
            gyro_noise: stillness::NoiseFloor::default(),
            acc_noise: stillness::NoiseFloor::default(),
            still_mean_acc: Vector3::zeros(),
            imu_moved: false,
            dead_zone_motion: None,
            last_wheel_motion: None,
            wheel_marks: [None; WHEEL_MARKS],
            lever_fit: LeverFit::default(),
            lever_arm: Vector3::from(cfg.lever_arm_m),
            mode_fit: Default::default(),
            settle_queue: std::collections::VecDeque::with_capacity(
                (4.0 * cfg.still_window_s * MAX_RATE_HZ).ceil() as usize + 2,
            ),
            sample_dt_s: (NOMINAL_SAMPLE_DT_S, 0),
            gravity: None,
            gravity_block: Default::default(),
            calm_share: 1.0,
            stop_bias: None,
            fwd: WindowIntegrator::with_capacity(win_cap),
            fwd_ctx: None,
            bwd: WindowIntegrator::with_capacity(win_cap),
            avg: Averager::new(
                cfg.averaging,
                cfg.average_capacity,
                cfg.window_sigma_prior_deg,
            ),
            open_pair: None,
            stop_window: None,
            baseline_pitch_rad: None,
            last_slope_rad: None,
            grade: GradePitch::default(),
            squat: GradePitch::default(),
            grade_share: average::SHARE_PRIOR,
            travel_yaw: (0.0, 0),
            floor_roll_rad: None,
            acc_matrix: {
                let m = Matrix3::from_fn(|i, j| cfg.acc_matrix[i][j]);
                (m != Matrix3::identity()).then_some(m)
            },
            estimate: None,
            live_offset_rad: 0.0,
            cfg,
        })
    }

    /// Current estimate, `None` before the first accepted window.
    pub fn estimate(&self) -> Option<Estimate> {
        let mut e = self.estimate?;
        e.road_to_body_deg += self.live_offset_rad.to_degrees();
        Some(e)
    }

    /// The body's pitch per m/s^2 of longitudinal force learnt from braking, deg
    /// (`estimator/grade.rs`).
    pub fn pitch_per_force_deg(&self) -> f64 {
        self.grade.per_force_rad().to_degrees()
    }

    /// The body's pitch per m/s^2 of the drivetrain's force learnt from pulling away,
    /// deg (`estimator/grade.rs`; the braking one until acceleration windows tell).
    pub fn squat_per_force_deg(&self) -> f64 {
        self.squat_per_force_rad().to_degrees()
    }

    /// The squat is the dive plus what pulling away showed of a difference, weighed
    /// against both learners' scatter with a prior of none, known to `SQUAT_PRIOR_SD`
    /// of the dive: a symmetric body's windows differ by their noise alone.
    fn squat_per_force_rad(&self) -> f64 {
        let dive = self.grade.per_force_rad();
        let d = self.squat.per_force_from_rad(dive) - dive;
        let noise = self.squat.per_force_var() + self.grade.per_force_var();
        let prior = (SQUAT_PRIOR_SD * dive).powi(2);
        let gain = prior / (prior + noise);
        dive + if gain.is_finite() { gain * d } else { 0.0 }
    }

    /// The share of its braking pitch the body shows standing on a grade, as the
    /// windows so far fit it (1 before they tell; `estimator/average.rs`, `GradeShare`).
    pub fn grade_share(&self) -> f64 {
        self.grade_share
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
        let st = self.settled_standstill()?;
        Some((pitch_from(&st.mean())?.to_degrees(), st.settled_s()))
    }

    /// Roll of the settled standstill reference, deg: the elevation of the IMU's y axis
    /// (left side up positive) from the raw mean force. On the level floor of the
    /// end-of-line calibration it is what `set_floor_roll_deg` takes.
    pub fn standstill_roll_deg(&self) -> Option<f64> {
        let f = self.settled_standstill()?.mean();
        let n = f.norm();
        (n > 0.0).then(|| (f.y / n).clamp(-1.0, 1.0).asin().to_degrees())
    }

    /// The current standstill once its reference has settled.
    fn settled_standstill(&self) -> Option<standstill::Standstill> {
        self.standstill.filter(|st| st.seg_n >= self.min_settled())
    }

    /// The IMU's roll on the level floor of the end-of-line calibration
    /// (`standstill_roll_deg` there), deg, or `None` when it was not measured. With it
    /// every window takes out what a lane falling to the side adds to the pitch of an
    /// IMU yawed on its mount (`lane_roll_pitch_rad`); without, they do not.
    pub fn set_floor_roll_deg(&mut self, roll_deg: Option<f64>) {
        self.floor_roll_rad = roll_deg.filter(|r| r.is_finite()).map(f64::to_radians);
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
            let v_mps = w.moving_mean_kmh(self.cfg.zero_speed_kmh) / 3.6;
            self.last_wheel_motion = Some((w.t_s, v_mps));
            if self.wheel_marks[0].is_none_or(|(t, _)| w.t_s - t >= WHEEL_MARK_EVERY_S) {
                self.wheel_marks.rotate_right(1);
                self.wheel_marks[0] = Some((w.t_s, v_mps));
            }
            self.check_forward_speed(w.t_s, v_mps, emit);
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
        self.flush_block(t_s, emit);
        if let Some(st) = self.standstill
            && !st.settled_done
            && st.seg_n >= self.min_settled()
        {
            self.on_settled(t_s, emit);
        }
    }

    /// Forget the wheel speeds (input lost): no standstill is declared until they return.
    pub fn wheels_lost(&mut self) {
        self.wheels = None;
        self.last_wheel_motion = None;
        self.wheel_marks = [None; WHEEL_MARKS];
        self.wheels_zero_since = None;
        self.wheels_stopped = false;
        self.motion_unknown = true;
    }

    /// Feed an IMU sample.
    pub fn push_imu(&mut self, mut s: ImuSample, emit: &mut dyn FnMut(Event)) {
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
        if let Some(m) = self.acc_matrix {
            s.acc_mps2 = (m * Vector3::from(s.acc_mps2)).into();
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
                let n = self.hist.len();
                if n > 0
                    && self.turn_unknown_across(&self.hist.get(n - 1), &s)
                    && let Some(st) = self.standstill.as_mut()
                {
                    st.gap_end_s = s.t_s;
                }
            }
        }
        if let Some(t) = self.last_t_s {
            self.learn_sample_interval(s.t_s - t);
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
            // Rocking, a door shock or a gap in the data only pause the standstill; it
            // ends when the wheels turn or the IMU sees the car pick up speed.
            let (v, gain) = if wheels_zero {
                self.track_motion()
            } else {
                (0.0, 0.0)
            };
            let thr = self.drive_off_speed_mps();
            if !wheels_zero || (v >= thr && gain >= thr) {
                self.imu_moved |= wheels_zero;
                self.dead_zone_motion = self
                    .standstill
                    .and_then(|st| st.motion)
                    .filter(|_| wheels_zero);
                self.end_standstill(s.t_s, emit);
            } else {
                if quiet && v < MOTION_PAUSE_SHARE * thr {
                    self.update_standstill(&s, emit);
                }
                self.close_stale_block(s.t_s, emit);
                self.track_live_pitch(s.t_s);
            }
        } else if let (true, Some(q0), Some(w0)) = (
            self.track_dead_zone(wheels_zero),
            self.quiet_since,
            self.wheels_zero_since,
        ) && s.t_s - q0 >= self.cfg.still_time_s
            && s.t_s - w0 >= self.cfg.zero_speed_time_s
        {
            self.begin_standstill(q0, s.t_s, emit);
        }

        if self.fwd.is_active() {
            let step = self.fwd.push(&s);
            self.finish_forward(step, s.t_s, emit);
        }
    }
}
