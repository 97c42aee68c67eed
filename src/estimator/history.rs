//! Walks over the buffered IMU history: where the car came to rest, the attitude
//! carried by the gyro, and the motion of the IMU on the rocking body.

use super::attitude;
use super::{Estimator, ImuSample, MAX_RATE_HZ};
use nalgebra::{UnitQuaternion, Vector3};

/// Half-width of the gyro smoothing behind the lever-arm acceleration, s:
/// `lever_acc_at(i)` needs twice as many samples after `i` (`lever_half`).
const LEVER_SMOOTH_HALF_S: f64 = 0.05;

/// Across a gap in the IMU data, a turn of the body the readings on either side could
/// make larger than this is unknown (see `turn_unknown_across`), rad.
const GAP_TURN_MAX_RAD: f64 = 0.2 * std::f64::consts::PI / 180.0;

/// The walk back to the rest edge steps over a knock at rest (a door shut, someone
/// sitting down): a disturbance of the longitudinal force no longer than this, s,
const KNOCK_MAX_S: f64 = 0.6;
/// that leaves the IMU with no more velocity than this, m/s (a knock leaves the body
/// where it was; what the integral keeps is the lever-arm model's smoothing of a
/// 5-8 Hz swing),
const KNOCK_MAX_DV_MPS: f64 = 0.05;
/// and never more than this on the way, m/s: braking gains that within 0.1 s at
/// 1 m/s^2, and never comes back to rest. A knock ends once this many samples in a row
/// are back at rest for this long, s (its oscillation crosses rest between swings).
const KNOCK_PEAK_DV_MPS: f64 = 0.1;
const KNOCK_QUIET_S: f64 = 0.1;

/// Span averaged where a walk looks for the car at rest, s, and the fewest samples
/// averaged (noise of one 100 Hz sample is about 0.03 m/s^2; five keep a single
/// outlier from ending the rest).
const REST_AVG_S: f64 = 0.05;
pub(super) const REST_AVG_MIN: usize = 5;
/// Most samples `REST_AVG_S` may span (the buffers that hold them), 200 Hz and more.
const REST_AVG_MAX: usize = 16;

/// A sample interval further than this factor from the learnt one is a drop or a burst
/// and does not teach it; this many such intervals in a row set a new rate.
const INTERVAL_OUTLIER: f64 = 1.5;
const INTERVAL_RUN: u32 = 8;

/// Share of the IMU's swing at rest (omega x lever arm) that rotation about the pitch
/// centre does not explain: the heave that rides along with the pitch, the arm's own
/// error. A body heaving 2 mm per m/s^2 of the force the stop released while it
/// pitches 0.25 deg per m/s^2 about a centre 2 m behind the IMU swings a fifth more or
/// less than the arm says, and the arm learnt from the same rocking takes up most of
/// it. Sized on the realistic drives with and without such a heave: with it an
/// INS-grade accelerometer reads late in the stop and a 300 ug/sqrt(Hz) one near the
/// edge, each where its deceleration windows came out best.
const SWING_UNMODELLED_SHARE: f64 = 0.03;

/// Most samples `rest_velocity` reads (1.5 s at 300 Hz).
const REST_VELOCITY_MAX_SAMPLES: usize = 450;

/// How far into a stop the velocity at its rest edge is read from, s (see
/// `rest_velocity`): by then a body's swing has fallen to a tenth or less.
pub(super) const REST_VELOCITY_REACH_S: f64 = 1.5;

/// Span of the plain mean `rest_velocity` takes at the rest edge, s.
pub(super) const REST_VELOCITY_S: f64 = 0.25;

/// A stop whose body settled later than this after its rest edge was moved by more
/// than its swing on the way (a load ramping in, a knock): its velocity is read at the
/// edge, s.
pub(super) const REST_VELOCITY_SETTLED_S: f64 = 2.0;

/// Gain of the interval's running mean (about 5 s at 100 Hz: frame jitter moves it by
/// less than 0.1 %).
const INTERVAL_GAIN: f64 = 0.002;

/// A forward walk starts this long before the extrapolated drive-off, s.
const DRIVE_OFF_MARGIN_S: f64 = 0.05;

impl Estimator {
    /// Follow the IMU's sample interval (`dt_s`, s, from one sample to the next): the
    /// history's spans are set in seconds and counted in samples at the IMU's own rate.
    /// A dropped frame or a burst is left out; a run of intervals that all disagree is a
    /// new rate (the first samples, an IMU configured otherwise).
    pub(super) fn learn_sample_interval(&mut self, dt_s: f64) {
        let dt = self.sample_dt_s.0;
        if dt_s > dt / INTERVAL_OUTLIER && dt_s < dt * INTERVAL_OUTLIER {
            self.sample_dt_s = (dt + INTERVAL_GAIN * (dt_s - dt), 0);
        } else if dt_s > 0.0 && dt_s <= 0.1 {
            let run = self.sample_dt_s.1 + 1;
            self.sample_dt_s = if run >= INTERVAL_RUN {
                (dt_s.max(0.5 / MAX_RATE_HZ), 0)
            } else {
                (dt, run)
            };
        }
    }

