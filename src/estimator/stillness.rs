//! IMU stillness over a sliding window and the gyro-bias low-pass of eq. 7.

use super::Estimator;
use super::types::ImuSample;
use nalgebra::Vector3;

impl Estimator {
    /// IMU stillness over the trailing `still_window_s`. Also records whether the
    /// window may feed the bias filter.
    pub(super) fn imu_still(&mut self, t_now: f64) -> bool {
        let n = self.hist.len();
        let (mut k, mut oldest) = (0usize, t_now);
        let (mut sa, mut qa, mut sg, mut qg) = (
            Vector3::zeros(),
            Vector3::zeros(),
            Vector3::zeros(),
            Vector3::zeros(),
        );
        for i in (0..n).rev() {
            let x = self.hist.get(i);
            if t_now - x.t_s > self.cfg.still_window_s {
                break;
            }
            let (a, w) = (x.acc(), x.gyro_rps());
            sa += a;
            qa += a.component_mul(&a);
            sg += w;
            qg += w.component_mul(&w);
            oldest = x.t_s;
            k += 1;
        }
        self.bias_window_ok = false;
        if k < 5 || t_now - oldest < 0.75 * self.cfg.still_window_s {
            return false;
        }
        let kf = k as f64;
        self.still_mean_acc = sa / kf;
        let std_axes = |s: Vector3<f64>, q: Vector3<f64>| {
            let m = s / kf;
            (q / kf - m.component_mul(&m)).map(|v| v.max(0.0).sqrt())
        };
        let acc_sd = std_axes(sa, qa);
        let acc_ok = acc_sd.max() <= self.still_acc_std_mps2();
        let gyro_sd = std_axes(sg, qg);
        if acc_ok && self.wheels_zero_since.is_some() {
            self.gyro_noise.learn(median3(gyro_sd), k);
        }
        let scale = self.gyro_gate_scale();
        let gyro_ok = gyro_sd.max().to_degrees() <= self.cfg.still_gyro_std_dps * scale;
        if gyro_ok && self.wheels_zero_since.is_some() {
            self.acc_noise.learn(median3(acc_sd), k);
        }
        let offset_dps = self.bias_rps.map(|b| (sg / kf - b).norm().to_degrees());
        let mean_ok = offset_dps.is_none_or(|o| o <= self.cfg.still_gyro_dps * scale);

        self.bias_window_ok = offset_dps.is_none_or(|o| o <= self.cfg.bias_gate_dps * scale);
        acc_ok && gyro_ok && mean_ok
    }

    /// Eq. 7 over a settled block that joined the stop's reference. Each of its samples
    /// passed `bias_gate_dps` over its own short window, but the body swinging back from
    /// its dive in the first second after the stop passes that gate with rates of one
    /// sign all along, and a bias taught by it misses that much of every turn the gyro
    /// carries afterwards. So a block teaches only when it began `BIAS_SETTLE_S` after
    /// the car came to rest (`early` otherwise) and its own mean rate is within the gate
    /// of the bias. With no bias yet, or `still_blocks_teach_bias` off, it teaches at once.
    pub(super) fn teach_bias_block(&mut self, mean_rps: &Vector3<f64>, n: u64, early: bool) {
        let gate = self.bias_gate_rps();
        let teach = match self.bias_rps {
            None => true,
            Some(_) if !self.cfg.still_blocks_teach_bias => true,
            Some(b) => !early && (mean_rps - b).norm() <= gate,
        };
        if teach {
            self.update_bias_block(mean_rps, n);
            self.bias_taught = true;
        }
    }

    /// How much wider the gyro gates (`still_gyro_std_dps`, `still_gyro_dps`,
    /// `bias_gate_dps`) are than configured: they are sized for a gyro with
    /// `gyro_noise_dps_rthz` of noise, and grow in proportion with the noise learnt at
    /// rest when it is higher. Never below 1, and never above `MAX_GATE_SCALE`: a
    /// gyro that noisy is broken, and its samples should fail the gates.
    pub(super) fn gyro_gate_scale(&self) -> f64 {
        if !self.cfg.scale_gyro_gates {
            return 1.0;
        }
        self.gyro_noise
            .density_dps_rthz(self.sample_dt_s.0)
            .map_or(1.0, |d| {
                (d / self.cfg.gyro_noise_dps_rthz).clamp(1.0, MAX_GATE_SCALE)
            })
    }

    /// How much wider the per-sample accelerometer gates (`still_acc_std_mps2`,
    /// `rest_acc_tol_mps2`) are than configured: they hold for an accelerometer with up
    /// to `acc_noise_ug_rthz` of noise, and grow in proportion with the spread learnt
    /// at rest when it is higher (an engine's vibration at idle counts).
    pub(super) fn acc_gate_scale(&self) -> f64 {
        self.acc_scale(self.acc_noise.density_per_rthz(self.sample_dt_s.0))
    }

