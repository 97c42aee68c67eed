//! What a simulated drive is: speed profile, road, load, vehicle and sensors.

use serde::{Deserialize, Serialize};

/// One piece of the speed profile: constant acceleration for a duration.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SpeedSegment {
    pub duration_s: f64,
    /// Longitudinal acceleration along the road, m/s^2.
    pub accel_mps2: f64,
}

/// Speed profile built from segments; speed never goes below zero.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct SpeedProfile {
    pub segments: Vec<SpeedSegment>,
}

impl SpeedProfile {
    pub fn hold(mut self, duration_s: f64) -> Self {
        self.segments.push(SpeedSegment {
            duration_s,
            accel_mps2: 0.0,
        });
        self
    }
    pub fn accel(mut self, accel_mps2: f64, duration_s: f64) -> Self {
        self.segments.push(SpeedSegment {
            duration_s,
            accel_mps2,
        });
        self
    }
    /// Stop, accelerate at `a` to `v_max`, cruise, brake at `b` to a stop, stop.
    pub fn stop_go(self, hold_s: f64, a: f64, v_max: f64, cruise_s: f64, b: f64) -> Self {
        let s = self.hold(hold_s).accel(a, v_max / a);
        let s = if cruise_s > 0.0 { s.hold(cruise_s) } else { s };
        s.accel(-b, v_max / b)
    }
    pub fn duration_s(&self) -> f64 {
        self.segments.iter().map(|s| s.duration_s).sum()
    }
}

/// Road geometry as functions of travelled distance.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Road {
    /// (distance m, grade angle deg) knots; linear between them, constant outside.
    /// Empty means level.
    pub grade_deg: Vec<(f64, f64)>,
    /// (from m, to m, curvature 1/m, positive turning left).
    pub curves: Vec<(f64, f64, f64)>,
    /// Curvature ramps in (and out) linearly over this distance at each end of a curve,
    /// as a driver turns the wheel in; 0 is a step, m.
    #[serde(default)]
    pub curve_ramp_m: f64,
    /// Unevenness on top of the grade, felt through the suspension (none by default).
    #[serde(default)]
    pub roughness: super::roughness::Roughness,
    /// Cross slope of the lane, percent, positive falling to the right (the right lane
    /// of a crowned road): the body stands rolled by it.
    #[serde(default)]
    pub cross_slope_pct: f64,
}

impl Road {
    pub fn constant(grade_deg: f64) -> Self {
        Self {
            grade_deg: vec![(0.0, grade_deg)],
            curves: Vec::new(),
            curve_ramp_m: 0.0,
            roughness: Default::default(),
            cross_slope_pct: 0.0,
        }
    }

    /// Grade angle (rad) and its derivative along the road (rad/m) at distance `s`.
    pub fn grade(&self, s: f64) -> (f64, f64) {
        let k = &self.grade_deg;
        match k.len() {
            0 => (0.0, 0.0),
            _ if s <= k[0].0 => (k[0].1.to_radians(), 0.0),
            _ if s >= k[k.len() - 1].0 => (k[k.len() - 1].1.to_radians(), 0.0),
            _ => {
                let i = k.partition_point(|p| p.0 <= s) - 1;
                let (s0, g0) = k[i];
                let (s1, g1) = k[i + 1];
                let slope = (g1 - g0) / (s1 - s0);
                ((g0 + slope * (s - s0)).to_radians(), slope.to_radians())
            }
        }
    }

