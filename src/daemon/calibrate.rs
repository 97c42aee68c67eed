//! `leveld calibrate`: end-of-line reference pitch on a level floor.
//!
//! The vehicle stands on a level floor, so the road-to-body pitch equals the IMU
//! pitch from gravity. The pipeline runs until a standstill has settled for the
//! requested time; the result is stored in the state file as the reference pitch and
//! seeds the estimate.

use super::pipeline::Pipeline;
use super::sink::{Notice, Sink};
use super::state::{self, Loaded, PersistedState};
use crate::can::candump::{Line, ReadLine, parse_bytes, read_line};
use crate::estimator::Event;
use anyhow::{Context, Result, bail};
use std::io::BufRead;
use std::path::Path;

struct Quiet;
impl Sink for Quiet {
    fn event(&mut self, _: &Event) {}
    fn notice(&mut self, n: &Notice) {
        tracing::warn!(?n, "input");
    }
    fn frame(&mut self, _: f64, _: u32, _: bool, _: &[u8; 8]) {}
}

/// Result of a calibration.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Calibration {
    pub reference_pitch_deg: f64,
    pub settled_s: f64,
}

/// The standstill a calibration needs must be a real one: 1 s to 1 h.
pub fn check_duration(duration_s: f64) -> Result<()> {
    if !(1.0..=3600.0).contains(&duration_s) {
        bail!("--duration {duration_s}: choose 1..3600 s of standstill (30 s is typical)");
    }
    Ok(())
}

/// Feed a log until the standstill has settled for `duration_s`.
pub fn from_log(
    p: &mut Pipeline,
    input: &mut dyn BufRead,
    interface: Option<&str>,
    duration_s: f64,
) -> Result<Calibration> {
    check_duration(duration_s)?;
    let mut line = Vec::with_capacity(256);
    let mut best: Option<Calibration> = None;
    loop {
        match read_line(input, &mut line).context("reading the log")? {
            ReadLine::Eof => break,
            ReadLine::TooLong => continue,
            ReadLine::Line => {}
        }
        if let Ok(Line::Frame(f)) = parse_bytes(&line)
            && interface.is_none_or(|i| i == f.iface())
            && !f.fd
        {
            p.on_can_frame(f.t_s, &f, &mut Quiet);
            if let Some((pitch, settled)) = p.standstill_pitch() {
                let cal = Calibration {
                    reference_pitch_deg: pitch,
                    settled_s: settled,
                };
                if settled >= duration_s {
                    return Ok(cal);
                }
                best = Some(cal);
            }
        }
    }
    match best {
        Some(c) => bail!(
            "the vehicle was still for only {:.1} s of the {duration_s:.1} s needed; record a longer standstill",
            c.settled_s
        ),
        None => bail!(
            "no standstill found: the wheels must read zero and the IMU be still (check that WHL_SPD11, IMU_ACC and IMU_GYR are in the log)"
        ),
    }
}

/// Store a calibration: reference pitch and a seeded estimate.
pub fn store(p: &mut Pipeline, path: &Path, cal: &Calibration) -> Result<()> {
    let weight = 4.0;
    if let Loaded::Corrupt { reason, moved_to } = state::load(path) {
        tracing::warn!(
            ?moved_to,
            "previous state unusable ({reason}); replaced by the calibration"
        );
    }
    p.seed_calibration(cal.reference_pitch_deg, weight);
    let st = PersistedState {
        format: PersistedState::FORMAT,
        estimator: p.estimator_state(),
        reference_pitch_deg: Some(cal.reference_pitch_deg),
    };
    state::save(path, &st).with_context(|| format!("saving the calibration to {}", path.display()))
}
