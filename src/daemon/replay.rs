//! `leveld replay`: the pipeline run over a candump log, with log stamps as time.

use super::frame_loop::{self, Observer, Received};
use super::inputs::{ACC, GYR, MsgStats, WHEELS};
use super::log_bus::LogBus;
use super::pipeline::Pipeline;
use super::sink::Notice;
use crate::can::candump::ParseError;
use crate::estimator::Event;
use anyhow::{Context, Result, bail};
use serde::Serialize;
use std::io::{BufRead, Write};
use std::ops::ControlFlow;

/// Options of one replay.
#[derive(Debug, Clone)]
pub struct ReplayOptions {
    /// Only frames from this interface; every interface when `None`.
    pub interface: Option<String>,
    /// Malformed lines are fatal.
    pub strict: bool,
    pub json: bool,
    /// Interface name written on output frames.
    pub output_interface: String,
}

impl Default for ReplayOptions {
    fn default() -> Self {
        Self {
            interface: None,
            strict: false,
            json: false,
            output_interface: "can0".into(),
        }
    }
}

#[derive(Debug, Clone, Serialize)]
pub struct FinalState {
    pub road_to_body_pitch_deg: Option<f64>,
    pub std_err_deg: Option<f64>,
    pub status: crate::can::codec::Status,
    pub estimate_count: u64,
    pub standstill: bool,
    pub suspension: crate::daemon::pipeline::Suspension,
}

#[derive(Debug, Clone, Serialize)]
pub struct Summary {
    pub lines: u64,
    pub frames: u64,
    pub malformed_lines: u64,
    /// Line numbers of the first malformed lines (at most 20).
    pub malformed_examples: Vec<u64>,
    pub ignored_frames: u64,
    /// Timestamps that jumped back or further ahead than `leveling.max_clock_step_s`.
    pub clock_steps: u64,
    pub messages: std::collections::BTreeMap<String, MsgStats>,
    pub estimates_accepted: u64,
    pub estimates_rejected: u64,
    /// Accepted windows taken back out (their stop was not at rest).
    pub estimates_withdrawn: u64,
    pub standstills: u64,
    pub leveling_frames: u64,
    #[serde(rename = "final")]
    pub final_state: FinalState,
}

struct ReplayObserver<'a> {
    events: &'a mut dyn Write,
    json: bool,
    strict: bool,
    frames: u64,
    malformed: u64,
    examples: Vec<u64>,
    /// A malformed line under `--strict`.
    strict_stop: Option<(u64, ParseError)>,
    err: Option<std::io::Error>,
}

impl ReplayObserver<'_> {
    fn keep(&mut self, r: std::io::Result<()>) {
        if let Err(e) = r {
            self.err.get_or_insert(e);
        }
    }
}

impl Observer for ReplayObserver<'_> {
    fn event(&mut self, e: &Event) {
        let r = if self.json {
            writeln!(
                self.events,
                "{}",
                serde_json::to_string(e).unwrap_or_default()
            )
        } else {
            write_text(self.events, e)
        };
        self.keep(r);
    }

    fn notice(&mut self, n: &Notice) {
        let r = if self.json {
            writeln!(
                self.events,
                "{}",
                serde_json::to_string(n).unwrap_or_default()
            )
        } else {
            write_notice(self.events, n)
        };
        self.keep(r);
    }

    fn after(&mut self, _: &mut Pipeline, r: &Received) -> ControlFlow<()> {
        match r {
            Received::Frame(_) => self.frames += 1,
            Received::Malformed { line, error } => {
                self.malformed += 1;
                if self.strict {
                    self.strict_stop = Some((*line, *error));
                    return ControlFlow::Break(());
                }
                if self.examples.len() < 20 {
                    self.examples.push(*line);
                }
                tracing::warn!("line {line}: {error}; line skipped");
            }
            _ => {}
        }
        if self.err.is_some() {
            return ControlFlow::Break(());
        }
        ControlFlow::Continue(())
    }
}

