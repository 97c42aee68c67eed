//! Human and JSON reports of simulator runs.

use crate::estimator::EstimatorConfig;
use crate::sim::paper::{self, Row, Sweep};
use anyhow::Result;
use std::io::Write;

/// `leveld simulate paper-grid`.
pub fn paper_grid(runs: usize, seed: u64, json: bool, threads: Option<usize>) -> Result<()> {
    let threads = threads.unwrap_or_else(|| {
        std::thread::available_parallelism()
            .map(|n| n.get())
            .unwrap_or(1)
    });
    let rows = paper::run_grid(
        &paper::grid(),
        runs,
        seed,
        &EstimatorConfig::default(),
        threads,
    );
    let mut out = std::io::stdout().lock();
    if json {
        for r in &rows {
            writeln!(out, "{}", serde_json::to_string(&json_row(r))?)?;
        }
    } else {
        write_table(&mut out, &rows)?;
    }
    Ok(())
}

fn json_row(r: &Row) -> serde_json::Value {
    let s = &r.setting;
    serde_json::json!({
        "sweep": match s.sweep { Sweep::Bias => "bias", Sweep::Noise => "noise" },
        "slope_pct": s.slope_pct,
        "pitch_deg": s.pitch_deg,
        "accel_mps2": s.accel_mps2,
        "bias_mps2": s.bias_mps2,
        "noise_ug": s.noise_ug,
        "n": r.n,
        "missing": r.missing,
        "imu_pitch_err_mean_deg": r.imu_pitch_err_mean_deg,
        "imu_pitch_err_std_deg": r.imu_pitch_err_std_deg,
        "slope_err_mean_deg": r.slope_err_mean_deg,
        "slope_err_std_deg": r.slope_err_std_deg,
        "pitch_err_mean_deg": r.pitch_err_mean_deg,
        "pitch_err_std_deg": r.pitch_err_std_deg,
    })
}

fn write_table(out: &mut impl Write, rows: &[Row]) -> Result<()> {
    writeln!(
        out,
        "{:<6} {:>6} {:>6} {:>5} {:>6} {:>6} {:>4} | {:>16} | {:>16} | {:>16}",
        "sweep",
        "slope%",
        "pitch",
        "acc",
        "bias",
        "noise",
        "n",
        "IMU pitch err",
        "slope err",
        "road-to-IMU err"
    )?;
    writeln!(
        out,
        "{:<47} | {:>16} | {:>16} | {:>16}",
        "", "mean / std deg", "mean / std deg", "mean / std deg"
    )?;
    for r in rows {
        let s = &r.setting;
        writeln!(
            out,
            "{:<6} {:>6.1} {:>6.2} {:>5.1} {:>6.2} {:>6.0} {:>4} | {:>7.3} / {:>6.3} | {:>7.3} / {:>6.3} | {:>7.3} / {:>6.3}",
            match s.sweep {
                Sweep::Bias => "bias",
                Sweep::Noise => "noise",
            },
            s.slope_pct,
            s.pitch_deg,
            s.accel_mps2,
            s.bias_mps2,
            s.noise_ug,
            r.n,
            r.imu_pitch_err_mean_deg,
            r.imu_pitch_err_std_deg,
            r.slope_err_mean_deg,
            r.slope_err_std_deg,
            r.pitch_err_mean_deg,
            r.pitch_err_std_deg
        )?;
    }
    Ok(())
}