    /// Position along the road profile at distance `s`: (horizontal m, height m).
    /// Exact for the piecewise-linear grade (closed-form integrals of cos and sin).
    pub fn elevation(&self, s: f64) -> (f64, f64) {
        let k = &self.grade_deg;
        if k.is_empty() {
            return (s, 0.0);
        }
        // Piece from a to b with grade g(a) and constant derivative dg.
        let piece = |a: f64, b: f64| -> (f64, f64) {
            let (g0, dg) = self.grade(0.5 * (a + b));
            let g0 = g0 - dg * (0.5 * (b - a));
            let len = b - a;
            if dg.abs() < 1e-12 {
                (g0.cos() * len, g0.sin() * len)
            } else {
                let g1 = g0 + dg * len;
                ((g1.sin() - g0.sin()) / dg, (g0.cos() - g1.cos()) / dg)
            }
        };
        let mut edges: Vec<f64> = Vec::with_capacity(k.len() + 2);
        let (lo, hi) = (s.min(0.0), s.max(0.0));
        edges.push(lo);
        edges.extend(k.iter().map(|p| p.0).filter(|&x| x > lo && x < hi));
        edges.push(hi);
        let (mut x, mut z) = (0.0, 0.0);
        for w in edges.windows(2) {
            let (dx, dz) = piece(w[0], w[1]);
            x += dx;
            z += dz;
        }
        if s < 0.0 { (-x, -z) } else { (x, z) }
    }

    /// Curvature (1/m) and heading (rad) at distance `s`.
    pub fn heading(&self, s: f64) -> (f64, f64) {
        let mut psi = 0.0;
        let mut kappa = 0.0;
        for &(a, b, k) in &self.curves {
            // Trapezoidal curvature: ramps of length r at both ends (r = 0: a step).
            let r = self.curve_ramp_m.clamp(0.0, 0.5 * (b - a).max(0.0));
            let kap = |x: f64| {
                if x <= a || x >= b {
                    0.0
                } else if r > 0.0 && x < a + r {
                    k * (x - a) / r
                } else if r > 0.0 && x > b - r {
                    k * (b - x) / r
                } else {
                    k
                }
            };
            // Heading gained from a to x: integral of the trapezoid.
            let gained = |x: f64| {
                let x = x.clamp(a, b);
                if r <= 0.0 {
                    return k * (x - a);
                }
                let up = (x - a).min(r);
                let mut p = k * up * up / (2.0 * r);
                if x > a + r {
                    p += k * (x.min(b - r) - (a + r)).max(0.0);
                }
                if x > b - r {
                    let d = b - x;
                    p += k * (r * r - d * d) / (2.0 * r);
                }
                p
            };
            if s > a {
                psi += gained(s);
            }
            kappa += kap(s);
        }
        (kappa, psi)
    }

    /// Mean slope (rad) of the road between distances `s0` and `s1` (chord of the profile).
    pub fn chord_slope(&self, s0: f64, s1: f64) -> f64 {
        let (lo, hi) = if s0 <= s1 { (s0, s1) } else { (s1, s0) };
        let n = 400;
        let ds = (hi - lo) / n as f64;
        let (mut x, mut z) = (0.0, 0.0);
        for i in 0..n {
            let g = self.grade(lo + (i as f64 + 0.5) * ds).0;
            x += g.cos() * ds;
            z += g.sin() * ds;
        }
        z.atan2(x)
    }
}

