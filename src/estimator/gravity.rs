//! The settled gravity magnitude (the g of eq. 12-13) and pitch from a specific force.

use super::attitude;
use super::vibration;
use super::{Estimator, Event};
use nalgebra::{Matrix3, UnitQuaternion, Vector3};

impl Estimator {
    /// One settled sample's specific force (pitch centre) for the gravity filter. The
    /// filter measures the magnitude of the mean of `GRAVITY_BLOCK_S` of samples, not
    /// of each sample: noise across gravity lengthens every single sample, by
    /// (var_x + var_y) / 2g on average, which would read as a larger g. The walk
    /// subtracts that g, and a window loses the excess over its forward acceleration:
    /// 0.14 deg on a drive-off at 0.4 m/s^2 with 0.1 m/s^2 of noise per sample (1000
    /// ug/sqrt(Hz) at 100 Hz, or an engine's vibration at idle). A block also ends at
    /// a gap, so that one mean never spans two stops (gravity along two body
    /// directions).
    ///
    /// `smoothed` is the same sample read through the vibration triangle (`None` where
    /// a missing sample spoils it): blocks of those teach `GravityFilter::r_smooth`, and
    /// measure the magnitude when the IMU vibrates.
    pub(super) fn update_gravity(
        &mut self,
        t_s: f64,
        f: &Vector3<f64>,
        smoothed: Option<&Vector3<f64>>,
    ) {
        if self
            .gravity_block
            .last_s
            .is_some_and(|t| t_s - t > GRAVITY_BLOCK_GAP_S)
        {
            self.flush_gravity_block();
            // The next block is not the continuation of this one.
            self.gravity_block.prev = None;
            self.gravity_block.prev_smooth = None;
        }
        if let Some(k) = self.gravity.as_mut() {
            k.learn_noise(f);
        }
        let b = &mut self.gravity_block;
        b.sum += f;
        b.n += 1;
        if let Some(s) = smoothed {
            b.smooth_sum += s;
            b.smooth_n += 1;
        }
        let m = f.norm();
        b.norm_sum += m;
        b.norm_sq_sum += m * m;
        b.last_s = Some(t_s);
        if b.n as usize >= self.samples_in(GRAVITY_BLOCK_S) {
            self.flush_gravity_block();
        }
    }

    fn flush_gravity_block(&mut self) {
        let (prev, prev_smooth) = (self.gravity_block.prev, self.gravity_block.prev_smooth);
        let b = std::mem::take(&mut self.gravity_block);
        let Some(t_s) = b.last_s else {
            return;
        };
        if b.n == 0 {
            return;
        }
        let mean = b.sum / f64::from(b.n);
        let m = mean.norm();
        self.gravity_block.prev = Some((m, b.n));
        // A block whose every sample was smoothed cleanly; its neighbour's smoothed
        // mean differs from it by the noise below the triangle's band.
        let smooth = (b.smooth_n == b.n).then(|| b.smooth_sum / f64::from(b.n));
        self.gravity_block.prev_smooth = smooth.map(|s| (s.norm(), b.n));
        let box_n = self.vibration_box();
        let q = self.cfg.gravity_walk_mps2_rts;
        let k = self.gravity.get_or_insert_with(|| {
            let mut k = GravityFilter::new(m, 1e-3, [0.0; 2], GravityFilter::BIAS_PRIOR_MPS2);
            // The filter learns the noise only from the samples after its first block,
            // which is known to no better than its own spread: taken at the nominal
            // 1e-3 (m/s^2)^2, a block shaken by an engine at forty times that held
            // the magnitude at its own, 13 mm/s^2 off, through the first stop.
            if b.n >= 2 {
                let nf = f64::from(b.n);
                let var = (b.norm_sq_sum - b.norm_sum * b.norm_sum / nf) / (nf - 1.0);
                k.r = k.r.max(var);
            }
            k
        });
        if let Some((m_prev, n_prev)) = prev {
            k.learn_block_noise(m - m_prev, n_prev, b.n);
        }
        if let (Some(s), Some((m_prev, n_prev))) = (smooth, prev_smooth) {
            let gain = vibration::smoothed_pair_gain(n_prev as usize, b.n as usize, box_n);
            k.learn_smooth_noise((s.norm() - m_prev) / gain.sqrt(), n_prev, b.n);
        }
        if k.vibration_seen() {
            // Smoothed samples only: a block spoilt by a missing sample still holds its
            // clean ones. The filter takes them from the first pairs that show the
            // vibration: a noise that is white reads the same through the triangle, and
            // the first stop's drive-off needs the magnitude.
            if b.smooth_n > 0 {
                let s = b.smooth_sum / f64::from(b.smooth_n);
                k.update_bounded(t_s, &s, q, k.r_smooth / f64::from(b.smooth_n));
            }
        } else {
            k.update_bounded(t_s, &mean, q, k.noise() / f64::from(b.n));
        }
    }