fn write_notice(out: &mut dyn Write, n: &Notice) -> std::io::Result<()> {
    match n {
        Notice::InputLost { t_s, message } => writeln!(
            out,
            "{t_s:12.3}  input lost        {message}: holding the last estimate"
        ),
        Notice::InputRestored { t_s, message } => {
            writeln!(out, "{t_s:12.3}  input restored    {message}")
        }
        Notice::MessageInvalid {
            t_s,
            message,
            reason,
        } => {
            writeln!(
                out,
                "{t_s:12.3}  input invalid     {message}: repeated {reason} failures"
            )
        }
        Notice::ClockStep { t_s, step_s } => writeln!(
            out,
            "{t_s:12.3}  clock step        {step_s:+.3} s in the frame timestamps: time goes on from here"
        ),
        Notice::BusOff { t_s } => writeln!(
            out,
            "{t_s:12.3}  bus off           FAULT until the controller restarts"
        ),
        Notice::BusRestarted { t_s } => {
            writeln!(out, "{t_s:12.3}  bus restarted")
        }
        Notice::EventsDropped { t_s, count } => writeln!(
            out,
            "{t_s:12.3}  events dropped    {count} events of one frame not reported"
        ),
    }
}

/// Replay `input` through `p`. Events go to `events`, LEVELING frames to `frames`.
pub fn replay<'a>(
    p: &mut Pipeline,
    input: &'a mut dyn BufRead,
    opts: &'a ReplayOptions,
    events: &'a mut dyn Write,
    frames: Option<&'a mut dyn Write>,
) -> Result<Summary> {
    let mut bus = LogBus::new(input)
        .only(opts.interface.clone())
        .output(frames, &opts.output_interface);
    let mut obs = ReplayObserver {
        events,
        json: opts.json,
        strict: opts.strict,
        frames: 0,
        malformed: 0,
        examples: Vec::new(),
        strict_stop: None,
        err: None,
    };
    frame_loop::block_on(frame_loop::run(
        p,
        &mut bus,
        &mut obs,
        std::future::pending(),
    ));
    if let Some((lineno, e)) = obs.strict_stop {
        bail!(
            "line {lineno}: {e}: {:?} (drop --strict to skip malformed lines)",
            bus.last_line()
        );
    }
    if let Some(e) = bus.take_error() {
        return Err(e).context("reading the input log or writing the output log");
    }
    if let Some(e) = obs.err.take() {
        return Err(e).context("writing output");
    }
    let names = p.message_names().clone();
    let mut messages = std::collections::BTreeMap::new();
    for slot in [WHEELS, ACC, GYR] {
        messages.insert(names[slot].clone(), p.stats(slot));
    }
    let est = p.estimate();
    let c = p.counters();
    Ok(Summary {
        lines: bus.lines(),
        frames: obs.frames,
        malformed_lines: obs.malformed,
        malformed_examples: obs.examples,
        ignored_frames: c.ignored_frames,
        clock_steps: p.clock_steps(),
        messages,
        estimates_accepted: c.windows_accepted,
        estimates_rejected: c.windows_rejected,
        estimates_withdrawn: c.windows_withdrawn,
        standstills: c.standstills,
        leveling_frames: c.frames_sent,
        final_state: FinalState {
            road_to_body_pitch_deg: est.map(|e| e.road_to_body_deg),
            std_err_deg: est.map(|e| e.std_err_deg),
            status: p.status(),
            estimate_count: est.map_or(0, |e| e.windows),
            standstill: p.is_standstill(),
            suspension: p.suspension(),
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
        Event::WheelsStopped { t_s } => writeln!(out, "{t_s:12.3}  wheels stopped"),
        Event::WheelsMoving { t_s } => writeln!(out, "{t_s:12.3}  wheels moving"),
        Event::WindowAccepted {
            window: w,
            estimate,
        } => writeln!(
            out,
            "{:12.3}  window accepted   {}: IMU pitch {:+.3}, slope {:+.3}, road-to-body {:+.3} deg -> estimate {:+.3} +- {:.3} deg ({} windows)",
            w.t_s,
            condition_name(w.condition),
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
                "{t_s:12.3}  window rejected   {}: {reason:?}",
                condition_name(*condition)
            )
        }
        Event::LoadChangeSuspected { t_s, delta_deg } => writeln!(
            out,
            "{t_s:12.3}  load change?      {delta_deg:+.3} deg since the last baseline; the next window decides"
        ),
        Event::LoadChanged {
            t_s,
            delta_deg,
            estimate,
        } => writeln!(
            out,
            "{t_s:12.3}  load change       {delta_deg:+.3} deg -> estimate {}",
            estimate.map_or("none".into(), |e| format!("{:+.3} deg", e.road_to_body_deg))
        ),
        Event::PitchShifted {
            t_s,
            delta_deg,
            estimate,
        } => writeln!(
            out,
            "{t_s:12.3}  pitch shift       {delta_deg:+.3} deg (windows in a row) -> estimate {}",
            estimate.map_or("none".into(), |e| format!("{:+.3} deg", e.road_to_body_deg))
        ),
        Event::WindowsRebiased {
            t_s,
            acc_bias_x_mps2,
            delta_deg,
            estimate,
        } => writeln!(
            out,
            "{t_s:12.3}  windows rebiased  accelerometer x bias {acc_bias_x_mps2:+.4} m/s^2: {delta_deg:+.3} deg -> estimate {}",
            estimate.map_or("none".into(), |e| format!("{:+.3} deg", e.road_to_body_deg))
        ),
        Event::WindowWithdrawn {
            t_s,
            road_to_body_deg,
            imu_mps,
            wheel_mps,
            estimate,
        } => writeln!(
            out,
            "{t_s:12.3}  window withdrawn  {road_to_body_deg:+.3} deg: wheels {wheel_mps:.2} m/s, IMU {imu_mps:.2} m/s since the stop -> estimate {}",
            estimate.map_or("none".into(), |e| format!("{:+.3} deg", e.road_to_body_deg))
        ),
        Event::SampleDropped { t_s, reason } => {
            writeln!(out, "{t_s:12.3}  sample dropped    {reason:?}")
        }
    }
}

fn condition_name(c: crate::estimator::Condition) -> &'static str {
    match c {
        crate::estimator::Condition::AccelAfterStop => "after stop ",
        crate::estimator::Condition::DecelBeforeStop => "before stop",
    }
}

