//! The accuracy benchmark: every method on identical simulated drives, against truth.

use super::baselines::{Kasaba, Leveld, Nilsson, PitchMethod};
use super::suite::Case;
use crate::estimator::{Averaging, EstimatorConfig};
use crate::sim::{Input, simulate};
use serde::Serialize;

/// One row: a scenario, a load case, a method.
#[derive(Debug, Clone, Serialize)]
pub struct Row {
    pub scenario: String,
    pub seed: u64,
    pub load: String,
    pub method: String,
    /// Mean of (estimate - truth) from the first converged status on, sampled at 1 Hz, deg.
    pub mean_err_deg: f64,
    /// Mean of |estimate - truth| over the same samples, deg.
    pub mean_abs_err_deg: f64,
    pub std_err_deg: f64,
    /// 95th percentile of |single window - truth| (baselines: their periodic estimates), deg.
    pub p95_window_err_deg: f64,
    pub accepted: usize,
    pub rejected: u64,
    pub time_to_valid_s: Option<f64>,
    pub distance_to_valid_m: Option<f64>,
    /// Estimate and truth at 1 Hz: (t s, estimate deg or NaN, truth deg), for plots.
    #[serde(skip)]
    pub track: Vec<(f64, f64, f64)>,
    #[serde(skip)]
    pub window_errors: Vec<f64>,
    /// Road grade under the vehicle at each window, deg (same order as `window_errors`).
    #[serde(skip)]
    pub window_grades_deg: Vec<f64>,
}