    /// `density` (m/s^2/sqrt(Hz)) over the configured `acc_noise_ug_rthz`; 1 with no
    /// density or `scale_acc_gates` off. Never below 1, never above `MAX_GATE_SCALE`.
    fn acc_scale(&self, density: Option<f64>) -> f64 {
        match density {
            Some(d) if self.cfg.scale_acc_gates => {
                (ug_rthz(d) / self.cfg.acc_noise_ug_rthz).clamp(1.0, MAX_GATE_SCALE)
            }
            _ => 1.0,
        }
    }

    /// Whether the accelerometer noise a walk integrates (`walk_acc_noise_per_rthz`) is
    /// below `chord_below_acc_noise_ug_rthz`: then the window's slope is the chord's.
    /// Not before the noise is learnt.
    pub(super) fn quiet_accelerometer(&self) -> bool {
        self.walk_acc_noise_per_rthz()
            .is_some_and(|d| ug_rthz(d) < self.cfg.chord_below_acc_noise_ug_rthz)
    }

    /// Whether the IMU vibrates at rest (an idling engine; see `vibration`).
    pub(super) fn vibrating(&self) -> bool {
        self.gravity.is_some_and(|g| g.vibrating())
    }

    /// The accelerometer noise a walk integrates, m/s^2/sqrt(Hz): the noise learnt at
    /// rest, or on a vibrating IMU what is left of it below the vibration; `None`
    /// before it is learnt.
    pub(super) fn walk_acc_noise_per_rthz(&self) -> Option<f64> {
        let sample = self.acc_noise.density_per_rthz(self.sample_dt_s.0)?;
        Some(match self.gravity {
            Some(g) if g.vibrating() => sample.min((g.r_smooth * self.sample_dt_s.0).sqrt()),
            _ => sample,
        })
    }

    /// `still_acc_std_mps2` widened for a noisy accelerometer, m/s^2.
    pub(super) fn still_acc_std_mps2(&self) -> f64 {
        self.cfg.still_acc_std_mps2 * self.acc_gate_scale()
    }

    /// `drive_off_speed_mps` widened for a noisy accelerometer, m/s: the speed the IMU
    /// integrates over a stop walks with the noise (not with a vibration, which
    /// integrates to nothing).
    pub(super) fn drive_off_speed_mps(&self) -> f64 {
        self.cfg.drive_off_speed_mps * self.acc_scale(self.walk_acc_noise_per_rthz())
    }

    /// `rest_acc_tol_mps2` for the smoothed force of a vibrating IMU (`vibration`),
    /// widened only by the noise a walk integrates, m/s^2.
    pub(super) fn smoothed_rest_acc_tol_mps2(&self) -> f64 {
        self.cfg.rest_acc_tol_mps2 * self.acc_scale(self.walk_acc_noise_per_rthz())
    }

    /// `rest_acc_tol_mps2` widened for a noisy accelerometer, m/s^2.
    pub(super) fn rest_acc_tol_mps2(&self) -> f64 {
        self.cfg.rest_acc_tol_mps2 * self.acc_gate_scale()
    }

    /// Eq. 7's alpha per sample at the IMU's rate, made smaller for a noisy gyro so
    /// that the bias keeps the spread it has with the gyro the gates are sized for.
    fn bias_alpha(&self) -> f64 {
        let alpha = (self.sample_dt_s.0 / self.cfg.gyro_bias_time_constant_s).min(1.0);
        alpha / self.gyro_gate_scale().powi(2)
    }

    /// `bias_gate_dps` widened for a noisy gyro, rad/s.
    pub(super) fn bias_gate_rps(&self) -> f64 {
        (self.cfg.bias_gate_dps * self.gyro_gate_scale()).to_radians()
    }

    /// Eq. 7 over a block of `n` samples whose mean rate was `mean_rps`: the same
    /// low-pass, stepped `n` times at once.
    pub(super) fn update_bias_block(&mut self, mean_rps: &Vector3<f64>, n: u64) {
        let k = 1.0 - (1.0 - self.bias_alpha()).powi(n.min(i32::MAX as u64) as i32);
        self.bias_rps = Some(match self.bias_rps {
            Some(b) => b + (mean_rps - b) * k,
            None => *mean_rps,
        });
    }

    pub(super) fn update_bias(&mut self, s: &ImuSample) {
        let w = s.gyro_rps();
        let a = self.bias_alpha();
        // Eq. 7: first-order low-pass of the gyro output while stopped.
        self.bias_rps = Some(match self.bias_rps {
            Some(b) => w * a + b * (1.0 - a),
            None => w,
        });
    }
}

fn median3(v: Vector3<f64>) -> f64 {
    v.x.max(v.y).min(v.x.min(v.y).max(v.z))
}