    /// Horizontal accelerometer bias the stop filter has seen, body axes, m/s^2 (zero
    /// before the first settled stop or with `correct_acc_bias` off). Windows and their
    /// references remove it alike; it changes once per settled stop, as the stop ends,
    /// so one window evaluation sees one value.
    pub(super) fn acc_bias_mps2(&self) -> Vector3<f64> {
        match self.stop_bias {
            Some(f) if self.cfg.correct_acc_bias => Vector3::new(f.x.y, f.x.z, 0.0),
            _ => Vector3::zeros(),
        }
    }

    /// The pitch, rad, of a raw force read at rest whose pitch is `pitch_rad` and whose
    /// y axis stands at `roll_rad` (as `standstill_pitch` and `standstill_roll_deg`
    /// read them), with the accelerometer bias learnt so far taken out.
    pub(super) fn unbiased_pitch_rad(&self, pitch_rad: f64, roll_rad: f64) -> f64 {
        let b = self.acc_bias_mps2();
        let (sp, sr) = (pitch_rad.sin(), roll_rad.sin());
        let up = Vector3::new(sp, sr, (1.0 - sp * sp - sr * sr).max(0.0).sqrt());
        let f = up * self.gravity_mps2(&up);
        match (pitch_from(&f), pitch_from(&(f - b))) {
            (Some(raw), Some(free)) if b != Vector3::zeros() => pitch_rad + (free - raw),
            _ => pitch_rad,
        }
    }

    /// Tell the average the x bias the stops know now (`rebias_windows`), and say so
    /// when that moved the estimate.
    pub(super) fn follow_stop_bias(&mut self, t_s: f64, emit: &mut dyn FnMut(Event)) {
        if !self.cfg.rebias_windows {
            return;
        }
        let before = self.estimate.map(|e| e.road_to_body_deg);
        let b = self.acc_bias_mps2().x;
        self.avg.set_acc_bias_x(b);
        self.refresh_estimate();
        if let (Some(before), Some(e)) = (before, self.estimate)
            && e.road_to_body_deg != before
        {
            emit(Event::WindowsRebiased {
                t_s,
                acc_bias_x_mps2: b,
                delta_deg: e.road_to_body_deg - before,
                estimate: self.estimate,
            });
        }
    }

    /// Standard deviation of the accelerometer's x and y bias as the stops know them,
    /// m/s^2 (the prior before any settled stop).
    pub(super) fn acc_bias_sd_mps2(&self) -> [f64; 2] {
        let prior = self.cfg.acc_bias_prior_mps2;
        self.stop_bias.map_or([prior; 2], |f| {
            [f.p[(1, 1)], f.p[(2, 2)]].map(|v| v.max(0.0).sqrt())
        })
    }

    /// One settled stop's mean specific force `f_mean` (pitch centre, `n` samples) for
    /// the accelerometer bias: stops at different pitch see gravity along different body
    /// directions, and the magnitude follows the bias along them.
    pub(super) fn update_stop_bias(&mut self, t_s: f64, f_mean: &Vector3<f64>, n: u64) {
        let m = f_mean.norm();
        if m <= 0.0 || n == 0 || !m.is_finite() {
            return;
        }
        // The noise per sample the gravity filter has learnt, averaged over the stop,
        // and a floor for what averaging does not remove (the rest of the rocking, a
        // door shock, the lever-arm model).
        let r_sample = self.gravity.map_or(1e-3, |g| g.noise());
        let r = STOP_FLOOR_MPS2 * STOP_FLOOR_MPS2 + r_sample / n as f64;
        let q = self.cfg.gravity_walk_mps2_rts;
        let prior = self.cfg.acc_bias_prior_mps2;
        let f = self
            .stop_bias
            .get_or_insert_with(|| GravityFilter::new(m, 1.0, [0.0; 2], prior));
        f.update_bounded(t_s, f_mean, q, r);
    }

