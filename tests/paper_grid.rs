//! The simulation study of Kim et al. (2023) reproduced with fixed seeds.
//! Tolerances come from the paper's bars and from the measured spread (see each test).

use leveld::estimator::{Condition, EstimatorConfig};
use leveld::sim::paper::{self, Row, Setting, Sweep, WindowError};

fn cfg() -> EstimatorConfig {
    paper::paper_config()
}

fn setting(
    sweep: Sweep,
    slope_pct: f64,
    pitch_deg: f64,
    accel_mps2: f64,
    bias_mps2: f64,
    noise_ug: f64,
) -> Setting {
    Setting {
        sweep,
        slope_pct,
        pitch_deg,
        accel_mps2,
        bias_mps2,
        noise_ug,
    }
}

#[test]
fn error_free_sensors_give_exact_road_to_imu_pitch_on_every_table1_combination() {
    for slope in [0.0, 5.0, 10.0] {
        for pitch in [0.0, 0.5, 1.0] {
            for acc in [1.0, 2.0, 3.0] {
                let st = setting(Sweep::Noise, slope, pitch, acc, 0.0, 0.0);
                let (errs, missing) = paper::run_setting(&st, 1, 11, &cfg());
                assert_eq!(missing, 0, "{st:?}: both windows must be accepted");
                for c in [Condition::AccelAfterStop, Condition::DecelBeforeStop] {
                    let e: Vec<&WindowError> = errs.iter().filter(|e| e.condition == c).collect();
                    assert_eq!(e.len(), 1, "{st:?} {c:?}");
                    assert!(e[0].pitch_deg.abs() < 0.01, "{st:?} {c:?}: {:?}", e[0]);
                    assert!(e[0].slope_deg.abs() < 0.01, "{st:?} {c:?}: {:?}", e[0]);
                }
            }
        }
    }
}

/// Road-to-IMU mean error of the selected rows pooled by window count, and that count.
fn pooled(rows: &[Row], key: impl Fn(&Row) -> bool) -> (f64, usize) {
    let sel: Vec<&Row> = rows.iter().filter(|r| key(r)).collect();
    let n: usize = sel.iter().map(|r| r.n).sum();
    let mean = sel
        .iter()
        .map(|r| r.pitch_err_mean_deg * r.n as f64)
        .sum::<f64>()
        / n as f64;
    (mean, n)
}

#[test]
fn bias_shifts_imu_pitch_and_slope_but_cancels_in_road_to_imu_pitch() {
    let settings: Vec<Setting> = paper::grid()
        .into_iter()
        .filter(|s| s.sweep == Sweep::Bias)
        .collect();
    let rows = paper::run_grid(&settings, 20, 3, &cfg(), 2);
    for r in &rows {
        assert_eq!(r.missing, 0, "{:?}", r.setting);
    }
    let biases = paper::bias_values();
    // IMU-pitch and slope errors grow with |bias| on either side of zero (Fig. 13-15).
    let mean_abs = |b: f64, f: &dyn Fn(&Row) -> f64| {
        let sel: Vec<f64> = rows
            .iter()
            .filter(|r| r.setting.bias_mps2 == b)
            .map(f)
            .collect();
        sel.iter().sum::<f64>() / sel.len() as f64
    };
    for pair in biases.windows(2) {
        let (lo, hi) = (pair[0], pair[1]);
        if lo >= 0.0 {
            assert!(
                mean_abs(hi, &|r| r.imu_pitch_err_mean_deg)
                    > mean_abs(lo, &|r| r.imu_pitch_err_mean_deg)
            );
            assert!(
                mean_abs(hi, &|r| r.slope_err_mean_deg) > mean_abs(lo, &|r| r.slope_err_mean_deg)
            );
        }
        if hi <= 0.0 {
            assert!(
                mean_abs(lo, &|r| r.imu_pitch_err_mean_deg)
                    < mean_abs(hi, &|r| r.imu_pitch_err_mean_deg)
            );
            assert!(
                mean_abs(lo, &|r| r.slope_err_mean_deg) < mean_abs(hi, &|r| r.slope_err_mean_deg)
            );
        }
    }
    // At 1 m/s^2 of bias the IMU pitch is off by degrees: the cancellation below is not trivial.
    assert!(mean_abs(1.0, &|r| r.imu_pitch_err_mean_deg) > 4.0);
    // Road-to-IMU pitch: zero-mean at every bias value. 140 windows per value with a
    // single-window spread of about 0.2 deg give a standard error near 0.017 deg.
    for &b in &biases {
        let (mean, n) = pooled(&rows, |r| r.setting.bias_mps2 == b);
        assert!(n >= 140);
        assert!(
            mean.abs() <= 0.05,
            "bias {b}: road-to-IMU mean error {mean:.4} deg"
        );
    }
}

#[test]
fn noise_drives_the_spread_and_acceleration_reduces_it() {
    let settings: Vec<Setting> = paper::grid()
        .into_iter()
        .filter(|s| s.sweep == Sweep::Noise)
        .collect();
    let rows = paper::run_grid(&settings, 25, 5, &cfg(), 2);
    let std_at = |nd: f64, slope: f64, pitch: f64, acc: f64| {
        rows.iter()
            .find(|r| {
                r.setting.noise_ug == nd
                    && r.setting.slope_pct == slope
                    && r.setting.pitch_deg == pitch
                    && r.setting.accel_mps2 == acc
            })
            .map(|r| r.pitch_err_std_deg)
            .unwrap()
    };
    // Pooled over the seven combinations, the single-window spread rises with noise density.
    let pooled_std = |nd: f64| {
        let sel: Vec<&Row> = rows.iter().filter(|r| r.setting.noise_ug == nd).collect();
        (sel.iter().map(|r| r.pitch_err_std_deg.powi(2)).sum::<f64>() / sel.len() as f64).sqrt()
    };
    let s: Vec<f64> = paper::noise_values()
        .iter()
        .map(|&nd| pooled_std(nd))
        .collect();
    for (i, pair) in s.windows(2).enumerate() {
        assert!(
            pair[1] > pair[0] * 0.95,
            "spread must not fall with noise: {s:?} at step {i}"
        );
    }
    assert!(s[6] > 2.5 * s[0], "{s:?}");
    // The paper's figure at 300 ug/sqrt(Hz) and 2 m/s^2: about 0.2 deg; at most that here.
    let s300 = std_at(300.0, 0.0, 0.0, 2.0);
    assert!(s300 <= 0.2, "{s300}");
    // Faster acceleration covers T_d sooner and integrates less noise.
    for nd in [300.0, 500.0, 700.0] {
        assert!(
            std_at(nd, 0.0, 0.0, 3.0) < std_at(nd, 0.0, 0.0, 1.0),
            "noise {nd}"
        );
    }
}