/// leveld with one improvement beyond the paper switched off at a time, and all of them
/// off ("paper-like"; the rest edge, settled reference and gravity filter stay).
pub fn ablation() -> Vec<Box<dyn PitchMethod>> {
    let d = EstimatorConfig::default;
    let no_lever = EstimatorConfig {
        lever_arm_m: [0.0; 3],
        ..d()
    };
    let no_turn = EstimatorConfig {
        max_yaw_rate_dps: 1e3,
        max_lateral_acc_mps2: 1e3,
        ..d()
    };
    let no_ext = EstimatorConfig {
        chord_check_extra_m: 0.0,
        ..d()
    };
    let no_load = EstimatorConfig {
        load_change_deg: 90.0,
        ..d()
    };
    let no_shift = EstimatorConfig {
        shift_windows: 0,
        ..d()
    };
    let no_learn = EstimatorConfig {
        learn_lever_arm: false,
        ..d()
    };
    let no_acc_bias = EstimatorConfig {
        correct_acc_bias: false,
        ..d()
    };
    let equal_weights = EstimatorConfig {
        weight_windows: false,
        ..d()
    };
    let no_live_pitch = EstimatorConfig {
        live_standstill_pitch: false,
        ..d()
    };
    let no_pairs = EstimatorConfig {
        pair_stop_windows: false,
        ..d()
    };
    let no_short_stops = EstimatorConfig {
        short_stop_windows: false,
        ..d()
    };
    let short_full_weight = EstimatorConfig {
        short_stop_weight: 1.0,
        ..d()
    };
    let raw_anchor = EstimatorConfig {
        derotated_motion_anchor: false,
        ..d()
    };
    let no_swing_gate = EstimatorConfig {
        rest_swing_gate_mps2: 1e3,
        ..d()
    };
    let no_reference_swing_gate = EstimatorConfig {
        reference_swing_gate_dps2: 1e6,
        ..d()
    };
    let every_block_bias = EstimatorConfig {
        still_blocks_teach_bias: false,
        ..d()
    };
    let fixed_gyro_gates = EstimatorConfig {
        scale_gyro_gates: false,
        ..d()
    };
    let no_imu_drive_off = EstimatorConfig {
        drive_off_speed_mps: 1e3,
        ..d()
    };
    let endpoint_slope = EstimatorConfig {
        velocity_free_slope: false,
        ..d()
    };
    let short_windows = EstimatorConfig {
        window_distance_m: crate::sim::paper::PAPER_WINDOW_M,
        ..d()
    };
    let no_fallback = EstimatorConfig {
        short_window_share: 0.0,
        ..d()
    };
    let no_noise_chord = EstimatorConfig {
        chord_noise_sigmas: 0.0,
        ..d()
    };
    let no_grade = EstimatorConfig {
        correct_grade_pitch: false,
        ..d()
    };
    let no_axle = EstimatorConfig {
        axle_chord: false,
        ..d()
    };
    let no_mode = EstimatorConfig {
        learn_pitch_mode: false,
        ..d()
    };
    let fixed_weights = EstimatorConfig {
        noise_scaled_weights: false,
        ..d()
    };
    let keep_bias = EstimatorConfig {
        rebias_windows: false,
        ..d()
    };
    let mean_dive_rebias = EstimatorConfig {
        rebias_by_walk: false,
        ..d()
    };
    let squat_as_dive = EstimatorConfig {
        learn_squat: false,
        ..d()
    };
    let keep_pitch = EstimatorConfig {
        follow_learnt_pitch: false,
        ..d()
    };
    let paper = EstimatorConfig {
        window_distance_m: crate::sim::paper::PAPER_WINDOW_M,
        shift_windows: 0,
        averaging: Averaging::Mean,
        lever_arm_m: [0.0; 3],
        max_yaw_rate_dps: 1e3,
        max_lateral_acc_mps2: 1e3,
        chord_check_extra_m: 0.0,
        load_change_deg: 90.0,
        learn_lever_arm: false,
        correct_acc_bias: false,
        weight_windows: false,
        drive_off_speed_mps: 1e3,
        live_standstill_pitch: false,
        pair_stop_windows: false,
        short_stop_windows: false,
        derotated_motion_anchor: false,
        rest_swing_gate_mps2: 1e3,
        reference_swing_gate_dps2: 1e6,
        scale_gyro_gates: false,
        scale_acc_gates: false,
        velocity_free_slope: false,
        short_window_share: 0.0,
        chord_noise_sigmas: 0.0,
        correct_grade_pitch: false,
        learn_pitch_mode: false,
        ..d()
    };
    vec![
        Box::new(Leveld::new(d(), "leveld")),
        Box::new(Leveld::new(
            EstimatorConfig {
                averaging: Averaging::Mean,
                ..d()
            },
            "eq17-average",
        )),
        Box::new(Leveld::new(no_lever, "no-lever-arm")),
        Box::new(Leveld::new(no_turn, "no-turn-check")),
        Box::new(Leveld::new(no_ext, "no-extended-chord")),
        Box::new(Leveld::new(no_load, "no-load-step")),
        Box::new(Leveld::new(no_shift, "no-shift-check")),
        Box::new(Leveld::new(no_learn, "no-lever-learning")),
        Box::new(Leveld::new(no_acc_bias, "no-acc-bias-correction")),
        Box::new(Leveld::new(equal_weights, "equal-weights")),
        Box::new(Leveld::new(no_imu_drive_off, "no-imu-drive-off")),
        Box::new(Leveld::new(no_live_pitch, "no-live-standstill-pitch")),
        Box::new(Leveld::new(no_pairs, "no-stop-pairs")),
        Box::new(Leveld::new(no_short_stops, "no-short-stop-windows")),
        Box::new(Leveld::new(short_full_weight, "short-stops-full-weight")),
        Box::new(Leveld::new(raw_anchor, "raw-motion-anchor")),
        Box::new(Leveld::new(no_swing_gate, "no-rest-swing-gate")),
        Box::new(Leveld::new(
            no_reference_swing_gate,
            "no-reference-swing-gate",
        )),
        Box::new(Leveld::new(every_block_bias, "every-block-teaches-bias")),
        Box::new(Leveld::new(fixed_gyro_gates, "fixed-gyro-gates")),
        Box::new(Leveld::new(endpoint_slope, "endpoint-slope")),
        Box::new(Leveld::new(short_windows, "2-m-windows")),
        Box::new(Leveld::new(no_fallback, "no-half-windows")),
        Box::new(Leveld::new(no_noise_chord, "no-chord-noise-floor")),
        Box::new(Leveld::new(no_grade, "no-grade-pitch")),
        Box::new(Leveld::new(no_axle, "no-axle-chord")),
        Box::new(Leveld::new(no_mode, "no-pitch-mode")),
        Box::new(Leveld::new(fixed_weights, "weights-at-300-ug")),
        Box::new(Leveld::new(keep_bias, "windows-keep-their-bias")),
        Box::new(Leveld::new(mean_dive_rebias, "rebias-by-mean-dive")),
        Box::new(Leveld::new(squat_as_dive, "squat-as-dive")),
        Box::new(Leveld::new(keep_pitch, "windows-keep-their-pitch")),
        Box::new(Leveld::new(d(), "no-lane-roll").without_floor_roll()),
        Box::new(Leveld::new(paper, "paper-like")),
    ]
}

