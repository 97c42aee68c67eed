//! Dead reckoning over one slope window (eq. 12-13) and the road slope (eq. 14-15).
//!
//! The integrator is fed IMU samples in the order it should walk through them:
//! forward in time after a stop, backward in time before a stop. Each step uses
//! the mean of the two samples it spans (the constant-acceleration model of eq. 12
//! with a trapezoidal acceleration), which makes forward and backward walks exact
//! inverses of one another.

use super::attitude::{pitch_of, propagate};
use super::types::ImuSample;
use nalgebra::{UnitQuaternion, Vector3};

/// Why a window was not used.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum RejectReason {
    /// The trajectory leaves its end-to-end chord: the slope changes inside the window (Fig. 11).
    SlopeNotConstant { chord_deviation_m: f64 },
    /// Yaw rate or lateral acceleration show a turn.
    Turning {
        yaw_rate_dps: f64,
        lateral_acc_mps2: f64,
    },
    /// The history or the drive ended before the window distance was covered.
    TooShort { distance_m: f64 },
    /// The window distance was not covered within `max_window_time_s`.
    TooSlow { duration_s: f64 },
    /// IMU samples are missing inside the window.
    ImuGap { gap_s: f64 },
    /// The first wheel speed above the dead zone after the drive-off disagrees with the
    /// speed the window integrated: the car was not at rest where the walk began (a
    /// rolling stop), or the reference is wrong.
    SpeedMismatch { imu_mps: f64, wheel_mps: f64 },
    /// The vehicle was not still where the window must start.
    NotStill,
}

/// Fixed inputs of one window.
#[derive(Debug, Clone, Copy)]
pub struct WindowSetup {
    /// Attitude at the start of the walk (from standstill gravity, eq. 9).
    pub q0: UnitQuaternion<f64>,
    /// Attitude the reference's mean force at rest was measured in (`q0` turned back
    /// by the gyro to the settled stop, or `q0` itself): the bias is taken out along
    /// its x axis (see `WindowIntegrator::bias`).
    pub reference_q: UnitQuaternion<f64>,
    /// Gyro bias to remove, rad/s (eq. 8).
    pub gyro_bias_rps: Vector3<f64>,
    /// Accelerometer bias to remove, m/s^2. The reference `q0` and `gravity_mps2` must
    /// come from a standstill mean with the same bias removed.
    pub acc_bias_mps2: Vector3<f64>,
    /// Magnitude of the standstill specific force, used as g of eq. 12, m/s^2.
    pub gravity_mps2: f64,
    /// IMU offset from the body pitch centre, body axes, m.
    pub lever_arm_m: Vector3<f64>,
    pub distance_m: f64,
    /// The straightness check goes this far past `distance_m` (the slope does not), m:
    /// a grade change or bump just past the window end bends the path there.
    pub check_extra_m: f64,
    pub max_time_s: f64,
    pub max_gap_s: f64,
    pub max_yaw_rate_rps: f64,
    pub max_lateral_acc_mps2: f64,
    pub max_chord_deviation_m: f64,
    /// The chord deviation the accelerometer's noise alone leaves on a walk of 1 s, m;
    /// it grows as the walk's duration^1.5. The short fallback's limit does not go
    /// below it, up to the limit of the whole window times the share
    /// (`Estimator::noise_chord_m`). 0 leaves the limits as set.
    pub noise_chord_m: f64,
    /// Slope from the velocity-free fit instead of the end point, on a path that
    /// leaves its chord by at most `velocity_free_max_chord_m`.
    pub velocity_free: bool,
    pub velocity_free_max_chord_m: f64,
    /// When the whole path bends or turns, the window falls back to this share of its
    /// distance, checked over its own length against the chord limits times the square
    /// of the share (0 turns the fallback off).
    pub short_share: f64,
    /// The walk notes where the pitch centre has gone this far, the wheelbase, m (see
    /// `AxlePoint`); 0 notes nothing.
    pub axle_m: f64,
}

/// Geometry of a completed window.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WindowGeometry {
    /// Road slope along body x, rad, positive rising ahead (eq. 14).
    pub slope_rad: f64,
    /// Horizontal path length (eq. 15), m.
    pub distance_m: f64,
    pub duration_s: f64,
    /// Time of the walk's first sample, s.
    pub start_s: f64,
    pub chord_deviation_m: f64,
    pub max_yaw_rate_rps: f64,
    pub max_lateral_acc_mps2: f64,
    /// Time means over the window of the body's pitch, rad, and of its acceleration
    /// along the start heading, m/s^2 (negative while braking, in either walk
    /// direction): how far the body dived or squatted under the acceleration.
    pub mean_pitch_rad: f64,
    pub mean_accel_mps2: f64,
    /// Direction of travel in the IMU's frame, rad: the angle from the IMU's x axis
    /// towards its y axis of the path walked, each step taken against the IMU's heading
    /// where it was walked (0 unless the IMU is yawed on its mount).
    pub travel_yaw_rad: f64,
    /// The y component of up in the IMU's frame at the walk's start: the sine of the
    /// elevation of the IMU's y axis (its roll), with `setup.acc_bias_mps2` taken out.
    pub start_up_y: f64,
    /// How `slope_rad` moves per m/s^2 more accelerometer x bias removed, the reference
    /// and the gravity magnitude taken again with it, less the tilt that moves the
    /// reference's pitch as much, rad per m/s^2: the walk turns the bias into the
    /// vertical as far as the body has pitched from rest (`WindowIntegrator`).
    pub slope_per_bias_x: f64,
    /// Where the walk had gone one wheelbase, on a window whose slope is the chord.
    pub axle: Option<AxlePoint>,
    /// The pitch the body swung about where the walk left the reference, rad (the
    /// caller's; `None` where the pitch mode is not known): what its dive is counted
    /// from (`grade.rs`).
    pub rest_centre_pitch_rad: Option<f64>,
}

