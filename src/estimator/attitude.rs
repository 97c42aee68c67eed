//! IMU attitude: from gravity at standstill (eq. 9) and by gyro integration (eq. 10-11).
//!
//! Axes are x forward, y left, z up. The attitude is the rotation from body to
//! navigation frame; navigation z is up and its x axis is the initial heading.
//! Pitch is positive nose-up, so it is the elevation of the body x axis.

use nalgebra::{UnitQuaternion, Vector3};

/// Attitude (yaw = 0) from the mean specific force measured at standstill, eq. 9.
///
/// `f_mps2` is the accelerometer reading in body axes; at rest it is gravity
/// reaction, about +9.81 on z when level. Returns `None` for a zero vector.
pub fn attitude_from_gravity(f_mps2: &Vector3<f64>) -> Option<UnitQuaternion<f64>> {
    let (pitch, roll) = pitch_roll_from_gravity(f_mps2)?;
    // Body-to-nav rotation: yaw 0, then pitch (nose-up is a negative turn about +y, which points left), then roll.
    Some(
        UnitQuaternion::from_axis_angle(&Vector3::y_axis(), -pitch)
            * UnitQuaternion::from_axis_angle(&Vector3::x_axis(), roll),
    )
}

/// Pitch (nose-up positive) and roll in rad from a standstill specific force, eq. 9.
pub fn pitch_roll_from_gravity(f_mps2: &Vector3<f64>) -> Option<(f64, f64)> {
    let n = f_mps2.norm();
    if !n.is_finite() || n < 1e-6 {
        return None;
    }
    let pitch = f_mps2.x.atan2(f_mps2.y.hypot(f_mps2.z));
    let roll = f_mps2.y.atan2(f_mps2.z);
    Some((pitch, roll))
}

/// Pitch of a body-to-nav attitude in rad, positive nose-up.
pub fn pitch_of(q: &UnitQuaternion<f64>) -> f64 {
    let x = q * Vector3::x();
    x.z.atan2(x.x.hypot(x.y))
}

/// One step of eq. 10-11: rotate by the body rate `omega_rps` (rad/s) over `dt_s`.
/// A negative `dt_s` integrates backwards in time.
pub fn propagate(
    q: &UnitQuaternion<f64>,
    omega_rps: &Vector3<f64>,
    dt_s: f64,
) -> UnitQuaternion<f64> {
    q * UnitQuaternion::from_scaled_axis(omega_rps * dt_s)
}

#[cfg(test)]
mod tests {
    use super::*;
    const G: f64 = 9.80665;

    #[test]
    fn gravity_attitude_recovers_tilt() {
        for &(pitch_deg, roll_deg) in &[
            (0.0, 0.0),
            (3.0, 0.0),
            (-5.71, 1.5),
            (10.0, -4.0),
            (0.5, 0.2),
        ] {
            let (p, r) = (f64::to_radians(pitch_deg), f64::to_radians(roll_deg));
            // Specific force at rest for this tilt, written out independently of the code under test.
            let f = Vector3::new(G * p.sin(), G * p.cos() * r.sin(), G * p.cos() * r.cos());
            let q = attitude_from_gravity(&f).unwrap();
            assert!((pitch_of(&q) - p).abs() < 1e-12, "pitch {pitch_deg}");
            // The attitude maps the measured specific force onto navigation up.
            let up = q * f;
            assert!((up - Vector3::new(0.0, 0.0, G)).norm() < 1e-9, "{up:?}");
        }
    }

    #[test]
    fn nose_up_tilt_gives_positive_acc_x() {
        let q = attitude_from_gravity(&Vector3::new(G * 0.01f64.sin(), 0.0, G * 0.01f64.cos()))
            .unwrap();
        assert!(pitch_of(&q) > 0.0);
    }

    #[test]
    fn forward_then_backward_returns_to_start() {
        let q0 = attitude_from_gravity(&Vector3::new(0.4, -0.2, 9.7)).unwrap();
        let mut q = q0;
        let rates: Vec<Vector3<f64>> = (0..300)
            .map(|k| {
                let t = k as f64 * 0.01;
                Vector3::new(0.1 * t.sin(), -0.05 + 0.02 * t, 0.2 * (2.0 * t).cos())
            })
            .collect();
        for w in &rates {
            q = propagate(&q, w, 0.01);
        }
        assert!(q.angle_to(&q0) > 0.01, "the test must actually rotate");
        for w in rates.iter().rev() {
            q = propagate(&q, w, -0.01);
        }
        assert!(q.angle_to(&q0) < 1e-12, "{}", q.angle_to(&q0));
    }

    #[test]
    fn constant_pitch_rate_integrates_to_expected_pitch() {
        // Nose-up pitch rate is negative about +y (left).
        let mut q = UnitQuaternion::identity();
        let rate = f64::to_radians(2.0);
        for _ in 0..100 {
            q = propagate(&q, &Vector3::new(0.0, -rate, 0.0), 0.01);
        }
        assert!((pitch_of(&q) - rate).abs() < 1e-12);
    }
}