    /// Attitude and gravity magnitude of a window whose reference is the raw standstill
    /// mean `f_mean`, with `acc_bias_mps2` removed from both. The magnitude is the one
    /// the gravity filter expects along the mean's direction (a short stop alone
    /// measures it too noisily); the bias comes off that vector, exactly: a 0.3 m/s^2
    /// bias shortens it by 4.6 mm/s^2 beyond its first-order term.
    pub(super) fn window_reference(
        &self,
        f_mean: &Vector3<f64>,
    ) -> Option<(UnitQuaternion<f64>, f64)> {
        let m = f_mean.norm();
        if !(m > 0.0) {
            return None;
        }
        let f = f_mean * (self.gravity_mps2(f_mean) / m) - self.acc_bias_mps2();
        Some((attitude::attitude_from_gravity(&f)?, f.norm()))
    }

    /// Gravity magnitude for a window whose reference is the standstill mean `f_mean`.
    pub(super) fn gravity_mps2(&self, f_mean: &Vector3<f64>) -> f64 {
        let m = f_mean.norm();
        match self.gravity {
            Some(g) if m > 0.0 => g.magnitude(&(f_mean / m)),
            _ => m,
        }
    }
}

pub(super) fn pitch_from(f: &Vector3<f64>) -> Option<f64> {
    attitude::pitch_roll_from_gravity(f).map(|(p, _)| p)
}

/// Span of settled samples whose mean is one measurement of the gravity filter, s.
const GRAVITY_BLOCK_S: f64 = 0.25;

/// Pairs of consecutive blocks compared before what they show counts (see
/// `GravityFilter::noise`).
const BLOCK_PAIRS_MIN: u32 = 20;

/// Pairs of consecutive smoothed blocks compared before they can tell a vibration (3 s
/// of settled samples; the first stop's drive-off already needs to know it), and
/// before the gravity filter takes smoothed blocks (1 s).
const SMOOTH_PAIRS_MIN: u32 = 12;
const SMOOTH_PAIRS_SEEN: u32 = 4;

/// The raw samples spread at least this many times more than block means say (per
/// sample) when the IMU vibrates: white noise gives 1, an engine's 0.2 m/s^2 at 25 Hz
/// next to a 30 ug/sqrt(Hz) accelerometer several hundred.
const VIBRATION_RATIO_MIN: f64 = 4.0;

/// The per-sample variance of white noise that spreads the means of `n0` and `n1`
/// samples by their difference `d`, (m/s^2)^2.
fn pair_variance(d: f64, n0: u32, n1: u32) -> f64 {
    d * d / (1.0 / f64::from(n0) + 1.0 / f64::from(n1))
}

/// A gap between settled samples longer than this closes the gravity block, s.
const GRAVITY_BLOCK_GAP_S: f64 = 0.1;

/// Settled samples summed for the gravity filter's next measurement.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct GravityBlock {
    sum: Vector3<f64>,
    n: u32,
    last_s: Option<f64>,
    /// Magnitude of the mean and sample count of the block just before, when this one
    /// continues it (no gap between them).
    prev: Option<(f64, u32)>,
    /// The same samples read through the vibration triangle, where it read them.
    smooth_sum: Vector3<f64>,
    smooth_n: u32,
    /// `prev` of the smoothed samples, when all of that block's were.
    prev_smooth: Option<(f64, u32)>,
    /// Sum of the samples' magnitudes and of their squares, m/s^2 and (m/s^2)^2.
    norm_sum: f64,
    norm_sq_sum: f64,
}

/// What one stop's mean magnitude leaves unexplained beyond its sample noise, m/s^2.
const STOP_FLOOR_MPS2: f64 = 0.003;

