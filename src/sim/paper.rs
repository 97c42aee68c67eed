//! Reproduction of the simulation study of Kim et al. (2023), Table 1 and Fig. 13-18.
//!
//! Each movement is stop - accelerate - brake - stop on a constant grade with a rigid
//! body, as in the paper's Fig. 12, and yields two windows: acceleration after the
//! first stop and deceleration before the second. The accelerometer bias is applied
//! equally to all three axes; the gyro is error-free, as in the paper.

use super::drive::simulate;
use super::scenario::{Road, Scenario, Sensors, SpeedProfile, Vehicle};
use crate::estimator::{Condition, Estimator, EstimatorConfig, Event};
use serde::Serialize;

/// One setting of the grid.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Setting {
    pub sweep: Sweep,
    pub slope_pct: f64,
    pub pitch_deg: f64,
    pub accel_mps2: f64,
    pub bias_mps2: f64,
    pub noise_ug: f64,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Sweep {
    Bias,
    Noise,
}

/// Errors (estimate minus truth) of one window, deg.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct WindowError {
    pub condition: Condition,
    pub imu_pitch_deg: f64,
    pub slope_deg: f64,
    pub pitch_deg: f64,
}

/// Statistics of one setting.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Row {
    #[serde(flatten)]
    pub setting: Setting,
    /// Accepted windows.
    pub n: usize,
    /// Windows expected (two per movement) but not accepted.
    pub missing: usize,
    pub imu_pitch_err_mean_deg: f64,
    pub imu_pitch_err_std_deg: f64,
    pub slope_err_mean_deg: f64,
    pub slope_err_std_deg: f64,
    pub pitch_err_mean_deg: f64,
    pub pitch_err_std_deg: f64,
}

/// Bias values of the sweep, m/s^2.
pub fn bias_values() -> Vec<f64> {
    (0..=10)
        .map(|i| -1.0 + 0.2 * i as f64)
        .map(|x: f64| (x * 10.0).round() / 10.0)
        .collect()
}

/// Noise densities of the sweep, ug/sqrt(Hz).
pub fn noise_values() -> Vec<f64> {
    (1..=7).map(|i| 100.0 * i as f64).collect()
}

/// The (slope %, pitch deg, accel m/s^2) combinations the paper varies one at a time
/// around (0 %, 0 deg, 2 m/s^2), without repeating the centre.
pub fn combos() -> Vec<(f64, f64, f64)> {
    let mut v = vec![
        (0.0, 0.0, 2.0),
        (5.0, 0.0, 2.0),
        (10.0, 0.0, 2.0),
        (0.0, 0.5, 2.0),
        (0.0, 1.0, 2.0),
    ];
    v.push((0.0, 0.0, 1.0));
    v.push((0.0, 0.0, 3.0));
    v
}

/// The paper's window distance T_d (eq. 15), m.
pub const PAPER_WINDOW_M: f64 = 2.0;

/// leveld's estimator as the grid runs it: its defaults with the paper's window
/// distance, so that the grid's figures compare with the paper's.
pub fn paper_config() -> EstimatorConfig {
    EstimatorConfig {
        window_distance_m: PAPER_WINDOW_M,
        ..EstimatorConfig::default()
    }
}

/// Every setting of both sweeps.
pub fn grid() -> Vec<Setting> {
    let mut out = Vec::new();
    for b in bias_values() {
        for (slope_pct, pitch_deg, accel_mps2) in combos() {
            out.push(Setting {
                sweep: Sweep::Bias,
                slope_pct,
                pitch_deg,
                accel_mps2,
                bias_mps2: b,
                noise_ug: 300.0,
            });
        }
    }
    for nd in noise_values() {
        for (slope_pct, pitch_deg, accel_mps2) in combos() {
            out.push(Setting {
                sweep: Sweep::Noise,
                slope_pct,
                pitch_deg,
                accel_mps2,
                bias_mps2: 0.0,
                noise_ug: nd,
            });
        }
    }
    out
}