/// Vehicle body and IMU mounting.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct Vehicle {
    /// IMU position relative to the body pitch centre, body axes (x fwd, y left, z up), m.
    pub lever_arm_m: [f64; 3],
    /// Steady body pitch per longitudinal acceleration, deg per m/s^2 (nose-up when accelerating).
    pub pitch_per_accel_deg: f64,
    /// The body's pitch per m/s^2 of forward force from the drivetrain (pulling away,
    /// driving uphill) as a share of its dive per m/s^2 of braking. Anti-squat and
    /// anti-dive geometry differ, and a driven axle reacts its torque otherwise than
    /// the brakes on both axles do, so a car squats less or more than it dives (1:
    /// alike). Held by its brakes at rest on a grade, it pitches as it brakes.
    pub squat_share: f64,
    /// The body pitches with the whole longitudinal force the tyres pass to it, which on
    /// a grade holds gravity's share along the road: a car at rest facing uphill squats
    /// as if pulling away at g sin(grade). Off, only the acceleration pitches it.
    pub pitch_from_grade: bool,
    /// A load change moves the body through its pitch mode, as any force on its springs
    /// does: a load put in quickly makes it overshoot and rock before it settles. Off,
    /// the body follows the load's pitch exactly.
    pub load_through_suspension: bool,
    /// Natural frequency of the body pitch mode, Hz.
    pub pitch_freq_hz: f64,
    /// Damping ratio of the body pitch mode.
    pub pitch_damping: f64,
    /// Natural frequency (Hz) and damping ratio of the body's heave mode, through which
    /// it follows road unevenness (the pitch mode above does so for pitch).
    pub heave_freq_hz: f64,
    pub heave_damping: f64,
    /// Heave of the body per m/s^2 of the longitudinal force that pitches it, mm,
    /// positive rising when pulling away; it follows through the heave mode. The
    /// suspension's geometry (anti-dive, anti-squat) and a stiffness balance that does
    /// not put the pitch node under the centre of mass make the body rise or sink as it
    /// pitches, so under a steady force it turns about another point than it rocks about
    /// when it swings free.
    pub heave_per_accel_mm: f64,
    /// Track width for wheel-speed differences in turns, m.
    pub track_m: f64,
    /// Distance between the axles, m; the body pitch follows the road chord between them.
    pub wheelbase_m: f64,
    /// Rough-road vertical vibration at the IMU at 50 km/h (zero-mean 8-14 Hz), m/s^2.
    pub rough_road_mps2: f64,
    /// Longitudinal structural vibration at the IMU as a share of the vertical one.
    pub rough_road_long_share: f64,
    /// Engine vibration at the IMU, running at rest as in motion: rms of the vertical
    /// specific force (m/s^2, 0 for none, as in an electric car) at `idle_vibration_hz`;
    /// the longitudinal part is `rough_road_long_share` of it.
    pub idle_vibration_mps2: f64,
    pub idle_vibration_hz: f64,
    /// IMU mounting misalignment to the body: roll, pitch, yaw, deg. The IMU pitch
    /// adds to what leveld measures (road-to-IMU); calibration takes it out.
    pub imu_mount_deg: [f64; 3],
    /// Drivers ramp the acceleration in over this time at each change of the speed
    /// profile (a jerk limit), except at the moment the car comes to rest, where the
    /// brake's deceleration ends at once, s. 0 gives steps everywhere.
    pub accel_ramp_s: f64,
}

impl Default for Vehicle {
    fn default() -> Self {
        Self {
            lever_arm_m: [2.0, 0.0, 0.3],
            pitch_per_accel_deg: 0.3,
            squat_share: 1.0,
            pitch_from_grade: true,
            load_through_suspension: false,
            pitch_freq_hz: 1.5,
            pitch_damping: 0.4,
            heave_freq_hz: 1.2,
            heave_damping: 0.3,
            heave_per_accel_mm: 0.0,
            track_m: 1.6,
            wheelbase_m: 2.7,
            rough_road_mps2: 0.0,
            rough_road_long_share: 0.0,
            idle_vibration_mps2: 0.0,
            idle_vibration_hz: 25.0,
            imu_mount_deg: [0.0; 3],
            accel_ramp_s: 0.0,
        }
    }
}

impl Vehicle {
    /// The paper's simulation: a rigid body with no pitch motion.
    pub fn rigid() -> Self {
        Self {
            pitch_per_accel_deg: 0.0,
            ..Self::default()
        }
    }
}

