//! Generation of IMU and wheel-speed samples with ground truth.
//!
//! Kinematics run on a sub-grid five times the IMU rate. The body-pitch-centre
//! acceleration is analytic (tangential plus vertical and horizontal centripetal
//! terms); the IMU adds the lever-arm motion and the angular rate, both from central
//! differences on the sub-grid.

use super::noise::Gauss;
use super::scenario::{Scenario, Vehicle};
use crate::estimator::{ImuSample, WheelSpeeds};
use nalgebra::{UnitQuaternion, Vector3};
use serde::Serialize;

/// Standard gravity used by the simulator, m/s^2.
pub const G_MPS2: f64 = 9.80665;

/// Ground truth at one IMU sample time.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Truth {
    pub t_s: f64,
    /// Distance travelled along the road, m.
    pub s_m: f64,
    pub v_mps: f64,
    /// Road grade under the vehicle, deg.
    pub grade_deg: f64,
    /// Static road-to-body pitch of the load, deg (what leveld estimates).
    pub load_pitch_deg: f64,
    /// Body pitch from the suspension, deg: its answer to the car's acceleration and to
    /// the road's unevenness (at rest, the unevenness under the axles), and its swing
    /// about the load's static pitch while a load settles.
    pub suspension_deg: f64,
}

/// A simulated drive.
#[derive(Debug, Clone)]
pub struct Drive {
    pub imu: Vec<ImuSample>,
    pub wheels: Vec<WheelSpeeds>,
    /// One entry per IMU sample time (including dropped samples).
    pub truth: Vec<Truth>,
}

impl Drive {
    /// Truth nearest to time `t`.
    pub fn truth_at(&self, t: f64) -> &Truth {
        let i = self
            .truth
            .partition_point(|x| x.t_s < t)
            .min(self.truth.len() - 1);
        &self.truth[i]
    }

    /// Events in time order, merging IMU and wheel samples.
    pub fn merged(&self) -> impl Iterator<Item = Input> + '_ {
        let (mut i, mut w) = (0, 0);
        std::iter::from_fn(move || {
            let ni = self.imu.get(i);
            let nw = self.wheels.get(w);
            match (ni, nw) {
                (Some(a), Some(b)) if b.t_s <= a.t_s => {
                    w += 1;
                    Some(Input::Wheels(*b))
                }
                (Some(a), _) => {
                    i += 1;
                    Some(Input::Imu(*a))
                }
                (None, Some(b)) => {
                    w += 1;
                    Some(Input::Wheels(*b))
                }
                (None, None) => None,
            }
        })
    }
}

/// One estimator input.
#[derive(Debug, Clone, Copy)]
pub enum Input {
    Imu(ImuSample),
    Wheels(WheelSpeeds),
}

#[derive(Debug, Clone, Copy)]
struct Kin {
    q: UnitQuaternion<f64>,
    /// Pitch-centre acceleration, nav frame, m/s^2.
    acc: Vector3<f64>,
    lever: Vector3<f64>,
    truth: Truth,
    kappa: f64,
}

/// Commanded longitudinal acceleration at time `t` with the driver's ramps: each change
/// of the profile is spread linearly over `ramp_s` centred on it, except where braking
/// ends at rest, which stays a step. A ramp is narrowed to half of each segment it
/// touches, so ramps never overlap and every segment keeps its speed change: a stop
/// planned at rest is at rest (a creep of 0.1 s segments does not leave the car rolling).
/// Body-to-IMU rotation of an IMU mounted at `[roll, pitch, yaw]` deg: the IMU frame
/// is the body frame turned by yaw, then pitch (nose-up), then roll.
fn body_to_imu(mount_deg: &[f64; 3]) -> UnitQuaternion<f64> {
    let [mr, mp, my] = mount_deg.map(f64::to_radians);
    (UnitQuaternion::from_axis_angle(&Vector3::z_axis(), my)
        * UnitQuaternion::from_axis_angle(&Vector3::y_axis(), -mp)
        * UnitQuaternion::from_axis_angle(&Vector3::x_axis(), mr))
    .inverse()
}

