//! The body's pitch mode on its springs, learnt from the swing after each stop.
//!
//! When the braking force drops at rest the body swings back from its dive about its
//! rest pitch, at 1-1.5 Hz on a sound suspension, and dies out within a second or two;
//! on worn dampers it swings at about 1 Hz for three. The swing is a damped
//! second-order mode: theta'' = -k (theta - c) - d theta', with c the pitch the body
//! swings about. The gyro gives the rate and its derivative, and the gyro-carried pitch
//! theta up to a constant and a drift, so each stop's swing is a linear fit of the
//! angular acceleration on (theta, rate, 1, t); the last two terms hold the stop's own
//! c and drift (`SwingSums`). Stiffness k and damping d belong to the car: the stops'
//! fits, each with its own terms taken out, add up. With them any sample shows how far the body stood from the pitch it swings
//! about, -(theta'' + d theta') / k: the body's dive under braking is counted from
//! there (`grade.rs`). leveld reports the mode's frequency and damping ratio with what
//! else it learnt of the suspension (a damping ratio that falls over the months is a
//! damper wearing out).

use super::Estimator;
use super::attitude;
use nalgebra::{UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

/// Frequencies and damping ratios a car's pitch mode can have: a stop whose own fit
/// falls outside them (a load ramping in through the swing, a knock) is left out, Hz.
const FREQ_RANGE_HZ: (f64, f64) = (0.5, 3.0);
const DAMPING_RANGE: (f64, f64) = (0.03, 1.0);

/// A stop whose gyro-carried pitch moved less than this (rms about its own straight
/// line in time) has no swing to fit: the gyro's noise would decide the mode, rad (0.02 deg).
const MIN_SWING_RAD: f64 = 0.02 * std::f64::consts::PI / 180.0;

/// Stops the mode needs before it is used.
const MIN_STOPS: u32 = 2;

/// Each stop keeps this share of what the earlier ones taught (about the last fifty
/// count): the mode follows a load, tyre pressure or a damper wearing out.
const FORGET: f64 = 0.98;

/// Samples of one stop's swing: normal equations of
/// alpha = -k theta - d rate + (k c + d b) + k b tau, where tau is the time since the
/// rest edge. The last two terms belong to the stop: the pitch it swings about, and a
/// drift of the gyro-carried pitch (a gyro bias b not yet learnt, or a load coming in
/// slowly) that would otherwise read as a softer spring.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct SwingSums {
    /// Sums of r r^T and r alpha for r = (-theta, -rate, 1, tau).
    rr: [[f64; 4]; 4],
    ra: [f64; 4],
}

impl SwingSums {
    pub(super) fn add(&mut self, theta_rad: f64, rate_rps: f64, alpha_rps2: f64, tau_s: f64) {
        let r = [-theta_rad, -rate_rps, 1.0, tau_s];
        for (a, ra) in r.iter().zip(self.ra.iter_mut()) {
            *ra += a * alpha_rps2;
        }
        for (row, a) in self.rr.iter_mut().zip(r) {
            for (x, b) in row.iter_mut().zip(r) {
                *x += a * b;
            }
        }
    }

    /// The stop's normal equations for (k, d) with its own two terms eliminated:
    /// ([m00, m01, m11], [v0, v1]); `None` without a swing to fit.
    fn reduced(&self) -> Option<([f64; 3], [f64; 2])> {
        let n = self.rr[2][2];
        if n < 10.0 {
            return None;
        }
        // Schur complement of the stop's block (1, tau).
        let c = nalgebra::Matrix2::new(self.rr[2][2], self.rr[2][3], self.rr[3][2], self.rr[3][3]);
        let ci = c.try_inverse()?;
        let b = nalgebra::Matrix2::new(self.rr[0][2], self.rr[0][3], self.rr[1][2], self.rr[1][3]);
        let a = nalgebra::Matrix2::new(self.rr[0][0], self.rr[0][1], self.rr[1][0], self.rr[1][1]);
        let m = a - b * ci * b.transpose();
        let v = nalgebra::Vector2::new(self.ra[0], self.ra[1])
            - b * ci * nalgebra::Vector2::new(self.ra[2], self.ra[3]);
        if m[(0, 0)] / n < MIN_SWING_RAD * MIN_SWING_RAD {
            return None;
        }
        Some(([m[(0, 0)], m[(0, 1)], m[(1, 1)]], [v[0], v[1]]))
    }
}