/// Kalman filter on the standstill specific-force magnitude. An accelerometer bias `b`
/// makes the magnitude depend on where gravity points in the body: |g u + b| is about
/// c + b_x u_x + b_y u_y for the unit gravity direction u (b_z folds into c). A window
/// cancels the bias only with the magnitude of its own stop (the reference the attitude
/// came from); a single short stop measures it noisily, a plain average over stops
/// misses the bias term by up to |b| sin(pitch), 4 mm/s^2 for 0.05 m/s^2 at 5 deg:
/// 0.25 deg of slope over a 2 s window. So the state is (c, b_x, b_y), each a random
/// walk of `gravity_walk_mps2_rts` (the bias drifts with temperature); each block of
/// settled samples measures the magnitude, with a noise learnt from the samples'
/// spread and from how far consecutive blocks differ (`GravityFilter::noise`).
#[derive(Debug, Clone, Copy)]
pub(super) struct GravityFilter {
    pub(super) x: Vector3<f64>,
    /// Covariance of `x`.
    pub(super) p: Matrix3<f64>,
    /// Per-sample measurement variance, (m/s^2)^2.
    pub(super) r: f64,
    /// The same learnt from consecutive block means, and how many pairs taught it.
    pub(super) r_block: f64,
    pub(super) block_pairs: u32,
    /// The same from consecutive means of smoothed samples (`vibration`), told as the
    /// white noise per raw sample that would spread them that far, and its pairs.
    pub(super) r_smooth: f64,
    pub(super) smooth_pairs: u32,
    pub(super) last_t: Option<f64>,
}

impl GravityFilter {
    /// Prior spread of the horizontal bias terms, m/s^2 (a MEMS accelerometer offset).
    pub(super) const BIAS_PRIOR_MPS2: f64 = 0.1;

    pub(super) fn new(c: f64, c_var: f64, bias: [f64; 2], bias_sd: f64) -> Self {
        let b2 = bias_sd * bias_sd;
        Self {
            x: Vector3::new(c, bias[0], bias[1]),
            p: Matrix3::from_diagonal(&Vector3::new(c_var, b2, b2)),
            r: 1e-3,
            r_block: 1e-3,
            block_pairs: 0,
            r_smooth: 1e-3,
            smooth_pairs: 0,
            last_t: None,
        }
    }

    fn regressor(u: &Vector3<f64>) -> Vector3<f64> {
        Vector3::new(1.0, u.x, u.y)
    }

    /// Expected magnitude for gravity along the body direction `u` (unit), m/s^2.
    pub(super) fn magnitude(&self, u: &Vector3<f64>) -> f64 {
        Self::regressor(u).dot(&self.x)
    }

    /// Learn the per-sample variance `r` of the magnitude from one sample `f`,
    /// against the current state (the state itself learns from block means).
    pub(super) fn learn_noise(&mut self, f: &Vector3<f64>) {
        let m = f.norm();
        if !(m > 0.0) {
            return;
        }
        let y = m - Self::regressor(&(f / m)).dot(&self.x);
        self.r = (0.995 * self.r + 0.005 * y * y).max(1e-8);
    }

    /// Learn from `d`, the difference between the magnitudes of two consecutive block
    /// means of `n0` and `n1` samples, the per-sample variance that white noise would
    /// need to spread block means that far. An idling engine shakes each sample by
    /// 0.1-0.3 m/s^2 at 20-30 Hz, which a quarter-second mean all but removes: a filter
    /// told that each sample is that noisy trusts its stops too little (learnt g and
    /// bias 0.01-0.1 m/s^2 behind the stops, windows 0.5-1.5 deg off).
    pub(super) fn learn_block_noise(&mut self, d: f64, n0: u32, n1: u32) {
        if !d.is_finite() || n0 == 0 || n1 == 0 {
            return;
        }
        let r = pair_variance(d, n0, n1);
        self.r_block = (0.95 * self.r_block + 0.05 * r).max(1e-8);
        self.block_pairs = self.block_pairs.saturating_add(1);
    }

    /// Learn `r_smooth` from `d`, the difference between consecutive smoothed block
    /// means already divided by the triangle's share of their white noise: the mean of
    /// the pairs so far, a running one of the last twenty or so later.
    pub(super) fn learn_smooth_noise(&mut self, d: f64, n0: u32, n1: u32) {
        if !d.is_finite() || n0 == 0 || n1 == 0 {
            return;
        }
        let r = pair_variance(d, n0, n1);
        let w = (1.0 / f64::from(self.smooth_pairs.saturating_add(1))).max(0.05);
        self.r_smooth = ((1.0 - w) * self.r_smooth + w * r).max(1e-8);
        self.smooth_pairs = self.smooth_pairs.saturating_add(1);
    }

    /// Whether the IMU vibrates at rest: the raw samples spread `VIBRATION_RATIO_MIN`
    /// times more than the smoothed block means say white noise would (the body's slow
    /// rocking spreads block means more than samples, never less).
    pub(super) fn vibrating(&self) -> bool {
        self.smooth_pairs >= SMOOTH_PAIRS_MIN && self.vibration_seen()
    }

