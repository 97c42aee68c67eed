//! The IMU's lever arm to the body pitch centre, learnt from the body rocking at rest.
//!
//! A headlamp IMU sits about 2 m ahead of the pitch centre, and after every stop the
//! body rocks on its suspension at 1-2 Hz. The IMU then moves on a 2 m arc at up to
//! 0.1 m/s: a deceleration window started at the stop must begin with that velocity,
//! omega x r, and a lever arm 5 % off in the configuration costs about 0.3 deg of slope.
//! The rocking itself measures the arm: at rest the accelerometer reads gravity turned
//! by the gyro-carried attitude plus alpha x r + omega x (omega x r), linear in r. Each
//! stop adds its rocking to a least-squares fit, held to the configured arm by a weak
//! prior (the lateral offset, which pitch rocking does not observe, stays configured).

use super::Estimator;
use super::attitude;
use nalgebra::{Matrix3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

/// Prior weight of the configured arm, 1/s^4: about a 0.2 m standard deviation against
/// a 0.03 m/s^2 accelerometer, so one stop's rocking (information of order 10) already
/// outweighs it.
const PRIOR_WEIGHT: f64 = 0.03;

/// Rocking on the springs moves a headlamp IMU by a few tenths of a m/s^2. A sample
/// whose smoothing reaches a raw reading further than this from gravity is left out:
/// a door slammed or someone sitting down gives the body a knock whose sharp edge
/// the smoothing of the rates and of the force do not follow alike, and the fit
/// comes out 10-40 % short on such a stop. m/s^2.
pub(super) const MAX_ROCKING_MPS2: f64 = 1.5;

/// Samples this far from what the arm in use predicts are not rocking (braking left
/// in), m/s^2. The test is symmetric about the prediction.
const MAX_RESIDUAL_MPS2: f64 = 1.0;

/// How long past the first settled sample the fit keeps reading, s.
const FIT_TAIL_S: f64 = 0.5;

/// Normal equations of the lever-arm fit.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct LeverFit {
    /// Sum of M^T M, row-major.
    pub mtm: [f64; 9],
    /// Sum of M^T residual.
    pub mtr: [f64; 3],
}

impl LeverFit {
    /// Remove the part of M^T M that noise in the angular acceleration adds on average
    /// over `n` samples: noise of variance `var_alpha` per axis adds 2 var_alpha to each
    /// diagonal entry of skew(alpha)^T skew(alpha). Left in, it shortens the fitted arm
    /// (about 2 % with a 0.01 deg/s/sqrt(Hz) gyro at 1.3 Hz rocking). An axis that
    /// saw little but noise stays at zero rather than going negative. Returns what it
    /// took off each diagonal entry.
    fn remove_noise(&mut self, n: usize, var_alpha: f64) -> f64 {
        let noise = n as f64 * 2.0 * var_alpha;
        for k in [0, 4, 8] {
            self.mtm[k] = (self.mtm[k] - noise).max(0.0);
        }
        noise
    }

    fn add(&mut self, m: &Matrix3<f64>, res: &Vector3<f64>) {
        let mtm = m.transpose() * m;
        let mtr = m.transpose() * res;
        for (a, b) in self.mtm.iter_mut().zip(mtm.transpose().iter()) {
            *a += b;
        }
        for (a, b) in self.mtr.iter_mut().zip(mtr.iter()) {
            *a += b;
        }
    }

    /// Lever arm (m): the fit held to `prior` by the prior weight.
    pub fn solve(&self, prior: &Vector3<f64>) -> Vector3<f64> {
        let mut a = Matrix3::from_row_slice(&self.mtm);
        let mut b = Vector3::from(self.mtr);
        for k in 0..3 {
            a[(k, k)] += PRIOR_WEIGHT;
            b[k] += PRIOR_WEIGHT * prior[k];
        }
        // The lateral arm is not observed by pitch rocking: keep the configured one.
        for k in 0..3 {
            a[(1, k)] = 0.0;
            a[(k, 1)] = 0.0;
        }
        a[(1, 1)] = 1.0;
        b[1] = prior[1];
        a.lu()
            .solve(&b)
            .filter(|r| r.iter().all(|v| v.is_finite() && v.abs() <= 10.0))
            .unwrap_or(*prior)
    }

