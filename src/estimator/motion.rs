//! Motion seen by the IMU while the wheels read zero.
//!
//! ABS wheel sensors read zero below 1-2 km/h, so a gentle drive-off, a creep or a
//! rolling stop look like rest to them for most of a second; a steady gentle
//! acceleration also has no variance, so it passes the stillness test. What gives it
//! away is physics: at rest the specific force is gravity, turned only as far as the
//! gyro says the body turned (a load change, a door shock, rocking). The tracker
//! carries the body attitude with the gyro from the last settled moment, removes
//! gravity and the lever-arm motion from the accelerometer, and integrates what is
//! left along the body x axis: the speed the car picked up since it was last surely
//! at rest. Settled moments whose tilt agrees with the carried attitude re-anchor it,
//! so gyro drift over a long stop does not accumulate; a steady acceleration never
//! agrees (it tilts the specific force by a/g without a turn), so it keeps counting.

use super::Estimator;
use super::attitude::{self, attitude_from_gravity, pitch_of};
use nalgebra::{UnitQuaternion, Vector3};

/// A settled window re-anchors the tracker when its tilt agrees with the carried
/// attitude within this, rad (0.3 deg: a gentle 0.05 m/s^2 acceleration is outside).
const ANCHOR_TOL_RAD: f64 = 0.3 * std::f64::consts::PI / 180.0;

/// Shortest time between two anchors, s.
const ANCHOR_PERIOD_S: f64 = 1.0;

/// A drive-off picks its speed up quickly (a gentle one at 0.3 m/s^2); a tilt the gyro
/// did not fully explain (a load ramping in, a gyro bias not yet learnt) leaves a small
/// residual that only adds up over seconds. So the speed must also have been picked up
/// within this long, s.
pub(super) const GAIN_SPAN_S: f64 = 1.0;

/// Steps of the speed record behind [`GAIN_SPAN_S`].
const GAIN_STEPS: usize = 10;

/// After a drive-off in the dead zone, the car counts as at rest again (a creep that
/// ended) once the tracked speed is below this share of `drive_off_speed_mps`.
const REST_AGAIN_SHARE: f64 = 0.3;

#[derive(Debug, Clone, Copy)]
pub(super) struct MotionTracker {
    /// Body attitude carried by the gyro since the last anchor.
    q: UnitQuaternion<f64>,
    /// Speed along body x picked up since the last anchor, m/s,
    v_mps: f64,
    /// and one sample before.
    v_prev_mps: f64,
    /// Time of the last sample integrated, s.
    t_last_s: f64,
    /// Time of the last anchor, s.
    t_anchor_s: f64,
    gravity_mps2: f64,
    /// The speed every `GAIN_SPAN_S / GAIN_STEPS` over the last `GAIN_SPAN_S`, oldest
    /// at `gain_next`, and when the newest was recorded.
    gain_v: [f64; GAIN_STEPS],
    gain_next: usize,
    gain_t_s: f64,
}

impl MotionTracker {
    pub(super) fn new(f_rest: &Vector3<f64>, t_s: f64, gravity_mps2: f64) -> Option<Self> {
        Some(Self {
            q: attitude_from_gravity(f_rest)?,
            v_mps: 0.0,
            v_prev_mps: 0.0,
            t_last_s: t_s,
            // The reference a standstill begins with is taken while the body may still
            // rock: the first settled window that agrees may anchor at once.
            t_anchor_s: f64::NEG_INFINITY,
            gravity_mps2,
            gain_v: [0.0; GAIN_STEPS],
            gain_next: 0,
            gain_t_s: t_s,
        })
    }

    /// Speed picked up, m/s: the lower of the last two samples', so that a door shock's
    /// sharp first swing, whose speed about the pitch centre the gyro's mean over a
    /// period splits over two samples, does not pass for a drive-off for one sample.
    pub(super) fn speed_mps(&self) -> f64 {
        self.v_mps.abs().min(self.v_prev_mps.abs())
    }

    /// Speed picked up over the last `GAIN_SPAN_S`, m/s.
    pub(super) fn recent_gain_mps(&self) -> f64 {
        (self.v_mps - self.gain_v[self.gain_next]).abs()
    }

    fn record(&mut self, t_s: f64) {
        let step = GAIN_SPAN_S / GAIN_STEPS as f64;
        if t_s - self.gain_t_s >= step {
            self.gain_v[self.gain_next] = self.v_mps;
            self.gain_next = (self.gain_next + 1) % GAIN_STEPS;
            self.gain_t_s = t_s;
        }
    }