/// What an end-of-line station reads as the IMU's pitch and roll with the car at rest
/// on a level floor under its first load, deg: the pitch (of its x axis) and the
/// elevation of its y axis from the force it measures there, its accelerometer bias at
/// the start of the drive included.
pub fn floor_attitude_deg(sc: &Scenario) -> (f64, f64) {
    let body = UnitQuaternion::from_axis_angle(
        &Vector3::y_axis(),
        -sc.load_pitch_deg_at(0.0).to_radians(),
    );
    let f = sc.sensors.acc_axes_matrix()
        * (body_to_imu(&sc.vehicle.imu_mount_deg) * (body.inverse() * Vector3::z() * G_MPS2))
        + Vector3::from(sc.sensors.acc_bias_mps2);
    let n = f.norm();
    ((f.x / n).asin().to_degrees(), (f.y / n).asin().to_degrees())
}

/// The roll of [`floor_attitude_deg`], deg.
pub fn floor_roll_deg(sc: &Scenario) -> f64 {
    floor_attitude_deg(sc).1
}

fn ramped_accel(segs: &[super::scenario::SpeedSegment], ramp_s: f64, t: f64) -> f64 {
    let ramps = |a: f64, b: f64| ramp_s > 0.0 && !(a < 0.0 && b == 0.0) && a != b;
    let half_between = |d0: f64, d1: f64| (0.5 * ramp_s).min(0.5 * d0).min(0.5 * d1);
    let mut t0 = 0.0;
    let mut prev: Option<&super::scenario::SpeedSegment> = None;
    for (i, sg) in segs.iter().enumerate() {
        let t1 = t0 + sg.duration_s;
        if t < t1 || i + 1 == segs.len() {
            if let Some(p) = prev
                && ramps(p.accel_mps2, sg.accel_mps2)
            {
                let half = half_between(p.duration_s, sg.duration_s);
                if half > 0.0 && t < t0 + half {
                    let x = (t - (t0 - half)) / (2.0 * half);
                    return p.accel_mps2 + (sg.accel_mps2 - p.accel_mps2) * x;
                }
            }
            if let Some(n) = segs.get(i + 1)
                && ramps(sg.accel_mps2, n.accel_mps2)
            {
                let half = half_between(sg.duration_s, n.duration_s);
                if half > 0.0 && t > t1 - half {
                    let x = (t - (t1 - half)) / (2.0 * half);
                    return sg.accel_mps2 + (n.accel_mps2 - sg.accel_mps2) * x;
                }
            }
            return if t < t1 { sg.accel_mps2 } else { 0.0 };
        }
        prev = Some(sg);
        t0 = t1;
    }
    0.0
}