/// The walk one wheelbase from rest. Forward, the rear wheels stand there where the
/// front wheels stood at rest; backward, the front wheels where the rear ones stood.
/// With the body's pitch there, this gives the height between the contact points the
/// body stood on at rest, which the window's slope over a road that is not one plane
/// (its unevenness, a vertical curve) does not.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AxlePoint {
    /// Slope of the chord from rest to there, of the pitch centre's path, rad,
    /// positive rising ahead.
    pub slope_rad: f64,
    /// The body's pitch there (gyro-carried from the walk's start), rad.
    pub pitch_rad: f64,
    /// Acceleration along the start heading there, low-passed, m/s^2 (negative while
    /// braking, in either walk direction).
    pub accel_mps2: f64,
    /// `WindowGeometry::slope_per_bias_x` of `slope_rad`, rad per m/s^2.
    pub slope_per_bias_x: f64,
}

/// Time constant of the acceleration noted at the axle point, s: about the lag of a
/// body's pitch answer to its acceleration (1.2-1.5 Hz, damping 0.2-0.4), and it
/// passes a tenth of the 9-14 Hz structural vibration.
const AXLE_ACCEL_TAU_S: f64 = 0.1;

/// Outcome of feeding a sample.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Step {
    Continue,
    Done(Result<WindowGeometry, RejectReason>),
}

/// Walks a window. Preallocates its trajectory once; stepping never allocates.
#[derive(Debug, Clone)]
pub struct WindowIntegrator {
    setup: WindowSetup,
    q: UnitQuaternion<f64>,
    v: Vector3<f64>,
    p: Vector3<f64>,
    lever0: Vector3<f64>,
    prev: Option<ImuSample>,
    t_start_s: f64,
    horizontal_m: f64,
    last_corrected: Vector3<f64>,
    max_yaw: f64,
    max_lat: f64,
    /// Corrected end point, horizontal length and duration when `distance_m` was reached.
    at_distance: Option<(Vector3<f64>, f64, f64)>,
    /// (horizontal path length, corrected height) per step.
    track: Vec<(f64, f64)>,
    /// Unit horizontal heading of the body at the start of the walk, (x, y).
    heading: (f64, f64),
    /// Time integrals of the corrected height and of the travel along `heading`, m s,
    /// and the last (height, travel) they were stepped with.
    int_z: f64,
    int_x: f64,
    last_zx: (f64, f64),
    /// Slope of the velocity-free fit when `distance_m` was reached, rad, and its
    /// weighted travel (`fit`'s `sx`), m s.
    fit_slope: Option<(f64, f64)>,
    /// Time integrals of the body's pitch, rad s, and of the acceleration along
    /// `heading`, m/s, and their values when `distance_m` was reached.
    int_pitch: f64,
    int_accel: f64,
    /// Body pitch at the last step's end, rad: the next step starts there.
    last_pitch: f64,
    ints_at_distance: (f64, f64),
    /// The short fallback window, taken as the walk passed its distance.
    short: Option<Span>,
    /// Horizontal path walked along and across the IMU's heading at each step, m, and
    /// its value when `distance_m` was reached.
    body_path: (f64, f64),
    body_path_at_distance: (f64, f64),
    /// Low-passed acceleration along `heading`, m/s^2, and the walk's state when it
    /// had gone `setup.axle_m`: (height, length, pitch, acceleration).
    accel_lp: f64,
    axle: Option<(f64, f64, f64, f64)>,
    /// The walk's answer to one m/s^2 more x bias removed: the rest's specific force
    /// then points as much further from x, so the reference and its gravity follow it
    /// and the vertical changes by how far x has turned from where it pointed in the
    /// reference (`WindowSetup::reference_q`).
    /// Its height (m), vertical speed (m/s), x's rise from the reference at the last
    /// step and the height's time integral (m s), per m/s^2, and (height, integral) at
    /// the window's distance and the height at the axle point.
    bias: BiasWalk,
    active: bool,
}

/// See `WindowIntegrator::bias`.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
struct BiasWalk {
    /// How far the IMU's x axis points up in the reference, sine.
    reference_up: f64,
    z: f64,
    vz: f64,
    rise: f64,
    int_z: f64,
    at_distance: (f64, f64),
    at_axle: f64,
}

impl WindowIntegrator {
    /// `max_points` bounds the stored trajectory (the window is rejected as too slow past it).
    pub fn with_capacity(max_points: usize) -> Self {
        Self {
            setup: WindowSetup {
                q0: UnitQuaternion::identity(),
                reference_q: UnitQuaternion::identity(),
                gyro_bias_rps: Vector3::zeros(),
                acc_bias_mps2: Vector3::zeros(),
                gravity_mps2: 9.80665,
                lever_arm_m: Vector3::zeros(),
                distance_m: 2.0,
                check_extra_m: 0.0,
                max_time_s: 10.0,
                max_gap_s: 0.1,
                max_yaw_rate_rps: 0.05,
                max_lateral_acc_mps2: 0.5,
                max_chord_deviation_m: 0.01,
                noise_chord_m: 0.0,
                velocity_free: true,
                velocity_free_max_chord_m: 0.006,
                short_share: 0.0,
                axle_m: 0.0,
            },
            q: UnitQuaternion::identity(),
            v: Vector3::zeros(),
            p: Vector3::zeros(),
            lever0: Vector3::zeros(),
            prev: None,
            t_start_s: 0.0,
            horizontal_m: 0.0,
            last_corrected: Vector3::zeros(),
            max_yaw: 0.0,
            max_lat: 0.0,
            at_distance: None,
            track: Vec::with_capacity(max_points.max(2)),
            heading: (1.0, 0.0),
            int_z: 0.0,
            int_x: 0.0,
            last_zx: (0.0, 0.0),
            fit_slope: None,
            int_pitch: 0.0,
            int_accel: 0.0,
            last_pitch: 0.0,
            ints_at_distance: (0.0, 0.0),
            short: None,
            body_path: (0.0, 0.0),
            body_path_at_distance: (0.0, 0.0),
            accel_lp: 0.0,
            axle: None,
            bias: BiasWalk::default(),
            active: false,
        }
    }

