//! The settled gravity magnitude (the g of eq. 12-13) and pitch from a specific force.

use super::Estimator;
use super::attitude;
use nalgebra::{Matrix3, Vector3};

impl Estimator {
    pub(super) fn update_gravity(&mut self, t_s: f64, f: &Vector3<f64>) {
        let q = self.cfg.gravity_walk_mps2_rts;
        let k = self.gravity.get_or_insert_with(|| {
            GravityFilter::new(f.norm(), 1e-3, [0.0; 2], GravityFilter::BIAS_PRIOR_MPS2)
        });
        k.update(t_s, f, q);
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

/// Kalman filter on the standstill specific-force magnitude. An accelerometer bias `b`
/// makes the magnitude depend on where gravity points in the body: |g u + b| is about
/// c + b_x u_x + b_y u_y for the unit gravity direction u (b_z folds into c). A window
/// cancels the bias only with the magnitude of its own stop (the reference the attitude
/// came from); a single short stop measures it noisily, a plain average over stops
/// misses the bias term by up to |b| sin(pitch), 4 mm/s^2 for 0.05 m/s^2 at 5 deg:
/// 0.25 deg of slope over a 2 s window. So the state is (c, b_x, b_y), each a random
/// walk of `gravity_walk_mps2_rts` (the bias drifts with temperature); each settled
/// sample measures the magnitude with a noise learnt from the innovations.
#[derive(Debug, Clone, Copy)]
pub(super) struct GravityFilter {
    pub(super) x: Vector3<f64>,
    /// Covariance of `x`.
    pub(super) p: Matrix3<f64>,
    /// Per-sample measurement variance, (m/s^2)^2.
    pub(super) r: f64,
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

    pub(super) fn update(&mut self, t_s: f64, f: &Vector3<f64>, q: f64) {
        let m = f.norm();
        if m <= 0.0 {
            return;
        }
        if let Some(t0) = self.last_t {
            let walk = q * q * (t_s - t0).max(0.0);
            self.p += Matrix3::from_diagonal_element(walk);
        }
        self.last_t = Some(t_s);
        let h = Self::regressor(&(f / m));
        let y = m - h.dot(&self.x);
        self.r = (0.995 * self.r + 0.005 * y * y).max(1e-8);
        let ph = self.p * h;
        let k = ph / (h.dot(&ph) + self.r);
        self.x += k * y;
        self.p -= k * ph.transpose();
    }
}