/// Human summary.
pub fn write_summary_text(out: &mut dyn Write, s: &Summary) -> std::io::Result<()> {
    writeln!(out, "--")?;
    writeln!(
        out,
        "{} lines, {} frames, {} malformed, {} ignored, {} clock steps",
        s.lines, s.frames, s.malformed_lines, s.ignored_frames, s.clock_steps
    )?;
    if !s.malformed_examples.is_empty() {
        writeln!(out, "malformed lines: {:?}", s.malformed_examples)?;
    }
    for (name, m) in &s.messages {
        writeln!(
            out,
            "{name:10} {:7} frames, {} checksum errors, {} counter errors, {} DLC errors, {} timeouts",
            m.frames, m.checksum_errors, m.counter_errors, m.dlc_errors, m.timeouts
        )?;
    }
    writeln!(
        out,
        "standstills {}, windows accepted {}, rejected {}, withdrawn {}, LEVELING frames {}",
        s.standstills,
        s.estimates_accepted,
        s.estimates_rejected,
        s.estimates_withdrawn,
        s.leveling_frames
    )?;
    writeln!(out, "suspension: {}", s.final_state.suspension)?;
    match s.final_state.road_to_body_pitch_deg {
        Some(p) => writeln!(
            out,
            "road-to-body pitch {p:+.3} deg +- {:.3} ({} windows), status {:?}",
            s.final_state.std_err_deg.unwrap_or(f64::NAN),
            s.final_state.estimate_count,
            s.final_state.status
        ),
        None => writeln!(
            out,
            "road-to-body pitch: no estimate yet, status {:?}",
            s.final_state.status
        ),
    }
}