    /// What `vibrating` asks of the noise, from `SMOOTH_PAIRS_SEEN` pairs on, with the
    /// per-sample spread counted in as one more pair, as if the noise were white: then
    /// a white noise cannot pass before the fourth pair, and passes at the fourth with a
    /// chance under 1 % (four pairs' sum below a quarter of one), where a nominal start
    /// took a white 1000 ug/sqrt(Hz) for a vibration. A vibration that makes the spread
    /// four times the noise below it passes from the fourth.
    fn vibration_seen(&self) -> bool {
        let k = f64::from(self.smooth_pairs);
        self.smooth_pairs >= SMOOTH_PAIRS_SEEN
            && self.r > VIBRATION_RATIO_MIN * (self.r + k * self.r_smooth) / (k + 1.0)
    }

    /// Variance per sample a mean of n samples is known to within, over n, (m/s^2)^2:
    /// the per-sample spread, or what consecutive block means show when that is less
    /// (vibration faster than a block), once enough of them have been compared; on a
    /// vibrating IMU what its smoothed blocks show.
    pub(super) fn noise(&self) -> f64 {
        if self.vibrating() {
            return self.r_smooth;
        }
        if self.block_pairs >= BLOCK_PAIRS_MIN {
            self.r.min(self.r_block)
        } else {
            self.r
        }
    }

    /// Update with a mean force `f` of nominal variance `r`, (m/s^2)^2, that counts as
    /// no more than 3 standard deviations from the prediction: a stop whose few settled
    /// samples still carried the body's motion (0.07 m/s^2 short on 7 samples) would
    /// otherwise turn its whole miss into a horizontal bias, whose only lever is the
    /// sine of a small pitch: 0.6 m/s^2, 3.5 deg of reference, for many stops after.
    /// The same holds for a block of the gravity filter, most of all with a quiet
    /// accelerometer, whose learnt noise is small: a block of one settled sample of a
    /// body still moving, 74 mm/s^2 over the magnitude, made its direction term 1.0
    /// m/s^2 where the bias was 0.25, and a short stop 3.5 deg of pitch away then read
    /// its gravity 22 mm/s^2 off. Measurements that agree with each other still move
    /// the state as fast as before.
    fn update_bounded(&mut self, t_s: f64, f: &Vector3<f64>, q: f64, r: f64) {
        if !(f.norm() > 0.0) || !(r > 0.0) {
            return;
        }
        let y = self.innovation(t_s, f, q);
        let h = Self::regressor(&(f / f.norm()));
        let hph = h.dot(&(self.p * h));
        self.correct(f, y, r.max(y * y / 9.0 - hph));
    }

    /// Let the state walk to `t_s`; the magnitude of `f` against the prediction.
    fn innovation(&mut self, t_s: f64, f: &Vector3<f64>, q: f64) -> f64 {
        if let Some(t0) = self.last_t {
            let walk = q * q * (t_s - t0).max(0.0);
            self.p += Matrix3::from_diagonal_element(walk);
        }
        self.last_t = Some(t_s);
        let m = f.norm();
        m - Self::regressor(&(f / m)).dot(&self.x)
    }