/// The car's pitch mode: stiffness k = omega^2 (1/s^2) and damping d = 2 zeta omega
/// (1/s).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PitchMode {
    pub stiffness_per_s2: f64,
    pub damping_per_s: f64,
}

impl PitchMode {
    fn from_normal(m: &[f64; 3], v: &[f64; 2]) -> Option<Self> {
        let det = m[0] * m[2] - m[1] * m[1];
        if !(det > 0.0) {
            return None;
        }
        let k = (m[2] * v[0] - m[1] * v[1]) / det;
        let d = (m[0] * v[1] - m[1] * v[0]) / det;
        let mode = Self {
            stiffness_per_s2: k,
            damping_per_s: d,
        };
        let f = mode.freq_hz();
        let z = mode.damping_ratio();
        (f >= FREQ_RANGE_HZ.0
            && f <= FREQ_RANGE_HZ.1
            && z >= DAMPING_RANGE.0
            && z <= DAMPING_RANGE.1)
            .then_some(mode)
    }

    /// Undamped natural frequency, Hz.
    pub fn freq_hz(&self) -> f64 {
        self.stiffness_per_s2.max(0.0).sqrt() / std::f64::consts::TAU
    }

    /// Damping ratio.
    pub fn damping_ratio(&self) -> f64 {
        self.damping_per_s / (2.0 * self.stiffness_per_s2.max(1e-12).sqrt())
    }

    /// How far the body stands from the pitch it swings about, about the gyro's y axis,
    /// given its angular acceleration and rate there, rad.
    pub fn offset_rad(&self, alpha_rps2: f64, rate_rps: f64) -> f64 {
        -(alpha_rps2 + self.damping_per_s * rate_rps) / self.stiffness_per_s2
    }
}

/// The stops' swings added up: the normal equations of (k, d), each stop's constant
/// taken out, and how many stops gave them.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct PitchModeFit {
    m: [f64; 3],
    v: [f64; 2],
    stops: u32,
}

impl PitchModeFit {
    /// Finite sums whose squares are not negative: what a saved state must hold.
    pub fn is_plausible(&self) -> bool {
        self.m.iter().chain(&self.v).all(|x| x.is_finite())
            && self.m[0] >= 0.0
            && self.m[2] >= 0.0
            && self.m[1] * self.m[1] <= self.m[0] * self.m[2] * (1.0 + 1e-9)
    }

    /// Add one stop's swing when its own fit is a car's pitch mode.
    pub(super) fn add_stop(&mut self, s: &SwingSums) -> bool {
        let Some((m, v)) = s.reduced() else {
            return false;
        };
        if PitchMode::from_normal(&m, &v).is_none() {
            return false;
        }
        for (a, b) in self.m.iter_mut().zip(m) {
            *a = FORGET * *a + b;
        }
        for (a, b) in self.v.iter_mut().zip(v) {
            *a = FORGET * *a + b;
        }
        self.stops = self.stops.saturating_add(1);
        true
    }

    pub(super) fn mode(&self) -> Option<PitchMode> {
        if self.stops < MIN_STOPS {
            return None;
        }
        PitchMode::from_normal(&self.m, &self.v)
    }
}

