//! `leveld calibrate`: end-of-line reference pitch on a level floor.
//!
//! The vehicle stands on a level floor, so the road-to-body pitch equals the IMU
//! pitch from gravity. The pipeline runs until a standstill has settled for the
//! requested time; the result is stored in the calibration file as the reference
//! pitch (with the IMU's roll there, which lets the windows take a lane's roll out)
//! and seeds the estimate in the state file.

use super::calibration::{self, CalibrationFile};
use super::frame_loop::{self, LinkEvent, Observer, Received};
use super::log_bus::LogBus;
use super::pipeline::Pipeline;
use super::sink::Notice;
use super::state::{self, Loaded, PersistedState};
use anyhow::{Context, Result, bail};
use std::io::BufRead;
use std::ops::ControlFlow;
use std::path::Path;

/// Result of a calibration.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Calibration {
    pub reference_pitch_deg: f64,
    /// The IMU's roll on the floor, deg (elevation of its y axis).
    pub reference_roll_deg: f64,
    pub settled_s: f64,
    /// Frame time of the frame it was read at, s.
    pub at_s: f64,
}

impl Calibration {
    /// On a level floor the IMU's pitch and roll are those of its mounting: beyond
    /// `MAX_REFERENCE_PITCH_DEG` (which a calibration file is refused for, too) the
    /// floor is not level or the IMU's axes are set up wrong, and nothing is stored.
    pub fn check_plausible(&self) -> Result<()> {
        let max = calibration::MAX_REFERENCE_PITCH_DEG;
        for (what, v) in [
            ("pitch", self.reference_pitch_deg),
            ("roll", self.reference_roll_deg),
        ] {
            if !(v.abs() <= max) {
                bail!(
                    "measured {what} {v:+.2} deg is implausible for a level floor (at most {max} deg); check the floor and the IMU mounting and axes"
                );
            }
        }
        Ok(())
    }
}

/// The standstill a calibration needs must be a real one: 1 s to 1 h.
pub fn check_duration(duration_s: f64) -> Result<()> {
    if !(1.0..=3600.0).contains(&duration_s) {
        bail!("--duration {duration_s}: choose 1..3600 s of standstill (30 s is typical)");
    }
    Ok(())
}

/// Watches the standstill until it has settled for `duration_s`.
pub struct Settle {
    duration_s: f64,
    /// The longest settled standstill so far.
    pub best: Option<Calibration>,
    /// Why the bus could not be opened (live calibration stops at it).
    pub link_error: Option<String>,
}

impl Settle {
    pub fn new(duration_s: f64) -> Self {
        Self {
            duration_s,
            best: None,
            link_error: None,
        }
    }

    /// The calibration, once the standstill has settled long enough.
    pub fn done(&self) -> Option<Calibration> {
        self.best.filter(|c| c.settled_s >= self.duration_s)
    }
}

impl Observer for Settle {
    fn notice(&mut self, n: &Notice) {
        tracing::warn!(?n, "input");
    }

    fn after(&mut self, p: &mut Pipeline, r: &Received) -> ControlFlow<()> {
        if let Received::Link(LinkEvent::Waiting(e) | LinkEvent::Lost(e)) = r {
            self.link_error = Some(e.clone());
            return ControlFlow::Break(());
        }
        if let Received::Frame(f) = r
            && let Some((pitch, settled)) = p.standstill_pitch()
            && let Some(roll) = p.standstill_roll_deg()
        {
            self.best = Some(Calibration {
                reference_pitch_deg: pitch,
                reference_roll_deg: roll,
                settled_s: settled,
                at_s: f.t_s,
            });
            if settled >= self.duration_s {
                return ControlFlow::Break(());
            }
        }
        ControlFlow::Continue(())
    }
}

/// Feed a log until the standstill has settled for `duration_s`.
pub fn from_log(
    p: &mut Pipeline,
    input: &mut dyn BufRead,
    interface: Option<&str>,
    duration_s: f64,
) -> Result<Calibration> {
    check_duration(duration_s)?;
    let mut bus = LogBus::new(input).only(interface.map(str::to_string));
    let mut settle = Settle::new(duration_s);
    frame_loop::block_on(frame_loop::run(
        p,
        &mut bus,
        &mut settle,
        std::future::pending(),
    ));
    if let Some(e) = bus.take_error() {
        return Err(e).context("reading the log");
    }
    match (settle.done(), settle.best) {
        (Some(c), _) => Ok(c),
        (None, best) => Err(not_settled(duration_s, best)),
    }
}

/// The error when no standstill settled for `duration_s`.
pub fn not_settled(duration_s: f64, best: Option<Calibration>) -> anyhow::Error {
    match best {
        Some(c) => anyhow::anyhow!(
            "the vehicle was still for only {:.1} s of the {duration_s:.1} s needed; record a longer standstill",
            c.settled_s
        ),
        None => anyhow::anyhow!(
            "no standstill found: the wheels must read zero and the IMU be still (check that WHL_SPD11, IMU_ACC and IMU_GYR are in the log)"
        ),
    }
}

/// Store a calibration: the calibration file (the reference pitch, which only this
/// writes) and a state file whose estimate is seeded with it, worth a few windows.
pub fn store(
    p: &mut Pipeline,
    calibration_path: &Path,
    state_path: &Path,
    cal: &Calibration,
) -> Result<()> {
    let weight = 4.0;
    let file = CalibrationFile {
        format: CalibrationFile::FORMAT,
        reference_pitch_deg: cal.reference_pitch_deg,
        reference_roll_deg: Some(cal.reference_roll_deg),
        settled_s: cal.settled_s,
        written_unix_s: super::status::unix_now_s(),
    };
    calibration::save(calibration_path, &file)
        .with_context(|| format!("saving the calibration to {}", calibration_path.display()))?;
    if let Loaded::Corrupt { reason, moved_to } = state::load(state_path) {
        tracing::warn!(
            ?moved_to,
            "previous state unusable ({reason}); replaced by the calibration"
        );
    }
    p.seed_calibration(cal.reference_pitch_deg, weight);
    let st = PersistedState {
        format: PersistedState::FORMAT,
        estimator: p.estimator_state(),
        reference_pitch_deg: None,
    };
    state::save(state_path, &st)
        .with_context(|| format!("saving the seeded state to {}", state_path.display()))
}