    pub fn is_finite(&self) -> bool {
        self.mtm
            .iter()
            .chain(self.mtr.iter())
            .all(|v| v.is_finite())
    }
}

/// Cross-product matrix: `skew(a) * r == a.cross(&r)`.
fn skew(a: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -a.z, a.y, a.z, 0.0, -a.x, -a.y, a.x, 0.0)
}

impl Estimator {
    /// Specific force at history sample `i` through the same smoothing that
    /// `rocking_at` puts on the angular acceleration, so that the fit compares like with
    /// like: the raw reading against the smoothed alpha would read the arm about 8 %
    /// long at 1.5 Hz, and a door shock at 6 Hz is smoothed to a third. The caller
    /// checks that the samples exist (as `rocking_at` does).
    fn acc_smoothed_like_rocking(&self, i: usize) -> Vector3<f64> {
        let h = self.lever_half();
        // alpha(i) = (mean rate over i+h +- h - mean rate over i-h +- h) / span: for each
        // of the 2h+1 centres k, the rate difference across k +- h is the trapezoid mean
        // of alpha over those 2h intervals. The same two means on the accelerometer:
        let mut sum = Vector3::zeros();
        for k in i - h..=i + h {
            let mut inner = (self.hist.get(k - h).acc() + self.hist.get(k + h).acc()) * 0.5;
            for j in k + 1 - h..k + h {
                inner += self.hist.get(j).acc();
            }
            sum += inner / (2 * h) as f64;
        }
        sum / (2 * h + 1) as f64
    }

    /// Variance of the noise in `rocking_at`'s angular acceleration per axis,
    /// (rad/s^2)^2, from the gyro's own noise between samples `from` and `to`: second
    /// differences of the pitch rate cancel the rocking (1-2 Hz at 100 Hz) and keep the
    /// noise (6 sigma^2); the median keeps door shocks out. The smoothing of
    /// `rocking_at` (two means of 2h + 1 samples, 2h apart, sharing one; 11 samples at
    /// 100 Hz) turns a rate noise sigma into an acceleration noise of
    /// sigma^2 * (2 / w - 2 / w^2) / span^2 for w = 2h + 1.
    fn alpha_noise_var(&self, from: usize, to: usize) -> f64 {
        let h = self.lever_half();
        const MAX: usize = 256;
        let mut d2 = [0.0f64; MAX];
        let mut n = 0;
        for i in from + 1..to.min(from + MAX) {
            let (a, b, c) = (self.hist.get(i - 1), self.hist.get(i), self.hist.get(i + 1));
            d2[n] = (a.gyro_rps().y - 2.0 * b.gyro_rps().y + c.gyro_rps().y).abs();
            n += 1;
        }
        if n < 20 {
            return 0.0;
        }
        let d = &mut d2[..n];
        d.sort_by(f64::total_cmp);
        // Median of |N(0, 6 s^2)| is 0.6745 * sqrt(6) s.
        let sigma = d[n / 2] / (0.6745 * 6f64.sqrt());
        let span = self.hist.get(to).t_s - self.hist.get(to - 2 * h).t_s;
        let w = (2 * h + 1) as f64;
        let var_diff = sigma * sigma * (2.0 / w - 2.0 / (w * w));
        if span > 0.0 {
            var_diff / (span * span)
        } else {
            0.0
        }
    }

    /// Lever arm in use: configured, refined by the rocking seen at stops, m.
    pub(super) fn lever_arm(&self) -> Vector3<f64> {
        self.lever_arm
    }

