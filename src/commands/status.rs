//! `leveld status`: the running daemon's own report, or, when it is not running, the
//! state it saved last.

use crate::daemon::state::{self, Loaded};
use crate::daemon::status::{self, StatusReport};
use crate::daemon::{load, pipeline::Pipeline};
use anyhow::Result;
use std::io::Write;
use std::path::Path;

/// Exit code 0: the daemon is running and published a fresh report; 3: it is not
/// running (as `systemctl status` does for an inactive unit).
pub fn run(config: Option<&Path>, json: bool) -> Result<i32> {
    let (cfg, db, _) = load(config)?;
    let status_path = &cfg.state.status_path;
    let published = if status_path.as_os_str().is_empty() {
        Ok(None)
    } else {
        status::read(status_path)
    };
    let now = status::unix_now_s();
    let mut out = std::io::stdout().lock();
    let (running, why) = match &published {
        Ok(Some(r)) if r.running && status::pid_is_leveld(r.pid) => (true, String::new()),
        Ok(Some(r)) if r.running => (
            false,
            format!(
                "not running: pid {} that published {} has gone without stopping (killed or crashed)",
                r.pid,
                status_path.display()
            ),
        ),
        Ok(Some(_)) => (false, "not running: stopped".to_string()),
        Ok(None) if status_path.as_os_str().is_empty() => (
            false,
            "unknown: state.status_path is empty, the daemon publishes no status".to_string(),
        ),
        Ok(None) => (
            false,
            format!("not running: no status at {}", status_path.display()),
        ),
        Err(e) => (false, format!("unknown: {e}")),
    };
    let saved = saved_state(&cfg, &db);
    let cal = crate::daemon::calibration::load(&cfg.state.calibration_path);
    let calibration = serde_json::json!({
        "path": cfg.state.calibration_path.display().to_string(),
        "reference_pitch_deg": cal.reference_pitch_deg(),
        "summary": cal.describe(),
    });
    if json {
        let v = serde_json::json!({
            "running": running,
            "reason": if running { None } else { Some(&why) },
            "report": published.as_ref().ok().and_then(|r| r.as_ref()),
            "report_age_s": published.as_ref().ok().and_then(|r| r.as_ref()).map(|r| now - r.updated_unix_s),
            "saved": saved,
            "calibration": calibration,
        });
        writeln!(out, "{v}")?;
    } else {
        if running {
            writeln!(out, "leveld: running")?;
        } else {
            writeln!(out, "leveld: {why}")?;
        }
        if let Ok(Some(r)) = &published {
            write_report(&mut out, r, now, running)?;
        }
        if !running {
            writeln!(
                out,
                "saved state: {}",
                saved["summary"].as_str().unwrap_or("-")
            )?;
            match (cal.reference_pitch_deg(), cal.reference_roll_deg()) {
                (Some(r), Some(roll)) => writeln!(
                    out,
                    "calibration file: reference pitch {r:+.3} deg, roll {roll:+.3} deg ({})",
                    cfg.state.calibration_path.display()
                )?,
                (Some(r), None) => writeln!(
                    out,
                    "calibration file: reference pitch {r:+.3} deg, no roll ({})",
                    cfg.state.calibration_path.display()
                )?,
                (None, _) => writeln!(
                    out,
                    "calibration file: {} ({})",
                    cal.describe(),
                    cfg.state.calibration_path.display()
                )?,
            }
        }
    }
    out.flush()?;
    Ok(if running { 0 } else { 3 })
}