/// The methods compared.
pub fn methods() -> Vec<Box<dyn PitchMethod>> {
    let eq17 = EstimatorConfig {
        averaging: Averaging::Mean,
        ..EstimatorConfig::default()
    };
    vec![
        Box::new(Leveld::new(EstimatorConfig::default(), "leveld")),
        Box::new(Leveld::new(eq17, "leveld-eq17")),
        Box::new(Kasaba::new()),
        Box::new(Nilsson::new()),
    ]
}

/// Run every method on one case.
pub fn run_case(case: &Case, make: &dyn Fn() -> Vec<Box<dyn PitchMethod>>) -> Vec<Row> {
    let drive = simulate(&case.scenario);
    let mut ms = make();
    // Every car has been through the end-of-line calibration.
    let floor_roll = crate::sim::floor_roll_deg(&case.scenario);
    for m in ms.iter_mut() {
        m.calibrate_floor_roll(floor_roll);
    }
    let mut tracks: Vec<Vec<(f64, f64, f64)>> = vec![Vec::new(); ms.len()];
    let mut valid_at: Vec<Option<(f64, f64)>> = vec![None; ms.len()];
    let mut next_sample = 0.0;
    for input in drive.merged() {
        let t = match input {
            Input::Imu(s) => {
                for m in ms.iter_mut() {
                    m.push_imu(s);
                }
                s.t_s
            }
            Input::Wheels(w) => {
                for m in ms.iter_mut() {
                    m.push_wheels(w);
                }
                w.t_s
            }
        };
        if t >= next_sample {
            next_sample = t + 1.0;
            let tr = drive.truth_at(t);
            for (i, m) in ms.iter().enumerate() {
                let e = m.estimate();
                if valid_at[i].is_none() && e.is_some_and(|e| e.1) {
                    valid_at[i] = Some((t, tr.s_m));
                }
                tracks[i].push((t, e.map_or(f64::NAN, |e| e.0), tr.load_pitch_deg));
            }
        }
    }
    let t_end = drive.truth.last().map_or(0.0, |x| x.t_s);
    for m in ms.iter_mut() {
        m.finish(t_end);
    }
    ms.iter()
        .enumerate()
        .map(|(i, m)| {
            let start = valid_at[i].map(|v| v.0);
            let errs: Vec<f64> = tracks[i]
                .iter()
                .filter(|(t, e, _)| start.is_some_and(|s| *t >= s) && e.is_finite())
                .map(|(_, e, tr)| e - tr)
                .collect();
            let n = errs.len().max(1) as f64;
            let mean = errs.iter().sum::<f64>() / n;
            let mean_abs = errs.iter().map(|e| e.abs()).sum::<f64>() / n;
            let std = (errs.iter().map(|e| (e - mean).powi(2)).sum::<f64>() / n).sqrt();
            let mut w: Vec<f64> = m
                .windows()
                .iter()
                .map(|(t, v)| (v - drive.truth_at(*t).load_pitch_deg).abs())
                .collect();
            w.sort_by(f64::total_cmp);
            let p95 = percentile95(&w);
            Row {
                scenario: case.scenario_name.clone(),
                seed: case.seed,
                load: case.load.clone(),
                method: m.name().to_string(),
                mean_err_deg: if errs.is_empty() { f64::NAN } else { mean },
                mean_abs_err_deg: if errs.is_empty() { f64::NAN } else { mean_abs },
                std_err_deg: if errs.is_empty() { f64::NAN } else { std },
                p95_window_err_deg: p95,
                accepted: m.windows().len(),
                rejected: m.rejected(),
                time_to_valid_s: valid_at[i].map(|v| v.0),
                distance_to_valid_m: valid_at[i].map(|v| v.1),
                track: tracks[i].clone(),
                window_errors: m
                    .windows()
                    .iter()
                    .map(|(t, v)| v - drive.truth_at(*t).load_pitch_deg)
                    .collect(),
                window_grades_deg: m
                    .windows()
                    .iter()
                    .map(|(t, _)| drive.truth_at(*t).grade_deg)
                    .collect(),
            }
        })
        .collect()
}

