//! Standstill: its start, the settled gravity reference, load changes seen while
//! stopped, and the windows on either side of it (deceleration before, acceleration after).

use super::attitude::{attitude_from_gravity, pitch_of};
use super::gravity::pitch_from;
use super::history::REST_AVG_MIN;
use super::motion::MotionTracker;
use super::window::{RejectReason, Step, WindowGeometry};
use super::{Condition, Estimator, Event, ImuSample};
use nalgebra::{UnitQuaternion, Vector3};

/// The speed check of a new standstill looks back at most this far to the last wheel
/// reading with a speed, s.
const REST_CHECK_SPAN_S: f64 = 6.0;
/// A settled block teaches the gyro bias only when it began this long after the car
/// came to rest: the body's swing back from its dive decays over about a second (1.3
/// Hz at damping 0.2-0.4), and what is left of it has one sign over a block.
const BIAS_SETTLE_S: f64 = 1.0;
/// A block that began this long after the car came to rest may begin the reference
/// whatever the angular acceleration it holds (`reference_swing_gate_dps2`), s: a
/// swing of damping 0.1 at 0.8 Hz has fallen to a seventh by then, and a gyro noisier
/// than the gate allows must not leave the stop without a reference.
const REFERENCE_SWING_SPAN_S: f64 = 4.0;
/// The speed the IMU says the car had at the last wheel reading with a speed may differ
/// from that reading by this much, m/s (wheel quantisation and update interval, a
/// body that still rocks).
const REST_SPEED_TOL_MPS: f64 = 0.15;
/// A rest edge this much before the last wheel reading with a speed is still the
/// wheels' and the IMU's clocks agreeing, s (CAN arrival jitter).
const REST_WHEEL_SLACK_S: f64 = 0.05;
/// The earlier wheel readings (`wheel_marks`) checked are at least this far before the
/// last one and at most this far before the rest edge, s,
const MARK_MIN_LEAD_S: f64 = 0.3;
const MARK_SPAN_MAX_S: f64 = 4.0;
/// and the IMU's speed may differ from them by this, m/s, plus this per second back to
/// the rest edge, m/s^2 (the tilt of a reference taken on a body that still rocks).
/// Over 4 realistic urban seeds with a 3 km/h dead zone, stops that reached rest
/// differed by at most 0.19 m/s at 1.6-3.5 s, rolling stops by 0.46-0.99 beyond 2.6 s.
const MARK_SPEED_TOL_MPS: f64 = 0.25;
const MARK_TILT_DRIFT_MPS2: f64 = 0.03;
/// The IMU's speed less the wheels' over the last wheel reading with a speed and the
/// marks before it (`rest_speed_drift_mps2`) may drift by this much per second, m/s^2.
/// A rolling stop that pulls away gently in the wheels' dead zone has its acceleration
/// in the "gravity" it is integrated with, and drifts by it. Over 1156 stops that
/// reached rest (8 seeds of realistic urban and stop-and-go, with their drive-offs and
/// with drive-offs of 0.15-0.3 m/s^2) the drift was -0.073..+0.092 m/s^2; of the 23
/// rolling stops that passed the checks above, 22 drifted by 0.095-0.19 (21 beyond this).
const REST_DRIFT_MAX_MPS2: f64 = 0.1;

/// A standstill's first reference is the last quarter second; when the rest edge is
/// nearer than this, s, it is taken from the samples after the edge (less the stop's
/// jerk, `REST_JERK_S`) alone. A car eased to rest at 0.2-0.5 m/s^2 whose reference held
/// the last 0.08 s of that braking was 0.5 deg off in pitch, and the motion tracker
/// anchored there took the stop for a drive-off within half a second.
const REST_SETTLE_S: f64 = 0.3;
const REST_JERK_S: f64 = 0.05;
/// Delays of a wheel reading tried by the drift fit, as shares of the speed's age.
const DRIFT_DELAY_SHARES: [f64; 4] = [0.0, 1.0 / 3.0, 2.0 / 3.0, 1.0];

/// Time constant of the smoothing of the live standstill pitch, s: it averages out a
/// door shock's 5-8 Hz swing and keeps the lag of a ramping load short.
const LIVE_PITCH_TAU_S: f64 = 0.15;
/// The live pitch must stay beyond the load-change threshold this long before the
/// estimate shows it, s (a door shock decays in about 0.3 s).
const LIVE_PITCH_PERSIST_S: f64 = 0.3;

/// A load change's pitch step in the specific force must match the turn the gyro saw
/// within this, rad, plus `TURN_MATCH_SHARE` of the step.
const TURN_MATCH_TOL_RAD: f64 = 0.1 * std::f64::consts::PI / 180.0;
const TURN_MATCH_SHARE: f64 = 0.3;

/// The pitch step seen in the specific force agrees with the turn the gyro saw, within
/// `TURN_MATCH_TOL_RAD` plus `TURN_MATCH_SHARE` of `scale_rad` (the step taken as the
/// more trustworthy of the two), rad.
fn turn_matches(force_step_rad: f64, gyro_turn_rad: f64, scale_rad: f64) -> bool {
    (force_step_rad - gyro_turn_rad).abs()
        <= TURN_MATCH_TOL_RAD + TURN_MATCH_SHARE * scale_rad.abs()
}

/// A stop that never settled must have lasted this long for a turn of the body to be
/// taken as a load change, s: a load ramps in over seconds, and 2.5 s after a stop even
/// a soft suspension (1 Hz, damping 0.15) has let the dive's swing fall to a tenth.
const UNSETTLED_LOAD_MIN_S: f64 = 2.5;

/// Only the windows of a stop shorter than this are paired (see `pair_stop_windows`):
/// over 16 seeds of each realistic scenario the errors of a stop's two windows
/// correlate at -0.7 to -0.95 under 4 s of hold, -0.1 to -0.55 at 4-8 s, and not at
/// all beyond, where the reference rests on enough quiet samples. s.
const PAIR_MAX_HOLD_S: f64 = 8.0;

/// A quiet sample still waiting to join the reference joins once it is this old and
/// the standstill goes on, s: the IMU's motion tracker ends a standstill within a few
/// tenths of a second of a drive-off (0.06 m/s at 0.3 m/s^2 is 0.2 s).
const QUEUE_STALE_S: f64 = 1.0;

/// Settled samples below `rest_swing_gate_mps2` stand for the gravity reference when at
/// least this share of them is below it; fewer, and the gyro's noise alone exceeds the
/// gate (a gyro noisier than it is sized for), so all of them do.
const CALM_SHARE_MIN: f64 = 0.25;
/// Time constant of the running share of calm samples the gravity filter looks at, s.
const CALM_SHARE_TAU_S: f64 = 0.5;

/// Settled samples that stand for the turn of a load ramped in before the stop
/// settled (see `early_turn`), s.
const EARLY_TURN_SETTLED_S: f64 = 1.0;

/// A pause this long in the quiet samples ends a load block, s.
const BLOCK_GAP_S: f64 = 0.1;

/// Shortest stretch of settled samples a reference or a load block is taken from, s,
/// and the fewest samples in it: quiet moments between the swings of a body, or before
/// a load ramps in, last a few hundredths of a second at any IMU rate.
const MIN_SETTLED_S: f64 = 0.05;
const MIN_SETTLED_SAMPLES: u64 = 3;

/// A stop's reference shorter than this does not average out the body's rocking
/// (one period of the pitch mode of a soft suspension, about 1 Hz): a load change
/// measured from it takes the mean of the force's step and the gyro's turn, s.
/// Load steps over 8 seeds of each realistic 5P drive, applied within 0.1 deg before
/// drive-off: force alone 28 of 32, with the mean 29; with a soft suspension (1.0-1.1
/// Hz, damping 0.15-0.25), 4 seeds each, 8 and 12 of 16.
const THIN_REF_S: f64 = 1.0;

/// How much of a stop's swing, from the rest edge, the pitch-mode fit reads, s: the
/// swing of a worn damper's body lasts about three.
const MODE_SPAN_S: f64 = 4.0;

/// A block of settled samples that differed from the stop's reference, waiting for a
/// second one to confirm a new pitch.
#[derive(Debug, Clone, Copy)]
pub(super) struct PendingBlock {
    /// Specific-force sum, m/s^2, and the samples in it.
    pub(super) sum: Vector3<f64>,
    pub(super) n: u64,
    /// Time of its first sample, s.
    pub(super) t0_s: f64,
    pub(super) gyro: GyroSum,
    pub(super) still: StillBlocks,
}