    /// Samples spanning `span_s` at the IMU's rate, at least one.
    pub(super) fn samples_in(&self, span_s: f64) -> usize {
        ((span_s / self.sample_dt_s.0).round() as usize).max(1)
    }

    /// Half-width of the gyro smoothing behind the lever-arm acceleration, samples:
    /// `LEVER_SMOOTH_HALF_S`, and at least 5 against the gyro's noise (a 50 Hz IMU with
    /// 3 was 0.05-0.11 deg worse in single-window p95 over 4 realistic urban seeds).
    pub(super) fn lever_half(&self) -> usize {
        self.samples_in(LEVER_SMOOTH_HALF_S).max(5)
    }

    /// Samples averaged where a walk looks for the car at rest: `REST_AVG_S`, and never
    /// fewer than `REST_AVG_MIN` against a single outlier.
    pub(super) fn rest_avg(&self) -> usize {
        self.samples_in(REST_AVG_S)
            .clamp(REST_AVG_MIN, REST_AVG_MAX)
    }

    /// Walking back from the newest sample, the index of the earliest sample of the
    /// trailing run whose mean specific force over `rest_avg` samples matches `f_rest`
    /// (not before `floor`).
    pub(super) fn rest_edge(&self, f_rest: &Vector3<f64>, floor: usize) -> usize {
        let avg = self.rest_avg();
        let n = self.hist.len();
        let tol = self.rest_acc_tol_mps2();
        let mut edge = n - 1;
        let mut i = n;
        while i >= floor + avg {
            let mut m = Vector3::zeros();
            for j in i - avg..i {
                m += self.hist.get(j).acc();
            }
            if ((m / avg as f64) - f_rest).amax() > tol {
                break;
            }
            edge = i - avg;
            i -= 1;
        }
        edge
    }

    /// Walking back from the newest sample, the newest one (not before `floor`) at which
    /// the car was still at rest: the mean specific force over `rest_avg` samples
    /// matches the standstill reference `g_mean`, and the body does not pitch. A driver
    /// ramps the acceleration in, and the body starts to squat with it: where the force
    /// first departs, the IMU 2 m ahead of the pitch centre already moves with the
    /// pitch rate, which a walk started there would miss. A body turning at rest (a
    /// load ramping in) has `drive_off_start_turned`.
    pub(super) fn drive_off_start(&self, g_mean: &Vector3<f64>, floor: usize) -> usize {
        let n = self.hist.len();
        let bias_y = self.bias_rps.map_or(0.0, |b| b.y);
        let gate = self.bias_gate_rps();
        let tol = self.rest_acc_tol_mps2();
        // Newest index whose mean departs by at most twice the tolerance, then by at most
        // the tolerance (and the body does not pitch).
        let (mut i_twice, mut i_rest) = (None, None);
        let avg = self.rest_avg();
        let mut i = n - 1;
        while i >= floor + avg {
            let (mut f, mut wy) = (Vector3::zeros(), 0.0);
            for j in i + 1 - avg..=i {
                let x = self.hist.get(j);
                f += x.acc();
                wy += x.gyro_rps().y;
            }
            let k = avg as f64;
            let dev = (f / k - g_mean).amax();
            if dev <= 2.0 * tol {
                i_twice.get_or_insert(i);
            }
            if dev <= tol && (wy / k - bias_y).abs() <= gate {
                i_rest = Some(i);
                break;
            }
            i -= 1;
        }
        let Some(i_rest) = i_rest else {
            return n - 1;
        };
        // A driver's acceleration ramps in: the force rose about linearly from the true
        // start, so the start lies as far before the first crossing as the second
        // crossing lies after it.
        let rise = i_twice.map_or(0, |i2| i2.saturating_sub(i_rest));
        let t0 = self.hist.get(i_rest.saturating_sub(rise).max(floor)).t_s - DRIVE_OFF_MARGIN_S;
        self.index_at(t0).max(floor)
    }

    /// `drive_off_start` for a stop too short to settle, where the body still rocks on
    /// its suspension when the car pulls away. Its pitch swing moves the raw specific
    /// force by up to 0.1 m/s^2 and its pitch rate by degrees per second, so neither
    /// says when the car moved. Each sample from the rest edge `floor` on is freed of
    /// the lever-arm motion and turned by the gyro into the body frame at the rest edge:
    /// there the force of a car at rest stays on gravity, however the body rocks, and
    /// departs from it with the car's own acceleration. The reference is the mean over
    /// `ROCKING_REF_S` after the stop jerk; `n - 1` when the stop is shorter than that.
    pub(super) fn drive_off_start_rocking(&self, floor: usize) -> usize {
        const ROCKING_REF_S: f64 = 0.3;
        let n = self.hist.len();
        let start = self.index_at(self.hist.get(floor).t_s + 0.1).min(n - 1);
        let ref_end = self.index_at(self.hist.get(start).t_s + ROCKING_REF_S);
        self.derotated_drive_off(floor, start, ref_end, None)
    }

