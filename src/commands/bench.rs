//! `leveld bench accuracy`: leveld against the baselines on simulated drives.

use anyhow::Result;
use std::io::Write;

/// `leveld bench accuracy`.
pub fn accuracy(
    scenarios: &[std::path::PathBuf],
    json: bool,
    plots: Option<&std::path::Path>,
    threads: Option<usize>,
    ablation: bool,
    seeds: u64,
    set: &[String],
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
        let mut spec = crate::bench::suite::DriveSpec::parse_with(&text, set)
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
            writeln!(out)?;
            writeln!(
                out,
                "| scenario | load | gentle drive-offs without a window | no standstill | reference not still | slope not constant | turning | speed mismatch | other |"
            )?;
            writeln!(
                out,
                "| --- | --- | --- | --- | --- | --- | --- | --- | --- |"
            )?;
            for s in &summary {
                let l = &s.gentle_lost;
                writeln!(
                    out,
                    "| {} | {} | {} | {} | {} | {} | {} | {} | {} |",
                    s.scenario,
                    s.load,
                    s.gentle_drive_offs - s.gentle_accepted,
                    l.no_standstill,
                    l.not_still,
                    l.slope_not_constant,
                    l.turning,
                    l.speed_mismatch,
                    l.other,
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