/// The blocks of a segment that stood still, for the accelerometer bias: their force
/// sum and samples. A door shock starting just as the stillness ends leaves a block of
/// a few samples most of which swung, 0.1 m/s^2 off gravity in magnitude; joined to a
/// one-second reference it moved the reference's magnitude by 12 mm/s^2, which the stop
/// filter read as an x bias of -0.17 m/s^2 on a perfect IMU (stop-and-go 304 5P). The
/// reference keeps such a block (its pitch is as good as the others'); the bias does
/// not.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct StillBlocks {
    pub(super) sum: Vector3<f64>,
    pub(super) n: u64,
}

impl StillBlocks {
    pub(super) fn add(&mut self, other: Self) {
        self.sum += other.sum;
        self.n += other.n;
    }
}

/// Sum of gyro readings over quiet samples, rad/s, and their count: their mean is the
/// gyro's bias at that moment, to the noise over their span.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct GyroSum {
    pub(super) sum: Vector3<f64>,
    pub(super) n: u64,
}

impl GyroSum {
    pub(super) fn add(&mut self, other: GyroSum) {
        self.sum += other.sum;
        self.n += other.n;
    }

    /// Mean rate, rad/s; `None` without samples.
    pub(super) fn mean(&self) -> Option<Vector3<f64>> {
        (self.n > 0).then(|| self.sum / self.n as f64)
    }
}

#[derive(Debug, Clone, Copy)]
pub(super) struct Standstill {
    /// Where the car came to rest (start of the deceleration walk).
    pub(super) t_rest_s: f64,
    /// Where the braking ended, seen on a body that may still rock (at or before
    /// `t_rest_s`): the rest of a stop too short to settle starts here.
    pub(super) t_braked_s: f64,
    /// Specific-force sums of the settled samples of the current load segment.
    pub(super) seg_sum: Vector3<f64>,
    pub(super) seg_n: u64,
    pub(super) seg_first_s: f64,
    pub(super) seg_last_s: f64,
    /// Gyro readings of the segment's blocks (all their quiet samples).
    pub(super) seg_gyro: GyroSum,
    /// The segment's blocks that stood still, for the accelerometer bias.
    pub(super) seg_still: StillBlocks,
    pub(super) block_sum: Vector3<f64>,
    pub(super) block_n: u64,
    /// Sum and count of the block's samples whose lever-arm motion stayed below
    /// `rest_swing_gate_mps2`: the block's mean when enough of them passed.
    pub(super) block_calm_sum: Vector3<f64>,
    pub(super) block_calm_n: u64,
    /// Largest angular acceleration of the body over the block's samples, rad/s^2.
    pub(super) block_alpha_max: f64,
    pub(super) block_t0_s: f64,
    /// Time of the newest sample in the block, s.
    pub(super) block_last_s: f64,
    /// A block that differed from the segment, waiting for a second one to confirm.
    pub(super) pending: Option<PendingBlock>,
    /// The car drove since the previous standstill.
    pub(super) moved: bool,
    /// The IMU saw the car move in the wheel sensors' dead zone since the previous
    /// standstill: a pitch step is not a load change.
    pub(super) crept: bool,
    /// Specific force at the start of the standstill (before anything settled), m/s^2,
    /// the mean over the quarter second before `t_begin_s`.
    pub(super) f_begin: Vector3<f64>,
    pub(super) t_begin_s: f64,
    /// Speed the IMU sees the car pick up; ends the standstill at a drive-off.
    pub(super) motion: Option<MotionTracker>,
    /// Nothing watched the wheels between the load baseline and this standstill.
    pub(super) motion_unknown: bool,
    /// The settled reference exists and the baseline and deceleration window were handled.
    pub(super) settled_done: bool,
    /// The body's turn between the start of the standstill and its settled samples was
    /// applied as a load change (see `early_turn`).
    pub(super) turn_applied: bool,
    /// Gyro sum of the current block: it teaches the bias only if the block joins the
    /// segment (the body did not turn), rad/s.
    pub(super) block_gyro_sum: Vector3<f64>,
    /// The body's attitude now, carried by the gyro from the segment's reference.
    pub(super) live: LivePitch,
    /// The body's turn since the start of a standstill that had not settled when it began.
    pub(super) begin: BeginPitch,
    /// Time of the first sample after the latest gap in the IMU data over which the
    /// body's turn is unknown, s.
    pub(super) gap_end_s: f64,
}

/// The body's pitch while stopped, followed by the gyro from the settled reference with
/// no more delay than a short smoothing: a load that ramps in shows while it happens,
/// before the settled blocks can confirm it.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct LivePitch {
    /// Attitude at the newest sample, and the segment (samples, first time) it was carried from.
    pub(super) q: Option<(UnitQuaternion<f64>, u64, f64)>,
    /// Pitch of the segment's reference, rad.
    pub(super) seg_pitch_rad: f64,
    /// Smoothed pitch now, rad.
    pub(super) smooth_rad: Option<f64>,
    /// Whether the offset is shown in the estimate.
    pub(super) shown: Shown,
}

/// Whether a turn of the body at rest is shown in the estimate: once it has stood
/// beyond its threshold for `LIVE_PITCH_PERSIST_S` (a door shock decays in about 0.3 s).
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct Shown {
    /// Since when the turn has stood beyond the threshold, s.
    beyond_since_s: Option<f64>,
    pub(super) active: bool,
}

impl Shown {
    /// Update with whether the turn stands beyond its threshold at `t_s`; returns
    /// whether it is shown.
    fn update(&mut self, beyond: bool, t_s: f64) -> bool {
        if beyond {
            let since = *self.beyond_since_s.get_or_insert(t_s);
            self.active |= t_s - since >= LIVE_PITCH_PERSIST_S;
        } else {
            *self = Shown::default();
        }
        self.active
    }
}

/// One step of the smoothing of a live pitch towards `pitch_rad` over `dt_s`.
fn smooth_pitch(prev_rad: Option<f64>, pitch_rad: f64, dt_s: f64) -> f64 {
    prev_rad.map_or(pitch_rad, |p| {
        p + (pitch_rad - p) * dt_s / (LIVE_PITCH_TAU_S + dt_s)
    })
}

/// The body's pitch while stopped, followed by the gyro from the start of a standstill
/// that nothing settled in: a load that ramps in from the first seconds of a stop keeps
/// every sample from settling, so `LivePitch` has no reference to follow it from, and
/// a ramp that ends shortly before drive-off was shown only as the car pulled away.
/// The turn is shown under the conditions `turn_without_settling` and
/// `turn_before_settling` apply it by: the stop has lasted `UNSETTLED_LOAD_MIN_S`, and
/// gyro and specific force agree on at least twice the load-change threshold.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct BeginPitch {
    /// Attitude at the newest sample, carried from the standstill's start.
    pub(super) q: Option<UnitQuaternion<f64>>,
    /// Pitch of the force at the standstill's start (`f_begin`), rad.
    pub(super) pitch0_rad: f64,
    /// Smoothed gyro pitch now, rad.
    pub(super) smooth_rad: Option<f64>,
    /// Smoothed specific force now, m/s^2.
    pub(super) f_smooth: Vector3<f64>,
    /// Whether the turn is shown in the estimate.
    pub(super) shown: Shown,
    /// Never again at this standstill: it settled before any turn showed, a load change
    /// was applied, or a gap hid part of the turn.
    pub(super) closed: bool,
}

