//! The body's pitch on a grade.
//!
//! The suspension pitches the body with the longitudinal force the tyres pass to it.
//! Braking at a m/s^2 dives it by k a; standing on a grade, the brakes hold gravity's
//! share along the road, g sin(grade), through the same path, and the body dives or
//! squats by k g sin(grade) as if it braked or pulled away that hard. A window's
//! reference is taken there, so it measures the road-to-body pitch of that grade, not
//! the one on level ground that the headlamps must be levelled for: 0.1-0.4 deg on a
//! 10 % grade for k of 0.1-0.3 deg per m/s^2.
//!
//! k is learnt from the deceleration windows: over the last metres before the stop the
//! body is dived by k times the braking, and the gyro carries that against the settled
//! reference. Braking, not pulling away, because a car held on a grade is held by its
//! brakes, and anti-dive geometry makes the two differ on many cars.
//!
//! Pulling away, the drivetrain pushes the body and it squats by its own k_s per m/s^2
//! (anti-squat geometry and the driven axle's torque reaction, not the brakes'),
//! learnt from the acceleration windows the same way from a prior of k. A window's
//! walk one wheelbase out takes out the pitch the force gave the body there
//! (`fusion.rs`, `axle_slope_rad`), and pulling away that is k_s's.
//!
//! Whether the body shows all of k g sin(grade) at rest is left to the windows: the
//! average fits the share of it (`average.rs`, `GradeShare`) with the load's pitch,
//! from stops at different grades. A car held by its foot brake shows all of it; one
//! held on a parking brake of one axle, or a vehicle model whose body stands on every
//! grade as on level ground, shows less or none, and taking the whole of it out would
//! add k g sin(grade) to every window there (0.2 deg on a 10 % grade).

use serde::{Deserialize, Serialize};

/// Largest k taken from the windows, rad per m/s^2 (1 deg per m/s^2, three times a
/// soft car's): beyond it a fit is noise.
const MAX_PER_FORCE_RAD: f64 = 0.0175;

/// Weight of the prior k = 0, in squared acceleration, (m/s^2)^2: one stop braked at
/// 0.7 m/s^2. A window's correction is taken with the k learnt by then and kept in the
/// average, so the first stops must already be corrected nearly in full; one window
/// braked at 1.5 m/s^2 gives 80 % of k.
const PRIOR_WEIGHT_MPS2_SQ: f64 = 0.5;

/// Each new window keeps this share of what the older ones taught: the load (the
/// springs' working point) changes k a little.
const FORGET: f64 = 0.98;

/// Windows braked more gently than this teach nothing, m/s^2: their dive is hardly
/// larger than the pitch of a grade change inside the window.
const MIN_ACCEL_MPS2: f64 = 0.3;

/// Least-squares fit through zero of the body's pitch against the braking under it.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct GradePitch {
    /// Sums of acceleration times pitch change, (m/s^2) rad, and of acceleration
    /// squared, (m/s^2)^2, forgotten at `FORGET` per window.
    sum_ap: f64,
    sum_aa: f64,
    /// Sum of the pitch changes squared, rad^2, and the number of windows, both
    /// forgotten alike: the fit's residual spread (absent in a state written before).
    #[serde(default)]
    sum_pp: f64,
    #[serde(default)]
    windows: f64,
}

impl GradePitch {
    /// Add one window: its mean acceleration along the travel (negative while braking),
    /// m/s^2, and the body's mean pitch over it less the pitch at rest, rad.
    pub fn learn(&mut self, accel_mps2: f64, pitch_change_rad: f64) {
        if !(accel_mps2.is_finite() && pitch_change_rad.is_finite())
            || accel_mps2.abs() < MIN_ACCEL_MPS2
        {
            return;
        }
        self.sum_ap = FORGET * self.sum_ap + accel_mps2 * pitch_change_rad;
        self.sum_aa = FORGET * self.sum_aa + accel_mps2 * accel_mps2;
        self.sum_pp = FORGET * self.sum_pp + pitch_change_rad * pitch_change_rad;
        self.windows = FORGET * self.windows + 1.0;
    }

    /// Variance of the fitted k, rad^2 per (m/s^2)^2: the windows' scatter about the
    /// line over their spread in acceleration. Infinite until three windows.
    pub fn per_force_var(&self) -> f64 {
        if !(self.windows >= 3.0 && self.sum_aa > 0.0) {
            return f64::INFINITY;
        }
        let k = self.sum_ap / self.sum_aa;
        let ss = (self.sum_pp - k * self.sum_ap).max(0.0);
        ss / (self.windows - 1.0) / self.sum_aa
    }