    /// Start a new walk with the pitch centre at rest. `v0_mps` is the IMU's velocity at
    /// the start sample in the frame of `setup.q0`: zero for a settled body, the swing
    /// about the pitch centre (omega x lever arm) for one still rocking.
    pub fn start(&mut self, setup: WindowSetup, v0_mps: Vector3<f64>) {
        self.setup = setup;
        self.q = setup.q0;
        self.v = v0_mps;
        self.p = Vector3::zeros();
        self.lever0 = setup.q0 * setup.lever_arm_m;
        self.prev = None;
        self.horizontal_m = 0.0;
        self.last_corrected = Vector3::zeros();
        self.max_yaw = 0.0;
        self.max_lat = 0.0;
        self.at_distance = None;
        self.track.clear();
        self.track.push((0.0, 0.0));
        let h = setup.q0 * Vector3::x();
        let hn = h.x.hypot(h.y).max(1e-9);
        self.heading = (h.x / hn, h.y / hn);
        self.int_z = 0.0;
        self.int_x = 0.0;
        self.last_zx = (0.0, 0.0);
        self.fit_slope = None;
        self.int_pitch = 0.0;
        self.int_accel = 0.0;
        self.last_pitch = pitch_of(&setup.q0);
        self.ints_at_distance = (0.0, 0.0);
        self.short = None;
        self.body_path = (0.0, 0.0);
        self.body_path_at_distance = (0.0, 0.0);
        self.accel_lp = 0.0;
        self.axle = None;
        self.bias = BiasWalk {
            reference_up: (setup.reference_q * Vector3::x()).z,
            ..BiasWalk::default()
        };
        self.bias.rise = self.x_rise(&setup.q0);
        self.active = true;
    }

    /// How far the IMU's x axis points up in `q` beyond the reference's, sine.
    fn x_rise(&self, q: &UnitQuaternion<f64>) -> f64 {
        (q * Vector3::x()).z - self.bias.reference_up
    }

    pub fn is_active(&self) -> bool {
        self.active
    }

    /// Horizontal speed integrated so far, m/s.
    pub fn horizontal_speed_mps(&self) -> f64 {
        self.v.x.hypot(self.v.y)
    }

    /// Time walked so far, s.
    pub fn elapsed_s(&self) -> f64 {
        self.prev.map_or(0.0, |p| (p.t_s - self.t_start_s).abs())
    }

    /// Feed the next sample of the walk (later in time going forward, earlier going backward).
    pub fn push(&mut self, s: &ImuSample) -> Step {
        if !self.active {
            return Step::Continue;
        }
        let Some(prev) = self.prev.replace(*s) else {
            self.t_start_s = s.t_s;
            return Step::Continue;
        };
        let dt = s.t_s - prev.t_s;
        if dt.abs() > self.setup.max_gap_s {
            return self.finish_with(Err(RejectReason::ImuGap { gap_s: dt.abs() }));
        }
        let bias = self.setup.gyro_bias_rps;
        let w0 = prev.gyro_rps() - bias;
        let w1 = s.gyro_rps() - bias;
        let g = Vector3::new(0.0, 0.0, self.setup.gravity_mps2);
        let q0 = self.q;
        let q1 = propagate(&q0, &((w0 + w1) * 0.5), dt);
        let b = self.setup.acc_bias_mps2;
        let a0 = q0 * (prev.acc() - b) - g;
        let a1 = q1 * (s.acc() - b) - g;
        // Eq. 12-13 with the acceleration varying linearly across the step.
        self.p += self.v * dt + (a0 * 2.0 + a1) * (dt * dt / 6.0);
        self.v += (a0 + a1) * (dt * 0.5);
        self.q = q1;
        // Per m/s^2 more bias removed, the vertical loses what x rose from the reference.
        let rise = self.x_rise(&q1);
        let bw = &mut self.bias;
        let (b0, b1) = (-bw.rise, -rise);
        let z_before = bw.z;
        bw.z += bw.vz * dt + (b0 * 2.0 + b1) * (dt * dt / 6.0);
        bw.vz += (b0 + b1) * (dt * 0.5);
        bw.rise = rise;
        bw.int_z += 0.5 * (z_before + bw.z) * dt.abs();

        let yaw = (q1 * w1).z.abs();
        let lat = a1.dot(&(q1 * Vector3::y())).abs();
        self.max_yaw = self.max_yaw.max(yaw);
        self.max_lat = self.max_lat.max(lat);

        // Remove the swing of the IMU about the pitch centre: what is left moves with the road.
        let corrected = self.p - (q1 * self.setup.lever_arm_m - self.lever0);
        let d = corrected - self.last_corrected;
        self.horizontal_m += d.x.hypot(d.y);
        self.last_corrected = corrected;
        // The step against the IMU's own heading over it: a turn carries the IMU round
        // with the path, so only its yaw on the mount is left.
        let ix = q0 * Vector3::x() + q1 * Vector3::x();
        let n = ix.x.hypot(ix.y).max(1e-9);
        let (cx, cy) = (ix.x / n, ix.y / n);
        self.body_path.0 += d.x * cx + d.y * cy;
        self.body_path.1 += d.y * cx - d.x * cy;
        if self.track.len() == self.track.capacity() {
            let duration_s = (s.t_s - self.t_start_s).abs();
            return self.finish_with(Err(RejectReason::TooSlow { duration_s }));
        }
        self.track.push((self.horizontal_m, corrected.z));

        let duration_s = (s.t_s - self.t_start_s).abs();
        let (hx, hy) = self.heading;
        let zx = (corrected.z, corrected.x * hx + corrected.y * hy);
        self.int_z += 0.5 * (zx.0 + self.last_zx.0) * dt.abs();
        self.int_x += 0.5 * (zx.1 + self.last_zx.1) * dt.abs();
        self.last_zx = zx;
        let along = |a: Vector3<f64>| a.x * hx + a.y * hy;
        let pitch = pitch_of(&q1);
        self.int_pitch += 0.5 * (self.last_pitch + pitch) * dt.abs();
        self.last_pitch = pitch;
        self.int_accel += 0.5 * (along(a0) + along(a1)) * dt.abs();
        self.accel_lp += (dt.abs() / AXLE_ACCEL_TAU_S).min(1.0) * (along(a1) - self.accel_lp);
        if self.axle.is_none() && self.setup.axle_m > 0.0 && self.horizontal_m >= self.setup.axle_m
        {
            self.axle = Some((corrected.z, self.horizontal_m, pitch, self.accel_lp));
            self.bias.at_axle = self.bias.z;
        }
        // Weights t (T - t) on the acceleration, moved onto the positions: the velocity
        // the walk started with drops out.
        let fit = || {
            let sz = duration_s * zx.0 - 2.0 * self.int_z;
            let sx = duration_s * zx.1 - 2.0 * self.int_x;
            ((sz * sx.signum()).atan2(sx.abs()), sx)
        };
        let share = self.setup.short_share;
        if share > 0.0 && self.short.is_none() && self.horizontal_m >= share * self.setup.distance_m
        {
            self.short = Some(Span {
                end: corrected,
                len: self.horizontal_m,
                duration_s,
                fit_slope: Some(fit()),
                ints: (self.int_pitch, self.int_accel),
                points: self.track.len(),
                max_yaw: self.max_yaw,
                max_lat: self.max_lat,
                body_path: self.body_path,
                bias: (self.bias.z, self.bias.int_z),
                // A bend of one curvature leaves a path of half the length a quarter as
                // far from its chord.
                limit_share: share * share,
            });
        }
        if self.at_distance.is_none() && self.horizontal_m >= self.setup.distance_m {
            self.at_distance = Some((corrected, self.horizontal_m, duration_s));
            self.body_path_at_distance = self.body_path;
            self.fit_slope = Some(fit());
            self.ints_at_distance = (self.int_pitch, self.int_accel);
            self.bias.at_distance = (self.bias.z, self.bias.int_z);
        }
        if self.at_distance.is_some()
            && self.horizontal_m >= self.setup.distance_m + self.setup.check_extra_m
        {
            let r = self.evaluate();
            return self.finish_with(r);
        }
        if duration_s > self.setup.max_time_s {
            if self.at_distance.is_some() {
                let r = self.evaluate();
                return self.finish_with(r);
            }
            return self.finish_with(Err(RejectReason::TooSlow { duration_s }));
        }
        Step::Continue
    }

