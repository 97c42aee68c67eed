//! `leveld simulate`: drives written as candump logs, and the paper's simulation grid.

use crate::sim::paper::{self, Row, Sweep};
use anyhow::Result;
use std::io::Write;

/// How `paper-grid` prints its rows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum GridFormat {
    Table,
    Json,
    /// Pooled over the settings of each bias or noise value.
    Summary,
}

/// `leveld simulate paper-grid`.
pub fn paper_grid(
    runs: usize,
    seed: u64,
    format: GridFormat,
    threads: Option<usize>,
) -> Result<()> {
    let threads = threads.unwrap_or_else(|| {
        std::thread::available_parallelism()
            .map(|n| n.get())
            .unwrap_or(1)
    });
    let rows = paper::run_grid(&paper::grid(), runs, seed, &paper::paper_config(), threads);
    let mut out = std::io::stdout().lock();
    match format {
        GridFormat::Json => {
            for r in &rows {
                writeln!(out, "{}", serde_json::to_string(&json_row(r))?)?;
            }
        }
        GridFormat::Table => write_table(&mut out, &rows)?,
        GridFormat::Summary => write_summary(&mut out, &rows)?,
    }
    Ok(())
}

/// Pooled errors per bias and per noise value (all slope, pitch and acceleration settings).
fn write_summary(out: &mut impl Write, rows: &[Row]) -> Result<()> {
    writeln!(
        out,
        "| sweep | value | windows | IMU pitch err mean | slope err mean | road-to-IMU err mean | road-to-IMU err std |"
    )?;
    writeln!(out, "| --- | --- | --- | --- | --- | --- | --- |")?;
    for (sweep, values, unit) in [
        (Sweep::Bias, paper::bias_values(), "m/s^2"),
        (Sweep::Noise, paper::noise_values(), "ug/sqrt(Hz)"),
    ] {
        for v in values {
            let sel: Vec<&Row> = rows
                .iter()
                .filter(|r| {
                    r.setting.sweep == sweep
                        && if sweep == Sweep::Bias {
                            r.setting.bias_mps2 == v
                        } else {
                            r.setting.noise_ug == v
                        }
                })
                .collect();
            let n: usize = sel.iter().map(|r| r.n).sum();
            let pooled = |f: &dyn Fn(&Row) -> f64| {
                sel.iter().map(|r| f(r) * r.n as f64).sum::<f64>() / n.max(1) as f64
            };
            let std = (sel
                .iter()
                .map(|r| r.pitch_err_std_deg.powi(2) * r.n as f64)
                .sum::<f64>()
                / n.max(1) as f64)
                .sqrt();
            writeln!(
                out,
                "| {} | {v} {unit} | {n} | {:+.3} | {:+.3} | {:+.3} | {:.3} |",
                if sweep == Sweep::Bias {
                    "bias"
                } else {
                    "noise"
                },
                pooled(&|r| r.imu_pitch_err_mean_deg),
                pooled(&|r| r.slope_err_mean_deg),
                pooled(&|r| r.pitch_err_mean_deg),
                std
            )?;
        }
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

/// `leveld simulate drive`.
#[allow(clippy::too_many_arguments)]
pub fn drive(
    preset: &str,
    scenario: Option<&std::path::Path>,
    load: Option<&str>,
    seed: Option<u64>,
    output: &std::path::Path,
    truth: Option<&std::path::Path>,
    iface: &str,
    t0: f64,
    dbc: &std::path::Path,
) -> Result<()> {
    use anyhow::{Context, bail};
    let sc = match scenario {
        Some(p) => {
            let text = std::fs::read_to_string(p)
                .with_context(|| format!("cannot read scenario {}", p.display()))?;
            let table: toml::Table = toml::from_str(&text)
                .with_context(|| format!("scenario {} is not valid TOML", p.display()))?;
            if table.contains_key("loads") {
                let mut spec = crate::bench::suite::DriveSpec::parse_with(&text, &[])
                    .with_context(|| format!("benchmark drive {} is not valid", p.display()))?;
                if let Some(seed) = seed {
                    spec.seed = seed;
                }
                let cases = spec.cases();
                let names: Vec<&str> = cases.iter().map(|c| c.load.as_str()).collect();
                let case = match load {
                    None => cases.first(),
                    Some(l) => cases.iter().find(|c| c.load == l),
                };
                match case {
                    Some(c) => c.scenario.clone(),
                    None => bail!(
                        "{} has no load case `{}`; choose one of: {}",
                        p.display(),
                        load.unwrap_or(""),
                        names.join(", ")
                    ),
                }
            } else {
                if load.is_some() {
                    bail!(
                        "--load needs a benchmark drive (a file with `loads`); {} is a simulator scenario",
                        p.display()
                    );
                }
                let mut sc: crate::sim::Scenario = toml::from_str(&text)
                    .with_context(|| format!("scenario {} is not valid", p.display()))?;
                sc.road
                    .roughness
                    .check()
                    .and_then(|()| sc.sensors.check())
                    .with_context(|| format!("scenario {} is not valid", p.display()))?;
                sc.seed = seed.unwrap_or(1);
                sc
            }
        }
        None => match crate::sim::presets::preset(preset, seed.unwrap_or(1)) {
            Some(sc) => sc,
            None => bail!(
                "unknown preset `{preset}`; choose one of: {}",
                crate::sim::presets::NAMES.join(", ")
            ),
        },
    };
    let db = crate::can::dbc::Database::load(dbc)?;
    let mut enc = crate::sim::canlog::InputEncoder::new(&db)?;
    let drive = crate::sim::simulate(&sc);
    let mut out: Box<dyn Write> = if output.as_os_str() == "-" {
        Box::new(std::io::BufWriter::new(std::io::stdout().lock()))
    } else {
        Box::new(std::io::BufWriter::new(
            std::fs::File::create(output)
                .with_context(|| format!("cannot create {}", output.display()))?,
        ))
    };
    let frames = crate::sim::canlog::write_candump(&drive, &mut enc, iface, t0, &mut out)?;
    out.flush()?;
    if let Some(tp) = truth {
        let mut t = std::io::BufWriter::new(
            std::fs::File::create(tp).with_context(|| format!("cannot create {}", tp.display()))?,
        );
        for (i, x) in drive.truth.iter().enumerate() {
            if i % 10 == 0 {
                let mut v = serde_json::to_value(x)?;
                v["t_s"] = serde_json::json!(x.t_s + t0);
                writeln!(t, "{v}")?;
            }
        }
        t.flush()?;
    }
    eprintln!(
        "simulated {:.0} s, {} frames",
        sc.speed.duration_s(),
        frames
    );
    Ok(())
}
