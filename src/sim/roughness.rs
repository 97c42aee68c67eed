//! Road unevenness: a random height profile on top of the smooth grade, with the
//! displacement spectrum of ISO 8608 (G_d(n) = G_d(n0) (n / n0)^-2, n0 = 0.1 cycle/m),
//! rolled off by first-order edges at wavelengths of 10 m (longer is the grade's
//! business) and 0.5 m (the tyre bridges shorter ones). The body feels it through its
//! suspension (`Ride`).

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

/// What a road's unevenness may be, for the errors that reject others.
pub const PSD_HINT: &str =
    "give 0 (a smooth road) or more, in 1e-6 m^3; ISO 8608 class A is 0-32, B 32-128, C 128-512";

impl Roughness {
    /// Reject a degree the profile cannot be drawn with; the error names the key.
    pub fn check(&self) -> anyhow::Result<()> {
        let r = self.psd_1e6_m3;
        if r.is_finite() && r >= 0.0 {
            Ok(())
        } else {
            anyhow::bail!("road.roughness.psd_1e6_m3 = {r}: {PSD_HINT}")
        }
    }
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

/// Road unevenness reaches the body through the tyre and the unsprung mass of each
/// wheel, taken as a first-order low-pass of this corner frequency, Hz (wheel hop is at
/// 10-15 Hz; above it a wheel no longer pushes the body).
const WHEEL_PASS_HZ: f64 = 6.0;

/// The body's answer to the unevenness under its axles, on top of the smooth road it
/// follows exactly: each wheel passes the road through its tyre and unsprung mass, and
/// a spring and damper between body and wheels carry it into the body's heave and
/// pitch modes.
#[derive(Debug, Clone)]
pub struct Ride {
    profile: Profile,
    wheelbase_m: f64,
    /// Angular frequency (rad/s) and damping ratio of the heave and pitch modes.
    heave_mode: (f64, f64),
    pitch_mode: (f64, f64),
    /// Fixed step of `step`, s, and the share of the road a wheel takes up in it.
    step_s: f64,
    wheel_gain: f64,
    /// Front and rear wheel heights, m, and the (heave m, pitch rad) input they gave,
    /// as of the last step; none before the first.
    last: Option<((f64, f64), (f64, f64))>,
    /// (heave m, its rate m/s) and (pitch rad, its rate rad/s).
    heave: (f64, f64),
    pitch: (f64, f64),
}

impl Ride {
    /// `heave_mode` and `pitch_mode`: natural frequency (Hz) and damping ratio; `step_s`,
    /// the fixed step of `step`.
    pub fn new(
        road: &Roughness,
        wheelbase_m: f64,
        heave_mode: (f64, f64),
        pitch_mode: (f64, f64),
        step_s: f64,
    ) -> Self {
        let w = |(hz, zeta): (f64, f64)| (std::f64::consts::TAU * hz, zeta);
        Self {
            profile: Profile::new(road),
            wheelbase_m,
            heave_mode: w(heave_mode),
            pitch_mode: w(pitch_mode),
            step_s,
            wheel_gain: 1.0 - (-std::f64::consts::TAU * WHEEL_PASS_HZ * step_s).exp(),
            last: None,
            heave: (0.0, 0.0),
            pitch: (0.0, 0.0),
        }
    }

    /// With the axles at `s_front_m` and `s_rear_m`: the body's pitch from the road now
    /// (rad) and its heave acceleration (m/s^2); then the state moves on by one step.
    /// The car starts at rest on the road as it is.
    pub fn step(&mut self, s_front_m: f64, s_rear_m: f64) -> (f64, f64) {
        let step_s = self.step_s;
        let road = (
            self.profile.height_m(s_front_m),
            self.profile.height_m(s_rear_m),
        );
        let wheels = match self.last {
            Some(((f, r), _)) => (
                f + self.wheel_gain * (road.0 - f),
                r + self.wheel_gain * (road.1 - r),
            ),
            None => road,
        };
        let input = (
            0.5 * (wheels.0 + wheels.1),
            (wheels.0 - wheels.1) / self.wheelbase_m,
        );
        let rate = match self.last {
            Some((_, prev)) => ((input.0 - prev.0) / step_s, (input.1 - prev.1) / step_s),
            None => {
                self.heave.0 = input.0;
                self.pitch.0 = input.1;
                (0.0, 0.0)
            }
        };
        self.last = Some((wheels, input));
        let accel = |(x, dx): (f64, f64), (u, du): (f64, f64), (w, zeta): (f64, f64)| {
            w * w * (u - x) + 2.0 * zeta * w * (du - dx)
        };
        let heave_dd = accel(self.heave, (input.0, rate.0), self.heave_mode);
        let pitch_dd = accel(self.pitch, (input.1, rate.1), self.pitch_mode);
        let pitch_rad = self.pitch.0;
        for (x, dd) in [(&mut self.heave, heave_dd), (&mut self.pitch, pitch_dd)] {
            x.1 += dd * step_s;
            x.0 += x.1 * step_s;
        }
        (pitch_rad, heave_dd)
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
        // A degree it cannot be drawn with is an error naming the key.
        assert!(r.check().is_ok());
        for bad in [-1.0, f64::NAN, f64::INFINITY] {
            let e = Roughness {
                psd_1e6_m3: bad,
                seed: 7,
            }
            .check()
            .unwrap_err();
            assert!(e.to_string().contains("road.roughness.psd_1e6_m3"), "{e}");
        }
    }
}