    fn correct(&mut self, f: &Vector3<f64>, y: f64, r: f64) {
        let h = Self::regressor(&(f / f.norm()));
        let ph = self.p * h;
        let k = ph / (h.dot(&ph) + r);
        self.x += k * y;
        self.p -= k * ph.transpose();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Mean specific force of a stop with the body pitched by `pitch_deg`, gravity
    /// `g` and accelerometer bias `b`, shortened by `miss` along itself.
    fn stop_force(pitch_deg: f64, g: f64, b: Vector3<f64>, miss: f64) -> Vector3<f64> {
        let p = pitch_deg.to_radians();
        let f = Vector3::new(-g * p.sin(), 0.0, g * p.cos()) + b;
        f * ((f.norm() - miss) / f.norm())
    }

    /// Deterministic standard normal draws (xorshift64* and Box-Muller).
    struct Normal(u64);

    impl Normal {
        fn uniform(&mut self) -> f64 {
            self.0 ^= self.0 >> 12;
            self.0 ^= self.0 << 25;
            self.0 ^= self.0 >> 27;
            let x = self.0.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11;
            (x as f64 + 0.5) / (1u64 << 53) as f64
        }

        fn draw(&mut self) -> f64 {
            let (u, v) = (self.uniform(), self.uniform());
            (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
        }
    }

    #[test]
    fn noise_across_gravity_does_not_lengthen_the_learnt_magnitude() {
        use crate::estimator::{Estimator, EstimatorConfig};
        // 0.2 m/s^2 per axis: an idle engine's vibration, or 2000 ug/sqrt(Hz) at 100 Hz.
        // Each sample's norm is longer than gravity by about (0.2^2 + 0.2^2) / 2g,
        // 4.1 mm/s^2; the mean of 1000 s of samples is known to 0.2 / sqrt(1e5), 0.6.
        let (sd, g, pitch) = (0.2, 9.85, 2f64.to_radians());
        let truth = Vector3::new(-g * pitch.sin(), 0.0, g * pitch.cos());
        let cfg = EstimatorConfig {
            gravity_walk_mps2_rts: 1e-6,
            ..EstimatorConfig::default()
        };
        let mut est = Estimator::new(cfg).unwrap();
        let mut rng = Normal(0x9E37_79B9_7F4A_7C15);
        for k in 0..100_000 {
            let noise = Vector3::new(rng.draw(), rng.draw(), rng.draw()) * sd;
            est.update_gravity(k as f64 * 0.01, &(truth + noise), None);
        }
        let learnt = est.gravity.unwrap().magnitude(&truth.normalize());
        // Measured: 0.6 mm/s^2 off; fed sample by sample (the old filter), 4.1 mm/s^2.
        assert!((learnt - g).abs() < 0.0015, "learnt {learnt:.5} for {g}");
    }

    #[test]
    fn an_idling_engines_vibration_does_not_slow_the_bias_the_stops_teach() {
        use crate::estimator::{Estimator, EstimatorConfig};
        // Stops of 5 s at pitches of 3-5 deg either way, an accelerometer bias of 0.2
        // m/s^2 along x, white noise of 0.03 m/s^2 per sample, and an engine shaking the
        // body by 0.3 m/s^2 rms vertically at 25 Hz: each sample moves by up to 0.42,
        // a quarter-second mean by a few mm/s^2, the stop's mean by nothing.
        let (g, b) = (9.81, Vector3::new(0.2, 0.0, 0.0));
        let mut est = Estimator::new(EstimatorConfig::default()).unwrap();
        let mut rng = Normal(0x2545_F491_4F6C_DD1D);
        let mut t = 0.0;
        let mut learnt = Vec::new();
        for pitch in [-4.0, 3.0, -3.0, 5.0] {
            let f0 = stop_force(pitch, g, b, 0.0);
            let mut sum = Vector3::zeros();
            for _ in 0..500 {
                let tone =
                    0.3 * std::f64::consts::SQRT_2 * (std::f64::consts::TAU * 25.0 * t + 0.4).sin();
                let f = f0
                    + Vector3::new(0.0, 0.0, tone)
                    + Vector3::new(rng.draw(), rng.draw(), rng.draw()) * 0.03;
                est.update_gravity(t, &f, None);
                sum += f;
                t += 0.01;
            }
            est.update_stop_bias(t, &(sum / 500.0), 500);
            learnt.push(est.acc_bias_mps2().x);
            t += 1.0;
        }
        // Measured after the 2nd, 3rd and 4th stop: 0.141 / 0.176 / 0.206 (without the
        // engine 0.181 / 0.183 / 0.205); trusting only the per-sample spread,
        // 0.116 / 0.123 / 0.166.
        assert!(
            (learnt[2] - b.x).abs() < 0.04,
            "after 3 stops: {:.3}",
            learnt[2]
        );
        assert!(
            (learnt[3] - b.x).abs() < 0.02,
            "after 4 stops: {:.3}",
            learnt[3]
        );
    }

    #[test]
    fn an_engines_first_quarter_second_does_not_hold_the_first_stops_magnitude() {
        use crate::estimator::{Estimator, EstimatorConfig};
        // 4 s of a first stop with an engine shaking the IMU by 0.2 m/s^2 rms at 25 Hz
        // along gravity, sampled at 100 Hz: a quarter-second block keeps one sample of
        // it, the first block its crest (+11 mm/s^2), the later ones alternate.
        let g = 9.81;
        let mut est = Estimator::new(EstimatorConfig::default()).unwrap();
        let mut rng = Normal(0x5DEE_CE66_D1CE_4E5B);
        for k in 0..400 {
            let t = k as f64 * 0.01;
            let tone =
                0.2 * std::f64::consts::SQRT_2 * (std::f64::consts::TAU * 25.0 * t + 1.57).sin();
            let noise = Vector3::new(rng.draw(), rng.draw(), rng.draw()) * 0.003;
            est.update_gravity(t, &(Vector3::new(0.0, 0.0, g + tone) + noise), None);
        }
        let learnt = est.gravity.unwrap().magnitude(&Vector3::z());
        // Measured: 1.0 mm/s^2 off; with the first block taken at the nominal noise,
        // 5.1.
        assert!((learnt - g).abs() < 0.004, "learnt {learnt:.5} for {g}");
    }

    #[test]
    fn a_white_noise_is_not_taken_for_a_vibration_and_an_engine_is_from_the_fourth_pair() {
        // Pairs of quarter-second means (25 samples each) whose difference spreads as a
        // white noise of per-sample variance `r_pairs` would, against a per-sample
        // spread `r`; each start as a fresh filter.
        let run = |r: f64, r_pairs: f64, seed: u64| {
            let mut f = GravityFilter::new(9.81, 1e-3, [0.0; 2], 0.1);
            f.r = r;
            let mut rng = Normal(seed);
            (1..=40)
                .map(|k| {
                    let d = rng.draw() * (r_pairs * 2.0 / 25.0).sqrt();
                    f.learn_smooth_noise(d, 25, 25);
                    (k, f.vibration_seen(), f.vibrating())
                })
                .collect::<Vec<_>>()
        };
        // White noise of 1000 ug/sqrt(Hz) (0.0096 (m/s^2)^2 per sample), 500 starts:
        // never before the fourth pair, and rarely at all.
        let (mut seen, mut vibrating) = (0, 0);
        for seed in 1..=500u64 {
            let pairs = run(0.0096, 0.0096, seed * 0x9E37_79B9);
            assert!(pairs.iter().all(|&(k, s, _)| k >= 4 || !s));
            seen += usize::from(pairs.iter().any(|&(_, s, _)| s));
            vibrating += usize::from(pairs.iter().any(|&(_, _, v)| v));
        }
        // Chi-square: about 0.7 % at each of the first few pairs, 2-3 % in all.
        assert!(seen <= 25, "{seen} of 500 white starts seen as a vibration");
        assert!(
            vibrating <= 5,
            "{vibrating} of 500 white starts taken for a vibration"
        );
        // An engine at 0.2 m/s^2 rms next to 30 ug/sqrt(Hz): seen from the fourth pair,
        // a vibration from the twelfth.
        let pairs = run(0.04, 9e-6, 7);
        assert!(
            pairs
                .iter()
                .all(|&(k, s, v)| s == (k >= 4) && v == (k >= 12))
        );
    }

    #[test]
    fn one_stop_short_of_gravity_does_not_become_a_bias_that_agreeing_stops_still_teach() {
        let (g, b) = (9.81, Vector3::new(0.03, 0.0, 0.0));
        let r = STOP_FLOOR_MPS2 * STOP_FLOOR_MPS2;
        let prior = crate::estimator::EstimatorConfig::default().acc_bias_prior_mps2;
        let mut f = GravityFilter::new(g, 1.0, [0.0; 2], prior);
        for (k, pitch) in [2.3, 1.5, 1.8, 1.7, -1.4, -0.8, -0.8].iter().enumerate() {
            f.update_bounded(k as f64 * 60.0, &stop_force(*pitch, g, b, 0.0), 0.0005, r);
        }
        let learnt = f.x.y;
        assert!((learnt - b.x).abs() < 0.01, "learnt {learnt:.4}");
        // A stop of a few settled samples of a body still swinging: 0.07 m/s^2 short.
        let bad = stop_force(1.1, g, b, 0.07);
        let mut plain = f;
        let y = plain.innovation(600.0, &bad, 0.0005);
        plain.correct(&bad, y, r);
        f.update_bounded(600.0, &bad, 0.0005, r);
        // Measured: the unbounded update moves the bias by 0.21 m/s^2, the bounded one
        // by 0.033.
        let (unbounded, bounded) = ((plain.x.y - learnt).abs(), (f.x.y - learnt).abs());
        assert!(unbounded > 0.15, "unbounded {unbounded:.3}");
        assert!(
            bounded < 0.05 && bounded < unbounded / 4.0,
            "bounded {bounded:.4}"
        );
    }
}