    /// End the walk because no more samples exist (history exhausted or the drive stopped).
    pub fn exhausted(&mut self) -> Step {
        if !self.active {
            return Step::Continue;
        }
        if self.at_distance.is_some() {
            // The window itself is complete; only part of the extra check was possible.
            let r = self.evaluate();
            return self.finish_with(r);
        }
        let distance_m = self.horizontal_m;
        self.finish_with(Err(RejectReason::TooShort { distance_m }))
    }

    fn finish_with(&mut self, r: Result<WindowGeometry, RejectReason>) -> Step {
        self.active = false;
        Step::Done(r)
    }

    fn evaluate(&self) -> Result<WindowGeometry, RejectReason> {
        let Some((end, len, duration_s)) = self.at_distance else {
            return Err(RejectReason::TooShort {
                distance_m: self.horizontal_m,
            });
        };
        let whole = Span {
            end,
            len,
            duration_s,
            fit_slope: self.fit_slope,
            ints: self.ints_at_distance,
            points: self.track.len(),
            max_yaw: self.max_yaw,
            max_lat: self.max_lat,
            body_path: self.body_path_at_distance,
            bias: self.bias.at_distance,
            limit_share: 1.0,
        };
        let r = self.evaluate_span(&whole);
        // A path that bends or turns past its first part (a speed bump ahead of the
        // stop line, a turn begun at the line) keeps that part as a shorter window.
        let bent = matches!(
            r,
            Err(RejectReason::SlopeNotConstant { .. } | RejectReason::Turning { .. })
        );
        match &self.short {
            Some(short) if bent => self.evaluate_span(short).or(r),
            _ => r,
        }
    }

    fn evaluate_span(&self, w: &Span) -> Result<WindowGeometry, RejectReason> {
        let s = &self.setup;
        if w.max_yaw > s.max_yaw_rate_rps || w.max_lat > s.max_lateral_acc_mps2 {
            return Err(RejectReason::Turning {
                yaw_rate_dps: w.max_yaw.to_degrees(),
                lateral_acc_mps2: w.max_lat,
            });
        }
        // Travel direction against the body heading at the start: +1 when the walk
        // goes nose-first (forward drive, forward in time), -1 otherwise.
        let along = w.end.x * self.heading.0 + w.end.y * self.heading.1;
        let sign = if along >= 0.0 { 1.0 } else { -1.0 };
        let height = w.end.z;
        let slope_rad = (sign * height).atan2(w.len);
        // Largest distance of the walked path from the chord joining its ends (Fig.
        // 11), the part checked past the window included.
        let track = &self.track[..w.points.clamp(1, self.track.len())];
        let (xl, zl) = track.last().copied().unwrap_or((w.len, height));
        let norm = xl.hypot(zl).max(1e-9);
        let dev = track
            .iter()
            .map(|&(x, z)| (z * xl - x * zl).abs() / norm)
            .fold(0.0, f64::max);
        // A bend limit below what the noise alone leaves would refuse straight roads
        // at random, the more the slower the walk; but a shorter path may bend no
        // further than what tilts its chord as much as the whole window's limit tilts
        // its own (that limit times the share of the length, the square root of
        // `limit_share`).
        let noise_m = (s.noise_chord_m * w.duration_s.powf(1.5))
            .min(s.max_chord_deviation_m * w.limit_share.sqrt());
        if dev > (s.max_chord_deviation_m * w.limit_share).max(noise_m) {
            return Err(RejectReason::SlopeNotConstant {
                chord_deviation_m: dev,
            });
        }
        // A path bent by more than `velocity_free_max_chord_m` may hold a grade change,
        // which the velocity-free fit would partly read as a start velocity.
        let fit = w
            .fit_slope
            .filter(|_| s.velocity_free && dev <= s.velocity_free_max_chord_m * w.limit_share);
        // The axle point is a chord too, from the same rest.
        let axle = self.axle.filter(|_| fit.is_none());
        // The bias walk's height read as the slope reads the walk's: through the same
        // fit, or over the same chord.
        let chord_per_height = |slope: f64, len: f64| sign * slope.cos().powi(2) / len.max(1e-9);
        let (zb, int_zb) = w.bias;
        let (slope_rad, slope_per_bias_x) = match fit {
            Some((fitted, sx)) if sx.abs() > 1e-9 => (
                fitted,
                fitted.cos().powi(2) / sx * (w.duration_s * zb - 2.0 * int_zb),
            ),
            Some((fitted, _)) => (fitted, 0.0),
            None => (slope_rad, chord_per_height(slope_rad, w.len) * zb),
        };
        let per_s = 1.0 / w.duration_s.max(1e-9);
        Ok(WindowGeometry {
            slope_rad,
            slope_per_bias_x,
            distance_m: w.len,
            duration_s: w.duration_s,
            start_s: self.t_start_s,
            chord_deviation_m: dev,
            max_yaw_rate_rps: w.max_yaw,
            max_lateral_acc_mps2: w.max_lat,
            mean_pitch_rad: w.ints.0 * per_s,
            mean_accel_mps2: w.ints.1 * per_s,
            // A backward walk goes tail-first: its path points against the travel.
            travel_yaw_rad: (sign * w.body_path.1).atan2(sign * w.body_path.0),
            start_up_y: (s.q0.inverse() * Vector3::z()).y,
            rest_centre_pitch_rad: None,
            axle: axle.map(|(z, len, pitch_rad, accel_mps2)| {
                let slope_rad = (sign * z).atan2(len);
                AxlePoint {
                    slope_rad,
                    pitch_rad,
                    accel_mps2,
                    slope_per_bias_x: chord_per_height(slope_rad, len) * self.bias.at_axle,
                }
            }),
        })
    }
}