/// Simulate a scenario. Deterministic for a given scenario (its seed included).
pub fn simulate(sc: &Scenario) -> Drive {
    let sen = &sc.sensors;
    let veh = &sc.vehicle;
    let sub = 5usize;
    let h = 1.0 / (sen.imu_rate_hz * sub as f64);
    let total = sc.speed.duration_s();
    let n_steps = (total / h).floor() as usize;
    let mut g = Gauss::new(sc.seed);
    let lever = Vector3::from(veh.lever_arm_m);
    let wn = std::f64::consts::TAU * veh.pitch_freq_hz;

    // Speed-profile cursor.
    let segs = &sc.speed.segments;
    let (mut seg, mut seg_t0) = (0usize, 0.0f64);
    let (mut v, mut s) = (0.0f64, 0.0f64);
    // Suspension state (rad, rad/s). The car stands where the drive begins: the body
    // has settled on the grade under its axles.
    let force0 = if veh.pitch_from_grade {
        let half_wb = 0.5 * veh.wheelbase_m;
        let (pf, pr) = (sc.road.elevation(half_wb), sc.road.elevation(-half_wb));
        let gam0 = (pf.1 - pr.1).atan2(pf.0 - pr.0);
        G_MPS2 * gam0.sin()
    } else {
        0.0
    };
    let beta0 = body_pitch_rad(veh, force0, false);
    let (mut beta, mut beta_dot) = (beta0, 0.0f64);
    // The load's pitch as the body takes it (rad, rad/s).
    let (mut load_body, mut load_body_dot) = (sc.load_pitch_deg_at(0.0).to_radians(), 0.0f64);
    // Heave with the longitudinal force (m, m/s), settled too.
    let heave_per_force = veh.heave_per_accel_mm * 1e-3;
    let wh = std::f64::consts::TAU * veh.heave_freq_hz;
    let (mut zf, mut zf_dot) = (heave_per_force * force0, 0.0f64);
    // The body's answer to the road's unevenness.
    let mut ride = super::roughness::Ride::new(
        &sc.road.roughness,
        veh.wheelbase_m,
        (veh.heave_freq_hz, veh.heave_damping),
        (veh.pitch_freq_hz, veh.pitch_damping),
        h,
    );

    let acc_sigma = sen.acc_noise_ug_rthz * 1e-6 * G_MPS2 * sen.imu_rate_hz.sqrt();
    let gyro_sigma = sen.gyro_noise_dps_rthz * sen.imu_rate_hz.sqrt();
    let imu_dt = 1.0 / sen.imu_rate_hz;
    let rough_phase = if veh.rough_road_mps2 > 0.0 {
        std::f64::consts::TAU * g.uniform()
    } else {
        0.0
    };
    let mut acc_bias = Vector3::from(sen.acc_bias_mps2);
    // Falling to the right rolls the body right side down: left side up, +x rotation.
    let cross = (sc.road.cross_slope_pct / 100.0).atan();
    let body_to_imu = body_to_imu(&veh.imu_mount_deg);
    let acc_axes = sen.acc_axes_matrix();
    // The longitudinal vibration gets its own phase without a draw of its own (the noise
    // sequence of existing scenarios stays as it was).
    let long_phase = rough_phase + 1.7;
    let mut gyro_bias = Vector3::from(sen.gyro_bias_dps);

    let mut imu = Vec::with_capacity(n_steps / sub + 1);
    let mut truth = Vec::with_capacity(n_steps / sub + 1);
    let mut wheels = Vec::new();
    let wheel_every = (sen.imu_rate_hz / sen.wheel_rate_hz).round().max(1.0) as usize;

    let mut window: [Option<Kin>; 3] = [None, None, None];
    // Specific force, rate and kinematics at each simulation step of one output period.
    type Step = (Vector3<f64>, Vector3<f64>, Kin);
    let mut inst: Vec<Option<Step>> = vec![None; sub];
    for k in 0..=n_steps {
        let t = k as f64 * h;
        // Advance the profile to time t (exact for piecewise-constant acceleration).
        while seg < segs.len() && t >= seg_t0 + segs[seg].duration_s {
            seg_t0 += segs[seg].duration_s;
            seg += 1;
        }
        let a_cmd = if veh.accel_ramp_s > 0.0 {
            ramped_accel(segs, veh.accel_ramp_s, t)
        } else if seg < segs.len() {
            segs[seg].accel_mps2
        } else {
            0.0
        };
        // Speed cannot go negative: a braking segment that overshoots holds at rest.
        let a_long = if v <= 0.0 && a_cmd < 0.0 { 0.0 } else { a_cmd };
        // The body rests on both axles: its road pitch is the chord between the contact
        // points and the pitch centre moves with their midpoint.
        let half_wb = 0.5 * veh.wheelbase_m;
        let (sf, sr) = (s + half_wb, s - half_wb);
        let (pf, pr) = (sc.road.elevation(sf), sc.road.elevation(sr));
        let gam = (pf.1 - pr.1).atan2(pf.0 - pr.0);
        let (kappa, psi) = sc.road.heading(s);
        let load = sc.load_pitch_deg_at(t).to_radians();
        let shock: f64 = sc.shocks.iter().map(|x| x.pitch_rad(t)).sum();
        let (rho, heave_dd) = ride.step(sf, sr);
        // The tyres pass the body the acceleration and, on a grade, gravity's share along
        // the road (`pitch_from_grade`); it pitches and heaves with that force.
        let force_long = if veh.pitch_from_grade {
            a_long + G_MPS2 * gam.sin()
        } else {
            a_long
        };
        let zf_dd =
            wh * wh * (heave_per_force * force_long - zf) - 2.0 * veh.heave_damping * wh * zf_dot;
        if !veh.load_through_suspension {
            load_body = load;
        }
        let pitch = gam + load_body + beta + shock + rho;
        let q = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), psi)
            * UnitQuaternion::from_axis_angle(&Vector3::y_axis(), -pitch)
            * UnitQuaternion::from_axis_angle(&Vector3::x_axis(), cross);
        // Acceleration of the midpoint in the vertical plane of the road: tangential plus
        // centripetal of each contact point, averaged.
        let mut along = 0.0;
        let mut vert = 0.0;
        for si in [sf, sr] {
            let (g, dg) = sc.road.grade(si);
            along += 0.5 * (a_long * g.cos() - v * v * dg * g.sin());
            vert += 0.5 * (a_long * g.sin() + v * v * dg * g.cos());
        }
        let (sp, cp) = psi.sin_cos();
        let left = Vector3::new(-sp, cp, 0.0);
        let acc =
            Vector3::new(along * cp, along * sp, vert + heave_dd + zf_dd) + left * (v * v * kappa);
        let kin = Kin {
            q,
            acc,
            lever: q * lever,
            truth: Truth {
                t_s: t,
                s_m: s,
                v_mps: v,
                grade_deg: sc.road.grade(s).0.to_degrees(),
                load_pitch_deg: load.to_degrees() + veh.imu_mount_deg[1],
                suspension_deg: (beta + rho + load_body - load).to_degrees(),
            },
            kappa,
        };
        window = [window[1], window[2], Some(kin)];

        // Instantaneous specific force and rate at the middle grid point (central differences).
        if k >= 2 {
            let (p, m, n) = (window[0].unwrap(), window[1].unwrap(), window[2].unwrap());
            let lever_acc = (n.lever - m.lever * 2.0 + p.lever) / (h * h);
            let f_b = m.q.inverse() * (m.acc + lever_acc + Vector3::new(0.0, 0.0, G_MPS2));
            let w_b = (p.q.inverse() * n.q).scaled_axis() / (2.0 * h);
            inst[(k - 1) % sub] = Some((f_b, w_b, m));
        }
        // A sensor sample is the mean over its output period centred on the sample time,
        // as a MEMS IMU's digital filter delivers it; point samples would alias steps.
        if k > sub && (k - 1 - sub / 2).is_multiple_of(sub) {
            let c = k - 1 - sub / 2;
            let mut f_b = Vector3::zeros();
            let mut w_b = Vector3::zeros();
            let mut centre = None;
            for (j, e) in inst.iter().enumerate() {
                let (f, w, kin) = e.expect("filled");
                f_b += f;
                w_b += w;
                if j == c % sub {
                    centre = Some(kin);
                }
            }
            f_b /= sub as f64;
            w_b /= sub as f64;
            let m = centre.expect("centre sample");
            let idx = c / sub;
            truth.push(m.truth);
            if sen.acc_bias_walk_mps2_rts > 0.0 {
                for i in 0..3 {
                    acc_bias[i] += sen.acc_bias_walk_mps2_rts * imu_dt.sqrt() * g.normal();
                }
            }
            if sen.gyro_bias_walk_dps_rts > 0.0 {
                for i in 0..3 {
                    gyro_bias[i] += sen.gyro_bias_walk_dps_rts * imu_dt.sqrt() * g.normal();
                }
            }
            let (f_b, w_b) = (acc_axes * (body_to_imu * f_b), body_to_imu * w_b);
            let mut f = f_b + acc_bias;
            if veh.rough_road_mps2 > 0.0 {
                // Zero-mean vertical vibration growing with speed; its displacement is a
                // few tenths of a millimetre, so it adds no drift of its own.
                let amp = veh.rough_road_mps2 * (m.truth.v_mps / 13.9).min(1.5);
                let t = m.truth.t_s;
                let vib: f64 = [(8.3, 0.0), (11.1, 1.3), (13.7, 2.9)]
                    .iter()
                    .map(|(hz, ph)| (std::f64::consts::TAU * hz * t + ph + rough_phase).sin())
                    .sum::<f64>()
                    / 3f64.sqrt();
                f[2] += amp * vib;
                if veh.rough_road_long_share > 0.0 {
                    let vib_x: f64 = [(9.4, 0.4), (12.6, 2.1)]
                        .iter()
                        .map(|(hz, ph)| (std::f64::consts::TAU * hz * t + ph + long_phase).sin())
                        .sum::<f64>()
                        / 2f64.sqrt();
                    f[0] += amp * veh.rough_road_long_share * vib_x;
                }
            }
            if veh.idle_vibration_mps2 > 0.0 {
                // The engine's firing frequency: one tone, sub-micrometre, at rest too.
                let ph = std::f64::consts::TAU * veh.idle_vibration_hz * m.truth.t_s + long_phase;
                let amp = veh.idle_vibration_mps2 * std::f64::consts::SQRT_2;
                f[2] += amp * ph.sin();
                f[0] += amp * veh.rough_road_long_share * (ph + 1.1).sin();
            }
            let mut w = w_b.map(f64::to_degrees) + gyro_bias;
            for i in 0..3 {
                f[i] += acc_sigma * g.normal();
                w[i] += gyro_sigma * g.normal();
            }
            let dropped = sen.imu_drop_prob > 0.0 && g.uniform() < sen.imu_drop_prob;
            let t_true = m.truth.t_s;
            let in_gap = sc
                .imu_gaps
                .iter()
                .any(|&(t0, d)| t_true >= t0 && t_true < t0 + d);
            let [j0, j1] = sen.imu_jitter_ms;
            let t_rx = if j1 > 0.0 {
                t_true + 1e-3 * (j0 + (j1 - j0) * g.uniform())
            } else {
                t_true
            };
            if !dropped && !in_gap {
                imu.push(ImuSample::new(t_rx, f.into(), w.into()));
            }
            if idx.is_multiple_of(wheel_every) {
                // The speed the frame carries is `wheel_delay_s` old (the drive's first
                // speed before it began).
                let lag = (sen.wheel_delay_s * sen.imu_rate_hz).round() as usize;
                let v_read = truth
                    .len()
                    .checked_sub(lag + 1)
                    .map_or(0.0, |i| truth[i].v_mps);
                wheels.push(wheel_speeds(m.truth.t_s, v_read, m.kappa, veh.track_m, sen));
            }
        }

        // Integrate to the next grid point, splitting a step that crosses a segment end
        // (a brake segment ends exactly at rest; rounding it to the grid would leave
        // the car creeping at up to a*h through the following stop).
        let end = segs.get(seg).map(|x| seg_t0 + x.duration_s);
        let next = segs.get(seg + 1);
        let a_step = match (end, next) {
            // Braking ends at rest inside this step: exact split, no creep but a rounding
            // residue (`REST_BELOW_MPS`).
            (Some(end), Some(next)) if t + h > end => {
                let before = end - t;
                let after = if veh.accel_ramp_s > 0.0 && !(a_long < 0.0 && next.accel_mps2 == 0.0) {
                    ramped_accel(segs, veh.accel_ramp_s, t + h)
                } else {
                    next.accel_mps2
                };
                (a_long * before + after * (h - before)) / h
            }
            // Within a ramp the acceleration is linear: the trapezoid is exact.
            _ if veh.accel_ramp_s > 0.0 => {
                0.5 * (a_long + ramped_accel(segs, veh.accel_ramp_s, t + h))
            }
            _ => a_long,
        };
        let v_next = (v + a_step * h).max(0.0);
        s += 0.5 * (v + v_next) * h;
        v = v_next;
        // The drivetrain pushes while the car pulls away or drives on; at rest the
        // brakes hold it, through the geometry that they brake with. The split step
        // where braking ends leaves the speed a rounding residue (up to 2e-5 m/s), so
        // rest is any speed below `REST_BELOW_MPS`.
        let driven = a_long > 0.0 || v > REST_BELOW_MPS;
        let target = body_pitch_rad(veh, force_long, driven);
        let beta_dd = wn * wn * (target - beta) - 2.0 * veh.pitch_damping * wn * beta_dot;
        beta_dot += beta_dd * h;
        beta += beta_dot * h;
        if veh.load_through_suspension {
            let ld_dd = wn * wn * (sc.load_pitch_deg_at(t + h).to_radians() - load_body)
                - 2.0 * veh.pitch_damping * wn * load_body_dot;
            load_body_dot += ld_dd * h;
            load_body += load_body_dot * h;
        }
        zf_dot += zf_dd * h;
        zf += zf_dot * h;
    }
    Drive { imu, wheels, truth }
}