impl Estimator {
    /// Add the swing of one stop to the pitch-mode fit: the samples from the rest edge
    /// `rest` to `last`, the gyro-carried pitch counted from the attitude `q_at` at
    /// sample `at`. Samples whose smoothing reaches a knock (a door shock rings at 5-8
    /// Hz, another mode) stay out.
    pub(super) fn learn_pitch_mode(
        &mut self,
        q_at: UnitQuaternion<f64>,
        at: usize,
        rest: usize,
        last: usize,
        g: f64,
    ) {
        if !self.cfg.learn_pitch_mode {
            return;
        }
        let n = self.hist.len();
        let h = self.lever_half();
        let last = last.min(n.saturating_sub(2 * h + 1));
        let first = rest + 2 * h + 2;
        if last <= first + 10 || at >= n {
            return;
        }
        // The gyro cannot carry the pitch across a gap in the samples, and the rate's
        // smoothing counts samples: the swing is read up to the first gap.
        let gap = 1.5 * self.sample_dt_s.0;
        let last = (rest + 1..=last)
            .find(|&j| self.hist.get(j).t_s - self.hist.get(j - 1).t_s > gap)
            .map_or(last, |j| j.saturating_sub(2 * h + 1).min(last));
        if last <= first + 10 {
            return;
        }
        let t_rest = self.hist.get(rest).t_s;
        let bias = self.bias_rps.unwrap_or_else(Vector3::zeros);
        let up = Vector3::new(0.0, 0.0, g);
        let mut q = self.carry(q_at, at, last);
        let mut sums = SwingSums::default();
        // A knock within 2h samples of a sample spoils its smoothing. The walk goes
        // down the history: the lowest knock seen so far is the only one that can
        // still be that close.
        let beyond = |j: usize, q: &UnitQuaternion<f64>| {
            (self.hist.get(j).acc() - q.inverse() * up).amax() > super::lever::MAX_ROCKING_MPS2
        };
        let mut knock_at = (last - 2 * h..=(last + 2 * h).min(n - 1)).find(|&j| beyond(j, &q));
        let mut i = last;
        while i > first {
            if let Some((alpha, omega)) = self.rocking_at(i)
                && knock_at.is_none_or(|k| k > i + 2 * h)
            {
                let theta = (q_at.inverse() * q).scaled_axis().y;
                sums.add(theta, omega.y, alpha.y, self.hist.get(i).t_s - t_rest);
            }
            let entering = i - 1 - 2 * h;
            if beyond(entering, &q) {
                knock_at = Some(entering);
            }
            let (a, b) = (self.hist.get(i - 1), self.hist.get(i));
            let w = (a.gyro_rps() + b.gyro_rps()) * 0.5 - bias;
            q = attitude::propagate(&q, &w, a.t_s - b.t_s);
            i -= 1;
        }
        self.mode_fit.add_stop(&sums);
    }

    /// The car's pitch mode as the stops have shown it: its natural frequency and
    /// damping. The fit sees the rate and its change through the smoothing of
    /// `rocking_at` (means over 2h + 1 samples; their difference over 2h samples), which
    /// passes a swing at omega with gains M and D a few per cent short of 1 (1.5 Hz at
    /// 100 Hz: 0.956 and 0.963); the fit's k is k M D and its d is d D.
    pub fn pitch_mode(&self) -> Option<PitchMode> {
        let seen = self.mode_fit.mode()?;
        let (h, dt) = (self.lever_half() as f64, self.sample_dt_s.0);
        let mut mode = seen;
        for _ in 0..4 {
            let w = mode.stiffness_per_s2.max(0.0).sqrt();
            let m =
                ((2.0 * h + 1.0) * w * dt / 2.0).sin() / ((2.0 * h + 1.0) * (w * dt / 2.0).sin());
            let d = (w * h * dt).sin() / (w * h * dt);
            if !(m > 0.0 && d > 0.0) {
                return Some(seen);
            }
            mode = PitchMode {
                stiffness_per_s2: seen.stiffness_per_s2 / (m * d),
                damping_per_s: seen.damping_per_s / d,
            };
        }
        Some(mode)
    }