/// The part of a walk a window is judged on.
#[derive(Debug, Clone, Copy)]
struct Span {
    end: Vector3<f64>,
    len: f64,
    duration_s: f64,
    fit_slope: Option<(f64, f64)>,
    /// Integrals of pitch and acceleration over the span (see `WindowGeometry`).
    ints: (f64, f64),
    /// Track points up to the end of the straightness check.
    points: usize,
    max_yaw: f64,
    max_lat: f64,
    /// Path along and across the IMU's heading (see `WindowIntegrator::body_path`).
    body_path: (f64, f64),
    /// The bias walk's height at the span's end and its time integral.
    bias: (f64, f64),
    /// Share of the chord limits that applies.
    limit_share: f64,
}

#[cfg(test)]
mod tests {
    use super::super::attitude::attitude_from_gravity;
    use super::*;
    const G: f64 = 9.80665;

    fn setup(q0: UnitQuaternion<f64>) -> WindowSetup {
        WindowSetup {
            q0,
            reference_q: q0,
            gyro_bias_rps: Vector3::zeros(),
            acc_bias_mps2: Vector3::zeros(),
            gravity_mps2: G,
            lever_arm_m: Vector3::zeros(),
            distance_m: 2.0,
            check_extra_m: 0.0,
            max_time_s: 10.0,
            max_gap_s: 0.1,
            max_yaw_rate_rps: 0.05,
            max_lateral_acc_mps2: 0.5,
            max_chord_deviation_m: 0.01,
            noise_chord_m: 0.0,
            velocity_free: true,
            velocity_free_max_chord_m: 0.006,
            short_share: 0.0,
            axle_m: 0.0,
        }
    }

    /// On one plane the axle point is the road's slope, the body has not turned, and
    /// the acceleration there is the walk's along its level heading; a window that
    /// keeps the velocity-free slope notes none.
    #[test]
    fn the_axle_point_is_noted_one_wheelbase_out_on_a_chord_window() {
        let (slope, mount, a) = (4.0_f64.to_radians(), 0.7_f64.to_radians(), 1.5);
        let q0 = attitude_from_gravity(&specific_force(slope, mount, 0.0)).unwrap();
        for velocity_free in [false, true] {
            let mut w = WindowIntegrator::with_capacity(2000);
            let setup = WindowSetup {
                axle_m: 1.5,
                velocity_free,
                ..setup(q0)
            };
            w.start(setup, Vector3::zeros());
            let mut out = None;
            for k in 0..1000 {
                let s = ImuSample::new(
                    k as f64 * 0.01,
                    specific_force(slope, mount, a).into(),
                    [0.0; 3],
                );
                if let Step::Done(r) = w.push(&s) {
                    out = Some(r.unwrap());
                    break;
                }
            }
            let g = out.expect("window must complete");
            if velocity_free {
                assert_eq!(g.axle, None);
                continue;
            }
            let p = g.axle.expect("a chord window notes its axle point");
            assert!(
                (p.slope_rad - slope).abs() < 1e-6,
                "{} deg",
                p.slope_rad.to_degrees()
            );
            assert!((p.pitch_rad - pitch_of(&q0)).abs() < 1e-9);
            // Along the level heading, as the grade's pitch is learnt.
            assert!(
                (p.accel_mps2 - a * slope.cos()).abs() < 1e-6,
                "{} m/s^2",
                p.accel_mps2
            );
        }
    }

    /// The slope's answer to the x bias, as the walk reports it, is what walking the
    /// same samples again with more bias removed (the reference and gravity taken
    /// again from the rest with it) gives, less the reference's tilt: on a body that
    /// squats as it pulls away, for the fitted slope, the chord and the axle point;
    /// and on one that starts the walk already turned from where the reference was
    /// measured (a stop's dive carried back by the gyro), which the bias follows too.
    #[test]
    fn the_slope_answers_the_x_bias_as_the_body_turned_from_the_reference() {
        let (slope, mount, a, bias) = (3.0_f64.to_radians(), 0.5_f64.to_radians(), 1.0, 0.2);
        let full = 0.3_f64.to_radians() * a;
        let db = 0.01;
        for start in [0.0, 0.4_f64.to_radians()] {
            // A squat from `start` to 0.3 deg per m/s^2 coming in over 0.4 s.
            let squat = |t: f64| start + (full - start) * (1.0 - (-t / 0.4).exp());
            let rate = |t: f64| (full - start) / 0.4 * (-t / 0.4).exp();
            let sample = |t: f64, a: f64, pitch: f64| {
                let f = specific_force(slope, mount + pitch, a) + Vector3::x() * bias;
                ImuSample::new(t, f.into(), [0.0, -rate(t).to_degrees(), 0.0])
            };
            let walk = |b: f64, velocity_free: bool| {
                let rest = Vector3::from(sample(0.0, 0.0, 0.0).acc_mps2) - Vector3::x() * b;
                let reference_q = attitude_from_gravity(&rest).unwrap();
                let q0 = reference_q * UnitQuaternion::from_axis_angle(&Vector3::y_axis(), -start);
                let mut w = WindowIntegrator::with_capacity(2000);
                let setup = WindowSetup {
                    reference_q,
                    acc_bias_mps2: Vector3::x() * b,
                    gravity_mps2: rest.norm(),
                    axle_m: 1.5,
                    velocity_free,
                    ..setup(q0)
                };
                w.start(setup, Vector3::zeros());
                for k in 0..1000 {
                    let t = k as f64 * 0.01;
                    if let Step::Done(r) = w.push(&sample(t, a, squat(t))) {
                        return (r.expect("window must be accepted"), pitch_of(&reference_q));
                    }
                }
                panic!("window must complete");
            };
            for velocity_free in [true, false] {
                let ((g1, p1), (g2, p2)) =
                    (walk(0.1, velocity_free), walk(0.1 + db, velocity_free));
                let tilt = p2 - p1;
                assert!(tilt.abs() > 5e-4, "the reference tilts by about db / g");
                let mut pairs = vec![(g2.slope_rad - g1.slope_rad - tilt, g1.slope_per_bias_x)];
                if let (Some(x1), Some(x2)) = (g1.axle, g2.axle) {
                    pairs.push((x2.slope_rad - x1.slope_rad - tilt, x1.slope_per_bias_x));
                }
                assert_eq!(pairs.len(), if velocity_free { 1 } else { 2 });
                for (moved, per_bias) in pairs {
                    // The squat turns x up, so more bias removed lowers the path ahead:
                    // about the mean squat over the walk per m/s^2.
                    assert!(per_bias < -0.5 * full, "{velocity_free}: {per_bias}");
                    assert!(
                        (moved - db * per_bias).abs() < 0.02 * (db * per_bias).abs(),
                        "{start} {velocity_free}: walked again {moved}, predicted {}",
                        db * per_bias
                    );
                }
            }
        }
    }