    /// `drive_off_start` for a settled stop whose body turned at rest after `floor`, the
    /// last settled sample: a load ramping in. `reference` is the settled mean force,
    /// freed of the lever-arm motion, in the body frame at `floor`; each later sample is
    /// turned by the gyro into that frame, so the turn of the load leaves the force on
    /// gravity and only the car's own acceleration departs from it. The raw force against
    /// the turned body's gravity finds the drive-off late, once the squat has begun.
    pub(super) fn drive_off_start_turned(&self, floor: usize, reference: Vector3<f64>) -> usize {
        self.derotated_drive_off(floor, floor, floor, Some(reference - self.acc_bias_mps2()))
    }

    /// The newest start of a drive-off after `start` (not before `floor`), on the force
    /// turned by the gyro into the body frame at `start`: against `given`, or against the
    /// mean from `start` to `ref_end` when `None`; `n - 1` when there is too little
    /// history after it.
    fn derotated_drive_off(
        &self,
        floor: usize,
        start: usize,
        ref_end: usize,
        given: Option<Vector3<f64>>,
    ) -> usize {
        let n = self.hist.len();
        let avg = self.rest_avg();
        if ref_end + avg >= n {
            return n - 1;
        }
        let bias = self.bias_rps.unwrap_or_else(Vector3::zeros);
        let acc_bias = self.acc_bias_mps2();
        let tol = self.rest_acc_tol_mps2();
        // One pass forward from `start`, the attitude carried by the gyro: first the
        // reference, then the trailing mean of `rest_avg` samples against it. Kept are
        // the newest sample whose mean matches within the tolerance, and within twice it.
        let mut q = UnitQuaternion::identity();
        let mut reference = given.unwrap_or_else(Vector3::zeros);
        let mut recent = [Vector3::zeros(); REST_AVG_MAX];
        let mut sum = Vector3::zeros();
        let (mut i_twice, mut i_rest) = (None, None);
        for j in start..n {
            if j > start {
                let (a, b) = (self.hist.get(j - 1), self.hist.get(j));
                let w = (a.gyro_rps() + b.gyro_rps()) * 0.5 - bias;
                q = attitude::propagate(&q, &w, b.t_s - a.t_s);
            }
            let f = q * (self.hist.get(j).acc() - acc_bias - self.lever_acc_at(j));
            let slot = (j - start) % avg;
            sum += f - recent[slot];
            recent[slot] = f;
            if given.is_none() {
                if j < ref_end {
                    reference += f;
                    continue;
                }
                if j == ref_end {
                    reference /= (ref_end - start) as f64;
                }
            }
            let dev = (sum / avg as f64 - reference).amax();
            if dev <= 2.0 * tol {
                i_twice = Some(j);
            }
            if dev <= tol {
                i_rest = Some(j);
            }
        }
        let Some(i_rest) = i_rest else {
            return n - 1;
        };
        // As in `drive_off_start`: the force ramps in about linearly from the true start.
        let rise = i_twice.map_or(0, |i2| i2.saturating_sub(i_rest));
        let t0 = self.hist.get(i_rest.saturating_sub(rise).max(floor)).t_s - DRIVE_OFF_MARGIN_S;
        self.index_at(t0).max(floor)
    }

    /// Mean specific force of the rest samples from `rest` to `first`, each freed of
    /// `acc_bias_mps2` and of the lever-arm motion and turned by the gyro into the body
    /// frame at `first`: the gravity reference of a window at `first` even while the
    /// body rocked. `None` with less than `MIN_REST_S` of samples.
    pub(super) fn derotated_reference(&self, rest: usize, first: usize) -> Option<Vector3<f64>> {
        const MIN_REST_S: f64 = 0.3;
        // The first samples after the rest edge still carry the stop jerk.
        let start = self.index_at(self.hist.get(rest).t_s + 0.1);
        if first <= start || self.hist.get(first).t_s - self.hist.get(start).t_s < MIN_REST_S {
            return None;
        }
        Some(self.derotated_mean(start, first, &self.acc_bias_mps2()))
    }

    /// Mean specific force of history samples `from..=to`, each freed of `acc_bias` and
    /// of the lever-arm motion and turned by the gyro into the body frame at `to`.
    pub(super) fn derotated_mean(
        &self,
        from: usize,
        to: usize,
        acc_bias: &Vector3<f64>,
    ) -> Vector3<f64> {
        self.derotated_spread(from, to, acc_bias).0
    }