/// Below this speed the car is at rest, held by its brakes: far above the integration's
/// rounding residue, far below any creep or rolling stop (0.05 m/s and up).
const REST_BELOW_MPS: f64 = 1e-3;

/// The body's steady pitch under a longitudinal force per unit mass, rad: it dives
/// under braking and squats by `squat_share` of that under a forward force that the
/// drivetrain gives (`driven`); held by its brakes on a grade, it pitches as it brakes.
fn body_pitch_rad(veh: &Vehicle, force_mps2: f64, driven: bool) -> f64 {
    let share = if driven && force_mps2 > 0.0 {
        veh.squat_share
    } else {
        1.0
    };
    veh.pitch_per_accel_deg.to_radians() * share * force_mps2
}

fn wheel_speeds(
    t: f64,
    v: f64,
    kappa: f64,
    track: f64,
    sen: &super::scenario::Sensors,
) -> WheelSpeeds {
    let read = |v_mps: f64| {
        let kmh = v_mps.max(0.0) * 3.6 * sen.wheel_scale;
        if kmh < sen.wheel_zero_below_kmh || kmh <= 0.0 {
            0.0
        } else if sen.wheel_quantum_kmh > 0.0 {
            (kmh / sen.wheel_quantum_kmh).floor() * sen.wheel_quantum_kmh
        } else {
            kmh
        }
    };
    let half = 0.5 * kappa * track;
    let (l, r) = (read(v * (1.0 - half)), read(v * (1.0 + half)));
    WheelSpeeds {
        t_s: t,
        kmh: [l, r, l, r],
    }
}