    /// Specific force of a rigid body pitched by `pitch` (road slope + mounting pitch)
    /// accelerating at `a` along a road of slope `slope`.
    fn specific_force(slope: f64, mount: f64, a: f64) -> Vector3<f64> {
        // Navigation-frame acceleration plus gravity reaction, rotated into the body.
        let acc_n = Vector3::new(a * slope.cos(), 0.0, a * slope.sin() + G);
        let q = UnitQuaternion::from_axis_angle(&Vector3::y_axis(), -(slope + mount));
        q.inverse() * acc_n
    }

    #[test]
    fn constant_acceleration_on_known_slope() {
        for &(slope_deg, mount_deg, a) in &[
            (0.0, 0.0, 2.0),
            (5.71, 0.0, 1.0),
            (-2.86, 1.0, 3.0),
            (8.0, -0.5, 2.0),
        ] {
            let (slope, mount) = (f64::to_radians(slope_deg), f64::to_radians(mount_deg));
            let q0 = attitude_from_gravity(&specific_force(slope, mount, 0.0)).unwrap();
            let mut w = WindowIntegrator::with_capacity(2000);
            w.start(setup(q0), Vector3::zeros());
            let mut out = None;
            for k in 0..1000 {
                let t = k as f64 * 0.01;
                let s = ImuSample::new(t, specific_force(slope, mount, a).into(), [0.0; 3]);
                if let Step::Done(r) = w.push(&s) {
                    out = Some(r);
                    break;
                }
            }
            let g = out
                .expect("window must complete")
                .expect("window must be accepted");
            assert!(
                (g.slope_rad - slope).abs() < 1e-9,
                "slope {} vs {}",
                g.slope_rad,
                slope
            );
            // 2 m along the road from rest at a: t = sqrt(2 d / a), within one sample.
            let t_expect = (2.0 * 2.0 / slope.cos() / a).sqrt();
            assert!(
                (g.duration_s - t_expect).abs() <= 0.011,
                "{} vs {}",
                g.duration_s,
                t_expect
            );
        }
    }

    #[test]
    fn a_start_velocity_the_walk_does_not_know_leaves_the_velocity_free_slope_exact() {
        // A gentle drive-off (0.4 m/s^2) up a 3 % road, walked from a start velocity of
        // 5 mm/s up that the IMU did not have (a rocking tail mistaken at the start).
        let (slope, a) = (0.03f64.atan(), 0.4);
        let q0 = attitude_from_gravity(&specific_force(slope, 0.0, 0.0)).unwrap();
        let walk = |velocity_free: bool| {
            let mut w = WindowIntegrator::with_capacity(2000);
            w.start(
                WindowSetup {
                    velocity_free,
                    ..setup(q0)
                },
                Vector3::new(0.0, 0.0, 0.005),
            );
            for k in 0..1000 {
                let s = ImuSample::new(
                    k as f64 * 0.01,
                    specific_force(slope, 0.0, a).into(),
                    [0.0; 3],
                );
                if let Step::Done(r) = w.push(&s) {
                    return r.expect("window must be accepted").slope_rad;
                }
            }
            panic!("window must complete");
        };
        let fitted = walk(true);
        assert!((fitted - slope).abs() < 1e-9, "{}", fitted.to_degrees());
        // The chord to the end point carries 5 mm/s over about 3.2 s across 2 m.
        let chord_err = (walk(false) - slope).to_degrees();
        assert!((chord_err - 0.45).abs() < 0.05, "{chord_err}");
    }

    #[test]
    fn backward_walk_of_deceleration_gives_same_slope() {
        let slope = f64::to_radians(4.0);
        let q0 = attitude_from_gravity(&specific_force(slope, 0.0, 0.0)).unwrap();
        let mut w = WindowIntegrator::with_capacity(2000);
        w.start(setup(q0), Vector3::zeros());
        // Braking at 2 m/s^2 into the stop: walking back in time from the stop the
        // specific force carries the braking deceleration.
        let mut res = None;
        for k in 0..1000 {
            let t = -(k as f64) * 0.01;
            let s = ImuSample::new(t, specific_force(slope, 0.0, -2.0).into(), [0.0; 3]);
            if let Step::Done(r) = w.push(&s) {
                res = Some(r);
                break;
            }
        }
        let g = res.unwrap().unwrap();
        assert!(
            (g.slope_rad - slope).abs() < 1e-9,
            "{}",
            g.slope_rad.to_degrees()
        );
    }