/// Sensor error models and rates.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Sensors {
    pub imu_rate_hz: f64,
    pub wheel_rate_hz: f64,
    /// Accelerometer white-noise density, micro-g per sqrt(Hz).
    pub acc_noise_ug_rthz: f64,
    /// Constant accelerometer bias per axis, m/s^2.
    pub acc_bias_mps2: [f64; 3],
    /// Accelerometer bias random walk, m/s^2 per sqrt(s).
    pub acc_bias_walk_mps2_rts: f64,
    /// The accelerometer's axes: row i is what channel i reads of a force along the
    /// IMU's x, y and z (identity: square axes of unit gain). `[2][0] = 0.005` is a z
    /// axis leaning 0.29 deg towards x.
    pub acc_axes: [[f64; 3]; 3],
    /// Gyro white-noise density, deg/s per sqrt(Hz).
    pub gyro_noise_dps_rthz: f64,
    /// Constant gyro bias per axis, deg/s.
    pub gyro_bias_dps: [f64; 3],
    /// Gyro bias random walk, deg/s per sqrt(s).
    pub gyro_bias_walk_dps_rts: f64,
    /// Wheel-speed resolution, km/h.
    pub wheel_quantum_kmh: f64,
    /// Wheel sensors read 0 below this speed, km/h.
    pub wheel_zero_below_kmh: f64,
    /// Speed the wheels report over the true speed: the ESC converts wheel turns with
    /// a nominal tyre circumference, and a worn tread (about 3 % smaller), the
    /// pressure or the load make the real one differ.
    pub wheel_scale: f64,
    /// Age of the speed a wheel frame carries when it is sent, s: an ESC derives it
    /// from tooth periods over a few tens of milliseconds and filters it.
    pub wheel_delay_s: f64,
    /// Probability that an IMU sample is lost.
    pub imu_drop_prob: f64,
    /// CAN arrival jitter of the IMU sample time, uniform in [min, max], ms.
    pub imu_jitter_ms: [f64; 2],
}

impl Default for Sensors {
    fn default() -> Self {
        Self {
            imu_rate_hz: 100.0,
            wheel_rate_hz: 50.0,
            acc_noise_ug_rthz: 300.0,
            acc_bias_mps2: [0.0; 3],
            acc_axes: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            acc_bias_walk_mps2_rts: 0.0,
            gyro_noise_dps_rthz: 0.01,
            gyro_bias_dps: [0.0; 3],
            gyro_bias_walk_dps_rts: 0.0,
            wheel_quantum_kmh: 0.03125,
            wheel_zero_below_kmh: 1.5,
            wheel_scale: 1.0,
            wheel_delay_s: 0.0,
            imu_drop_prob: 0.0,
            imu_jitter_ms: [0.0; 2],
        }
    }
}

/// `Ok` when `v` is finite and within `lo..=hi`; else an error naming `key`, its value
/// and `hint`.
pub(crate) fn in_range(key: &str, v: f64, lo: f64, hi: f64, hint: &str) -> anyhow::Result<()> {
    if v.is_finite() && (lo..=hi).contains(&v) {
        Ok(())
    } else {
        Err(anyhow::anyhow!("{key} = {v}: {hint}"))
    }
}

impl Sensors {
    /// Reject settings the simulator cannot run; the error names the key and its range.
    pub fn check(&self) -> anyhow::Result<()> {
        let [j0, j1] = self.imu_jitter_ms;
        #[rustfmt::skip]
        let checks = [
            ("imu_rate_hz", self.imu_rate_hz, 10.0, 2000.0, "give 10-2000 Hz"),
            ("wheel_rate_hz", self.wheel_rate_hz, 1.0, self.imu_rate_hz, "give 1 Hz up to the IMU's rate"),
            ("acc_noise_ug_rthz", self.acc_noise_ug_rthz, 0.0, 1e5, "give 0-100000"),
            ("gyro_noise_dps_rthz", self.gyro_noise_dps_rthz, 0.0, 100.0, "give 0-100"),
            ("acc_bias_walk_mps2_rts", self.acc_bias_walk_mps2_rts, 0.0, 10.0, "give 0-10"),
            ("gyro_bias_walk_dps_rts", self.gyro_bias_walk_dps_rts, 0.0, 100.0, "give 0-100"),
            ("wheel_quantum_kmh", self.wheel_quantum_kmh, 0.0, 10.0, "give 0-10 km/h"),
            ("wheel_zero_below_kmh", self.wheel_zero_below_kmh, 0.0, 30.0, "give 0-30 km/h"),
            ("wheel_scale", self.wheel_scale, 0.5, 2.0, "give 0.5-2 (a worn tread reads about 1.03)"),
            ("wheel_delay_s", self.wheel_delay_s, 0.0, 1.0, "give 0-1 s"),
            ("imu_drop_prob", self.imu_drop_prob, 0.0, 0.99, "give 0-0.99"),
            ("imu_jitter_ms[0]", j0, 0.0, 100.0, "give [min, max] within 0-100 ms"),
            ("imu_jitter_ms[1]", j1, j0, 100.0, "give [min, max] within 0-100 ms"),
        ];
        for (key, v, lo, hi, hint) in checks {
            in_range(&format!("sensors.{key}"), v, lo, hi, hint)?;
        }
        for (i, row) in self.acc_axes.iter().enumerate() {
            for (j, &v) in row.iter().enumerate() {
                let (lo, hi) = if i == j { (0.5, 1.5) } else { (-0.2, 0.2) };
                in_range(
                    &format!("sensors.acc_axes[{i}][{j}]"),
                    v,
                    lo,
                    hi,
                    "give 0.5-1.5 on the diagonal, -0.2..0.2 off it",
                )?;
            }
        }
        for axis in 0..3 {
            let (a, w) = (self.acc_bias_mps2[axis], self.gyro_bias_dps[axis]);
            in_range(
                &format!("sensors.acc_bias_mps2[{axis}]"),
                a,
                -50.0,
                50.0,
                "give -50..50 m/s^2",
            )?;
            in_range(
                &format!("sensors.gyro_bias_dps[{axis}]"),
                w,
                -500.0,
                500.0,
                "give -500..500 deg/s",
            )?;
        }
        Ok(())
    }

