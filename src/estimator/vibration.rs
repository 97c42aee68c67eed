//! An engine idling next to the IMU. Its firing shakes every sample at rest by 0.1-0.3
//! m/s^2 at 20-40 Hz, which integrates to nothing, but a mean over a span that is not
//! a whole number of its periods keeps part of a cycle: up to a sample's worth over
//! the samples averaged, about 1 mm/s^2 in a 3 s stop, and a window reads 1 mm/s^2 of
//! gravity as 0.1 deg of slope on a gentle drive-off. The per-sample spread also counts
//! the shaking as noise, so a good accelerometer next to an engine looks like a noisy
//! one to every choice made on its noise. The settled samples are therefore also read
//! through a triangle that passes what a stop's mean and a walk's speed are made of
//! (below a few hertz) and all but removes 20-40 Hz; when blocks of those readings
//! differ far less than the raw samples spread (`GravityFilter::vibrating`), the stops
//! average them instead, and the noise a walk integrates is theirs.

use super::Estimator;
use nalgebra::Vector3;

/// Length of each of the two boxes whose convolution is the smoothing triangle, s: its
/// response is under 2 % at 20-40 Hz (a four- to six-cylinder engine at idle) and at
/// least 0.9 below 1 Hz.
pub(super) const VIBRATION_BOX_S: f64 = 0.1;

impl Estimator {
    /// Samples per box of the smoothing triangle (at least 2).
    pub(super) fn vibration_box(&self) -> usize {
        self.samples_in(VIBRATION_BOX_S).max(2)
    }

    /// The accelerometer at history sample `i` smoothed by the triangle of
    /// `vibration_box`, m/s^2; `None` near either end of the history or when a sample in
    /// its span is missing: a dropped sample takes its part of the shaking out of any
    /// mean, smoothed or not, and leaves the rest of the cycle in it.
    pub(super) fn smoothed_acc_at(&self, i: usize) -> Option<Vector3<f64>> {
        let l = self.vibration_box();
        if i + 1 < l || i + l > self.hist.len() {
            return None;
        }
        let max_dt = 1.5 * self.sample_dt_s.0;
        let (first, last) = (i + 1 - l, i + l - 1);
        let mut sum = Vector3::zeros();
        let mut prev_t = self.hist.get(first).t_s;
        for j in first..=last {
            let x = self.hist.get(j);
            if x.t_s - prev_t > max_dt {
                return None;
            }
            prev_t = x.t_s;
            let w = (l - i.abs_diff(j)) as f64;
            sum += x.acc() * w;
        }
        Some(sum / (l * l) as f64)
    }
}

/// For white noise of unit variance per sample: the variance of the difference between
/// the means of two adjacent blocks of `n0` and `n1` samples read through the triangle of
/// two boxes of `l`, over the same for raw samples (1/n0 + 1/n1). The triangle spans the
/// blocks' joint and ends, which it smooths: about 0.6-0.7 for quarter-second blocks at
/// 100 Hz.
pub(super) fn smoothed_pair_gain(n0: usize, n1: usize, l: usize) -> f64 {
    if n0 == 0 || n1 == 0 || l == 0 {
        return 1.0;
    }
    let (a, b) = (1.0 / n0 as f64, 1.0 / n1 as f64);
    let norm = (l * l) as f64;
    // Raw sample j (offset by l - 1 so that it never goes negative) weighs in the
    // difference by the sum over the block samples k whose triangle reaches it.
    let total = n0 + n1 + 2 * (l - 1);
    let mut sum_sq = 0.0;
    for j in 0..total {
        let mut w = 0.0;
        for d in 0..(2 * l - 1) {
            // Block sample k = j - (l - 1) + (d - (l - 1)) = j + d - 2(l - 1).
            let Some(k) = (j + d).checked_sub(2 * (l - 1)) else {
                continue;
            };
            let tri = (l - d.abs_diff(l - 1)) as f64 / norm;
            if k < n0 {
                w -= a * tri;
            } else if k < n0 + n1 {
                w += b * tri;
            }
        }
        sum_sq += w * w;
    }
    sum_sq / (a + b)
}

#[cfg(test)]
mod tests {
    use super::smoothed_pair_gain;
    use crate::estimator::{Estimator, EstimatorConfig, ImuSample};

    #[test]
    fn the_pair_gain_is_one_without_smoothing_and_matches_a_simulation() {
        // A box of one sample is no smoothing.
        assert!((smoothed_pair_gain(25, 25, 1) - 1.0).abs() < 1e-12);
        // Monte Carlo of the same quantity: white noise, triangle of two boxes of 10,
        // adjacent blocks of 25.
        let (n, l) = (25usize, 10usize);
        let mut x = 0x9E37_79B9_7F4A_7C15u64;
        let mut normal = || {
            let mut u = || {
                x ^= x >> 12;
                x ^= x << 25;
                x ^= x >> 27;
                ((x.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f64 + 0.5) / (1u64 << 53) as f64
            };
            let (u1, u2) = (u(), u());
            (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
        };
        let trials = 20_000;
        let mut var = 0.0;
        let len = 2 * n + 2 * (l - 1);
        let mut raw = vec![0.0; len];
        for _ in 0..trials {
            raw.iter_mut().for_each(|v| *v = normal());
            let smooth = |k: usize| {
                let c = k + l - 1;
                (0..2 * l - 1)
                    .map(|d| (l - d.abs_diff(l - 1)) as f64 * raw[c + d + 1 - l])
                    .sum::<f64>()
                    / (l * l) as f64
            };
            let m0 = (0..n).map(smooth).sum::<f64>() / n as f64;
            let m1 = (n..2 * n).map(smooth).sum::<f64>() / n as f64;
            var += (m1 - m0).powi(2);
        }
        let measured = var / trials as f64 / (2.0 / n as f64);
        let g = smoothed_pair_gain(n, n, l);
        assert!(g < 0.9 && g > 0.4, "gain {g}");
        assert!(
            (measured - g).abs() < 0.03,
            "simulated {measured:.3}, computed {g:.3}"
        );
    }

    #[test]
    fn the_triangle_removes_an_engines_tone_and_keeps_a_slow_change() {
        let mut est = Estimator::new(EstimatorConfig::default()).unwrap();
        // 1 s of 100 Hz samples: gravity, a slow tilt and a 27 Hz tone of 0.3 m/s^2.
        for k in 0..100 {
            let t = k as f64 * 0.01;
            let tone = 0.3 * (std::f64::consts::TAU * 27.0 * t).sin();
            est.hist
                .push(ImuSample::new(t, [0.01 * t, 0.0, 9.81 + tone], [0.0; 3]));
        }
        est.sample_dt_s = (0.01, 0);
        let s = est.smoothed_acc_at(50).unwrap();
        assert!((s.z - 9.81).abs() < 0.01, "z {}", s.z);
        assert!((s.x - 0.005).abs() < 1e-9, "x {}", s.x);
        assert!(est.smoothed_acc_at(5).is_none() && est.smoothed_acc_at(95).is_none());
    }
}