    fn reset_speed(&mut self) {
        self.v_mps = 0.0;
        self.v_prev_mps = 0.0;
        self.gain_v = [0.0; GAIN_STEPS];
    }
}

impl Estimator {
    /// Advance the standstill's motion tracker; returns the speed picked up since the
    /// car was last surely at rest and how much of it within the last `GAIN_SPAN_S`, m/s.
    pub(super) fn track_motion(&mut self) -> (f64, f64) {
        let Some(mut m) = self.standstill.and_then(|st| st.motion) else {
            return (0.0, 0.0);
        };
        let v = self.advance_motion(&mut m);
        if let Some(st) = self.standstill.as_mut() {
            st.motion = Some(m);
        }
        (v, m.recent_gain_mps())
    }

    /// Carry on tracking after the IMU ended a standstill while the wheels still read
    /// zero: until the wheels see the drive-off, or the tracker sees the car at rest
    /// again (a creep), no new standstill may begin. Returns whether one may.
    pub(super) fn track_dead_zone(&mut self, wheels_zero: bool) -> bool {
        let Some(mut m) = self.dead_zone_motion.take() else {
            return true;
        };
        if !wheels_zero {
            return true;
        }
        let v = self.advance_motion(&mut m);
        self.dead_zone_motion = Some(m);
        v < REST_AGAIN_SHARE * self.drive_off_speed_mps()
    }

    /// Integrate the samples that have become available to `m`.
    fn advance_motion(&self, m: &mut MotionTracker) -> f64 {
        let n = self.hist.len();
        let lag = self.motion_lag();
        if n <= lag + 1 {
            return m.speed_mps();
        }
        let newest = n - 1 - lag;
        let mut i = self.index_at(m.t_last_s).max(1);
        if self.hist.get(i).t_s <= m.t_last_s {
            i += 1;
        }
        let bias = self.bias_rps.unwrap_or_else(Vector3::zeros);
        let up = Vector3::new(0.0, 0.0, m.gravity_mps2);
        let lever = self.lever_arm();
        while i <= newest {
            let (a, b) = (self.hist.get(i - 1), self.hist.get(i));
            let dt = b.t_s - a.t_s;
            if dt > 0.0 && dt <= self.cfg.max_imu_gap_s {
                let (wa, wb) = (a.gyro_rps() - bias, b.gyro_rps() - bias);
                m.q = attitude::propagate(&m.q, &((wa + wb) * 0.5), dt);
                // The speed of the pitch centre: the IMU's own speed change over the
                // sample, less the change of its speed about the centre (omega x r)
                // and the centripetal part of its acceleration. A sample holds the mean
                // over its period, so the rate at the period's ends is the mean of the
                // readings on either side: the change over the period is half the
                // difference of the readings after and before it. From the readings
                // themselves, a door shock's 5-8 Hz swing is removed whole.
                //
                // After a dropped sample the reading holds its own period only; the one
                // lost is taken as one in which a body at rest kept its speed (a door
                // shock's first swing counted twice would pass for a drive-off).
                let wc = self.hist.get(i + 1).gyro_rps() - bias;
                let f = b.acc() - wb.cross(&wb.cross(&lever));
                let swing = ((wc - wa) * 0.5).cross(&lever).x;
                let period = if dt > 1.5 * self.sample_dt_s.0 {
                    self.sample_dt_s.0
                } else {
                    dt
                };
                m.v_prev_mps = m.v_mps;
                m.v_mps += (f.x - (m.q.inverse() * up).x) * period - swing;
                m.record(b.t_s);
            }
            // Across a gap the body's turn and speed are unknown: a body at rest kept
            // its speed, and the tilt left unexplained is for the next anchor to take.
            m.t_last_s = b.t_s;
            i += 1;
        }
        // A settled window that agrees with the carried tilt: the car is at rest there.
        // Checked once per period, so that an acceleration ramping in slowly cannot be
        // absorbed a sample at a time.
        if self.bias_window_ok
            && m.t_last_s - m.t_anchor_s >= ANCHOR_PERIOD_S
            && let Some(f_now) = self.anchor_mean(newest)
            && let Some(q_now) = attitude_from_gravity(&f_now)
            && (pitch_of(&q_now) - pitch_of(&m.q)).abs() <= ANCHOR_TOL_RAD
        {
            m.q = q_now;
            m.reset_speed();
            m.t_anchor_s = m.t_last_s;
        }
        m.speed_mps()
    }

