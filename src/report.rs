//! Human and JSON reports of simulator runs.

use crate::estimator::EstimatorConfig;
use crate::sim::paper::{self, Row, Sweep};
use anyhow::Result;
use std::io::Write;

/// `leveld simulate paper-grid`.
pub fn paper_grid(
    runs: usize,
    seed: u64,
    format: crate::cli::Format,
    threads: Option<usize>,
) -> Result<()> {
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
    match format {
        crate::cli::Format::Json => {
            for r in &rows {
                writeln!(out, "{}", serde_json::to_string(&json_row(r))?)?;
            }
        }
        crate::cli::Format::Table => write_table(&mut out, &rows)?,
        crate::cli::Format::Summary => write_summary(&mut out, &rows)?,
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
pub fn simulate_drive(
    preset: &str,
    scenario: Option<&std::path::Path>,
    seed: u64,
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
            let mut sc: crate::sim::Scenario = toml::from_str(&text)
                .with_context(|| format!("scenario {} is not valid", p.display()))?;
            sc.seed = seed;
            sc
        }
        None => match crate::sim::presets::preset(preset, seed) {
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

/// `leveld replay`.
pub fn replay(
    input: &std::path::Path,
    config: Option<&std::path::Path>,
    output: Option<&std::path::Path>,
    interface: Option<String>,
    json: bool,
    strict: bool,
) -> Result<i32> {
    use crate::daemon::{pipeline::Pipeline, replay};
    use anyhow::Context;
    let (cfg, db, _src) = crate::daemon::load(config)?;
    let mut p = Pipeline::new(&cfg, &db)?;
    let mut reader: Box<dyn std::io::BufRead> = if input.as_os_str() == "-" {
        Box::new(std::io::stdin().lock())
    } else {
        let f = std::fs::File::open(input)
            .with_context(|| format!("cannot open log {}", input.display()))?;
        Box::new(std::io::BufReader::with_capacity(1 << 16, f))
    };
    let mut frames_out = match output {
        Some(o) => Some(std::io::BufWriter::new(
            std::fs::File::create(o).with_context(|| format!("cannot create {}", o.display()))?,
        )),
        None => None,
    };
    let opts = replay::ReplayOptions {
        interface,
        strict,
        json,
        output_interface: cfg.can.output_interface.clone(),
    };
    let mut out = std::io::BufWriter::new(std::io::stdout().lock());
    let summary = replay::replay(
        &mut p,
        &mut reader,
        &opts,
        &mut out,
        frames_out.as_mut().map(|w| w as &mut dyn Write),
    )
    .with_context(|| format!("replaying {}", input.display()))?;
    if let Some(w) = frames_out.as_mut() {
        w.flush().context("writing the output log")?;
    }
    if json {
        writeln!(out, "{}", serde_json::json!({ "summary": summary }))?;
    } else {
        replay::write_summary_text(&mut out, &summary)?;
    }
    out.flush()?;
    Ok(0)
}

/// `leveld check-config`.
pub fn check_config(config: Option<&std::path::Path>) -> Result<i32> {
    use crate::daemon::pipeline::{ACC, GYR, Pipeline, WHEELS};
    let (cfg, db, src) = crate::daemon::load(config)?;
    let p = Pipeline::new(&cfg, &db)?;
    let mut out = std::io::stdout().lock();
    writeln!(out, "config: {src}")?;
    writeln!(out, "DBC:    {}", db.path.display())?;
    writeln!(
        out,
        "input interfaces: {}; output on {}",
        cfg.can.input_interfaces.join(", "),
        cfg.can.output_interface
    )?;
    for (slot, m) in [(WHEELS, &cfg.wheels), (ACC, &cfg.acc), (GYR, &cfg.gyro)] {
        let c = p.input_codec(slot);
        writeln!(
            out,
            "{:6} <- {} (0x{:X}{}), signals {}, counter [{}]{}, checksum {:?} [{}]{}, timeout {:.0} ms",
            c.name,
            m.message,
            c.id,
            if c.extended { " ext" } else { "" },
            m.signals.join(" "),
            m.counter.join(" "),
            if m.check_counter {
                ""
            } else {
                " (not checked)"
            },
            m.checksum_kind,
            m.checksum.join(" "),
            if m.check_checksum {
                ""
            } else {
                " (not checked)"
            },
            c.timeout_s * 1000.0
        )?;
    }
    let o = p.output();
    writeln!(
        out,
        "output -> {} (0x{:X}) every {} ms and on change; actuator {:+.2}..{:+.2} deg; reference pitch {:+.3} deg",
        cfg.output.message,
        o.id,
        cfg.output.period_ms,
        cfg.leveling.actuator_min_deg,
        cfg.leveling.actuator_max_deg,
        cfg.leveling.reference_pitch_deg
    )?;
    writeln!(out, "state file: {}", cfg.state.path.display())?;
    writeln!(out, "ok")?;
    Ok(0)
}

/// `leveld calibrate`.
pub fn calibrate(
    config: Option<&std::path::Path>,
    log: Option<&std::path::Path>,
    interface: Option<&str>,
    duration_s: f64,
    state: Option<&std::path::Path>,
    dry_run: bool,
) -> Result<i32> {
    use crate::daemon::{calibrate, pipeline::Pipeline};
    use anyhow::{Context, bail};
    calibrate::check_duration(duration_s)?;
    let (cfg, db, _) = crate::daemon::load(config)?;
    let mut p = Pipeline::new(&cfg, &db)?;
    let cal = match log {
        Some(path) => {
            let f = std::fs::File::open(path)
                .with_context(|| format!("cannot open log {}", path.display()))?;
            calibrate::from_log(
                &mut p,
                &mut std::io::BufReader::new(f),
                interface,
                duration_s,
            )?
        }
        None => crate::daemon::live::calibrate_live(&cfg, &mut p, duration_s)?,
    };
    if cal.reference_pitch_deg.abs() > 10.0 {
        bail!(
            "measured pitch {:+.2} deg is implausible for a level floor; check the IMU mounting and axes",
            cal.reference_pitch_deg
        );
    }
    println!(
        "reference pitch {:+.3} deg from {:.1} s of standstill",
        cal.reference_pitch_deg, cal.settled_s
    );
    if !dry_run {
        let path = state.map_or_else(|| cfg.state.path.clone(), |p| p.to_path_buf());
        calibrate::store(&mut p, &path, &cal)?;
        println!("stored in {}", path.display());
    }
    Ok(0)
}

/// `leveld bench accuracy`.
pub fn bench_accuracy(
    scenarios: &[std::path::PathBuf],
    json: bool,
    plots: Option<&std::path::Path>,
    threads: Option<usize>,
    ablation: bool,
    seeds: u64,
) -> Result<i32> {
    use anyhow::Context;
    let files: Vec<std::path::PathBuf> = if scenarios.is_empty() {
        let mut v: Vec<_> = std::fs::read_dir("scenarios")
            .context("no --scenarios given and no scenarios/ folder here")?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.extension().is_some_and(|x| x == "toml"))
            .collect();
        v.sort();
        v
    } else {
        scenarios.to_vec()
    };
    let mut cases = Vec::new();
    // Plots show each scenario with its own seed.
    let mut plotted: Vec<(String, u64)> = Vec::new();
    for f in &files {
        let text =
            std::fs::read_to_string(f).with_context(|| format!("cannot read {}", f.display()))?;
        let mut spec = crate::bench::suite::DriveSpec::parse(&text)
            .with_context(|| format!("scenario {} is not valid", f.display()))?;
        let base = spec.seed;
        plotted.push((spec.name.clone(), base));
        for k in 0..seeds {
            spec.seed = base.wrapping_add(k);
            cases.extend(spec.cases());
        }
    }
    let threads = threads.unwrap_or_else(|| {
        std::thread::available_parallelism()
            .map(|n| n.get())
            .unwrap_or(1)
    });
    let make = if ablation {
        crate::bench::accuracy::ablation
    } else {
        crate::bench::accuracy::methods
    };
    let rows = crate::bench::accuracy::run(&cases, threads, make);
    let mut out = std::io::stdout().lock();
    if seeds > 1 {
        let pooled = crate::bench::accuracy::pool(&rows);
        if json {
            for p in &pooled {
                writeln!(out, "{}", serde_json::to_string(p)?)?;
            }
        } else {
            writeln!(
                out,
                "| scenario | load | method | seeds | mean abs err | median drive | worst drive | mean window err | p95 window err | accepted | never valid |"
            )?;
            writeln!(
                out,
                "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"
            )?;
            for p in &pooled {
                writeln!(
                    out,
                    "| {} | {} | {} | {} | {:.3} | {:.3} | {:.3} | {:+.3} | {:.3} | {} | {} |",
                    p.scenario,
                    p.load,
                    p.method,
                    p.seeds,
                    p.mean_abs_err_deg,
                    p.median_mean_abs_err_deg,
                    p.worst_mean_abs_err_deg,
                    p.mean_window_err_deg,
                    p.p95_window_err_deg,
                    p.accepted,
                    p.never_valid,
                )?;
            }
        }
    } else if json {
        for r in &rows {
            writeln!(out, "{}", serde_json::to_string(r)?)?;
        }
    } else {
        writeln!(
            out,
            "| scenario | load | method | mean err | mean abs err | std | p95 window err | accepted | rejected | time to valid | distance to valid |"
        )?;
        writeln!(
            out,
            "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"
        )?;
        for r in &rows {
            writeln!(
                out,
                "| {} | {} | {} | {:+.3} | {:.3} | {:.3} | {:.3} | {} | {} | {} | {} |",
                r.scenario,
                r.load,
                r.method,
                r.mean_err_deg,
                r.mean_abs_err_deg,
                r.std_err_deg,
                r.p95_window_err_deg,
                r.accepted,
                r.rejected,
                r.time_to_valid_s
                    .map_or("never".into(), |t| format!("{t:.0} s")),
                r.distance_to_valid_m
                    .map_or("never".into(), |d| format!("{d:.0} m")),
            )?;
        }
    }
    if cases.iter().any(|c| c.plan.is_some()) {
        let checks = stop_checks(&cases, threads);
        let summary = crate::bench::stops::summarize(&checks);
        if json {
            for s in &summary {
                writeln!(out, "{}", serde_json::to_string(s)?)?;
            }
        } else {
            writeln!(out)?;
            writeln!(
                out,
                "| scenario | load | drives | gentle drive-offs with a window | rolling stops with output | load changes applied before drive-off | valid within 5 stops | leveld mean window err |"
            )?;
            writeln!(out, "| --- | --- | --- | --- | --- | --- | --- | --- |")?;
            for s in &summary {
                writeln!(
                    out,
                    "| {} | {} | {} | {}/{} | {}/{} | {}/{} | {}/{} | {:+.3} |",
                    s.scenario,
                    s.load,
                    s.drives,
                    s.gentle_accepted,
                    s.gentle_drive_offs,
                    s.rolling_with_output,
                    s.rolling_stops,
                    s.load_applied,
                    s.load_changes,
                    s.valid_within_5,
                    s.valid_checked,
                    s.mean_window_err_deg,
                )?;
            }
        }
    }
    if let Some(dir) = plots {
        let shown: Vec<_> = rows
            .iter()
            .filter(|r| {
                plotted
                    .iter()
                    .any(|(s, k)| *s == r.scenario && *k == r.seed)
            })
            .cloned()
            .collect();
        crate::bench::plots::write(dir, &shown)?;
    }
    Ok(0)
}

/// Per-stop checks of the realistic cases, on `threads` threads.
fn stop_checks(
    cases: &[crate::bench::suite::Case],
    threads: usize,
) -> Vec<crate::bench::stops::StopChecks> {
    use crate::bench::baselines::{VALID_MAX_STD_ERR_DEG, VALID_MIN_WEIGHT};
    let real: Vec<&crate::bench::suite::Case> = cases.iter().filter(|c| c.plan.is_some()).collect();
    let valid = |e: &crate::estimator::Estimate| {
        e.std_err_deg <= VALID_MAX_STD_ERR_DEG && e.weight >= VALID_MIN_WEIGHT
    };
    let mut out = vec![crate::bench::stops::StopChecks::default(); real.len()];
    std::thread::scope(|sc| {
        let chunk = real.len().div_ceil(threads.max(1)).max(1);
        for (cs, slots) in real.chunks(chunk).zip(out.chunks_mut(chunk)) {
            sc.spawn(move || {
                for (c, slot) in cs.iter().zip(slots.iter_mut()) {
                    *slot = crate::bench::stops::check(c, &valid);
                }
            });
        }
    });
    out
}