#[cfg(test)]
mod tests {
    use super::ramped_accel;
    use crate::sim::scenario::SpeedProfile;

    /// Speed in the middle of each segment, integrating the ramped acceleration finely.
    fn speeds_mid_segment(p: &SpeedProfile, ramp_s: f64) -> Vec<f64> {
        let h = 1e-4;
        let (mut t, mut v, mut out, mut start) = (0.0, 0.0, Vec::new(), 0.0);
        for sg in &p.segments {
            let mid = start + 0.5 * sg.duration_s;
            while t + h <= mid + 1e-12 {
                let a = ramped_accel(&p.segments, ramp_s, t);
                v += 0.5 * (a + ramped_accel(&p.segments, ramp_s, t + h)) * h;
                t += h;
            }
            out.push(v);
            start += sg.duration_s;
        }
        out
    }

    #[test]
    fn ramps_keep_every_segments_speed_change_even_for_short_segments() {
        // A stop with a creep of 0.1 s segments (shorter than the 0.5 s ramp), a drive
        // off, a cruise, a brake to rest: every hold is at its planned speed.
        let p = SpeedProfile::default()
            .hold(2.0)
            .accel(0.5, 0.1)
            .accel(-0.5, 0.1)
            .hold(3.0)
            .accel(1.0, 4.0)
            .hold(5.0)
            .accel(-2.0, 2.0)
            .hold(3.0);
        let v = speeds_mid_segment(&p, 0.5);
        for (k, want) in [(0, 0.0), (3, 0.0), (5, 4.0), (7, 0.0)] {
            assert!(
                (v[k] - want).abs() < 1e-3,
                "hold {k}: {} m/s, planned {want}",
                v[k]
            );
        }
    }

