//! Named drives for demos and tests. Users can write their own as TOML (see `Scenario`).

use super::scenario::{Road, Scenario, Sensors, SpeedProfile, Vehicle};

/// Names accepted by `preset`.
pub const NAMES: &[&str] = &["multi-stop", "load-change"];

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

/// A road whose grade is `grades[i]` (percent) around stop `i` and changes half-way between stops.
pub fn road_around_stops(stops: &[f64], grades_pct: &[f64]) -> Road {
    let deg = |pct: f64| (pct / 100.0).atan().to_degrees();
    let mut knots = Vec::new();
    for (i, &s) in stops.iter().enumerate() {
        let g = deg(grades_pct[i % grades_pct.len()]);
        let lo = if i == 0 {
            s - 50.0
        } else {
            0.5 * (stops[i - 1] + s) + 15.0
        };
        let hi = if i + 1 < stops.len() {
            0.5 * (s + stops[i + 1]) - 15.0
        } else {
            s + 50.0
        };
        knots.push((lo, g));
        knots.push((hi, g));
    }
    Road {
        grade_deg: knots,
        curves: Vec::new(),
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
                seed,
            })
        }
        _ => None,
    }
}