fn write_report(out: &mut impl Write, r: &StatusReport, now: f64, running: bool) -> Result<()> {
    let age = now - r.updated_unix_s;
    writeln!(
        out,
        "{} report: pid {}, {:.0} s old, up {:.0} s",
        if running { "live" } else { "last" },
        r.pid,
        age,
        r.updated_unix_s - r.started_unix_s
    )?;
    let status = serde_json::to_value(r.status)?;
    match (r.road_to_body_deg, r.std_err_deg, r.windows) {
        (Some(v), Some(se), Some(n)) => writeln!(
            out,
            "status: {}  road-to-body {v:+.3} deg +- {se:.3} ({n} windows)",
            status.as_str().unwrap_or("?")
        )?,
        _ => writeln!(
            out,
            "status: {}  no estimate yet",
            status.as_str().unwrap_or("?")
        )?,
    }
    match (r.reference_pitch_deg, r.level_reference_deg) {
        (Some(c), Some(l)) => writeln!(
            out,
            "calibration: reference pitch {c:+.3} deg, {l:+.3} without the accelerometer bias learnt ({})",
            r.calibration
        )?,
        (Some(c), None) => writeln!(
            out,
            "calibration: reference pitch {c:+.3} deg ({})",
            r.calibration
        )?,
        (None, _) => writeln!(
            out,
            "calibration: {}; the config's reference pitch is used",
            r.calibration
        )?,
    }
    writeln!(out, "CAN: {}", r.can)?;
    for i in &r.inputs {
        writeln!(
            out,
            "  {:<10} {:<7} frames {}, checksum errors {}, counter errors {}, DLC errors {}, timeouts {}",
            i.message,
            i.state,
            i.frames,
            i.checksum_errors,
            i.counter_errors,
            i.dlc_errors,
            i.timeouts
        )?;
    }
    writeln!(
        out,
        "sent {} (dropped {}, {} of them on a full queue), windows accepted {} rejected {} withdrawn {}, standstills {}, reconnects {}, bus-off {}, wall-clock steps {}",
        r.frames_sent,
        r.send_dropped,
        r.send_queue_full,
        r.windows_accepted,
        r.windows_rejected,
        r.windows_withdrawn,
        r.standstills,
        r.reconnects,
        r.bus_off,
        r.wall_clock_steps
    )?;
    if let Some(s) = r.suspension {
        writeln!(out, "suspension: {s}")?;
    }
    match &r.last_save {
        Some(s) if s.ok => writeln!(
            out,
            "last save: {:.0} s ago to {}",
            now - s.unix_s,
            r.state_path
        )?,
        Some(s) => writeln!(
            out,
            "last save: FAILED {:.0} s ago to {}: {}",
            now - s.unix_s,
            r.state_path,
            s.error.as_deref().unwrap_or("?")
        )?,
        None => writeln!(out, "last save: none since start ({})", r.state_path)?,
    }
    Ok(())
}

/// The saved state, read without touching it (a bad file is reported, not moved).
fn saved_state(
    cfg: &crate::daemon::config::Config,
    db: &crate::can::dbc::Database,
) -> serde_json::Value {
    let path = &cfg.state.path;
    let modified = std::fs::metadata(path)
        .and_then(|m| m.modified())
        .ok()
        .and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok())
        .map(|d| d.as_secs_f64());
    let summary = match state::read(path) {
        Loaded::Missing => format!("none at {}", path.display()),
        Loaded::Corrupt { reason, .. } => format!("{} is unusable: {reason}", path.display()),
        Loaded::State(st) => {
            let estimate = Pipeline::new(cfg, db).ok().and_then(|mut p| {
                p.restore(&st.estimator).ok()?;
                p.estimate()
            });
            let est = match estimate {
                Some(e) => format!(
                    "road-to-body {:+.3} deg +- {:.3} ({} windows)",
                    e.road_to_body_deg, e.std_err_deg, e.windows
                ),
                None => "no estimate".to_string(),
            };
            let cal = match st.reference_pitch_deg {
                Some(c) => format!(", reference pitch {c:+.3} deg kept by an earlier leveld"),
                None => String::new(),
            };
            let age = modified.map_or(String::new(), |m| {
                format!(", saved {:.0} s ago", status::unix_now_s() - m)
            });
            format!("{est}{cal}{age} ({})", path.display())
        }
    };
    serde_json::json!({ "path": path.display().to_string(), "modified_unix_s": modified, "summary": summary })
}