    /// `derotated_mean`, and the largest standard deviation of the turned samples about
    /// it over the three axes, m/s^2.
    pub(super) fn derotated_spread(
        &self,
        from: usize,
        to: usize,
        acc_bias: &Vector3<f64>,
    ) -> (Vector3<f64>, f64) {
        let bias = self.bias_rps.unwrap_or_else(Vector3::zeros);
        // Rotation from the frame at sample j to the frame at `to`.
        let mut q = UnitQuaternion::identity();
        let (mut sum, mut sq, mut k) = (Vector3::zeros(), Vector3::zeros(), 0usize);
        let mut j = to;
        loop {
            let f = q * (self.hist.get(j).acc() - acc_bias - self.lever_acc_at(j));
            sum += f;
            sq += f.component_mul(&f);
            k += 1;
            if j <= from {
                break;
            }
            let (a, b) = (self.hist.get(j - 1), self.hist.get(j));
            let w = (a.gyro_rps() + b.gyro_rps()) * 0.5 - bias;
            q = attitude::propagate(&q, &w, a.t_s - b.t_s);
            j -= 1;
        }
        let mean = sum / k as f64;
        let var = sq / k as f64 - mean.component_mul(&mean);
        (mean, var.max().max(0.0).sqrt())
    }

    /// The lowest and highest forward speed (m/s, along the heading at rest) that a car
    /// at rest at history sample `rest` with attitude `q_rest` had from sample `late`
    /// back to sample `early`: the accelerometer integrated backwards with the
    /// gyro-carried attitude. A wheel reading taken somewhere in that span may show any
    /// of them.
    pub(super) fn speeds_before_rest(
        &self,
        q_rest: UnitQuaternion<f64>,
        rest: usize,
        late: usize,
        early: usize,
        g: f64,
    ) -> (f64, f64) {
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        self.walk_back_from_rest(q_rest, rest, early.min(late), g, |j, s| {
            if j <= late {
                (lo, hi) = (lo.min(s), hi.max(s));
            }
        });
        (lo, hi)
    }

    /// Integrate the accelerometer backwards from history sample `rest`, where the car
    /// is taken to be at rest with attitude `q_rest`, down to sample `stop`, with the
    /// gyro-carried attitude; `visit` gets each sample's index and the forward speed
    /// there (m/s, along the heading at rest).
    pub(super) fn walk_back_from_rest(
        &self,
        q_rest: UnitQuaternion<f64>,
        rest: usize,
        stop: usize,
        g: f64,
        mut visit: impl FnMut(usize, f64),
    ) {
        let bias = self.bias_rps.unwrap_or_else(Vector3::zeros);
        let up = Vector3::new(0.0, 0.0, g);
        let heading = q_rest * Vector3::x();
        let along = |v: &Vector3<f64>| v.x * heading.x + v.y * heading.y;
        let (mut q, mut v) = (q_rest, Vector3::zeros());
        let mut j = rest;
        loop {
            visit(j, along(&v));
            if j <= stop {
                break;
            }
            let (a, b) = (self.hist.get(j - 1), self.hist.get(j));
            let dt = b.t_s - a.t_s;
            let q_prev =
                attitude::propagate(&q, &((a.gyro_rps() + b.gyro_rps()) * 0.5 - bias), -dt);
            // v(a) = v(b) - integral of the acceleration between them.
            v -= ((q * b.acc() - up) + (q_prev * a.acc() - up)) * (0.5 * dt);
            q = q_prev;
            j -= 1;
        }
    }