impl Standstill {
    /// Gyro readings of every sample of the current block.
    fn block_gyro(&self) -> GyroSum {
        GyroSum {
            sum: self.block_gyro_sum,
            n: self.block_n,
        }
    }
    /// Force sum and sample count the current block stands for: its calm samples when
    /// at least a quarter of them (and `min_n`) are calm, else all.
    pub(super) fn block_force(&self, min_n: u64) -> (Vector3<f64>, u64) {
        if self.block_is_calm(min_n) {
            (self.block_calm_sum, self.block_calm_n)
        } else {
            (self.block_sum, self.block_n)
        }
    }
    /// At least `min_n` of the block's samples, and a quarter of them, passed the
    /// lever-arm gate.
    fn block_is_calm(&self, min_n: u64) -> bool {
        self.block_calm_n >= min_n
            && self.block_calm_n as f64 >= CALM_SHARE_MIN * self.block_n as f64
    }
    pub(super) fn clear_block(&mut self) {
        self.block_sum = Vector3::zeros();
        self.block_calm_sum = Vector3::zeros();
        self.block_gyro_sum = Vector3::zeros();
        self.block_n = 0;
        self.block_calm_n = 0;
        self.block_alpha_max = 0.0;
    }
    pub(super) fn mean(&self) -> Vector3<f64> {
        self.seg_sum / self.seg_n.max(1) as f64
    }
    /// Make the settled stretch of `n` samples summing to `sum`, from `first_s` to
    /// `last_s`, the stop's reference in place of the current one.
    fn restart_segment(
        &mut self,
        sum: Vector3<f64>,
        n: u64,
        first_s: f64,
        last_s: f64,
        gyro: GyroSum,
        still: StillBlocks,
    ) {
        self.seg_still = still;
        self.seg_sum = sum;
        self.seg_n = n;
        self.seg_gyro = gyro;
        self.seg_first_s = first_s;
        self.seg_last_s = last_s;
    }
    /// Middle of the current reference's span, s.
    fn segment_mid_s(&self) -> f64 {
        0.5 * (self.seg_first_s + self.seg_last_s)
    }
    pub(super) fn settled_s(&self) -> f64 {
        if self.seg_n == 0 {
            0.0
        } else {
            self.seg_last_s - self.seg_first_s
        }
    }
}

#[derive(Debug, Clone, Copy)]
pub(super) struct ForwardCtx {
    pub(super) imu_pitch_rad: f64,
    /// The reference came from a stop that settled (else it was turned by the gyro
    /// from the samples of a body still rocking).
    pub(super) reference_settled: bool,
    /// The first wheel reading above the dead zone has been compared with the window's
    /// speed; `Some` holds a mismatch (IMU, wheels, m/s).
    pub(super) speed_checked: bool,
    pub(super) speed_mismatch: Option<(f64, f64)>,
    /// The stop filter as it was before this stop taught it (`Some` when it did): a
    /// stop the speed check finds was none teaches no bias.
    pub(super) stop_bias_before: Option<Option<super::gravity::GravityFilter>>,
}

impl Estimator {
    /// Fewest settled samples a reference or a load block stands on: `MIN_SETTLED_S` at
    /// the IMU's rate, and never fewer than `MIN_SETTLED_SAMPLES`.
    pub(super) fn min_settled(&self) -> u64 {
        (self.samples_in(MIN_SETTLED_S) as u64).max(MIN_SETTLED_SAMPLES)
    }

