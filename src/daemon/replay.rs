//! `leveld replay`: the gateway run over a candump log, with log timestamps as time.

use super::gateway::{ACC, GYR, Gateway, MsgStats, WHEELS};
use crate::can::candump::{Line, parse_line};
use crate::estimator::Event;
use anyhow::{Context, Result, bail};
use serde::Serialize;
use std::io::{BufRead, Write};

/// Options of one replay.
#[derive(Debug, Clone, Default)]
pub struct ReplayOptions {
    /// Only frames from this interface; all interfaces when `None`.
    pub interface: Option<String>,
    /// Malformed lines are fatal.
    pub strict: bool,
    pub json: bool,
}

#[derive(Debug, Clone, Serialize)]
pub struct FinalState {
    pub road_to_body_pitch_deg: Option<f64>,
    pub std_err_deg: Option<f64>,
    pub estimate_count: u64,
    pub standstill: bool,
}

#[derive(Debug, Clone, Serialize)]
pub struct Summary {
    pub lines: u64,
    pub frames: u64,
    pub malformed_lines: u64,
    /// Line numbers of the first malformed lines (at most 20).
    pub malformed_examples: Vec<u64>,
    pub ignored_frames: u64,
    pub messages: std::collections::BTreeMap<String, MsgStats>,
    pub estimates_accepted: u64,
    pub estimates_rejected: u64,
    pub standstills: u64,
    #[serde(rename = "final")]
    pub final_state: FinalState,
}

/// Replay `input` through `gw`, writing events to `out` as they happen.
pub fn replay(
    gw: &mut Gateway,
    input: &mut dyn BufRead,
    opts: &ReplayOptions,
    out: &mut dyn Write,
) -> Result<Summary> {
    let mut line = String::new();
    let (mut lineno, mut frames, mut malformed) = (0u64, 0u64, 0u64);
    let mut examples = Vec::new();
    let mut standstills = 0u64;
    let write_err: std::cell::RefCell<Option<std::io::Error>> = std::cell::RefCell::new(None);
    let json = opts.json;
    let mut on_event = |e: Event, out: &mut dyn Write| {
        if let Event::StandstillStarted { .. } = e {
            standstills += 1;
        }
        let r = if json {
            writeln!(out, "{}", serde_json::to_string(&e).unwrap_or_default())
        } else {
            write_text(out, &e)
        };
        if let Err(err) = r {
            write_err.borrow_mut().get_or_insert(err);
        }
    };
    loop {
        line.clear();
        let n = input
            .read_line(&mut line)
            .context("reading the input log")?;
        if n == 0 {
            break;
        }
        lineno += 1;
        match parse_line(&line) {
            Ok(Line::Skip) => {}
            Ok(Line::Frame(f)) => {
                if opts.interface.as_deref().is_some_and(|i| i != f.iface()) {
                    continue;
                }
                frames += 1;
                if f.remote || f.fd {
                    gw.ignored_frames += 1;
                    continue;
                }
                gw.on_frame(f.t_s, f.id, f.extended, f.payload(), &mut |e| {
                    on_event(e, out)
                });
            }
            Err(e) => {
                malformed += 1;
                if opts.strict {
                    bail!("line {lineno}: {e}: {:?}", line.trim_end());
                }
                if examples.len() < 20 {
                    examples.push(lineno);
                }
                tracing::warn!("line {lineno}: {e}; line skipped");
            }
        }
        if let Some(e) = write_err.borrow_mut().take() {
            return Err(e).context("writing events");
        }
    }
    gw.finish(&mut |e| on_event(e, out));
    let names = gw.codecs().names();
    let mut messages = std::collections::BTreeMap::new();
    for slot in [WHEELS, ACC, GYR] {
        messages.insert(names[slot].to_string(), gw.stats[slot]);
    }
    let est = gw.est.estimate();
    Ok(Summary {
        lines: lineno,
        frames,
        malformed_lines: malformed,
        malformed_examples: examples,
        ignored_frames: gw.ignored_frames,
        messages,
        estimates_accepted: gw.windows_accepted,
        estimates_rejected: gw.windows_rejected,
        standstills,
        final_state: FinalState {
            road_to_body_pitch_deg: est.map(|e| e.road_to_body_deg),
            std_err_deg: est.map(|e| e.std_err_deg),
            estimate_count: est.map_or(0, |e| e.windows),
            standstill: gw.est.is_standstill(),
        },
    })
}

fn write_text(out: &mut dyn Write, e: &Event) -> std::io::Result<()> {
    match e {
        Event::StandstillStarted { t_s, imu_pitch_deg } => {
            writeln!(
                out,
                "{t_s:12.3}  standstill        IMU pitch {imu_pitch_deg:+.3} deg"
            )
        }
        Event::StandstillEnded { t_s, duration_s } => {
            writeln!(out, "{t_s:12.3}  drive-off         after {duration_s:.1} s")
        }
        Event::WindowAccepted {
            window: w,
            estimate,
        } => writeln!(
            out,
            "{:12.3}  window accepted   {:?}: IMU pitch {:+.3}, slope {:+.3}, road-to-body {:+.3} deg -> estimate {:+.3} +- {:.3} deg ({} windows)",
            w.t_s,
            w.condition,
            w.imu_pitch_deg,
            w.road_slope_deg,
            w.road_to_body_deg,
            estimate.road_to_body_deg,
            estimate.std_err_deg,
            estimate.windows
        ),
        Event::WindowRejected {
            t_s,
            condition,
            reason,
        } => {
            writeln!(
                out,
                "{t_s:12.3}  window rejected   {condition:?}: {reason:?}"
            )
        }
        Event::LoadChanged {
            t_s,
            delta_deg,
            estimate,
        } => writeln!(
            out,
            "{t_s:12.3}  load change       {delta_deg:+.3} deg -> estimate {}",
            estimate.map_or("none".into(), |e| format!("{:+.3} deg", e.road_to_body_deg))
        ),
        Event::SampleDropped { t_s, reason } => {
            writeln!(out, "{t_s:12.3}  sample dropped    {reason:?}")
        }
    }
}

/// Human summary.
pub fn write_summary_text(out: &mut dyn Write, s: &Summary) -> std::io::Result<()> {
    writeln!(out, "--")?;
    writeln!(
        out,
        "{} lines, {} frames, {} malformed, {} ignored",
        s.lines, s.frames, s.malformed_lines, s.ignored_frames
    )?;
    for (name, m) in &s.messages {
        writeln!(
            out,
            "{name:10} {:7} frames, {} checksum errors, {} counter errors, {} DLC errors",
            m.frames, m.checksum_errors, m.counter_errors, m.dlc_errors
        )?;
    }
    writeln!(
        out,
        "standstills {}, windows accepted {}, rejected {}",
        s.standstills, s.estimates_accepted, s.estimates_rejected
    )?;
    match s.final_state.road_to_body_pitch_deg {
        Some(p) => writeln!(
            out,
            "road-to-body pitch {p:+.3} deg +- {:.3} ({} windows)",
            s.final_state.std_err_deg.unwrap_or(f64::NAN),
            s.final_state.estimate_count
        ),
        None => writeln!(
            out,
            "road-to-body pitch: no estimate yet (the vehicle must stop and drive off)"
        ),
    }
}