    /// The attitude `q` of history sample `i` turned to the pitch the body swings about
    /// there, `-(theta'' + d theta') / k` away (in the fit's own terms, where the
    /// smoothing's gains cancel); `None` without a learnt mode or where the history
    /// cannot show the swing.
    pub(super) fn pitch_at_swing_centre(
        &self,
        q: UnitQuaternion<f64>,
        i: usize,
    ) -> Option<UnitQuaternion<f64>> {
        let mode = self.mode_fit.mode()?;
        let (alpha, omega) = self.rocking_at(i)?;
        let off = mode.offset_rad(alpha.y, omega.y);
        Some(q * UnitQuaternion::from_axis_angle(&Vector3::y_axis(), -off))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A damped swing about `c` sampled at 100 Hz: (theta, rate, alpha).
    fn swing(f_hz: f64, zeta: f64, amp: f64, c: f64) -> Vec<(f64, f64, f64)> {
        let w = std::f64::consts::TAU * f_hz;
        let (k, d) = (w * w, 2.0 * zeta * w);
        let (mut x, mut v) = (amp, 0.0);
        let dt = 0.01;
        let mut out = Vec::new();
        for _ in 0..300 {
            let a = -k * x - d * v;
            out.push((x + c, v, a));
            // Semi-implicit Euler at a fine step.
            for _ in 0..100 {
                let a = -k * x - d * v;
                v += a * dt / 100.0;
                x += v * dt / 100.0;
            }
        }
        out
    }

    #[test]
    fn two_stops_give_the_mode_whatever_each_swings_about() {
        let mut fit = PitchModeFit::default();
        for (amp, c) in [(0.004, 0.01), (-0.003, -0.02)] {
            let mut s = SwingSums::default();
            for (k, (t, r, a)) in swing(1.1, 0.2, amp, c).into_iter().enumerate() {
                // A gyro bias of 0.05 deg/s carried into the pitch.
                let drift = 0.05f64.to_radians() * 0.01 * k as f64;
                s.add(t + drift, r + 0.05f64.to_radians(), a, 0.01 * k as f64);
            }
            assert!(fit.add_stop(&s));
        }
        let m = fit.mode().expect("two stops");
        assert!((m.freq_hz() - 1.1).abs() < 0.01, "{m:?}");
        assert!((m.damping_ratio() - 0.2).abs() < 0.01, "{m:?}");
        // The offset from the centre at any sample.
        for (t, r, a) in swing(1.1, 0.2, 0.004, 0.01).into_iter().step_by(37) {
            assert!(
                (m.offset_rad(a, r) - (t - 0.01)).abs() < 5e-5,
                "{t} {r} {a}"
            );
        }
    }

    #[test]
    fn the_mode_follows_a_damper_wearing_out() {
        let mut fit = PitchModeFit::default();
        let add = |fit: &mut PitchModeFit, zeta: f64| {
            let mut s = SwingSums::default();
            for (k, (t, r, a)) in swing(1.2, zeta, 0.004, 0.0).into_iter().enumerate() {
                s.add(t, r, a, 0.01 * k as f64);
            }
            assert!(fit.add_stop(&s));
        };
        for _ in 0..500 {
            add(&mut fit, 0.3);
        }
        assert!((fit.mode().unwrap().damping_ratio() - 0.3).abs() < 0.01);
        for _ in 0..150 {
            add(&mut fit, 0.15);
        }
        let z = fit.mode().unwrap().damping_ratio();
        assert!((z - 0.15).abs() < 0.02, "{z}");
    }

    #[test]
    fn one_stop_or_a_swing_too_small_teaches_nothing() {
        let mut fit = PitchModeFit::default();
        let mut s = SwingSums::default();
        for (k, (t, r, a)) in swing(1.3, 0.3, 0.004, 0.0).into_iter().enumerate() {
            s.add(t, r, a, 0.01 * k as f64);
        }
        assert!(fit.add_stop(&s));
        assert!(fit.mode().is_none(), "one stop");
        let mut quiet = SwingSums::default();
        for (k, (t, r, a)) in swing(1.3, 0.3, 1e-5, 0.0).into_iter().enumerate() {
            quiet.add(t, r, a, 0.01 * k as f64);
        }
        assert!(!fit.add_stop(&quiet));
    }

    #[test]
    fn a_saved_fit_that_no_stops_could_give_is_implausible() {
        let mut fit = PitchModeFit::default();
        assert!(fit.is_plausible());
        let mut s = SwingSums::default();
        for (k, (t, r, a)) in swing(1.3, 0.3, 0.004, 0.0).into_iter().enumerate() {
            s.add(t, r, a, 0.01 * k as f64);
        }
        fit.add_stop(&s);
        assert!(fit.is_plausible());
        let json = serde_json::to_string(&fit).unwrap();
        for bad in [
            json.replacen("\"m\":[", "\"m\":[-", 1),
            json.replacen("\"v\":[", "\"v\":[1e999,", 1)
                .replacen(",0]", "]", 0),
        ] {
            let parsed: Result<PitchModeFit, _> = serde_json::from_str(&bad);
            assert!(parsed.is_err() || !parsed.unwrap().is_plausible(), "{bad}");
        }
        // Sums no set of samples can have: a cross term beyond the squares'.
        let skewed = PitchModeFit {
            m: [1.0, 2.0, 1.0],
            ..fit
        };
        assert!(!skewed.is_plausible());
    }

    #[test]
    fn a_fit_outside_a_cars_mode_is_left_out() {
        // 6 Hz: a door shock ringing, not the body on its springs.
        let mut s = SwingSums::default();
        for (k, (t, r, a)) in swing(6.0, 0.1, 0.004, 0.0).into_iter().enumerate() {
            s.add(t, r, a, 0.01 * k as f64);
        }
        assert!(!PitchModeFit::default().add_stop(&s));
    }
}