    #[test]
    fn slope_change_inside_window_is_rejected() {
        // Level for 0.8 m, a vertical curve up to 6 % by 1.2 m, then 6 %: the chord test must see it.
        match walk_into_a_rise(0.8, 0.0, 0.0) {
            Err(RejectReason::SlopeNotConstant { chord_deviation_m }) => {
                assert!(chord_deviation_m > 0.015, "{chord_deviation_m}")
            }
            other => panic!("expected rejection, got {other:?}"),
        }
    }

    /// Walk a 2 m window of a drive-off at 1 m/s^2 over a road that is level up to `s0`
    /// and rises into a 6 % grade over the next 0.4 m, checked `check_extra_m` further,
    /// with the short fallback at `short_share`.
    fn walk_into_a_rise(
        s0: f64,
        check_extra_m: f64,
        short_share: f64,
    ) -> Result<WindowGeometry, RejectReason> {
        let q0 = attitude_from_gravity(&specific_force(0.0, 0.0, 0.0)).unwrap();
        let setup = WindowSetup {
            short_share,
            check_extra_m,
            ..setup(q0)
        };
        let top = 0.06f64.atan();
        walk_drive_off(setup, 1.0, |s| {
            let gam = top * ((s - s0) / 0.4).clamp(0.0, 1.0);
            let dgam_ds = if (s0..s0 + 0.4).contains(&s) {
                top / 0.4
            } else {
                0.0
            };
            (gam, dgam_ds)
        })
    }

    /// Walk a drive-off at `a` m/s^2 from rest with `setup` over a road of slope
    /// `slope(s)` (rad, and its derivative per m) that the body follows exactly, on
    /// exact 100 Hz samples, until the window is done.
    fn walk_drive_off(
        setup: WindowSetup,
        a: f64,
        slope: impl Fn(f64) -> (f64, f64),
    ) -> Result<WindowGeometry, RejectReason> {
        let mut w = WindowIntegrator::with_capacity(4000);
        w.start(setup, Vector3::zeros());
        for k in 0..4000 {
            let t = k as f64 * 0.01;
            let (s, v) = (0.5 * a * t * t, a * t);
            let (gam, dgam_ds) = slope(s);
            // Tangential plus centripetal acceleration along the vertical curve.
            let tan = Vector3::new(gam.cos(), 0.0, gam.sin());
            let nrm = Vector3::new(-gam.sin(), 0.0, gam.cos());
            let acc_n = tan * a + nrm * (v * v * dgam_ds) + Vector3::new(0.0, 0.0, G);
            let q = UnitQuaternion::from_axis_angle(&Vector3::y_axis(), -gam);
            let rate_dps = [0.0, -(dgam_ds * v).to_degrees(), 0.0];
            if let Step::Done(r) =
                w.push(&ImuSample::new(t, (q.inverse() * acc_n).into(), rate_dps))
            {
                return r;
            }
        }
        panic!("window must complete");
    }

    #[test]
    fn a_rise_past_the_first_half_leaves_the_straight_half_as_a_window() {
        // 2 m windows checked 0.5 m further; the rise begins 1.4 m out.
        assert!(matches!(
            walk_into_a_rise(1.4, 0.5, 0.0),
            Err(RejectReason::SlopeNotConstant { .. })
        ));
        let g = walk_into_a_rise(1.4, 0.5, 0.5).expect("the first metre is straight");
        assert!((g.distance_m - 1.0).abs() < 0.02, "{}", g.distance_m);
        assert!(g.slope_rad.abs() < 1e-6, "{}", g.slope_rad.to_degrees());
        // A rise inside the first half leaves no straight part.
        assert!(matches!(
            walk_into_a_rise(0.6, 0.5, 0.5),
            Err(RejectReason::SlopeNotConstant { .. })
        ));
    }

    /// Walk a 3 m window (checked 1 m further, with the half-window fallback) of a
    /// drive-off at 0.4 m/s^2 over a road of slope `slope(s)`, with the chord noise
    /// floor `noise_chord_m`.
    fn walk_road(
        slope: impl Fn(f64) -> (f64, f64),
        noise_chord_m: f64,
    ) -> Result<WindowGeometry, RejectReason> {
        let q0 = attitude_from_gravity(&specific_force(0.0, 0.0, 0.0)).unwrap();
        let setup = WindowSetup {
            distance_m: 3.0,
            check_extra_m: 1.0,
            max_chord_deviation_m: 0.012,
            short_share: 0.5,
            noise_chord_m,
            ..setup(q0)
        };
        walk_drive_off(setup, 0.4, slope)
    }

    #[test]
    fn a_half_window_is_refused_for_no_less_than_the_noise_bends_it_and_no_more_than_a_whole_one() {
        // A hump of `h` over the first 1.5 m (what a noisy walk may show), a speed
        // bump's 6 % rise from 1.6 m: the whole window bends, its first half is tried.
        let road = |h: f64| {
            move |s: f64| {
                let k = std::f64::consts::PI / 1.5;
                if s < 1.5 {
                    // z = h sin^2(k s): slope h k sin(2 k s), its derivative 2 h k^2 cos(2 k s).
                    let dz = h * k * (2.0 * k * s).sin();
                    (dz.atan(), 2.0 * h * k * k * (2.0 * k * s).cos())
                } else if s < 1.6 {
                    (0.0, 0.0)
                } else if s < 2.0 {
                    (0.06f64.atan() * (s - 1.6) / 0.4, 0.06f64.atan() / 0.4)
                } else {
                    (0.06f64.atan(), 0.0)
                }
            }
        };
        // 1.5 m at 0.4 m/s^2 takes 2.74 s; 300 ug/sqrt(Hz) leaves 5.8 mm at 3 sigma.
        let noise = 3.0 * 300e-6 * G / 48f64.sqrt();
        // 4.5 mm: beyond the half window's bend limit (3 mm), within the noise.
        assert!(matches!(
            walk_road(road(0.0045), 0.0),
            Err(RejectReason::SlopeNotConstant { .. })
        ));
        let g = walk_road(road(0.0045), noise).expect("a hump the noise could make");
        assert!((g.distance_m - 1.5).abs() < 0.02, "{}", g.distance_m);
        assert!(g.slope_rad.abs() < 1e-3, "{}", g.slope_rad.to_degrees());
        // 7 mm tilts a 1.5 m chord further than 12 mm tilts 3 m: refused at any noise.
        assert!(matches!(
            walk_road(road(0.007), 1.0),
            Err(RejectReason::SlopeNotConstant { .. })
        ));
    }