    /// Finite sums, the squares' not negative: what a saved state must hold.
    pub fn is_plausible(&self) -> bool {
        self.sum_ap.is_finite()
            && self.sum_aa.is_finite()
            && self.sum_aa >= 0.0
            && self.sum_pp.is_finite()
            && self.sum_pp >= 0.0
            && self.windows.is_finite()
            && self.windows >= 0.0
    }

    /// Body pitch per m/s^2 of longitudinal force, rad (nose-up for a force forward).
    pub fn per_force_rad(&self) -> f64 {
        self.per_force_from_rad(0.0)
    }

    /// `per_force_rad` from a prior of `prior_rad` instead of 0 (the squat from the
    /// dive: until acceleration windows tell, a body squats as it dives).
    pub fn per_force_from_rad(&self, prior_rad: f64) -> f64 {
        let prior = if prior_rad.is_finite() {
            prior_rad
        } else {
            0.0
        };
        ((self.sum_ap + PRIOR_WEIGHT_MPS2_SQ * prior) / (self.sum_aa + PRIOR_WEIGHT_MPS2_SQ))
            .clamp(0.0, MAX_PER_FORCE_RAD)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const DEG: f64 = std::f64::consts::PI / 180.0;

    #[test]
    fn the_dive_under_braking_gives_the_squat_on_a_grade() {
        let mut g = GradePitch::default();
        assert_eq!(g.per_force_rad(), 0.0, "nothing learnt, nothing corrected");
        // A car that dives 0.25 deg per m/s^2, braked at 0.8-2.4 m/s^2, with the pitch
        // of a grade change inside each window (+-0.05 deg) on top.
        for i in 0..40 {
            let a = -(0.8 + 0.04 * i as f64);
            let noise = if i % 2 == 0 { 0.05 } else { -0.05 } * DEG;
            g.learn(a, 0.25 * DEG * a + noise);
        }
        let k = g.per_force_rad() / DEG;
        // The prior still holds k back by a percent.
        assert!((k - 0.25).abs() < 0.01, "{k}");
    }

    /// The squat starts from the dive and follows what pulling away shows.
    #[test]
    fn the_squat_starts_as_the_dive_and_learns_its_own() {
        let (dive, mut squat) = (0.25 * DEG, GradePitch::default());
        assert_eq!(squat.per_force_from_rad(dive), dive);
        assert_eq!(squat.per_force_from_rad(f64::NAN), 0.0);
        // A body that squats 0.1 deg per m/s^2, pulling away at 0.5-1.7 m/s^2.
        for i in 0..30 {
            let a = 0.5 + 0.04 * i as f64;
            squat.learn(a, 0.1 * DEG * a);
        }
        let k = squat.per_force_from_rad(dive) / DEG;
        assert!((k - 0.1).abs() < 0.01, "{k}");
        // Windows on the line leave k known exactly; scatter about it, less so.
        assert!(squat.per_force_var() < 1e-12, "{}", squat.per_force_var());
        let mut noisy = GradePitch::default();
        assert!(noisy.per_force_var().is_infinite());
        for i in 0..30 {
            let a = 0.5 + 0.04 * i as f64;
            let scatter = if i % 2 == 0 { 0.05 } else { -0.05 } * DEG;
            noisy.learn(a, 0.1 * DEG * a + scatter);
        }
        // 0.05 deg of scatter over windows whose squared accelerations sum to about
        // 25 (m/s^2)^2 once forgotten: k to about 0.01 deg per m/s^2.
        let sd = noisy.per_force_var().sqrt() / DEG;
        assert!(sd > 0.005 && sd < 0.02, "{sd}");
    }

    #[test]
    fn gentle_braking_and_bad_numbers_teach_nothing_and_k_stays_physical() {
        let mut g = GradePitch::default();
        g.learn(-0.2, -DEG);
        g.learn(f64::NAN, 0.0);
        g.learn(-1.0, f64::INFINITY);
        assert_eq!(g, GradePitch::default());
        // A body that pitched up while braking is no suspension: k is not negative.
        for _ in 0..10 {
            g.learn(-1.5, 0.3 * DEG);
        }
        assert_eq!(g.per_force_rad(), 0.0);
        for _ in 0..10 {
            g.learn(-1.5, -30.0 * DEG);
        }
        assert_eq!(g.per_force_rad(), MAX_PER_FORCE_RAD);
    }
}
