//! Road unevenness: a random height profile on top of the smooth grade, with the
//! displacement spectrum of ISO 8608 (G_d(n) = G_d(n0) (n / n0)^-2, n0 = 0.1 cycle/m),
//! rolled off by first-order edges at wavelengths of 10 m (longer is the grade's
//! business) and 0.5 m (the tyre bridges shorter ones). The body feels it through its
//! suspension (`drive.rs`).

use super::noise::Gauss;
use serde::{Deserialize, Serialize};

/// Spacing of the profile's samples, m.
const STEP_M: f64 = 0.02;
/// Spatial frequency of ISO 8608's reference, cycle/m.
const N0_PER_M: f64 = 0.1;
/// Band kept, cycle/m: longer waves are grade, the tyre's contact patch bridges shorter.
const N_LOW_PER_M: f64 = 0.1;
const N_HIGH_PER_M: f64 = 2.0;
/// The profile starts this far behind the start line (the rear axle begins behind it), m.
const BEHIND_M: f64 = 20.0;

/// Unevenness of a road: its degree (0: smooth) and the seed of its profile.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Roughness {
    /// ISO 8608 displacement PSD at 0.1 cycle/m, 1e-6 m^3 (class A 0-32, B 32-128).
    pub psd_1e6_m3: f64,
    pub seed: u64,
}

/// The height profile of a `Roughness`, drawn as far ahead as it is asked for.
#[derive(Debug, Clone)]
pub struct Profile {
    noise: Gauss,
    /// Slope increment per step, m.
    inc_sigma_m: f64,
    high_pass: f64,
    low_pass: f64,
    /// (high-passed, low-passed) state of the last sample drawn.
    state: (f64, f64),
    heights_m: Vec<f64>,
}

impl Profile {
    pub fn new(r: &Roughness) -> Self {
        // G_d ~ n^-2 is a height whose slope is white with one-sided PSD (2 pi n0)^2 G_d(n0).
        let slope_psd = (std::f64::consts::TAU * N0_PER_M).powi(2) * r.psd_1e6_m3 * 1e-6;
        let pole = |n: f64| (-std::f64::consts::TAU * n * STEP_M).exp();
        Self {
            noise: Gauss::new(r.seed ^ 0x726f_7567_6821),
            inc_sigma_m: (0.5 * slope_psd * STEP_M).sqrt(),
            high_pass: pole(N_LOW_PER_M),
            low_pass: 1.0 - pole(N_HIGH_PER_M),
            state: (0.0, 0.0),
            heights_m: Vec::new(),
        }
    }

    /// Height of the profile at distance `s_m` (linear between samples), m.
    pub fn height_m(&mut self, s_m: f64) -> f64 {
        if self.inc_sigma_m == 0.0 {
            return 0.0;
        }
        let x = ((s_m + BEHIND_M) / STEP_M).max(0.0);
        let i = x.floor() as usize;
        while self.heights_m.len() < i + 2 {
            let (hp, lp) = self.state;
            let hp = self.high_pass * (hp + self.inc_sigma_m * self.noise.normal());
            let lp = lp + self.low_pass * (hp - lp);
            self.state = (hp, lp);
            self.heights_m.push(lp);
        }
        let f = x - i as f64;
        self.heights_m[i] * (1.0 - f) + self.heights_m[i + 1] * f
    }
}

#[cfg(test)]
mod tests {
    use super::{Profile, Roughness};

    /// Height variance of ISO 8608's spectrum through the profile's first-order band
    /// edges at n1 and n2, m^2: G0 n0^2 pi n2 / (2 n1 (n1 + n2)).
    fn filtered_iso_variance(psd_1e6_m3: f64) -> f64 {
        let (n0, n1, n2) = (0.1, 0.1, 2.0);
        psd_1e6_m3 * 1e-6 * n0 * n0 * std::f64::consts::PI * n2 / (2.0 * n1 * (n1 + n2))
    }

    #[test]
    fn heights_have_the_iso_spread_and_a_seed_gives_one_road() {
        let r = Roughness {
            psd_1e6_m3: 32.0,
            seed: 7,
        };
        let mut p = Profile::new(&r);
        let h: Vec<f64> = (0..250_000).map(|k| p.height_m(k as f64 * 0.02)).collect();
        let mean = h.iter().sum::<f64>() / h.len() as f64;
        let var = h.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / h.len() as f64;
        // 5 km hold about 500 of the longest waves: a 10 % spread.
        let ratio = var / filtered_iso_variance(32.0);
        assert!(ratio > 0.8 && ratio < 1.2, "variance {ratio} of ISO's");
        assert!(mean.abs() < 0.5e-3, "mean {mean}");
        // The same road read again, out of order, is the same road.
        let mut q = Profile::new(&r);
        assert_eq!(q.height_m(1234.5), p.height_m(1234.5));
        assert_eq!(Profile::new(&Roughness::default()).height_m(10.0), 0.0);
    }
}