/// Rows of several seeds of the same scenario, load case and method, pooled.
#[derive(Debug, Clone, Serialize)]
pub struct Pooled {
    pub scenario: String,
    pub load: String,
    pub method: String,
    pub seeds: usize,
    /// Mean over the seeds of each drive's mean |error|, deg.
    pub mean_abs_err_deg: f64,
    /// The median and the worst drive's mean |error|, deg.
    pub median_mean_abs_err_deg: f64,
    pub worst_mean_abs_err_deg: f64,
    /// Mean signed error over all the seeds' windows, deg (a bias shows here).
    pub mean_window_err_deg: f64,
    /// 95th percentile of |single window error| over all the seeds' windows, deg.
    pub p95_window_err_deg: f64,
    pub accepted: usize,
    /// Seeds that never reached a converged estimate.
    pub never_valid: usize,
}

/// Pool rows by scenario, load case and method (in first-seen order).
pub fn pool(rows: &[Row]) -> Vec<Pooled> {
    let mut keys: Vec<(&str, &str, &str)> = Vec::new();
    for r in rows {
        let k = (r.scenario.as_str(), r.load.as_str(), r.method.as_str());
        if !keys.contains(&k) {
            keys.push(k);
        }
    }
    keys.into_iter()
        .map(|(s, l, m)| {
            let group: Vec<&Row> = rows
                .iter()
                .filter(|r| r.scenario == s && r.load == l && r.method == m)
                .collect();
            let finite: Vec<f64> = group
                .iter()
                .map(|r| r.mean_abs_err_deg)
                .filter(|x| x.is_finite())
                .collect();
            let signed: Vec<f64> = group
                .iter()
                .flat_map(|r| r.window_errors.iter().copied())
                .collect();
            let mut w: Vec<f64> = signed.iter().map(|e| e.abs()).collect();
            let mut sorted = finite.clone();
            sorted.sort_by(f64::total_cmp);
            let median = match sorted.len() {
                0 => f64::NAN,
                n if n % 2 == 1 => sorted[n / 2],
                n => 0.5 * (sorted[n / 2 - 1] + sorted[n / 2]),
            };
            w.sort_by(f64::total_cmp);
            Pooled {
                scenario: s.to_string(),
                load: l.to_string(),
                method: m.to_string(),
                seeds: group.len(),
                mean_abs_err_deg: if finite.is_empty() {
                    f64::NAN
                } else {
                    finite.iter().sum::<f64>() / finite.len() as f64
                },
                median_mean_abs_err_deg: median,
                worst_mean_abs_err_deg: finite.iter().copied().fold(f64::NAN, f64::max),
                mean_window_err_deg: if signed.is_empty() {
                    f64::NAN
                } else {
                    signed.iter().sum::<f64>() / signed.len() as f64
                },
                p95_window_err_deg: percentile95(&w),
                accepted: group.iter().map(|r| r.accepted).sum(),
                never_valid: group.iter().filter(|r| r.time_to_valid_s.is_none()).count(),
            }
        })
        .collect()
}

/// 95th percentile (nearest rank) of sorted values; NaN when empty.
pub fn percentile95(sorted: &[f64]) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    let n = sorted.len();
    sorted[((n as f64 * 0.95).ceil() as usize).clamp(1, n) - 1]
}

/// Run cases on `threads` threads; rows in case order.
pub fn run(cases: &[Case], threads: usize, make: fn() -> Vec<Box<dyn PitchMethod>>) -> Vec<Row> {
    let mut out: Vec<Vec<Row>> = vec![Vec::new(); cases.len()];
    std::thread::scope(|sc| {
        let chunk = cases.len().div_ceil(threads.max(1)).max(1);
        for (ci, (cs, slots)) in cases.chunks(chunk).zip(out.chunks_mut(chunk)).enumerate() {
            let _ = ci;
            sc.spawn(move || {
                for (c, slot) in cs.iter().zip(slots.iter_mut()) {
                    *slot = run_case(c, &make);
                }
            });
        }
    });
    out.into_iter().flatten().collect()
}