    /// Index of the first history sample at or after `t`.
    pub(super) fn index_at(&self, t: f64) -> usize {
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
    /// while braking shows fully in x. A knock between the stop and the settled samples
    /// (a door, someone sitting down: a swing the lever-arm model does not fully
    /// explain) is stepped over when it dies out within `KNOCK_MAX_S` and leaves no
    /// speed; braking never returns to rest and gains speed. Returns the edge and the
    /// attitude there. The search goes back at most 2 s before `floor`, the first quiet
    /// sample.
    pub(super) fn rocking_rest_edge(
        &self,
        q_ref: UnitQuaternion<f64>,
        from: usize,
        floor: usize,
        g: f64,
    ) -> (usize, UnitQuaternion<f64>) {
        let avg = self.rest_avg();
        let knock_quiet = self.samples_in(KNOCK_QUIET_S);
        // A vibrating IMU is read through the vibration triangle, against a tolerance
        // widened only by the noise below the vibration: the raw force averaged over
        // `rest_avg` keeps a good part of a 20-40 Hz cycle, and a tolerance widened
        // for it missed the end of the braking (deceleration windows of an INS-grade
        // unit next to an engine 0.118 -> 0.105 deg rms, measured).
        let vibrating = self.vibrating();
        let tol = if vibrating {
            self.smoothed_rest_acc_tol_mps2()
        } else {
            self.rest_acc_tol_mps2()
        };
        let lowest = floor.saturating_sub(self.samples_in(2.0));
        let bias = self.bias_rps.unwrap_or_else(Vector3::zeros);
        let up = Vector3::new(0.0, 0.0, g);
        let mut q = q_ref;
        let mut res = [0.0f64; REST_AVG_MAX];
        let (mut edge, mut q_edge) = (from, q_ref);
        // A knock open on the walk: (time it began, velocity change across it so far,
        // samples in a row back at rest).
        let mut knock: Option<(f64, f64, usize)> = None;
        let mut i = from;
        let mut k = 0usize;
        loop {
            let x = self.hist.get(i);
            // The IMU rides the rocking body at the lever arm: remove that acceleration.
            let lever_acc = self.lever_acc_at(i);
            let ax = if vibrating {
                self.smoothed_acc_at(i).map_or(x.acc_mps2[0], |a| a.x)
            } else {
                x.acc_mps2[0]
            };
            let r = ax - (q.inverse() * up).x - lever_acc.x;
            res[k % avg] = r;
            k += 1;
            if let Some((_, dv, _)) = knock.as_mut()
                && i + 1 < self.hist.len()
            {
                *dv += r * (self.hist.get(i + 1).t_s - x.t_s);
            }
            if k >= avg {
                let disturbed = (res[..avg].iter().sum::<f64>() / avg as f64).abs() > tol;
                knock = match (disturbed, knock) {
                    (true, None) => Some((x.t_s, 0.0, 0)),
                    (true, Some((t0, dv, _))) => {
                        // Braking goes on and gains speed; a knock does neither.
                        if t0 - x.t_s > KNOCK_MAX_S || dv.abs() > KNOCK_PEAK_DV_MPS {
                            break;
                        }
                        Some((t0, dv, 0))
                    }
                    (false, Some((t0, dv, quiet))) if quiet + 1 < knock_quiet => {
                        Some((t0, dv, quiet + 1))
                    }
                    (false, Some((_, dv, _))) => {
                        if dv.abs() > KNOCK_MAX_DV_MPS {
                            break;
                        }
                        None
                    }
                    (false, None) => None,
                };
                if knock.is_none() {
                    // The window's oldest sample is the edge: the first one at rest. Four
                    // samples later the body already rebounds from its dive at 0.02-0.05
                    // rad/s, and the walk's start velocity omega x lever arm leans on the
                    // learnt arm, which comes out about 1 % short. A braking sample inside
                    // the window would have failed the test above.
                    edge = i;
                    q_edge = q;
                }
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

    /// Velocity of the IMU at sample `i` (frame of its window attitude `q_i`, which
    /// assumes `acc_bias_mps2` removed, m/s) while the pitch centre is at rest but the
    /// body may still rock on its suspension. Each rest sample j on the `later` side
    /// gives omega_j x lever arm carried to `i` by the integrated acceleration between
    /// them. With `reach_s` None the estimate is their mean over the first
    /// `REST_VELOCITY_S`, which averages out the gyro's noise (a single sample's noise
    /// times a 2 m lever arm costs about 0.1 deg of slope). Right at the stop, though,
    /// the swing is largest, and with it what rotation about the pitch centre misses
    /// (`SWING_UNMODELLED_SHARE`: a body that heaves as it pitches); a second later the
    /// swing has died out, but the accelerometer's noise integrated on the way has
    /// grown. Given `reach_s`, the samples up to that far are weighed by their own
    /// errors (that share of the swing, the gyro's noise in one sample times the arm),
    /// and the span read is the one whose estimate has the least predicted error,
    /// counting the unmodelled swing as shared by neighbouring samples and the
    /// integrated noise as the random walk it is (its density learnt at rest). The
    /// samples of the first 0.02 s are left out in case `i` is a step early; a knock
    /// ends a weighed span (see below).
    pub(super) fn rest_velocity(
        &self,
        q_i: UnitQuaternion<f64>,
        i: usize,
        later: bool,
        reach_s: Option<f64>,
        g: f64,
    ) -> Vector3<f64> {
        let weigh = reach_s.is_some();
        let reach_s = reach_s.unwrap_or(REST_VELOCITY_S);
        let skip = self.samples_in(0.02);
        let bias = self.bias_rps.unwrap_or_else(Vector3::zeros);
        let acc_bias = self.acc_bias_mps2();
        let lever = self.lever_arm();
        let up = Vector3::new(0.0, 0.0, g);
        let dt_s = self.sample_dt_s.0;
        let walk_var_per_s = self
            .walk_acc_noise_per_rthz()
            .unwrap_or(self.cfg.acc_noise_ug_rthz * 1e-6 * super::STANDARD_GRAVITY_MPS2)
            .powi(2);
        let gyro_var = self
            .gyro_noise
            .density_per_rthz(dt_s)
            .unwrap_or(self.cfg.gyro_noise_dps_rthz.to_radians())
            .powi(2)
            / dt_s.max(1e-4)
            * lever.norm_squared();
        let n = self.hist.len();
        let t_i = self.hist.get(i).t_s;
        // (time from i s, estimate m/s, weight, unmodelled swing m/s) per sample read.
        let mut read = [(0.0, Vector3::zeros(), 0.0, 0.0); REST_VELOCITY_MAX_SAMPLES];
        let mut count = 0usize;
        let (mut q, mut dv) = (q_i, Vector3::zeros());
        let mut j = i;
        while count < read.len() {
            let next = if later { j + 1 } else { j.wrapping_sub(1) };
            if next >= n {
                break;
            }
            let (a, b) = (self.hist.get(j), self.hist.get(next));
            let span_s = (b.t_s - t_i).abs();
            if span_s > reach_s {
                break;
            }
            let dt = b.t_s - a.t_s;
            let q_next = attitude::propagate(&q, &((a.gyro_rps() + b.gyro_rps()) * 0.5 - bias), dt);
            let acc_next = q_next * (b.acc() - acc_bias) - up;
            // A knock (a door, someone boarding: 5-8 Hz, several m/s^2 at the IMU) is
            // integrated a few per cent off at the IMU's rate, which every later sample
            // would carry: a long span ends before it. (Over the short span at the edge
            // the samples before a knock alone did worse than its integration error.)
            if weigh && acc_next.amax() > super::lever::MAX_ROCKING_MPS2 {
                break;
            }
            // dv = v_next - v_i, in time order whichever way the walk goes.
            dv += ((q * (a.acc() - acc_bias) - up) + acc_next) * (0.5 * dt);
            q = q_next;
            j = next;
            if j.abs_diff(i) > skip {
                let swing = q * (b.gyro_rps() - bias).cross(&lever);
                let unmodelled = SWING_UNMODELLED_SHARE * swing.norm();
                let w = if weigh {
                    1.0 / (unmodelled * unmodelled + gyro_var).max(1e-12)
                } else {
                    1.0
                };
                read[count] = (span_s, swing - dv, w, unmodelled);
                count += 1;
            }
        }
        if count == 0 {
            return q_i * (self.hist.get(i).gyro_rps() - bias).cross(&lever);
        }
        // Predicted error variance of the estimate from the first k samples read, from
        // running sums: the weight W, the weighted unmodelled swing A (shared, so it
        // adds as (A / W)^2), the gyro's share B, and for the random walk
        // C = sum_jl w_j w_l min(t_j, t_l): a sample later than all before it adds
        // w^2 t + 2 w sum_l w_l t_l.
        let (mut big_w, mut a_sum, mut b_sum, mut c_sum, mut wt_sum) = (0.0, 0.0, 0.0, 0.0, 0.0);
        let (mut best, mut best_var) = (count, f64::INFINITY);
        if weigh {
            for (k, &(t, _, w, u)) in read[..count].iter().enumerate() {
                c_sum += w * w * t + 2.0 * w * wt_sum;
                wt_sum += w * t;
                big_w += w;
                a_sum += w * u;
                b_sum += w * w * gyro_var;
                let var =
                    (a_sum / big_w).powi(2) + (b_sum + walk_var_per_s * c_sum) / (big_w * big_w);
                if var < best_var {
                    best_var = var;
                    best = k + 1;
                }
            }
        }
        let (sum, weight) = read[..best]
            .iter()
            .fold((Vector3::zeros(), 0.0), |(s, w), r| {
                (s + r.1 * r.2, w + r.2)
            });
        sum / weight
    }

    /// Whether the body's turn between consecutive samples `a` and `b` is unknown: a
    /// gap in the data over which the readings on either side, held for the whole
    /// gap, would turn the body by more than `GAP_TURN_MAX_RAD`. A load ramping in
    /// turns it by a few hundredths of a degree over such a gap, and the mean of the
    /// two readings bridges it. A door shock's swing at its fastest would turn it by
    /// most of a degree, where a body at rest turned by no more than the swing's
    /// amplitude: such a gap turns nothing.
    pub(super) fn turn_unknown_across(&self, a: &ImuSample, b: &ImuSample) -> bool {
        let dt = b.t_s - a.t_s;
        if dt <= self.cfg.max_imu_gap_s {
            return false;
        }
        let bias = self.bias_rps.unwrap_or_else(Vector3::zeros);
        let rate = (a.gyro_rps() - bias)
            .norm()
            .max((b.gyro_rps() - bias).norm());
        rate * dt > GAP_TURN_MAX_RAD
    }

    /// Carry an attitude along the history from sample `from` to sample `to` with the
    /// bias-corrected gyro (eq. 10-11), in either direction.
    pub(super) fn carry(
        &self,
        q: UnitQuaternion<f64>,
        from: usize,
        to: usize,
    ) -> UnitQuaternion<f64> {
        self.carry_with_bias(q, from, to, self.bias_rps.unwrap_or_else(Vector3::zeros))
    }

    /// `carry` with a given gyro bias, rad/s.
    pub(super) fn carry_with_bias(
        &self,
        mut q: UnitQuaternion<f64>,
        from: usize,
        to: usize,
        bias: Vector3<f64>,
    ) -> UnitQuaternion<f64> {
        let step = |q: UnitQuaternion<f64>, i: usize, sign: f64| {
            let (a, b) = (self.hist.get(i), self.hist.get(i + 1));
            if self.turn_unknown_across(&a, &b) {
                return q;
            }
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

    /// Acceleration of the IMU at history sample `i` from the body still rocking about
    /// the pitch centre (angular acceleration and rate from smoothed gyro readings), in
    /// body axes, m/s^2. Mounted 2 m ahead of the pitch centre, the IMU sees a rocking
    /// tail of 0.1 deg/s as 1 mm/s^2 in the standstill mean: 0.05 deg of slope over a
    /// gentle 2 s window.
    pub(super) fn lever_acc_at(&self, i: usize) -> Vector3<f64> {
        if self.lever_arm() == Vector3::zeros() {
            return Vector3::zeros();
        }
        self.lever_acc_from(self.rocking_at(i))
    }

    /// `lever_acc_at` from the sample's `rocking_at`, m/s^2.
    pub(super) fn lever_acc_from(
        &self,
        rocking: Option<(Vector3<f64>, Vector3<f64>)>,
    ) -> Vector3<f64> {
        let lever = self.lever_arm();
        match rocking {
            Some((alpha, w)) => alpha.cross(&lever) + w.cross(&w.cross(&lever)),
            None => Vector3::zeros(),
        }
    }

    /// Angular acceleration (rad/s^2) and bias-free rate (rad/s) of the body at history
    /// sample `i`, from gyro readings smoothed over `2 lever_half + 1` samples;
    /// `None` too near either end of the history.
    pub(super) fn rocking_at(&self, i: usize) -> Option<(Vector3<f64>, Vector3<f64>)> {
        let h = self.lever_half();
        if i < 2 * h || i + 2 * h >= self.hist.len() {
            return None;
        }
        let rate = |c: usize| {
            let mut w = Vector3::zeros();
            for j in c - h..=c + h {
                w += self.hist.get(j).gyro_rps();
            }
            w / (2 * h + 1) as f64
        };
        let span = self.hist.get(i + h).t_s - self.hist.get(i - h).t_s;
        if span <= 0.0 {
            return None;
        }
        let alpha = (rate(i + h) - rate(i - h)) / span;
        Some((
            alpha,
            rate(i) - self.bias_rps.unwrap_or_else(Vector3::zeros),
        ))
    }
}

#[cfg(test)]
mod tests {
    use crate::estimator::{Estimator, EstimatorConfig, ImuSample};
    use nalgebra::{UnitQuaternion, Vector3};

    const G: f64 = 9.80665;

    /// A decaying swing of the body about the pitch centre, `x` s after it began: pitch
    /// (nose down positive about -y as in the simulator), rate and acceleration.
    fn swing(amp_deg: f64, freq_hz: f64, tau_s: f64, x: f64) -> (f64, f64, f64) {
        if x < 0.0 {
            return (0.0, 0.0, 0.0);
        }
        let (amp, w) = (amp_deg.to_radians(), 2.0 * std::f64::consts::PI * freq_hz);
        let e = (-x / tau_s).exp();
        let (s, c) = ((w * x).sin(), (w * x).cos());
        (
            amp * e * s,
            amp * e * (w * c - s / tau_s),
            amp * e * ((1.0 / (tau_s * tau_s) - w * w) * s - 2.0 * w / tau_s * c),
        )
    }

    /// The IMU sample at the default lever arm of a body pitched `th` (rate, angular
    /// acceleration) on a car accelerating at `a`, plus `extra` along x.
    fn swung_sample(t: f64, (th, rate, alpha): (f64, f64, f64), a: f64, extra: f64) -> ImuSample {
        let arm = Vector3::from(EstimatorConfig::default().lever_arm_m);
        let q = UnitQuaternion::from_axis_angle(&Vector3::y_axis(), th);
        let omega = Vector3::new(0.0, rate, 0.0);
        let lever = Vector3::new(0.0, alpha, 0.0).cross(&arm) + omega.cross(&omega.cross(&arm));
        let f = q.inverse() * Vector3::new(a, 0.0, G) + lever + Vector3::new(extra, 0.0, 0.0);
        ImuSample::new(t, f.into(), [0.0, rate.to_degrees(), 0.0])
    }

    /// A car at rest from t = 0 whose body still rocks from the stop (0.8 deg at
    /// 1.3 Hz, decaying over 0.5 s, about the default pitch centre), pulling away at
    /// `drive_off_s` with 0.4 m/s^2 ramped in over 0.5 s. 100 Hz up to `end_s`.
    fn rocking_stop(drive_off_s: f64, end_s: f64) -> Estimator {
        let mut est = Estimator::new(EstimatorConfig::default()).unwrap();
        est.bias_rps = Some(Vector3::zeros());
        let mut t = 0.0;
        while t <= end_s {
            let a = 0.4 * ((t - drive_off_s) / 0.5).clamp(0.0, 1.0);
            est.hist
                .push(swung_sample(t, swing(0.8, 1.3, 0.5, t), a, 0.0));
            t += 0.01;
        }
        est
    }

    #[test]
    fn spans_in_seconds_count_samples_at_the_imus_own_rate() {
        // 100 Hz with frames dropped, 200 Hz, and 50 Hz whose first interval is a drop:
        // the spans stay the same in seconds.
        for (rate_hz, lever_half, knock) in [(100.0, 5, 10), (200.0, 10, 20), (50.0, 5, 5)] {
            let mut est = Estimator::new(EstimatorConfig::default()).unwrap();
            let dt = 1.0 / rate_hz;
            let mut t = 0.0;
            for k in 0..2000 {
                // Every 37th frame lost, and the second one too.
                let lost = k == 1 || k % 37 == 0;
                let jitter = 0.0004 * ((k * 7919) % 5) as f64 / 4.0;
                t += dt;
                if !lost {
                    est.push_imu(
                        ImuSample::new(t + jitter, [0.0, 0.0, G], [0.0; 3]),
                        &mut |_| {},
                    );
                }
            }
            assert_eq!(est.lever_half(), lever_half, "{rate_hz} Hz");
            assert_eq!(est.samples_in(0.1), knock, "{rate_hz} Hz");
            assert_eq!(
                est.samples_in(2.0),
                (2.0 * rate_hz) as usize,
                "{rate_hz} Hz"
            );
        }
    }

    #[test]
    fn the_drive_off_from_a_rocking_body_is_found_where_the_car_moved() {
        for drive_off_s in [0.9, 1.2, 1.6] {
            let est = rocking_stop(drive_off_s, drive_off_s + 0.6);
            let first = est.hist.get(est.drive_off_start_rocking(0)).t_s;
            assert!(
                (drive_off_s - 0.2..=drive_off_s + 0.05).contains(&first),
                "drive-off at {drive_off_s} s found at {first:.2} s"
            );
            // Against the raw force of the first rest samples (and the pitch rate), the
            // rocking puts the drive-off far from where it was.
            let f0 = est.hist.get(0).acc();
            let raw = est.hist.get(est.drive_off_start(&f0, 0)).t_s;
            assert!((raw - drive_off_s).abs() > 0.3, "raw {raw:.2} s");
        }
    }

    /// A car braking at 1.5 m/s^2 comes to rest at `stop_s`; at `knock_s` a door is
    /// shut: the body swings 0.2 deg at 6 Hz, decaying in 0.1 s, and the structure adds
    /// 0.5 m/s^2 along x that the lever arm does not explain. 100 Hz up to 4 s.
    fn knocked_stop(stop_s: f64, knock_s: f64) -> Estimator {
        let mut est = Estimator::new(EstimatorConfig::default()).unwrap();
        est.bias_rps = Some(Vector3::zeros());
        let mut t = 0.0;
        while t <= 4.0 {
            let x = t - knock_s;
            let extra = if x < 0.0 {
                0.0
            } else {
                0.5 * (-x / 0.1).exp() * (2.0 * std::f64::consts::PI * 6.0 * x).cos()
            };
            let a = if t < stop_s { -1.5 } else { 0.0 };
            est.hist
                .push(swung_sample(t, swing(0.2, 6.0, 0.1, x), a, extra));
            t += 0.01;
        }
        est
    }

    #[test]
    fn the_walk_back_to_the_rest_edge_steps_over_a_knock_but_not_into_braking() {
        for knock_s in [1.3, 1.8, 2.5] {
            let est = knocked_stop(1.0, knock_s);
            let (from, floor) = (est.index_at(3.5), est.index_at(2.9));
            let (edge, _) = est.rocking_rest_edge(UnitQuaternion::identity(), from, floor, G);
            let t = est.hist.get(edge).t_s;
            assert!(
                (0.99..=1.04).contains(&t),
                "knock at {knock_s} s: rest edge at {t:.2} s, the car stopped at 1.00 s"
            );
        }
        // The same knock while the car still brakes: the walk stops where the braking
        // ended, not inside it.
        let est = knocked_stop(1.6, 1.3);
        let (from, floor) = (est.index_at(3.5), est.index_at(2.9));
        let (edge, _) = est.rocking_rest_edge(UnitQuaternion::identity(), from, floor, G);
        let t = est.hist.get(edge).t_s;
        assert!(t >= 1.59, "rest edge at {t:.2} s inside the braking");
    }
}