    /// A car standing `hold_s` on `road`, with ideal sensors.
    fn at_rest(
        hold_s: f64,
        road: crate::sim::scenario::Road,
        vehicle: crate::sim::scenario::Vehicle,
    ) -> super::Drive {
        ideal_drive(SpeedProfile::default().hold(hold_s), road, vehicle)
    }

    /// A car driving `speed` on `road`, with ideal sensors.
    fn ideal_drive(
        speed: SpeedProfile,
        road: crate::sim::scenario::Road,
        vehicle: crate::sim::scenario::Vehicle,
    ) -> super::Drive {
        super::simulate(&crate::sim::scenario::Scenario {
            speed,
            road,
            load_pitch_deg: 0.0,
            load_changes: Vec::new(),
            vehicle,
            sensors: crate::sim::scenario::Sensors::ideal(),
            shocks: Vec::new(),
            imu_gaps: Vec::new(),
            seed: 1,
        })
    }

    #[test]
    fn a_body_at_rest_on_a_grade_squats_as_if_it_pulled_away_at_g_sin_grade() {
        use crate::sim::scenario::{Road, Vehicle};
        let rest_pitch = |grade_pct: f64, from_grade: bool| {
            let vehicle = Vehicle {
                pitch_per_accel_deg: 0.25,
                pitch_from_grade: from_grade,
                ..Vehicle::default()
            };
            let road = Road::constant(grade_pct.atan2(100.0).to_degrees());
            at_rest(6.0, road, vehicle).truth_at(5.0).suspension_deg
        };
        // 0.25 deg per m/s^2 times g sin(atan 0.1) = 0.976 m/s^2, nose up facing uphill.
        assert!((rest_pitch(10.0, true) - 0.244).abs() < 0.005);
        assert!((rest_pitch(-10.0, true) + 0.244).abs() < 0.005);
        assert!(rest_pitch(10.0, false).abs() < 1e-6);
        assert!(rest_pitch(0.0, true).abs() < 1e-6);
        // A body that squats half as much as it dives stands on a grade as it brakes:
        // its brakes hold it.
        let half = |grade_pct: f64| {
            let vehicle = Vehicle {
                pitch_per_accel_deg: 0.25,
                squat_share: 0.5,
                ..Vehicle::default()
            };
            let road = Road::constant(grade_pct.atan2(100.0).to_degrees());
            at_rest(6.0, road, vehicle).truth_at(5.0).suspension_deg
        };
        assert!((half(10.0) - 0.244).abs() < 0.005);
        assert!((half(-10.0) + 0.244).abs() < 0.005);
    }