/// The scenario of one movement.
pub fn movement(st: &Setting, seed: u64) -> Scenario {
    let a = st.accel_mps2;
    // Reach 4 m of travel while accelerating, then brake at the same rate.
    let v_max = (8.0 * a).sqrt();
    Scenario {
        speed: SpeedProfile::default()
            .stop_go(3.0, a, v_max, 0.0, a)
            .hold(3.0),
        road: Road::constant((st.slope_pct / 100.0).atan().to_degrees()),
        load_pitch_deg: st.pitch_deg,
        load_changes: Vec::new(),
        vehicle: Vehicle::rigid(),
        sensors: Sensors {
            acc_noise_ug_rthz: st.noise_ug,
            acc_bias_mps2: [st.bias_mps2; 3],
            ..Sensors::ideal()
        },
        shocks: Vec::new(),
        imu_gaps: Vec::new(),
        seed,
    }
}

/// Run `runs` movements of one setting and return the window errors.
pub fn run_setting(
    st: &Setting,
    runs: usize,
    seed: u64,
    cfg: &EstimatorConfig,
) -> (Vec<WindowError>, usize) {
    let slope = (st.slope_pct / 100.0).atan().to_degrees();
    let mut errs = Vec::with_capacity(2 * runs);
    for r in 0..runs {
        let sc = movement(
            st,
            seed.wrapping_mul(0x9E37_79B9_7F4A_7C15)
                .wrapping_add(r as u64),
        );
        let drive = simulate(&sc);
        let mut est = Estimator::new(cfg.clone()).expect("valid config");
        let mut emit = |e: Event| {
            if let Event::WindowAccepted { window, .. } = e {
                errs.push(WindowError {
                    condition: window.condition,
                    imu_pitch_deg: window.imu_pitch_deg - (slope + st.pitch_deg),
                    slope_deg: window.road_slope_deg - slope,
                    pitch_deg: window.road_to_body_deg - st.pitch_deg,
                });
            }
        };
        for input in drive.merged() {
            match input {
                super::Input::Imu(s) => est.push_imu(s, &mut emit),
                super::Input::Wheels(w) => est.push_wheels(w, &mut emit),
            }
        }
        est.finish(drive.imu.last().map_or(0.0, |s| s.t_s), &mut emit);
    }
    let missing = (2 * runs).saturating_sub(errs.len());
    (errs, missing)
}

fn mean_std(xs: impl Iterator<Item = f64> + Clone) -> (f64, f64) {
    let n = xs.clone().count();
    if n == 0 {
        return (f64::NAN, f64::NAN);
    }
    let m = xs.clone().sum::<f64>() / n as f64;
    let v = if n > 1 {
        xs.map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1) as f64
    } else {
        0.0
    };
    (m, v.sqrt())
}

/// Summarise window errors into a row.
pub fn summarise(setting: Setting, errs: &[WindowError], missing: usize) -> Row {
    let (im, is) = mean_std(errs.iter().map(|e| e.imu_pitch_deg));
    let (sm, ss) = mean_std(errs.iter().map(|e| e.slope_deg));
    let (pm, ps) = mean_std(errs.iter().map(|e| e.pitch_deg));
    Row {
        setting,
        n: errs.len(),
        missing,
        imu_pitch_err_mean_deg: im,
        imu_pitch_err_std_deg: is,
        slope_err_mean_deg: sm,
        slope_err_std_deg: ss,
        pitch_err_mean_deg: pm,
        pitch_err_std_deg: ps,
    }
}

/// Run the whole grid, spreading settings over `threads` threads.
pub fn run_grid(
    settings: &[Setting],
    runs: usize,
    seed: u64,
    cfg: &EstimatorConfig,
    threads: usize,
) -> Vec<Row> {
    let threads = threads.max(1);
    let mut rows: Vec<Option<Row>> = vec![None; settings.len()];
    std::thread::scope(|sc| {
        let chunks: Vec<_> = rows
            .chunks_mut(settings.len().div_ceil(threads).max(1))
            .collect();
        let mut start = 0;
        for chunk in chunks {
            let base = start;
            start += chunk.len();
            sc.spawn(move || {
                for (j, slot) in chunk.iter_mut().enumerate() {
                    let st = settings[base + j];
                    let (errs, missing) =
                        run_setting(&st, runs, seed ^ ((base + j) as u64) << 20, cfg);
                    *slot = Some(summarise(st, &errs, missing));
                }
            });
        }
    });
    rows.into_iter()
        .map(|r| r.expect("every setting ran"))
        .collect()
}