    /// A drive-off at 0.5 m/s^2 on a plane rising `grade` along the starting heading and
    /// `crossfall` to its left, steering into a turn of curvature `kappa` (1/m, ramped
    /// in over 1 m) from 0.3 m on, walked as a 3 m window with no turn limit. Exact
    /// samples at 100 Hz from an IMU yawed by `mount_yaw` (rad) on the body. Returns
    /// the slope error against the grade along the starting heading and the heading
    /// change over the window, deg, and the window.
    fn turning_walk(
        grade: f64,
        crossfall: f64,
        kappa: f64,
        mount_yaw: f64,
    ) -> (f64, f64, WindowGeometry) {
        let (a, h, every) = (0.5, 0.0005, 20);
        let heading_at = |s: f64| {
            // Heading after `s` m: the curvature ramps in over 1 m from 0.3 m.
            let ramp = (s - 0.3).clamp(0.0, 1.0);
            kappa * (0.5 * ramp * ramp + (s - 1.3).max(0.0))
        };
        let (mut x, mut y, mut s_prev) = (0.0f64, 0.0f64, 0.0f64);
        let mut states = Vec::new();
        for k in 0..12_000 {
            let t = k as f64 * h;
            let s = 0.5 * a * t * t;
            let psi = heading_at(s);
            x += (s - s_prev) * psi.cos();
            y += (s - s_prev) * psi.sin();
            s_prev = s;
            let along = grade * psi.cos() + crossfall * psi.sin();
            let left = -grade * psi.sin() + crossfall * psi.cos();
            let q = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), psi)
                * UnitQuaternion::from_axis_angle(&Vector3::y_axis(), -along.atan())
                * UnitQuaternion::from_axis_angle(&Vector3::x_axis(), left.atan());
            let imu = q * UnitQuaternion::from_axis_angle(&Vector3::z_axis(), mount_yaw);
            states.push((Vector3::new(x, y, grade * x + crossfall * y), imu, psi));
        }
        let up = Vector3::new(0.0, 0.0, G);
        let q0 = attitude_from_gravity(&(states[0].1.inverse() * up)).unwrap();
        let mut w = WindowIntegrator::with_capacity(2000);
        w.start(
            WindowSetup {
                distance_m: 3.0,
                max_yaw_rate_rps: 1e3,
                max_lateral_acc_mps2: 1e3,
                max_chord_deviation_m: 1.0,
                ..setup(q0)
            },
            Vector3::zeros(),
        );
        w.push(&ImuSample::new(
            0.0,
            (states[0].1.inverse() * up).into(),
            [0.0; 3],
        ));
        for k in (every..states.len() - 1).step_by(every) {
            let (p, q, _) = states[k];
            let acc = (states[k + 1].0 - p * 2.0 + states[k - 1].0) / (h * h);
            let rate = (states[k - 1].1.inverse() * states[k + 1].1).scaled_axis() / (2.0 * h);
            let s = ImuSample::new(
                k as f64 * h,
                (q.inverse() * (acc + up)).into(),
                rate.map(f64::to_degrees).into(),
            );
            if let Step::Done(r) = w.push(&s) {
                let g = r.expect("window must be accepted");
                let end = (g.duration_s / h).round() as usize;
                return (
                    (g.slope_rad - grade.atan()).to_degrees(),
                    states[end].2.to_degrees(),
                    g,
                );
            }
        }
        panic!("the window must complete");
    }

    #[test]
    fn a_turn_is_walked_exactly_but_on_a_crossfall_it_reads_the_slope_of_another_heading() {
        // Turning on a plane that falls along the drive only, or driving straight across
        // a crossfall: the walk is exact.
        let (err, turned, _) = turning_walk(0.03, 0.0, 1.0 / 15.0, 0.0);
        assert!(turned > 5.0, "{turned}");
        assert!(err.abs() < 0.002, "{err}");
        let (err, _, _) = turning_walk(0.03, 0.025, 0.0, 0.0);
        assert!(err.abs() < 0.002, "{err}");
        // A turn at a junction with 2.5 % crossfall: the walk measures part of the
        // crossfall as slope, which is why turning windows are rejected.
        let (err, turned, _) = turning_walk(0.03, 0.025, 1.0 / 15.0, 0.0);
        assert!(
            turned > 5.0 && err > 0.1,
            "{turned} deg turn, {err} deg error"
        );
        let (mirrored, _, _) = turning_walk(0.03, -0.025, 1.0 / 15.0, 0.0);
        assert!((mirrored + err).abs() < 0.002, "{mirrored} against {err}");
    }

    #[test]
    fn the_travel_is_found_in_the_frame_of_an_imu_yawed_on_its_mount() {
        // Body forward lies at minus the mount's yaw in the IMU's frame, straight or
        // turning (the IMU turns with the path), and the roll of the crossfall shows in
        // the IMU's up at the start.
        for (kappa, yaw_deg) in [(0.0, 1.5), (0.0, -0.8), (1.0 / 15.0, 1.5)] {
            let (_, _, g) = turning_walk(0.03, 0.025, kappa, f64::to_radians(yaw_deg));
            let travel = g.travel_yaw_rad.to_degrees();
            assert!(
                (travel + yaw_deg).abs() < 0.01,
                "{kappa}: {travel} for {yaw_deg}"
            );
            // Up leans to the low side: the IMU's y axis (left) is raised by the roll.
            let roll = g.start_up_y.asin().to_degrees();
            assert!((roll - 0.025f64.atan().to_degrees()).abs() < 0.05, "{roll}");
        }
    }

    #[test]
    fn gap_breaks_window() {
        let mut w = WindowIntegrator::with_capacity(100);
        w.start(setup(UnitQuaternion::identity()), Vector3::zeros());
        assert_eq!(
            w.push(&ImuSample::new(0.0, [0.0, 0.0, G], [0.0; 3])),
            Step::Continue
        );
        assert!(matches!(
            w.push(&ImuSample::new(0.5, [0.0, 0.0, G], [0.0; 3])),
            Step::Done(Err(RejectReason::ImuGap { .. }))
        ));
    }
}