    /// The gravity a re-anchored tracker stands on: the mean specific force over the
    /// trailing `still_window_s` up to history sample `to`, freed of the lever arm's
    /// rocking and turned by the gyro into the body frame at `to`, so that it is the
    /// gravity the body sees there even while it still rocks a little (the raw mean
    /// lags a body turning by its rate times half the window). `None` when the samples
    /// so corrected still spread wider than `still_acc_std_mps2`: the window holds
    /// motion the rocking model does not explain, such as the 5-8 Hz ringing of a door
    /// shock, whose mean over a window is no gravity to stand on. With
    /// `derotated_motion_anchor` off, the raw mean of the last stillness window.
    fn anchor_mean(&self, to: usize) -> Option<Vector3<f64>> {
        if !self.cfg.derotated_motion_anchor {
            return Some(self.still_mean_acc);
        }
        let t_to = self.hist.get(to).t_s;
        let from = self.index_at(t_to - self.cfg.still_window_s);
        let (mean, sd) = self.derotated_spread(from, to, &Vector3::zeros());
        (sd <= self.still_acc_std_mps2()).then_some(mean)
    }

    /// Time from which a tracker started now integrates: the newest sample it can use.
    pub(super) fn motion_start_s(&self) -> f64 {
        let n = self.hist.len();
        self.hist.get(n.saturating_sub(self.motion_lag() + 1)).t_s
    }

    /// Samples the tracker runs behind the newest one: the lever-arm acceleration at a
    /// sample needs the gyro readings after it.
    fn motion_lag(&self) -> usize {
        2 * self.lever_half() + 1
    }
}

#[cfg(test)]
mod tests {
    use crate::estimator::{Estimator, EstimatorConfig, Event, ImuSample, WheelSpeeds};
    use nalgebra::{UnitQuaternion, Vector3};

    const G: f64 = 9.80665;
    /// A gyro bias that appears with the boarding, unlearnt, deg/s.
    const BIAS_DPS: f64 = 0.1;

    /// A car with its wheels at zero throughout (inside the ABS dead zone): at rest
    /// for 12 s, then `body(t)` gives its pitch (rad), the pitch rate the gyro reports
    /// (deg/s) and its acceleration along the road (m/s^2) from then on.
    fn events(body: impl Fn(f64) -> (f64, f64, f64)) -> Vec<Event> {
        let mut est = Estimator::new(EstimatorConfig::default()).unwrap();
        let mut ev = Vec::new();
        for k in 0..2500 {
            let t = k as f64 * 0.01;
            let (pitch, rate_dps, a) = if t < 12.0 {
                (0.0, 0.0, 0.0)
            } else {
                body(t - 12.0)
            };
            let q = UnitQuaternion::from_axis_angle(&Vector3::y_axis(), -pitch);
            let f = q.inverse() * Vector3::new(a, 0.0, G);
            let s = ImuSample::new(t, f.into(), [0.0, -rate_dps, 0.0]);
            est.push_imu(s, &mut |e| ev.push(e));
            if k % 2 == 0 {
                let w = WheelSpeeds {
                    t_s: t,
                    kmh: [0.0; 4],
                };
                est.push_wheels(w, &mut |e| ev.push(e));
            }
        }
        ev
    }

    fn ended(ev: &[Event]) -> Option<f64> {
        ev.iter().find_map(|e| match e {
            Event::StandstillEnded { t_s, .. } => Some(*t_s),
            _ => None,
        })
    }

    #[test]
    fn a_load_ramping_in_under_an_unlearnt_gyro_bias_is_a_load_change_not_a_drive_off() {
        // From 12 s the gyro reads BIAS_DPS too much nose-up (a bias the standstill has
        // not learnt yet); from 13 s people board and the body pitches 1 deg in 3 s.
        let ramp = |t: f64| {
            let x = ((t - 1.0) / 3.0).clamp(0.0, 1.0);
            let rate = if (0.0..1.0).contains(&x) {
                6.0 * x * (1.0 - x) / 3.0
            } else {
                0.0
            };
            ((x * x * (3.0 - 2.0 * x)).to_radians(), rate + BIAS_DPS, 0.0)
        };
        let ev = events(ramp);
        assert_eq!(ended(&ev), None, "{ev:#?}");
        let delta = ev.iter().find_map(|e| match e {
            Event::LoadChanged { delta_deg, .. } => Some(*delta_deg),
            _ => None,
        });
        assert!(delta.is_some_and(|d| (d - 1.0).abs() < 0.1), "{delta:?}");
    }

