//! Named drives for demos and tests. Users can write their own as TOML (see `Scenario`).

use super::scenario::{Road, Scenario, Sensors, SpeedProfile, Vehicle};

/// Names accepted by `preset`.
pub const NAMES: &[&str] = &["multi-stop", "load-change", "short"];

/// Stop-and-go city legs: each holds, accelerates to `top_kmh`, cruises and brakes.
/// Returns the profile and the distance at which each stop happens.
pub fn city_legs(
    legs: &[(f64, f64, f64, f64, f64)],
    final_hold_s: f64,
) -> (SpeedProfile, Vec<f64>) {
    let mut p = SpeedProfile::default();
    let mut stops = vec![0.0];
    let mut s = 0.0;
    for &(hold_s, accel, top_kmh, cruise_s, brake) in legs {
        let v = top_kmh / 3.6;
        p = p.stop_go(hold_s, accel, v, cruise_s, brake);
        s += v * v / (2.0 * accel) + v * cruise_s + v * v / (2.0 * brake);
        stops.push(s);
    }
    (p.hold(final_hold_s), stops)
}

/// A road whose grade is `grades[i]` (percent) around stop `i`, changing half-way
/// between stops over at most 30 m, so that each stop keeps at least 4 m of constant
/// grade on either side (the windows and the wheelbase need about 3.5 m).
pub fn road_around_stops(stops: &[f64], grades_pct: &[f64]) -> Road {
    let deg = |pct: f64| (pct / 100.0).atan().to_degrees();
    let half = |a: f64, b: f64| (0.5 * (b - a) - 4.0).clamp(0.0, 15.0);
    let mut knots = Vec::new();
    for (i, &s) in stops.iter().enumerate() {
        let g = deg(grades_pct[i % grades_pct.len()]);
        let lo = if i == 0 {
            s - 50.0
        } else {
            0.5 * (stops[i - 1] + s) + half(stops[i - 1], s)
        };
        let hi = if i + 1 < stops.len() {
            0.5 * (s + stops[i + 1]) - half(s, stops[i + 1])
        } else {
            s + 50.0
        };
        knots.push((lo, g));
        knots.push((hi, g));
    }
    Road {
        grade_deg: knots,
        curves: Vec::new(),
        curve_ramp_m: 0.0,
        roughness: Default::default(),
        cross_slope_pct: 0.0,
    }
}

/// A named scenario.
pub fn preset(name: &str, seed: u64) -> Option<Scenario> {
    let legs = [
        (6.0, 1.5, 50.0, 8.0, 2.0),
        (8.0, 2.5, 40.0, 6.0, 2.5),
        (5.0, 1.0, 30.0, 10.0, 1.5),
        (10.0, 2.0, 50.0, 5.0, 3.0),
        (7.0, 3.0, 45.0, 8.0, 2.0),
        (6.0, 1.5, 35.0, 6.0, 2.0),
        (9.0, 2.0, 50.0, 7.0, 2.5),
        (6.0, 2.5, 40.0, 6.0, 1.5),
    ];
    let grades = [0.0, 4.0, -3.0, 6.0, 2.0, -5.0, 1.0, -2.0, 3.0];
    let sensors = Sensors {
        acc_bias_mps2: [0.05, -0.03, 0.08],
        gyro_bias_dps: [0.2, -0.3, 0.1],
        ..Sensors::default()
    };
    match name {
        "multi-stop" => {
            let (speed, stops) = city_legs(&legs, 8.0);
            Some(Scenario {
                speed,
                road: road_around_stops(&stops, &grades),
                load_pitch_deg: 0.8,
                load_changes: Vec::new(),
                vehicle: Vehicle::default(),
                sensors,
                shocks: Vec::new(),
                imu_gaps: Vec::new(),
                seed,
            })
        }
        "load-change" => {
            // As multi-stop, with a boot full of luggage loaded during the fourth stop.
            let mut l = legs.to_vec();
            l[3].0 = 25.0;
            let (speed, stops) = city_legs(&l, 8.0);
            let t_fourth_stop: f64 = speed
                .segments
                .iter()
                .take(3 * 3)
                .map(|s| s.duration_s)
                .sum::<f64>()
                + 8.0;
            Some(Scenario {
                speed,
                road: road_around_stops(&stops, &grades),
                load_pitch_deg: 0.2,
                load_changes: vec![(t_fourth_stop, 1.4, 3.0)],
                vehicle: Vehicle::default(),
                sensors,
                shocks: Vec::new(),
                imu_gaps: Vec::new(),
                seed,
            })
        }
        "short" => {
            // About 80 s of stop-and-go for real-time playback on a bus.
            let short = [(7.0, 2.5, 25.0, 1.0, 2.5); 6];
            let (speed, stops) = city_legs(&short, 7.0);
            Some(Scenario {
                speed,
                road: road_around_stops(&stops, &[0.0, 3.0, -2.0, 4.0, 1.0, -3.0, 2.0]),
                load_pitch_deg: 0.6,
                load_changes: Vec::new(),
                vehicle: Vehicle::default(),
                sensors,
                shocks: Vec::new(),
                imu_gaps: Vec::new(),
                seed,
            })
        }
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grade_is_constant_near_every_stop_and_knots_increase() {
        for name in NAMES {
            let sc = preset(name, 1).unwrap();
            let k = &sc.road.grade_deg;
            assert!(
                k.windows(2).all(|w| w[0].0 <= w[1].0),
                "{name}: knots out of order"
            );
            let legs: Vec<_> = sc.speed.segments.chunks(3).collect();
            let _ = legs;
            let (_, stops) = match *name {
                "short" => city_legs(&[(7.0, 2.5, 25.0, 1.0, 2.5); 6], 7.0),
                _ => continue,
            };
            for s in stops {
                let g0 = sc.road.grade(s).0;
                for ds in [-4.0, -2.0, 2.0, 4.0] {
                    assert!(
                        (sc.road.grade(s + ds).0 - g0).abs() < 1e-12,
                        "{name}: grade changes near stop at {s}"
                    );
                }
            }
        }
    }
}