    /// `acc_axes` as a matrix: what the accelerometer reads of a force in the IMU's axes.
    pub fn acc_axes_matrix(&self) -> nalgebra::Matrix3<f64> {
        nalgebra::Matrix3::from_fn(|i, j| self.acc_axes[i][j])
    }

    /// Error-free sensors with ideal wheel speeds.
    pub fn ideal() -> Self {
        Self {
            acc_noise_ug_rthz: 0.0,
            gyro_noise_dps_rthz: 0.0,
            wheel_zero_below_kmh: 0.0,
            ..Self::default()
        }
    }
}

/// A complete drive to simulate.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Scenario {
    pub speed: SpeedProfile,
    #[serde(default)]
    pub road: Road,
    /// Road-to-body pitch of the load, deg, at the start.
    pub load_pitch_deg: f64,
    /// Load steps: (start time s, new road-to-body pitch deg, ramp duration s).
    #[serde(default)]
    pub load_changes: Vec<(f64, f64, f64)>,
    #[serde(default)]
    pub vehicle: Vehicle,
    #[serde(default)]
    pub sensors: Sensors,
    /// Door and boarding shocks at standstill: decaying body-pitch oscillations.
    #[serde(default)]
    pub shocks: Vec<Shock>,
    /// Spans without IMU samples: (start s, duration s).
    #[serde(default)]
    pub imu_gaps: Vec<(f64, f64)>,
    pub seed: u64,
}

/// A decaying body-pitch oscillation, such as a door slammed or a passenger boarding.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Shock {
    pub t_s: f64,
    pub amplitude_deg: f64,
    pub freq_hz: f64,
    /// Time constant of the exponential decay, s.
    pub decay_s: f64,
}

impl Shock {
    /// Pitch added at time `t`, rad.
    pub fn pitch_rad(&self, t: f64) -> f64 {
        if t < self.t_s {
            return 0.0;
        }
        let x = t - self.t_s;
        self.amplitude_deg.to_radians()
            * (-x / self.decay_s).exp()
            * (std::f64::consts::TAU * self.freq_hz * x).sin()
    }
}

impl Scenario {
    /// Road-to-body pitch of the load at time `t`, deg.
    pub fn load_pitch_deg_at(&self, t: f64) -> f64 {
        let mut p = self.load_pitch_deg;
        for &(t0, to, ramp) in &self.load_changes {
            if t >= t0 + ramp {
                p = to;
            } else if t > t0 {
                // Smoothstep: the body rotates without a jump in rate.
                let x = (t - t0) / ramp.max(1e-9);
                p += (to - p) * x * x * (3.0 - 2.0 * x);
            }
        }
        p
    }
}