    /// The wheel readings (`wheel_marks`) the rest check compares besides the last one
    /// with a speed at `t_w`: at least `MARK_MIN_LEAD_S` before it, at most
    /// `MARK_SPAN_MAX_S` before the rest edge at `t_rest`, and within the history.
    fn rest_marks(&self, t_w: f64, t_rest: f64) -> impl Iterator<Item = (f64, f64)> + '_ {
        let first_s = self.hist.get(0).t_s;
        self.wheel_marks
            .iter()
            .flatten()
            .copied()
            .filter(move |&(t_m, _)| {
                t_m < t_w - MARK_MIN_LEAD_S && t_rest - t_m <= MARK_SPAN_MAX_S && first_s < t_m
            })
    }

    /// How fast the IMU's speed, integrated back from the rest edge (history sample
    /// `rest`, time `t_rest`, attitude `q`), drifts off the wheels' over the last reading
    /// with a speed (`t_w`, `v_w`) and the marks of the seconds before it, m/s^2 per
    /// second back: the slope of a straight line fitted to the differences. The wheels'
    /// speed is some fixed time old (up to `max_wheel_speed_age_s`); the delay that fits
    /// best is taken, so that the change of braking over the readings does not pass for
    /// a drift. `None` with fewer than three readings or under a second between them.
    fn rest_speed_drift_mps2(
        &self,
        q: UnitQuaternion<f64>,
        rest: usize,
        t_rest: f64,
        g: f64,
        t_w: f64,
        v_w: f64,
    ) -> Option<f64> {
        const N: usize = super::WHEEL_MARKS + 1;
        let first_s = self.hist.get(0).t_s;
        let age = self.cfg.max_wheel_speed_age_s;
        let mut obs = [(0.0, 0.0); N];
        let mut n = 0;
        for (t, v) in std::iter::once((t_w, v_w)).chain(self.rest_marks(t_w, t_rest)) {
            if n < N && t - age > first_s {
                obs[n] = (t, v);
                n += 1;
            }
        }
        let obs = &obs[..n];
        let (t_first, t_last) = obs
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), o| {
                (a.min(o.0), b.max(o.0))
            });
        if n < 3 || t_last - t_first < 1.0 {
            return None;
        }
        let mut best: Option<(f64, f64)> = None;
        for share in DRIFT_DELAY_SHARES {
            let d = share * age;
            let mut at = [(0usize, f64::NAN); N];
            for (slot, o) in at.iter_mut().zip(obs) {
                slot.0 = self.index_at(o.0 - d).min(rest);
            }
            let stop = at[..n].iter().map(|a| a.0).min().unwrap_or(rest);
            self.walk_back_from_rest(q, rest, stop, g, |j, s| {
                for a in at.iter_mut().filter(|a| a.0 == j) {
                    a.1 = s;
                }
            });
            // Least squares of (IMU - wheels) on the time back from the rest edge.
            let (mut sx, mut sy, mut sxx, mut sxy, mut syy) = (0.0, 0.0, 0.0, 0.0, 0.0);
            for (o, a) in obs.iter().zip(&at) {
                let (x, y) = (t_rest - o.0, a.1 - o.1);
                (sx, sy, sxx, sxy, syy) = (sx + x, sy + y, sxx + x * x, sxy + x * y, syy + y * y);
            }
            let k = n as f64;
            let (vx, vy, cxy) = (sxx - sx * sx / k, syy - sy * sy / k, sxy - sx * sy / k);
            let slope = cxy / vx;
            let resid = (vy - slope * cxy).max(0.0);
            if slope.is_finite() && best.is_none_or(|b| resid < b.1) {
                best = Some((slope, resid));
            }
        }
        best.map(|b| b.0)
    }

    pub(super) fn begin_standstill(&mut self, q0_t: f64, t_now: f64, emit: &mut dyn FnMut(Event)) {
        // A window of the previous stop no longer has a partner coming.
        self.open_pair = None;
        self.stop_window = None;
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
            .max(first_quiet.saturating_sub(self.samples_in(1.0)))
            .min(n - 1);
        // A car eased to rest from a walking pace brakes gently until a moment before,
        // below the wheels' dead zone, and the IMU can be quiet through it: when the
        // rest edge is less than `REST_SETTLE_S` behind, the reference (and the motion
        // tracker's anchor) is taken from the samples after it alone.
        let after_edge = self.index_at(self.hist.get(rest).t_s + REST_JERK_S) + 1;
        if t_now - self.hist.get(rest).t_s < REST_SETTLE_S && n >= after_edge + REST_AVG_MIN {
            f_rest = Vector3::zeros();
            for i in after_edge..n {
                f_rest += self.hist.get(i).acc();
            }
            f_rest /= (n - after_edge) as f64;
        }
        // At rest the car lost, from the last wheel reading on, just the speed that
        // reading showed. A rolling stop that never reached rest, taken here while it
        // brakes or pulls away steadily, fails this by the speed it still had.
        if let Some((t_w, v_w)) = self.last_wheel_motion {
            let t_rest = self.hist.get(rest).t_s;
            // Nor can it have come to rest before the wheels last showed it moving: a
            // force that has been steady since then is braking or pulling away in the
            // wheels' dead zone, not gravity (a 3 km/h dead zone hides the last 1-2 s of
            // a gentle stop).
            if t_rest < t_w - REST_WHEEL_SLACK_S && t_w - t_rest < REST_CHECK_SPAN_S {
                self.quiet_since = None;
                return;
            }
            if t_rest > t_w && t_rest - t_w < REST_CHECK_SPAN_S && self.hist.get(0).t_s < t_w {
                let q = attitude_from_gravity(&f_rest);
                let g = self.gravity_mps2(&f_rest);
                // A wheel speed is up to `max_wheel_speed_age_s` old: it may be any
                // speed the IMU had over that span.
                let age = self.cfg.max_wheel_speed_age_s;
                let span_at = |t: f64| {
                    q.map(|q| {
                        let (late, early) = (self.index_at(t), self.index_at(t - age));
                        self.speeds_before_rest(q, rest, late, early, g)
                    })
                };
                let off = |(lo, hi): (f64, f64), v: f64| (lo - v).max(v - hi).max(0.0);
                if span_at(t_w).is_some_and(|span| off(span, v_w) > REST_SPEED_TOL_MPS) {
                    self.quiet_since = None;
                    return;
                }
                // The same against the readings up to 3 s before: a car that reached
                // rest and a reference that is its gravity keep the speeds within a
                // tilt's drift; a car still rolling that pulls away steadily, whose
                // "gravity" holds its acceleration, drifts off them by that acceleration
                // every second (a dead zone of 3 km/h hides the whole rolling stop).
                let mark_off = self.rest_marks(t_w, t_rest).any(|(t_m, v_m)| {
                    let tol = MARK_SPEED_TOL_MPS + MARK_TILT_DRIFT_MPS2 * (t_rest - t_m);
                    span_at(t_m).is_some_and(|span| off(span, v_m) > tol)
                });
                if mark_off {
                    self.quiet_since = None;
                    return;
                }
                // Each reading alone may pass while the two effects of a rolling stop
                // cancel: the speed it still has at the "rest" edge, and the pull-away
                // its "gravity" holds. Together the readings show the second as a drift.
                let drift =
                    q.and_then(|q| self.rest_speed_drift_mps2(q, rest, t_rest, g, t_w, v_w));
                if drift.is_some_and(|d| d.abs() > REST_DRIFT_MAX_MPS2) {
                    self.quiet_since = None;
                    return;
                }
            }
        }
        // A body still rocking after the stop moves the raw force as much as braking
        // does, and the IMU turns quiet only once the rocking died down, a second or
        // more after the car stopped. With the attitude carried by the gyro the end of
        // the braking shows earlier; never before the wheels last showed motion.
        let braked = match attitude_from_gravity(&f_rest) {
            Some(q) => {
                let g = self.gravity_mps2(&f_rest);
                let (edge, _) = self.rocking_rest_edge(q, n - 1, first_quiet, g);
                let wheels = self
                    .last_wheel_motion
                    .map_or(0, |(t_w, _)| self.index_at(t_w));
                rest.min(edge.max(wheels))
            }
            None => rest,
        };
        let moved = self.travelled_m > 0.5;
        let crept = std::mem::take(&mut self.imu_moved);
        let t_track = self.motion_start_s().max(self.hist.get(first_quiet).t_s);
        // The tracker starts from the attitude at `t_track`: the mean force of the last
        // samples, turned by the gyro into the body frame there, so that a body still
        // rocking a little does not leave it tilted against the gravity it then sees.
        // The tracker compares raw samples, so the accelerometer bias the reference
        // took out goes back in. Only samples after the braking ended count: a car
        // eased to rest from a walking pace brakes gently below the wheels' dead zone
        // until a moment before, and that force is not gravity.
        let i_track = self.index_at(t_track).min(n - 1);
        let derotated = if self.cfg.derotated_motion_anchor {
            let from = self.index_at(t_now - 0.6).max(braked).min(i_track);
            self.derotated_reference(from, i_track)
        } else {
            None
        };
        let f_track = derotated.map_or(f_rest, |f| f + self.acc_bias_mps2());
        let motion = MotionTracker::new(&f_track, t_track, self.gravity_mps2(&f_rest));
        self.dead_zone_motion = None;
        // From here on the wheels are watched; before, motion may have gone unseen.
        let motion_unknown = self.motion_unknown && !moved;
        self.motion_unknown = false;
        self.settle_queue.clear();
        self.standstill = Some(Standstill {
            t_rest_s: self.hist.get(rest).t_s,
            t_braked_s: self.hist.get(braked).t_s,
            seg_sum: Vector3::zeros(),
            seg_n: 0,
            seg_gyro: GyroSum::default(),
            seg_still: StillBlocks::default(),
            seg_first_s: t_now,
            seg_last_s: t_now,
            block_sum: Vector3::zeros(),
            block_n: 0,
            block_calm_sum: Vector3::zeros(),
            block_calm_n: 0,
            block_alpha_max: 0.0,
            block_t0_s: t_now,
            block_last_s: t_now,
            pending: None,
            moved,
            crept,
            f_begin: f_rest,
            t_begin_s: t_now,
            motion,
            motion_unknown,
            settled_done: false,
            turn_applied: false,
            block_gyro_sum: Vector3::zeros(),
            live: LivePitch::default(),
            begin: BeginPitch::default(),
            gap_end_s: f64::NEG_INFINITY,
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

    pub(super) fn update_standstill(&mut self, s: &ImuSample, emit: &mut dyn FnMut(Event)) {
        if !self.bias_window_ok {
            // The first bias is the mean rate where the first standstill began, which
            // may hold the body's swing; until a settled block has taught it, eq. 7
            // follows every quiet sample, or a seed further off than the gate would
            // keep any sample from settling for the rest of the drive.
            if !self.bias_taught {
                self.update_bias(s);
            }
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

    pub(super) fn commit_settled(&mut self, s: &ImuSample, emit: &mut dyn FnMut(Event)) {
        // The gravity reference is the specific force of the pitch centre: what the IMU
        // would read without the rocking tail.
        let i = self.index_at(s.t_s);
        let rocking = self.rocking_at(i);
        let swing = self.lever_acc_from(rocking);
        let f = s.acc() - swing;
        let smoothed = self.smoothed_acc_at(i).map(|a| a - swing);
        let calm = swing.norm() <= self.cfg.rest_swing_gate_mps2;
        let gain = (self.sample_dt_s.0 / CALM_SHARE_TAU_S).min(1.0);
        self.calm_share += (f64::from(u8::from(calm)) - self.calm_share) * gain;
        if calm || self.calm_share < CALM_SHARE_MIN {
            self.update_gravity(s.t_s, &f, smoothed.as_ref());
        }
        let min_n = self.min_settled();
        // On a vibrating IMU the stop averages the smoothed samples; one that a missing
        // sample spoilt stays out of the stop's sums but keeps its block open.
        let f = if self.vibrating() { smoothed } else { Some(f) };
        let Some(st) = self.standstill.as_mut() else {
            self.update_bias(s);
            return;
        };
        // A block holds one stretch of quiet samples: a gap (the body moved, a load
        // ramped in) closes it, or drops it when it is too short to stand for a pitch
        // (a few samples between two swings of the body).
        if st.block_n > 0 && s.t_s - st.block_last_s > BLOCK_GAP_S {
            if st.block_n >= min_n {
                let t_last = st.block_last_s;
                self.close_block(t_last, emit);
            } else {
                st.clear_block();
            }
        }
        let Some(st) = self.standstill.as_mut() else {
            return;
        };
        if st.block_n == 0 {
            st.block_t0_s = s.t_s;
        }
        st.block_alpha_max = st
            .block_alpha_max
            .max(rocking.map_or(0.0, |(a, _)| a.norm()));
        if let Some(f) = f {
            st.block_gyro_sum += s.gyro_rps();
            st.block_sum += f;
            st.block_n += 1;
            if calm {
                st.block_calm_sum += f;
                st.block_calm_n += 1;
            }
        }
        st.block_last_s = s.t_s;
        if s.t_s - st.block_t0_s >= self.cfg.load_block_s {
            self.close_block(s.t_s, emit);
        }
        // Wait for a long gravity average, but not so long that the history loses the
        // samples before the stop.
        let deadline_s = self.cfg.history_s - self.cfg.max_window_time_s - 1.0;
        let Some(st) = self.standstill else { return };
        if !st.settled_done
            && st.seg_n > 0
            && (st.settled_s() >= self.cfg.settle_time_s || s.t_s - st.t_rest_s >= deadline_s)
        {
            self.on_settled(s.t_s, emit);
        }
    }

    /// Close the current block of settled samples: it joins the segment when it agrees
    /// with it; two blocks in a row that agree with each other on another pitch are a
    /// load change. Blocks are compared from the first settled sample on, so a load that
    /// ramps in while the stop is still settling is seen at this stop: the deceleration
    /// window then uses the segment from before the change as its reference, and the
    /// acceleration window the one after it.
    pub(super) fn close_block(&mut self, t_s: f64, emit: &mut dyn FnMut(Event)) {
        let thr = self.cfg.load_change_deg.to_radians();
        let min_n = self.min_settled();
        let swing_gate = self.cfg.reference_swing_gate_dps2.to_radians() * self.gyro_gate_scale();
        let gate_works = self.calm_share >= CALM_SHARE_MIN;
        let Some(st) = self.standstill.as_mut() else {
            return;
        };
        if st.block_n == 0 {
            return;
        }
        let (block, block_n) = st.block_force(min_n);
        // A block whose samples mostly swung, while the gate sees calm samples at other
        // times, stands for the reference but teaches no bias (`StillBlocks`).
        let still = if st.block_is_calm(min_n) || !gate_works {
            StillBlocks {
                sum: block,
                n: block_n,
            }
        } else {
            StillBlocks::default()
        };
        let (block_t0, block_last) = (st.block_t0_s, st.block_last_s);
        let gyro = st.block_gyro();
        let swinging = st.block_alpha_max > swing_gate;
        let (gyro_mean, gyro_n) = (gyro.sum / gyro.n as f64, gyro.n);
        // Too soon after the stop to teach the bias: the body still swings back.
        let early = block_t0 - st.t_rest_s < BIAS_SETTLE_S;
        st.clear_block();
        st.block_t0_s = t_s;
        if st.seg_n == 0 {
            // A body still swinging stands off its rest pitch (see
            // `reference_swing_gate_dps2`); its next turning point is nearer rest.
            if swinging && block_t0 - st.t_rest_s < REFERENCE_SWING_SPAN_S {
                return;
            }
            st.restart_segment(block, block_n, block_t0, block_last, gyro, still);
            self.teach_bias_block(&gyro_mean, gyro_n, early);
            return;
        }
        let block_mean = block / block_n as f64;
        let (Some(bp), Some(sp)) = (pitch_from(&block_mean), pitch_from(&st.mean())) else {
            return;
        };
        if (bp - sp).abs() <= thr {
            st.seg_sum += block;
            st.seg_n += block_n;
            st.seg_gyro.add(gyro);
            st.seg_still.add(still);
            st.seg_last_s = block_last;
            st.pending = None;
            let joined = *st;
            self.teach_bias_block(&gyro_mean, gyro_n, early);
            self.early_turn(&joined, t_s, emit);
            return;
        }
        match st.pending.take() {
            Some(p)
                if pitch_from(&(p.sum / p.n as f64))
                    .is_some_and(|pp| (pp - bp).abs() <= thr / 2.0) =>
            {
                let (psum, pn, pt0) = (p.sum, p.n, p.t0_s);
                let mut pair = p.still;
                pair.add(still);
                // Two blocks agree on a new pitch. A load change turns the body, and the
                // gyro sees the same turn; a reference taken from a few samples while the
                // body still swung (its lever-arm motion left in the force) does not.
                let new_mean = (psum + block) / (pn + block_n) as f64;
                let new_pitch = pitch_from(&new_mean).unwrap_or(bp);
                let sf_delta = new_pitch - sp;
                let new_mid = 0.5 * (pt0 + block_last);
                let reference = *st;
                let mut after = p.gyro;
                after.add(gyro);
                let gyro_delta = self.turn_since_reference(&reference, new_mid, after.mean());
                // A reference that spans less than one period of the body's pitch mode
                // holds the rocking two ways: the force carries the lever arm's
                // acceleration, the gyro's turn starts from wherever the swing was. The
                // two errors are unrelated; their mean halves their variance.
                let thin_ref = reference.seg_last_s - reference.seg_first_s < THIN_REF_S;
                let delta = match gyro_delta {
                    Some(g) if thin_ref => 0.5 * (g + sf_delta),
                    _ => sf_delta,
                };
                let Some(st) = self.standstill.as_mut() else {
                    return;
                };
                // The newer stretch is the better reference and the load stays when the
                // gyro did not see the force's turn, or when the step, measured as it
                // would be applied, is within the threshold: a reference of a few samples
                // at the end of a swing (a worn damper's body still rocks 0.1 deg two
                // seconds after the stop) put the force's step past the threshold while
                // the gyro turned a third as far.
                if gyro_delta.is_some_and(|g| !turn_matches(sf_delta, g, sf_delta))
                    || delta.abs() <= thr
                {
                    st.restart_segment(psum + block, pn + block_n, pt0, block_last, after, pair);
                    return;
                }
                if !st.settled_done {
                    // The stop settles on what came before the change.
                    self.on_settled(t_s, emit);
                }
                let Some(st) = self.standstill.as_mut() else {
                    return;
                };
                st.restart_segment(psum + block, pn + block_n, pt0, block_last, after, pair);
                self.apply_load_change(delta, new_pitch, t_s, emit);
            }
            _ => {
                // A reference taken from a few samples while the body still swung from
                // the stop can sit a few tenths of a degree off. A longer block that
                // disagrees with it while the gyro saw no matching turn is the better
                // reference, not the first half of a load change: without this, the
                // next short block that happened to agree with the thin reference
                // dropped the good one and kept the swing.
                let thin = st.seg_last_s - st.seg_first_s < THIN_REF_S && st.seg_n < block_n;
                if thin {
                    let step = bp - sp;
                    let reference = *st;
                    let turn = self.turn_since_reference(
                        &reference,
                        0.5 * (block_t0 + block_last),
                        gyro.mean(),
                    );
                    if turn.is_some_and(|g| !turn_matches(step, g, step)) {
                        let Some(st) = self.standstill.as_mut() else {
                            return;
                        };
                        st.restart_segment(block, block_n, block_t0, block_last, gyro, still);
                        st.pending = None;
                        return;
                    }
                }
                let Some(st) = self.standstill.as_mut() else {
                    return;
                };
                st.pending = Some(PendingBlock {
                    sum: block,
                    n: block_n,
                    t0_s: block_t0,
                    gyro,
                    still,
                });
            }
        }
    }

    /// A load that ramped in before anything settled: the gyro saw the body turn from
    /// the start of the standstill to its settled samples. `on_settled` applies that
    /// turn once `settle_time_s` of them stand, and a drive-off sooner than that came
    /// first. It is applied here once `EARLY_TURN_SETTLED_S` stand: blocks that agree
    /// over that span show a body no longer turning (a ramp still going on leaves a
    /// block behind that the segment does not take). `on_settled` still looks if this
    /// found nothing.
    fn early_turn(&mut self, st: &Standstill, t_s: f64, emit: &mut dyn FnMut(Event)) {
        if !st.moved || st.settled_done || st.turn_applied || st.settled_s() < EARLY_TURN_SETTLED_S
        {
            return;
        }
        let Some(pitch) = pitch_from(&st.mean()) else {
            return;
        };
        if let Some(turn) = self.turn_before_settling(st, pitch) {
            if let Some(st) = self.standstill.as_mut() {
                st.turn_applied = true;
            }
            self.apply_load_change(turn, pitch, t_s, emit);
        }
    }

    /// The step of a load that turned the body after the stop settled, as the live pitch
    /// shows it and as the drive-off applies it: the gyro's turn from the settled
    /// reference (`gyro_turn_rad`), averaged with the force's step where the body came
    /// to rest after the turn: the quiet samples since, in the block still waiting for a
    /// second one to confirm it (`Standstill::pending`) and in the open block. The gyro's
    /// turn is carried over the 3-5 s of the ramp with a bias known to about 0.015 deg/s;
    /// the quiet samples span a few tenths of a second. Their errors are unrelated (bumpy
    /// 404: gyro 0.896, force 1.038 for 1.0). Loads applied within 0.1 deg before
    /// drive-off, 5P: 27 -> 30 of the family's 32, 49 -> 50 of 64 on the 16 seeds after
    /// each scenario's eight. A force that does not match the turn is not the body at
    /// rest after it (`turn_matches`). rad.
    fn turn_with_rest_force(&self, st: &Standstill, gyro_turn_rad: f64) -> f64 {
        let min_n = self.min_settled();
        let (mut sum, mut n) = st.pending.map_or((Vector3::zeros(), 0), |p| (p.sum, p.n));
        if st.block_n > 0 {
            let (b_sum, b_n) = st.block_force(min_n);
            sum += b_sum;
            n += b_n;
        }
        let force = match (pitch_from(&(sum / n.max(1) as f64)), pitch_from(&st.mean())) {
            (Some(after), Some(before)) if n >= min_n => after - before,
            _ => return gyro_turn_rad,
        };
        if turn_matches(force, gyro_turn_rad, gyro_turn_rad) {
            0.5 * (force + gyro_turn_rad)
        } else {
            gyro_turn_rad
        }
    }

    /// The gyro's bias as the quiet samples after a turn at rest show it (the block
    /// waiting for a second one to confirm a new pitch, and the open block), when they
    /// span at least `load_block_s`. The learnt bias dates from an earlier stop and has
    /// drifted since; a turn carried with it over the seconds of a load ramp is off by
    /// that drift times the ramp's length. rad/s.
    fn rest_gyro_after_turn(&self, st: &Standstill) -> Option<Vector3<f64>> {
        let mut g = st.pending.map(|p| p.gyro).unwrap_or_default();
        g.add(st.block_gyro());
        (g.n as f64 * self.sample_dt_s.0 >= self.cfg.load_block_s)
            .then(|| g.mean())
            .flatten()
    }

    /// Pitch turn the gyro saw from the middle of the stop's reference to `t_s`, rad,
    /// starting from the attitude of the reference's gravity. The learnt bias carries
    /// it to the reference's end; from there `after_bias_rps`, the bias the quiet
    /// samples after the turn show, when given.
    fn turn_since_reference(
        &self,
        st: &Standstill,
        t_s: f64,
        after_bias_rps: Option<Vector3<f64>>,
    ) -> Option<f64> {
        let learnt = self.bias_rps.unwrap_or_else(Vector3::zeros);
        let after = after_bias_rps.unwrap_or(learnt);
        attitude_from_gravity(&st.mean()).map(|q| {
            let (from, to) = (self.index_at(st.segment_mid_s()), self.index_at(t_s));
            let end = self
                .index_at(st.seg_last_s)
                .clamp(from.min(to), from.max(to));
            let q1 = self.carry_with_bias(q, from, end, learnt);
            let q2 = self.carry_with_bias(q1, end, to, after);
            pitch_of(&q2) - pitch_of(&q)
        })
    }

    /// Close the current block once no quiet sample can still join it. A pause of
    /// `BLOCK_GAP_S` ends a block, but the block used to see the pause only when the
    /// next quiet sample came. A load ramping in right after the first block of a stop
    /// leaves no quiet sample until the ramp ends: the block stayed open through the
    /// ramp, the stop had no settled reference, and the live pitch could not follow the
    /// ramp. Quiet samples wait `2 * still_window_s` before they join the blocks, so
    /// once that and the pause have passed with none waiting inside the pause, none can
    /// still come.
    pub(super) fn close_stale_block(&mut self, t_s: f64, emit: &mut dyn FnMut(Event)) {
        let lag = 2.0 * self.cfg.still_window_s;
        // A quiet sample waits for a later quiet one `lag` after it before it joins, so
        // the last ones before a drive-off stay out. When the body turns instead (a load
        // ramping in right after the first quiet moment of a stop), no quiet sample comes
        // until the ramp ends, and the stop has no reference to follow the ramp from. A
        // drive-off ends the standstill well within `QUEUE_STALE_S`; a sample that old
        // with the car still at rest was at rest. Only a stop with no reference yet takes
        // them: they are the last before the turn began, and a reference that has its
        // own quiet samples is better off without them.
        while let Some(x) = self.settle_queue.front().copied() {
            let unsettled = self.standstill.is_some_and(|st| st.seg_n == 0);
            if !unsettled || t_s - x.t_s < lag.max(QUEUE_STALE_S) {
                break;
            }
            self.settle_queue.pop_front();
            self.commit_settled(&x, emit);
        }
        let Some(st) = self.standstill else { return };
        if st.block_n >= self.min_settled()
            && t_s - st.block_last_s > lag + BLOCK_GAP_S
            && self
                .settle_queue
                .front()
                .is_none_or(|x| x.t_s - st.block_last_s > BLOCK_GAP_S)
        {
            self.close_block(st.block_last_s, emit);
        }
    }

    /// Close a partial block (at the end of a stop or of the input) if it holds enough
    /// samples to compare.
    pub(super) fn flush_block(&mut self, t_s: f64, emit: &mut dyn FnMut(Event)) {
        if self
            .standstill
            .is_some_and(|st| st.block_n >= self.min_settled())
        {
            self.close_block(t_s, emit);
        }
    }

    /// The standstill has a settled gravity reference: check the load baseline and
    /// evaluate the deceleration window.
    pub(super) fn on_settled(&mut self, t_now: f64, emit: &mut dyn FnMut(Event)) {
        let Some(st) = self.standstill.as_mut() else {
            return;
        };
        st.settled_done = true;
        let st = *st;
        let Some(q_ref) = attitude_from_gravity(&st.mean()) else {
            return;
        };
        let pitch = pitch_of(&q_ref);
        // A load that came in before the reference settled turned the body between the
        // rest edge and the reference.
        let mut load_before_settled = st.turn_applied;
        // Stopped or parked without driving since the last baseline: a pitch step is a load change.
        match self.baseline_pitch_rad {
            Some(base) if !st.moved && !st.crept => {
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
            _ => {
                if st.moved
                    && !st.turn_applied
                    && let Some(turn) = self.turn_before_settling(&st, pitch)
                {
                    self.apply_load_change(turn, pitch, t_now, emit);
                    load_before_settled = true;
                }
                self.baseline_pitch_rad = Some(pitch);
            }
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
        let (settled, floor) = (self.index_at(st.seg_first_s), self.index_at(st.t_rest_s));
        let (rest, _) = self.rocking_rest_edge(q_ref, settled, floor, g);
        // The rocking after this stop refines the lever arm before the walk uses it.
        let at_rest = self.index_at(st.seg_last_s);
        self.learn_lever(q_ref, rest, settled, at_rest, g);
        let swing_end = at_rest.min(rest + self.samples_in(MODE_SPAN_S));
        self.learn_pitch_mode(q_ref, settled, rest, swing_end, g);
        let (rest, q0) = self.rocking_rest_edge(q_ref, settled, floor, g);
        let Some((q_win, g_win)) = self.window_reference(&st.mean()) else {
            let r = Err(RejectReason::NotStill);
            self.report_window(r, Condition::DecelBeforeStop, pitch, st.t_rest_s, emit);
            return;
        };
        // The walk starts from the reference freed of the accelerometer bias, turned by
        // the gyro as far as the rest edge.
        let q0 = q_win * (q_ref.inverse() * q0);
        let setup = self.window_setup(q0, q_win, g_win);
        // With a quiet accelerometer the velocity at the rest edge is read where the
        // swing has died out, no further than the last sample at rest, on a body that
        // settled within `REST_VELOCITY_SETTLED_S` of the edge. A noisy accelerometer's
        // noise integrated over that second outweighs the swing's share (measured: the
        // late read on a 300 ug/sqrt(Hz) part was 0.005-0.02 deg worse in rms per window
        // kind), and a load that came in before the stop settled moved the body by more
        // than its swing: both are read at the edge.
        use super::history::{REST_VELOCITY_REACH_S, REST_VELOCITY_S, REST_VELOCITY_SETTLED_S};
        let t_edge = self.hist.get(rest).t_s;
        let reach_s = (self.quiet_accelerometer()
            && !load_before_settled
            && st.seg_first_s - t_edge <= REST_VELOCITY_SETTLED_S)
            .then(|| (st.seg_last_s - t_edge).clamp(REST_VELOCITY_S, REST_VELOCITY_REACH_S));
        let v0 = self.rest_velocity(q0, rest, true, reach_s, g_win);
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
        let pitch_win = pitch_of(&q_win);
        // The walk left the reference at its first settled sample, a turning point of
        // the swing after the stop and on the same side of the rest pitch at every
        // stop (the body swings back from its dive): the dive is counted from the
        // swing's centre there.
        let centre = self
            .pitch_at_swing_centre(q_win, settled)
            .map(|q| pitch_of(&q));
        // The axle point's pitch is carried from the rest edge; against a reference
        // taken after a load it would read the load's turn as the road's.
        let r = r.map(|g| WindowGeometry {
            axle: g.axle.filter(|_| !load_before_settled),
            rest_centre_pitch_rad: centre,
            ..g
        });
        let times = (st.t_rest_s, st.segment_mid_s());
        self.report_window_weighted(r, Condition::DecelBeforeStop, pitch_win, times, 1.0, emit);
    }

    /// A load that came in before the stop settled: a door shock or the ramp itself
    /// kept the samples from settling until it was done, so neither the settled blocks
    /// nor the live pitch had a reference before it. The gyro saw the body turn from
    /// the start of the standstill to the settled samples, and the specific force
    /// moved with it. Returns the turn, rad, when both agree on at least twice the
    /// load-change threshold (twice: the body may still rock a little at the start).
    /// The settled samples' mean rate is the bias the turn is carried with only where a
    /// block of them may teach the bias (`BIAS_SETTLE_S`); sooner after the stop it
    /// holds the body's swing: a 1.6 s stop of a worn damper's body settled on five
    /// samples just past a turning point, rising at 0.26 deg/s, and that rate taken for
    /// the bias doubled the swing's 0.22 deg into a 0.43 deg load change.
    fn turn_before_settling(&self, st: &Standstill, settled_pitch_rad: f64) -> Option<f64> {
        let mid = self.index_at(0.5 * (st.seg_first_s + st.seg_last_s));
        let bias = if st.seg_first_s - st.t_rest_s < BIAS_SETTLE_S {
            None
        } else {
            st.seg_gyro.mean()
        };
        self.turn_since_begin(st, mid, settled_pitch_rad, bias)
    }

    /// A load that turned the body through a whole stop of at least
    /// `UNSETTLED_LOAD_MIN_S`: the ramp kept every sample from settling, so neither the
    /// blocks nor the live pitch had a reference. The gyro's turn from the start of the
    /// standstill to the drive-off's first sample `first` is the step when the force
    /// over the samples before `first` turned with it (as `turn_before_settling`). The
    /// length keeps out the body still swinging after a short stop.
    fn turn_without_settling(&self, st: &Standstill, first: usize, t_now: f64) -> Option<f64> {
        if t_now - st.t_rest_s < UNSETTLED_LOAD_MIN_S {
            return None;
        }
        let to = first.min(self.hist.len() - 1);
        let k = self.rest_avg().min(to);
        let f = (to + 1 - k..=to).fold(Vector3::zeros(), |f, j| {
            f + self.hist.get(j).acc() - self.lever_acc_at(j)
        });
        self.turn_since_begin(st, to, pitch_from(&(f / k as f64))?, None)
    }

    /// The gyro's turn of the body from the start of the standstill to history sample
    /// `to`, rad, when the force's pitch there (`force_pitch_rad`) moved with it by at
    /// least twice the load-change threshold (twice: the body may still rock a little at
    /// the start).
    fn turn_since_begin(
        &self,
        st: &Standstill,
        to: usize,
        force_pitch_rad: f64,
        bias_rps: Option<Vector3<f64>>,
    ) -> Option<f64> {
        let (q_begin, from) = self.begin_attitude(st)?;
        let to = to.min(self.hist.len() - 1);
        if to <= from {
            return None;
        }
        let bias = bias_rps.or(self.bias_rps).unwrap_or_else(Vector3::zeros);
        let turn = pitch_of(&self.carry_with_bias(q_begin, from, to, bias)) - pitch_of(&q_begin);
        let sf = force_pitch_rad - pitch_of(&q_begin);
        self.turn_since_begin_agrees(turn, sf).then_some(turn)
    }

    /// The attitude of the force at the start of the standstill and the history sample
    /// it stands at (`f_begin` is the mean of the quarter second before the start).
    fn begin_attitude(&self, st: &Standstill) -> Option<(UnitQuaternion<f64>, usize)> {
        let q = attitude_from_gravity(&st.f_begin)?;
        let at = self
            .index_at(st.t_begin_s - 0.125)
            .min(self.hist.len().max(1) - 1);
        Some((q, at))
    }

    /// The gyro's turn since the start of the standstill and the force's pitch change
    /// over it (rad) agree on a load: at least twice the load-change threshold (the
    /// body may still rock a little at the start), the same sign, and within
    /// `turn_matches`.
    fn turn_since_begin_agrees(&self, turn_rad: f64, force_step_rad: f64) -> bool {
        let thr = 2.0 * self.cfg.load_change_deg.to_radians();
        turn_rad.abs() > thr
            && force_step_rad.signum() == turn_rad.signum()
            && turn_matches(force_step_rad, turn_rad, turn_rad)
    }

    /// Follow the body's pitch at rest with the gyro from the settled reference (see
    /// `LivePitch`). The estimate shows the difference once it has stood beyond the
    /// load-change threshold for `LIVE_PITCH_PERSIST_S`; the settled blocks or the
    /// drive-off then decide whether it was a load change.
    pub(super) fn track_live_pitch(&mut self, t_s: f64) {
        let Some(mut st) = self.standstill else {
            return;
        };
        if self.cfg.live_standstill_pitch {
            let shown = self.track_begin_pitch(&mut st, t_s);
            self.standstill = Some(st);
            if let Some(turn) = shown {
                self.live_offset_rad = turn;
                return;
            }
        }
        let n = self.hist.len();
        if !self.cfg.live_standstill_pitch || st.seg_n < self.min_settled() || n < 2 {
            self.live_offset_rad = 0.0;
            return;
        }
        if st.gap_end_s > st.seg_last_s {
            // The gyro's turn across the gap is unknown (a door shock may have swung
            // the body through it): the live pitch waits for a settled block after
            // the gap to carry it from.
            st.live = LivePitch::default();
            self.live_offset_rad = 0.0;
            self.standstill = Some(st);
            return;
        }
        let q = match st.live.q {
            Some((q, seg_n, seg_first)) if seg_n == st.seg_n && seg_first == st.seg_first_s => {
                self.carry(q, n - 2, n - 1)
            }
            _ => {
                let Some(q_seg) = attitude_from_gravity(&st.mean()) else {
                    return;
                };
                st.live.seg_pitch_rad = pitch_of(&q_seg);
                let from = self.index_at(st.seg_last_s).min(n - 1);
                self.carry(q_seg, from, n - 1)
            }
        };
        st.live.q = Some((q, st.seg_n, st.seg_first_s));
        let pitch = pitch_of(&q);
        let dt = (t_s - self.hist.get(n - 2).t_s).max(0.0);
        let smooth = smooth_pitch(st.live.smooth_rad, pitch, dt);
        st.live.smooth_rad = Some(smooth);
        let offset = smooth - st.live.seg_pitch_rad;
        let thr = self.cfg.load_change_deg.to_radians();
        // Hysteresis: once shown, the offset stays until it falls to half the threshold.
        let beyond = offset.abs() > if st.live.shown.active { 0.5 * thr } else { thr };
        let shown = st.live.shown.update(beyond, t_s);
        self.live_offset_rad = if shown {
            self.turn_with_rest_force(&st, offset)
        } else {
            0.0
        };
        self.standstill = Some(st);
    }

    /// Follow the body's turn since the start of a standstill that nothing settled in
    /// (see `BeginPitch`); returns it, rad, while it is shown.
    fn track_begin_pitch(&self, st: &mut Standstill, t_s: f64) -> Option<f64> {
        let n = self.hist.len();
        if st.begin.closed || n < 2 {
            return None;
        }
        // A load change applied at this standstill closes it as well (`apply_load_change`).
        let open = st.moved
            && !st.settled_done
            && st.gap_end_s <= st.t_begin_s
            && (st.begin.shown.active || st.seg_n < self.min_settled());
        let q = match (open, st.begin.q) {
            (false, _) => None,
            (true, Some(q)) => Some(self.carry(q, n - 2, n - 1)),
            (true, None) => self.begin_attitude(st).map(|(q0, from)| {
                st.begin.pitch0_rad = pitch_of(&q0);
                st.begin.f_smooth = st.f_begin;
                self.carry(q0, from, n - 1)
            }),
        };
        let Some(q) = q else {
            st.begin = BeginPitch {
                closed: true,
                ..BeginPitch::default()
            };
            return None;
        };
        let b = &mut st.begin;
        b.q = Some(q);
        let dt = (t_s - self.hist.get(n - 2).t_s).max(0.0);
        let smooth = smooth_pitch(b.smooth_rad, pitch_of(&q), dt);
        b.smooth_rad = Some(smooth);
        b.f_smooth += (self.hist.get(n - 1).acc() - b.f_smooth) * dt / (LIVE_PITCH_TAU_S + dt);
        let turn = smooth - b.pitch0_rad;
        let sf = pitch_from(&b.f_smooth).map_or(0.0, |p| p - b.pitch0_rad);
        // Once shown, the turn stays until it falls below the load-change threshold:
        // the force leaves it as the car pulls away, and the drive-off checks the two
        // again.
        let beyond = if b.shown.active {
            turn.abs() > self.cfg.load_change_deg.to_radians()
        } else {
            t_s - st.t_rest_s >= UNSETTLED_LOAD_MIN_S && self.turn_since_begin_agrees(turn, sf)
        };
        b.shown.update(beyond, t_s).then_some(turn)
    }

    pub(super) fn end_standstill(&mut self, t_now: f64, emit: &mut dyn FnMut(Event)) {
        self.flush_block(t_now, emit);
        let Some(st) = self.standstill else { return };
        if !st.settled_done && st.seg_n >= self.min_settled() {
            // A short stop: use what settled.
            self.on_settled(t_now, emit);
        }
        let live_active = st.live.shown.active;
        if t_now - st.t_rest_s >= PAIR_MAX_HOLD_S {
            self.open_pair = None;
        }
        self.live_offset_rad = 0.0;
        self.standstill = None;
        emit(Event::StandstillEnded {
            t_s: t_now,
            duration_s: t_now - st.t_rest_s,
        });
        // Start the walk at the last sample that still matched the standstill: from
        // there the car moves. The current sample is pushed by the caller.
        let n = self.hist.len();
        let floor = self.index_at(st.t_rest_s);
        let settled = st.seg_n >= self.min_settled();
        let bias_before = self.stop_bias;
        // The stop teaches the accelerometer bias only from a reference that stood
        // still. One shorter than a period of the body's pitch mode holds what is left
        // of the rocking (its magnitude off gravity by 10 mm/s^2 rms, 20 with a gyro
        // three times noisier, against 1 from one to four seconds). One whose body was
        // turning as the car pulled away (a load coming in that the live pitch showed)
        // may hold the start of the turn: a load's ramp moves a headlamp 2 m ahead of
        // the pitch centre by 0.02 m/s^2 vertically, which a gyro too noisy to see it
        // leaves in.
        let still = st.seg_still;
        let bias_stop = settled
            && still.n >= self.min_settled()
            && st.settled_s() >= THIN_REF_S
            && !live_active;
        if bias_stop {
            self.update_stop_bias(t_now, &(still.sum / still.n as f64), still.n);
            self.follow_stop_bias(t_now, emit);
        }
        let g_mean = if settled { st.mean() } else { st.f_begin };
        // After the body turned at rest, it rests on the gravity of its new attitude.
        let g_mean = match (st.live.q, attitude_from_gravity(&g_mean)) {
            (Some((q_live, ..)), Some(q_seg)) if settled && live_active => {
                q_live.inverse() * (q_seg * g_mean)
            }
            _ => g_mean,
        };
        // A stop too short to settle rests from where the braking ended, the body
        // rocking all the while.
        let floor = if settled {
            floor
        } else {
            self.index_at(st.t_braked_s)
        };
        let mut first = if settled {
            self.drive_off_start(&g_mean, floor)
        } else {
            self.drive_off_start_rocking(floor)
        };
        // A load that ramped in through the whole of a stop: the body never settled, and
        // the car pulls away as the ramp ends.
        if !settled && let Some(turn) = self.turn_without_settling(&st, first, t_now) {
            let pitch = pitch_from(&st.f_begin).unwrap_or(0.0) + turn;
            self.apply_load_change(turn, pitch, t_now, emit);
            if st.moved {
                let r = Err(RejectReason::NotStill);
                self.report_window(r, Condition::DecelBeforeStop, 0.0, t_now, emit);
            }
            let r = Err(RejectReason::NotStill);
            self.report_window(r, Condition::AccelAfterStop, pitch, t_now, emit);
            return;
        }
        // A load that turned the body after the stop settled: no sample after the turn
        // began is at rest by the pitch rate, and the raw force matches the turned
        // body's gravity only once the squat has begun. The force turned back by the
        // gyro into the settled frame finds the drive-off before the squat.
        if settled && live_active {
            let seg_last = self.index_at(st.seg_last_s).min(n - 1);
            first = self.drive_off_start_turned(seg_last, st.mean());
        }
        let q_ref = if settled {
            attitude_from_gravity(&st.mean()).map(|q| {
                (
                    q,
                    self.carry(q, self.index_at(st.seg_last_s).min(n - 1), first),
                )
            })
        } else if self.cfg.short_stop_windows {
            // A stop too short to settle (a stop sign, a queue): its rest samples,
            // turned by the gyro into the body frame at drive-off, give the reference
            // there although the body still rocked.
            self.derotated_reference(floor, first)
                .and_then(|f| attitude_from_gravity(&f))
                .map(|q| (q, q))
        } else {
            None
        };
        let Some((q_ref, q0)) = q_ref else {
            if st.moved {
                let r = Err(RejectReason::NotStill);
                self.report_window(r, Condition::DecelBeforeStop, 0.0, t_now, emit);
            }
            let r = Err(RejectReason::NotStill);
            self.report_window(r, Condition::AccelAfterStop, 0.0, t_now, emit);
            return;
        };
        if !settled && st.moved {
            let r = Err(RejectReason::NotStill);
            self.report_window(r, Condition::DecelBeforeStop, 0.0, t_now, emit);
        }
        // The body turned at rest since the settled reference and the live pitch showed
        // it: a load that came in too late for the settled blocks to confirm. The gyro
        // gives the step up to the drive-off, and the force too once the body came to
        // rest after the turn.
        let imu_pitch_rad = pitch_of(&q_ref);
        if settled && live_active {
            let seg_last = self.index_at(st.seg_last_s).min(n - 1);
            let turn = match self.rest_gyro_after_turn(&st) {
                Some(bias) => pitch_of(&self.carry_with_bias(q_ref, seg_last, first, bias)),
                None => pitch_of(&q0),
            } - imu_pitch_rad;
            let delta = self.turn_with_rest_force(&st, turn);
            let turned_pitch = imu_pitch_rad + delta;
            if delta.abs() > self.cfg.load_change_deg.to_radians() {
                self.apply_load_change(delta, turned_pitch, t_now, emit);
                // The load was still moving the body as the car pulled away: the body
                // need not keep one pitch over the road through the window.
                let r = Err(RejectReason::NotStill);
                self.report_window(r, Condition::AccelAfterStop, turned_pitch, t_now, emit);
                return;
            }
        }
        // The window's reference, freed of the accelerometer bias (the derotated reference
        // of a short stop already is).
        let q_win = if settled {
            self.window_reference(&st.mean()).map(|(q, _)| q)
        } else {
            Some(q_ref)
        };
        let (Some(q_win), Some((_, g_win))) = (q_win, self.window_reference(&g_mean)) else {
            let r = Err(RejectReason::NotStill);
            self.report_window(r, Condition::AccelAfterStop, imu_pitch_rad, t_now, emit);
            return;
        };
        // A settled reference is turned to the drive-off by the gyro as the raw one was;
        // the derotated one already stands there.
        let (q0, reference_q, imu_pitch_rad) = if settled {
            (q_win * (q_ref.inverse() * q0), q_win, pitch_of(&q_win))
        } else {
            (q0, q0, imu_pitch_rad)
        };
        let setup = self.window_setup(q0, reference_q, g_win);
        // A stop that settled ends with the body at rest: its rate is zero, not noise.
        // An IMU that vibrates is never at rest, though: its speed swings by up to the
        // vibration over its angular frequency (1.8 mm/s for 0.28 m/s^2 at 25 Hz, 5 mm
        // of height over a gentle 3 s window), which the plain read averages out.
        let settled_at_start =
            settled && self.hist.get(first).t_s - st.seg_last_s < 1.0 && !self.vibrating();
        let v0 = if settled_at_start {
            Vector3::zeros()
        } else {
            self.rest_velocity(q0, first, false, None, setup.gravity_mps2)
        };
        self.fwd.start(setup, v0);
        self.fwd_ctx = Some(ForwardCtx {
            imu_pitch_rad,
            reference_settled: settled,
            speed_checked: false,
            speed_mismatch: None,
            stop_bias_before: settled.then_some(bias_before),
        });
        for i in first..n - 1 {
            let step = self.fwd.push(&self.hist.get(i));
            if let Step::Done(_) = step {
                self.finish_forward(step, t_now, emit);
                return;
            }
        }
    }
}
