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
use super::history::LEVER_SMOOTH_HALF;
use nalgebra::{UnitQuaternion, Vector3};

/// A settled window re-anchors the tracker when its tilt agrees with the carried
/// attitude within this, rad (0.3 deg: a gentle 0.05 m/s^2 acceleration is outside).
const ANCHOR_TOL_RAD: f64 = 0.3 * std::f64::consts::PI / 180.0;

/// Shortest time between two anchors, s.
const ANCHOR_PERIOD_S: f64 = 1.0;

/// Samples the tracker runs behind the newest one: the lever-arm acceleration at a
/// sample needs the gyro readings after it.
const LAG_SAMPLES: usize = 2 * LEVER_SMOOTH_HALF + 1;

/// After a drive-off in the dead zone, the car counts as at rest again (a creep that
/// ended) once the tracked speed is below this share of `drive_off_speed_mps`.
const REST_AGAIN_SHARE: f64 = 0.3;

#[derive(Debug, Clone, Copy)]
pub(super) struct MotionTracker {
    /// Body attitude carried by the gyro since the last anchor.
    q: UnitQuaternion<f64>,
    /// Speed along body x picked up since the last anchor, m/s.
    v_mps: f64,
    /// Time of the last sample integrated, s.
    t_last_s: f64,
    /// Time of the last anchor, s.
    t_anchor_s: f64,
    gravity_mps2: f64,
}

impl MotionTracker {
    pub(super) fn new(f_rest: &Vector3<f64>, t_s: f64, gravity_mps2: f64) -> Option<Self> {
        Some(Self {
            q: attitude_from_gravity(f_rest)?,
            v_mps: 0.0,
            t_last_s: t_s,
            // The reference a standstill begins with is taken while the body may still
            // rock: the first settled window that agrees may anchor at once.
            t_anchor_s: f64::NEG_INFINITY,
            gravity_mps2,
        })
    }

    pub(super) fn speed_mps(&self) -> f64 {
        self.v_mps.abs()
    }
}

impl Estimator {
    /// Advance the standstill's motion tracker; returns the speed picked up since the
    /// car was last surely at rest, m/s.
    pub(super) fn track_motion(&mut self) -> f64 {
        let Some(mut m) = self.standstill.and_then(|st| st.motion) else {
            return 0.0;
        };
        let v = self.advance_motion(&mut m);
        if let Some(st) = self.standstill.as_mut() {
            st.motion = Some(m);
        }
        v
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
        v < REST_AGAIN_SHARE * self.cfg.drive_off_speed_mps
    }

    /// Integrate the samples that have become available to `m`.
    fn advance_motion(&self, m: &mut MotionTracker) -> f64 {
        let n = self.hist.len();
        if n <= LAG_SAMPLES + 1 {
            return m.speed_mps();
        }
        let newest = n - 1 - LAG_SAMPLES;
        let mut i = self.index_at(m.t_last_s).max(1);
        if self.hist.get(i).t_s <= m.t_last_s {
            i += 1;
        }
        let bias = self.bias_rps.unwrap_or_else(Vector3::zeros);
        let up = Vector3::new(0.0, 0.0, m.gravity_mps2);
        while i <= newest {
            let (a, b) = (self.hist.get(i - 1), self.hist.get(i));
            let dt = b.t_s - a.t_s;
            if dt > 0.0 && dt <= self.cfg.max_imu_gap_s {
                let w = (a.gyro_rps() + b.gyro_rps()) * 0.5 - bias;
                m.q = attitude::propagate(&m.q, &w, dt);
                let f = b.acc() - self.lever_acc_at(i);
                m.v_mps += (f.x - (m.q.inverse() * up).x) * dt;
            }
            m.t_last_s = b.t_s;
            i += 1;
        }
        // A settled window that agrees with the carried tilt: the car is at rest there.
        // Checked once per period, so that an acceleration ramping in slowly cannot be
        // absorbed a sample at a time.
        if self.bias_window_ok
            && m.t_last_s - m.t_anchor_s >= ANCHOR_PERIOD_S
            && let Some(q_now) = attitude_from_gravity(&self.still_mean_acc)
            && (pitch_of(&q_now) - pitch_of(&m.q)).abs() <= ANCHOR_TOL_RAD
        {
            m.q = q_now;
            m.v_mps = 0.0;
            m.t_anchor_s = m.t_last_s;
        }
        m.speed_mps()
    }

    /// Time from which a tracker started now integrates: the newest sample it can use.
    pub(super) fn motion_start_s(&self) -> f64 {
        let n = self.hist.len();
        self.hist.get(n.saturating_sub(LAG_SAMPLES + 1)).t_s
    }
}