    /// Braking to rest on a grade leaves the car held by its brakes, as one that started
    /// the drive at rest: the body pitches as it brakes, whatever its squat, with or
    /// without the acceleration ramping between segments.
    #[test]
    fn a_car_that_brakes_to_rest_on_a_grade_is_held_by_its_brakes() {
        use crate::sim::scenario::{Road, Vehicle};
        for accel_ramp_s in [0.0, 0.4] {
            for grade_pct in [10.0, -10.0] {
                let vehicle = Vehicle {
                    pitch_per_accel_deg: 0.25,
                    squat_share: 0.5,
                    accel_ramp_s,
                    ..Vehicle::default()
                };
                let speed = SpeedProfile::default()
                    .hold(1.0)
                    .accel(1.3, 5.0)
                    .hold(2.0)
                    .accel(-0.9, 6.5 / 0.9)
                    .hold(8.0);
                let road = Road::constant(f64::atan2(grade_pct, 100.0).to_degrees());
                let d = ideal_drive(speed, road, vehicle);
                let mut rest = d.truth.iter().filter(|x| x.t_s > 16.5 && x.t_s < 23.0);
                assert!(rest.all(|x| x.v_mps < 1e-4), "ramp {accel_ramp_s} s");
                // As braking: 0.25 deg per m/s^2 of g sin(grade), the dive's, not half.
                let held = d.truth_at(22.0).suspension_deg;
                let want = 0.244 * grade_pct.signum();
                assert!((held - want).abs() < 0.005, "{held} on {grade_pct} %");
            }
        }
    }

    /// Pulling away the body squats by `squat_share` of what it dives braking.
    #[test]
    fn a_body_squats_by_its_share_of_the_dive_when_the_drivetrain_pushes() {
        use crate::sim::scenario::{Road, Vehicle};
        let pitch = |squat_share: f64| {
            let vehicle = Vehicle {
                pitch_per_accel_deg: 0.25,
                squat_share,
                ..Vehicle::default()
            };
            let speed = SpeedProfile::default()
                .hold(1.0)
                .accel(1.0, 6.0)
                .accel(-1.0, 6.0)
                .hold(1.0);
            let d = ideal_drive(speed, Road::constant(0.0), vehicle);
            (
                d.truth_at(6.5).suspension_deg,
                d.truth_at(12.5).suspension_deg,
            )
        };
        let (squat, dive) = pitch(0.5);
        assert!((squat - 0.125).abs() < 0.005, "{squat}");
        assert!((dive + 0.25).abs() < 0.005, "{dive}");
        let (squat, _) = pitch(1.0);
        assert!((squat - 0.25).abs() < 0.005, "{squat}");
    }