/// A sensor's white noise, learnt from the stillness windows while the wheels read
/// zero and the other sensor is quiet: a running low quantile of the per-sample
/// standard deviation in those windows (the median of the three axes), so that the
/// body rocking after a stop, a door shock or a load ramping in, which only add to the
/// spread, do not raise it unless they fill nearly every window. One for the gyro
/// (rad/s) and one for the accelerometer (m/s^2).
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct NoiseFloor {
    /// Log of the tracked quantile of the windows' standard deviation (rad/s or m/s^2).
    log_sd: Option<f64>,
    /// Samples per window the quantile was last corrected with.
    window_samples: usize,
}

/// A density in m/s^2/sqrt(Hz) in ug/sqrt(Hz).
fn ug_rthz(d: f64) -> f64 {
    d / (1e-6 * super::STANDARD_GRAVITY_MPS2)
}

/// Widest the gyro and accelerometer gates grow, as a multiple of their configured size.
const MAX_GATE_SCALE: f64 = 10.0;

/// The quantile tracked, and its step in log units per window.
const NOISE_QUANTILE: f64 = 0.1;
const NOISE_STEP: f64 = 0.01;

impl NoiseFloor {
    pub(super) fn learn(&mut self, sd_rps: f64, samples: usize) {
        if !sd_rps.is_finite() || sd_rps <= 0.0 {
            return;
        }
        let l = sd_rps.ln();
        self.window_samples = samples;
        self.log_sd = Some(match self.log_sd {
            None => l,
            Some(q) if l < q => q - NOISE_STEP * (1.0 - NOISE_QUANTILE),
            Some(q) => q + NOISE_STEP * NOISE_QUANTILE,
        });
    }

    /// Noise density, deg/s/sqrt(Hz), for samples `dt_s` apart: the tracked quantile
    /// corrected to the noise's standard deviation: the standard deviation of k samples
    /// (over k) is about sqrt((k - 1) / k) of it and spreads by 1/sqrt(2(k - 1)) of it,
    /// the median of three axes by 0.67 of that, and the 10 % quantile lies 1.28 of
    /// those spreads below the middle.
    pub(super) fn density_dps_rthz(&self, dt_s: f64) -> Option<f64> {
        self.density_per_rthz(dt_s).map(f64::to_degrees)
    }

    /// The same in the unit learnt, per sqrt(Hz).
    pub(super) fn density_per_rthz(&self, dt_s: f64) -> Option<f64> {
        let q = self.log_sd?;
        let k = self.window_samples.max(5) as f64;
        let low = ((k - 1.0) / k).sqrt() * (1.0 - 1.2816 * 0.67 / (2.0 * (k - 1.0)).sqrt());
        Some(q.exp() / low * dt_s.sqrt())
    }
}

#[cfg(test)]
mod tests {
    use super::NoiseFloor;

    /// A small deterministic normal generator (Box-Muller on an LCG).
    fn normals(seed: u64) -> impl FnMut() -> f64 {
        let mut x = seed;
        let mut u = move || {
            x = x
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((x >> 11) as f64 + 0.5) / (1u64 << 53) as f64
        };
        move || (-2.0 * u().ln()).sqrt() * (std::f64::consts::TAU * u()).cos()
    }

    #[test]
    fn the_noise_is_learnt_from_windows_of_which_many_also_rock() {
        // 20-sample windows of white noise of 0.3 deg/s per 100 Hz sample (0.03
        // deg/s/sqrt(Hz)); in 6 of every 10 windows one axis (pitch) also rocks with a
        // spread of 1 deg/s. The median of the three axes keeps the rocking out.
        let sigma = 0.3f64.to_radians();
        let mut n = normals(7);
        let mut g = NoiseFloor::default();
        for w in 0..3000 {
            let rocking = w % 10 < 6;
            let mut sd = [0.0; 3];
            for (axis, v) in sd.iter_mut().enumerate() {
                let (mut s, mut q) = (0.0, 0.0);
                for _ in 0..20 {
                    let mut x = sigma * n();
                    if rocking && axis == 1 {
                        x += 1f64.to_radians() * n();
                    }
                    s += x;
                    q += x * x;
                }
                *v = (q / 20.0 - (s / 20.0).powi(2)).sqrt();
            }
            g.learn(super::median3(sd.into()), 20);
        }
        let d = g.density_dps_rthz(0.01).unwrap();
        assert!(
            (d - 0.03).abs() <= 0.003,
            "learnt {d:.4} deg/s/sqrt(Hz) for 0.03"
        );
    }

    #[test]
    fn nothing_learnt_means_no_noise_and_bad_input_teaches_nothing() {
        let mut g = NoiseFloor::default();
        assert_eq!(g.density_dps_rthz(0.01), None);
        g.learn(f64::NAN, 20);
        g.learn(f64::INFINITY, 20);
        g.learn(0.0, 20);
        g.learn(-1.0, 20);
        assert_eq!(g.density_dps_rthz(0.01), None);
    }
}