    /// A car at rest with its wheels at zero whose body rings from a door slammed at
    /// 14 s (`amp_deg` at `freq_hz`, decaying with `decay_s`), seen by an IMU at the
    /// configured lever arm, with no IMU samples from `gap_s.0` to `gap_s.1`. From
    /// `go_s` the car pulls away at 1 m/s^2.
    fn shock_events(
        amp_deg: f64,
        freq_hz: f64,
        decay_s: f64,
        gap_s: (f64, f64),
        go_s: f64,
    ) -> Vec<Event> {
        let cfg = EstimatorConfig::default();
        let arm = Vector3::from(cfg.lever_arm_m);
        let mut est = Estimator::new(cfg).unwrap();
        let mut ev = Vec::new();
        let (amp, w) = (amp_deg.to_radians(), std::f64::consts::TAU * freq_hz);
        for k in 0..2500 {
            let t = k as f64 * 0.01;
            let x = t - 14.0;
            let (th, rate, acc) = if x < 0.0 {
                (0.0, 0.0, 0.0)
            } else {
                let (e, s, c) = ((-x / decay_s).exp(), (w * x).sin(), (w * x).cos());
                let k2 = 1.0 / (decay_s * decay_s) - w * w;
                (
                    amp * e * s,
                    amp * e * (w * c - s / decay_s),
                    amp * e * (k2 * s - 2.0 * w / decay_s * c),
                )
            };
            let a = if t >= go_s { 1.0 } else { 0.0 };
            if k % 2 == 0 {
                let w = WheelSpeeds {
                    t_s: t,
                    kmh: [3.6 * a * (t - go_s); 4],
                };
                est.push_wheels(w, &mut |e| ev.push(e));
            }
            if t > gap_s.0 && t < gap_s.1 {
                continue;
            }
            // Nose-up pitch turns the body about -y.
            let q = UnitQuaternion::from_axis_angle(&Vector3::y_axis(), -th);
            let omega = Vector3::new(0.0, -rate, 0.0);
            let alpha = Vector3::new(0.0, -acc, 0.0);
            let f = q.inverse() * Vector3::new(a, 0.0, G)
                + alpha.cross(&arm)
                + omega.cross(&omega.cross(&arm));
            let s = ImuSample::new(t, f.into(), [0.0, -rate.to_degrees(), 0.0]);
            est.push_imu(s, &mut |e| ev.push(e));
        }
        ev
    }

    #[test]
    fn a_door_shock_across_a_gap_in_the_imu_data_is_not_a_drive_off() {
        // The samples resume mid-swing: the stillness window that follows holds the
        // ringing, whose mean is no gravity to re-anchor the tracker on.
        for (amp_deg, freq_hz) in [(0.25, 5.25), (0.4, 8.0), (0.2, 6.5)] {
            let ev = shock_events(amp_deg, freq_hz, 0.1, (13.91, 14.05), f64::INFINITY);
            assert_eq!(ended(&ev), None, "{amp_deg} deg at {freq_hz} Hz: {ev:#?}");
            let load = ev.iter().find(|e| matches!(e, Event::LoadChanged { .. }));
            assert!(load.is_none(), "{amp_deg} deg at {freq_hz} Hz: {load:?}");
        }
    }

    #[test]
    fn a_door_shock_across_a_gap_just_before_drive_off_is_no_load_change() {
        // No settled block follows the gap before the car pulls away, so the body's
        // pitch at drive-off is carried by the gyro from before the gap. The readings
        // on either side of it are the swing at its fastest: bridged by them, the
        // carry turned the body by 0.3-0.9 deg, and the drive-off applied that as a
        // load change.
        for go_s in [14.4, 14.6, 15.0] {
            for (amp_deg, freq_hz) in [(0.25, 5.25), (0.4, 8.0), (0.2, 6.5)] {
                let ev = shock_events(amp_deg, freq_hz, 0.1, (13.91, 14.05), go_s);
                let case = format!("{amp_deg} deg at {freq_hz} Hz, drive-off at {go_s} s");
                let t = ended(&ev).unwrap_or_else(|| panic!("{case}: no drive-off"));
                assert!(t >= go_s, "{case}: standstill ended at {t}");
                let load = ev.iter().find(|e| matches!(e, Event::LoadChanged { .. }));
                assert!(load.is_none(), "{case}: {load:?}");
            }
        }
    }

    #[test]
    fn a_gentle_drive_off_inside_the_dead_zone_ends_the_standstill_at_once() {
        // 0.3 m/s^2 from 12 s; the wheels still read zero.
        let ev = events(|_| (0.0, 0.0, 0.3));
        let t = ended(&ev).expect("the drive-off ends the standstill");
        assert!((12.0..12.6).contains(&t), "ended at {t}");
    }
}