    /// Add the rocking of one stop to the fit: samples from the rest edge `rest` to
    /// `FIT_TAIL_S` past the first settled sample `settled`, whose attitude is `q_ref`,
    /// and no further than the last settled sample `at_rest` allows.
    pub(super) fn learn_lever(
        &mut self,
        q_ref: UnitQuaternion<f64>,
        rest: usize,
        settled: usize,
        at_rest: usize,
        g: f64,
    ) {
        let prior = Vector3::from(self.cfg.lever_arm_m);
        if prior == Vector3::zeros() || !self.cfg.learn_lever_arm {
            return;
        }
        let n = self.hist.len();
        let t_end = self.hist.get(settled.min(n - 1)).t_s + FIT_TAIL_S;
        let h = self.lever_half();
        // A stop shorter than the tail is fitted when it ends, with the drive-off in
        // the history: the car pulling away reads as force along x while the body
        // squats, as a lever arm metres below the pitch centre would. The smoothing
        // reaches 2 H samples ahead, so the fit stops that far before the last sample
        // known to be at rest.
        let last = self
            .index_at(t_end)
            .min(n - 1)
            .min(at_rest.saturating_sub(2 * h));
        if last <= rest + 2 * h + 2 {
            return;
        }
        let bias = self.bias_rps.unwrap_or_else(Vector3::zeros);
        let up = Vector3::new(0.0, 0.0, g);
        let mut q = self.carry(q_ref, settled.min(n - 1), last);
        let var_alpha = self.alpha_noise_var(rest, last);
        let mut fit = self.lever_fit;
        let mut used = 0usize;
        let mut i = last;
        // The smoothing reaches 2 H samples either side: keep braking out of it.
        let first = rest + 2 * h + 2;
        while i > first {
            // Every sample of the rocking enters, whatever its angular acceleration:
            // samples chosen by that noisy regressor would be those whose noise added
            // to the rocking, and `remove_noise` takes off only the noise's mean share.
            // With a 0.03-0.05 deg/s/sqrt(Hz) gyro a cut at 0.05 rad/s^2 kept mostly
            // noise late in the rocking, and the arm came out short enough to bias the
            // deceleration windows by +0.05 to +0.12 deg.
            if let Some((alpha, omega)) = self.rocking_at(i) {
                let g_imu = q.inverse() * up;
                let res = self.acc_smoothed_like_rocking(i) - g_imu;
                let m = skew(&alpha) + skew(&omega) * skew(&omega);
                let predicted = m * self.lever_arm;
                let impulsive = (i - 2 * h..=(i + 2 * h).min(n - 1))
                    .any(|j| (self.hist.get(j).acc() - g_imu).amax() > MAX_ROCKING_MPS2);
                if !impulsive && (res - predicted).amax() <= MAX_RESIDUAL_MPS2 {
                    fit.add(&m, &res);
                    used += 1;
                }
            }
            let (a, b) = (self.hist.get(i - 1), self.hist.get(i));
            let w = (a.gyro_rps() + b.gyro_rps()) * 0.5 - bias;
            q = attitude::propagate(&q, &w, a.t_s - b.t_s);
            i -= 1;
        }
        // A stop whose rocking is weaker than the gyro's noise in it (a smooth stop, a
        // noisy gyro) measures nothing: taking the noise's mean share off leaves too
        // little, and one such stop read 9 m for a 2.1 m arm. Its samples are left out
        // when what remains after `remove_noise` is less than the noise taken off.
        let before = self.lever_fit;
        let noise = fit.remove_noise(used, var_alpha);
        if [0, 8].iter().any(|&k| fit.mtm[k] - before.mtm[k] < noise) {
            return;
        }
        if fit.is_finite() {
            self.lever_fit = fit;
            self.lever_arm = fit.solve(&prior);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fit_recovers_an_arm_from_rocking_and_keeps_the_lateral_prior() {
        let truth = Vector3::new(2.1, 0.65, 0.4);
        let prior = Vector3::new(2.0, 0.0, 0.3);
        let mut fit = LeverFit::default();
        for k in 0..200 {
            let t = k as f64 * 0.01;
            let alpha = Vector3::new(0.0, 0.5 * (8.0 * t).sin(), 0.0);
            let omega = Vector3::new(0.0, 0.06 * (8.0 * t).cos(), 0.0);
            let m = skew(&alpha) + skew(&omega) * skew(&omega);
            fit.add(&m, &(m * truth));
        }
        let r = fit.solve(&prior);
        assert!((r.x - 2.1).abs() < 0.01, "{r}");
        assert!((r.z - 0.4).abs() < 0.01, "{r}");
        assert_eq!(r.y, 0.0, "lateral arm is not observed and stays configured");
    }

    #[test]
    fn without_rocking_the_configured_arm_stands() {
        let prior = Vector3::new(2.0, 0.0, 0.3);
        assert_eq!(LeverFit::default().solve(&prior), prior);
    }
}