    #[test]
    fn a_load_put_in_quickly_rocks_the_body_before_it_settles_on_the_loads_pitch() {
        use crate::sim::scenario::{Road, Vehicle};
        // One degree in 0.3 s at t = 2 s, on a pitch mode of 1.3 Hz, damping 0.3.
        let body_pitch = |through_suspension: bool| {
            let vehicle = Vehicle {
                pitch_freq_hz: 1.3,
                pitch_damping: 0.3,
                load_through_suspension: through_suspension,
                ..Vehicle::default()
            };
            let mut sc = crate::sim::scenario::Scenario {
                speed: SpeedProfile::default().hold(8.0),
                road: Road::constant(0.0),
                load_pitch_deg: 0.0,
                load_changes: vec![(2.0, 1.0, 0.3)],
                vehicle,
                sensors: crate::sim::scenario::Sensors::ideal(),
                shocks: Vec::new(),
                imu_gaps: Vec::new(),
                seed: 1,
            };
            sc.sensors.imu_rate_hz = 100.0;
            let d = super::simulate(&sc);
            let at = |t: f64| {
                let tr = d.truth_at(t);
                tr.load_pitch_deg + tr.suspension_deg
            };
            let peak = (0..300)
                .map(|k| at(2.0 + 0.01 * k as f64))
                .fold(f64::MIN, f64::max);
            (peak, at(7.5), d.truth_at(7.5).load_pitch_deg)
        };
        // Through the suspension the body overshoots (a step on a mode damped 0.3
        // overshoots by 37 %; a 0.3 s ramp excites less) and settles on the load.
        let (peak, settled, load) = body_pitch(true);
        assert!(peak > 1.1 && peak < 1.37, "peak {peak}");
        assert!((settled - 1.0).abs() < 0.005 && (load - 1.0).abs() < 1e-9);
        // Off, the body follows the load's ramp exactly.
        let (peak, settled, _) = body_pitch(false);
        assert!((peak - 1.0).abs() < 1e-9 && (settled - 1.0).abs() < 1e-9);
    }

    #[test]
    fn a_lane_falling_to_the_right_rolls_the_body_and_a_yawed_imu_sees_it_as_pitch() {
        use crate::sim::scenario::{Road, Vehicle};
        // At rest on a level road with a 2.5 % cross slope: (pitch, roll) from gravity.
        let rest_attitude = |yaw_deg: f64| {
            let road = Road {
                cross_slope_pct: 2.5,
                ..Road::constant(0.0)
            };
            let vehicle = Vehicle {
                imu_mount_deg: [0.0, 0.0, yaw_deg],
                ..Vehicle::default()
            };
            let d = at_rest(3.0, road, vehicle);
            let f = d.imu[d.imu.len() / 2].acc_mps2;
            let (pitch, roll) =
                crate::estimator::attitude::pitch_roll_from_gravity(&f.into()).unwrap();
            (pitch.to_degrees(), roll.to_degrees())
        };
        let camber_deg = 0.025f64.atan().to_degrees();
        // Right side down: the IMU's left (y) axis points up the slope.
        let (p0, r0) = rest_attitude(0.0);
        assert!(
            p0.abs() < 1e-6 && (r0 - camber_deg).abs() < 1e-6,
            "{p0} {r0}"
        );
        // Yawed 1.5 deg to the left, the IMU's x axis takes a share of the roll as pitch
        // the load does not have: yaw x cross slope, 0.037 deg.
        let (p1, _) = rest_attitude(1.5);
        let share = 1.5f64.to_radians().sin() * camber_deg;
        assert!((p1 - share).abs() < 1e-3, "{p1} against {share}");
    }

    #[test]
    fn an_end_of_line_station_reads_the_mount_roll_with_the_accelerometer_bias() {
        use crate::sim::scenario::{Road, Vehicle};
        let vehicle = Vehicle {
            imu_mount_deg: [0.5, 0.8, 1.2],
            ..Vehicle::default()
        };
        let mut d = at_rest(3.0, Road::constant(0.0), vehicle.clone());
        let sc = |bias: [f64; 3]| crate::sim::scenario::Scenario {
            speed: SpeedProfile::default().hold(3.0),
            road: Road::constant(0.0),
            load_pitch_deg: 0.0,
            load_changes: Vec::new(),
            vehicle: vehicle.clone(),
            sensors: crate::sim::scenario::Sensors {
                acc_bias_mps2: bias,
                ..crate::sim::scenario::Sensors::ideal()
            },
            shocks: Vec::new(),
            imu_gaps: Vec::new(),
            seed: 1,
        };
        // The same roll the IMU reads at rest on a level road, from its own samples.
        let f: nalgebra::Vector3<f64> = d.imu.remove(d.imu.len() / 2).acc_mps2.into();
        let read = (f.y / f.norm()).asin().to_degrees();
        let floor = super::floor_roll_deg(&sc([0.0; 3]));
        assert!((floor - read).abs() < 1e-6, "{floor} against {read}");
        assert!((floor - 0.5).abs() < 0.02, "{floor}");
        // A bias to the left reads as more roll: 0.1 m/s^2 is 0.58 deg.
        let biased = super::floor_roll_deg(&sc([0.0, 0.1, 0.0]));
        assert!((biased - floor - 0.584).abs() < 0.005, "{biased}");
    }
}
