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
        let std_max = |s: Vector3<f64>, q: Vector3<f64>| {
            let m = s / kf;
            (q / kf - m.component_mul(&m))
                .map(|v| v.max(0.0).sqrt())
                .max()
        };
        let acc_ok = std_max(sa, qa) <= self.cfg.still_acc_std_mps2;
        let gyro_ok = std_max(sg, qg).to_degrees() <= self.cfg.still_gyro_std_dps;
        let offset_dps = self.bias_rps.map(|b| (sg / kf - b).norm().to_degrees());
        let mean_ok = offset_dps.is_none_or(|o| o <= self.cfg.still_gyro_dps);

        self.bias_window_ok = offset_dps.is_none_or(|o| o <= self.cfg.bias_gate_dps);
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
        let gate = self.cfg.bias_gate_dps.to_radians();
        let teach = match self.bias_rps {
            None => true,
            Some(_) if !self.cfg.still_blocks_teach_bias => true,
            Some(b) => !early && (mean_rps - b).norm() <= gate,
        };
        if teach {
            self.update_bias_block(mean_rps, n);
        }
    }

    /// Eq. 7 over a block of `n` samples whose mean rate was `mean_rps`: the same
    /// low-pass, stepped `n` times at once.
    pub(super) fn update_bias_block(&mut self, mean_rps: &Vector3<f64>, n: u64) {
        let k = 1.0 - (1.0 - self.cfg.gyro_bias_alpha).powi(n.min(i32::MAX as u64) as i32);
        self.bias_rps = Some(match self.bias_rps {
            Some(b) => b + (mean_rps - b) * k,
            None => *mean_rps,
        });
    }

    pub(super) fn update_bias(&mut self, s: &ImuSample) {
        let w = s.gyro_rps();
        let a = self.cfg.gyro_bias_alpha;
        // Eq. 7: first-order low-pass of the gyro output while stopped.
        self.bias_rps = Some(match self.bias_rps {
            Some(b) => w * a + b * (1.0 - a),
            None => w,
        });
    }
}
