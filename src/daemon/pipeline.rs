//! Frames in, leveling frames and events out: the pipeline live runs and replays share.
//!
//! Time is the frame clock (kernel receive stamps live, log stamps in replay); the
//! same frames with the same stamps give the same output. Only configured IDs are
//! decoded, through codecs prepared at start; the per-frame path does not allocate.

use super::calibration::Calibration;
use super::clock::{FrameClock, Mapped};
use super::config::Config;
use super::inputs::{ACC, GYR, Inputs, MsgStats, WHEELS};
use super::sink::{EventBuf, Notice, Sink};
use crate::can::codec::{MsgCodec, OutputCodec, Status};
use crate::can::dbc::Database;
use crate::estimator::{Estimate, Estimator, EstimatorState, Event, ImuSample, WheelSpeeds};
use serde::Serialize;

/// Most periodic frames sent at once when time jumps ahead; the period then realigns
/// so that a gap in the input is not flooded afterwards.
const MAX_CATCH_UP_FRAMES: u32 = 11;

/// What the pipeline has counted since it started.
/// The suspension as the estimator has learnt it (`Pipeline::suspension`).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Suspension {
    /// Body pitch per m/s^2 of braking, deg (0 until a brisk stop teaches it).
    pub pitch_per_braking_deg_per_mps2: f64,
    /// Body pitch per m/s^2 of pulling away, deg (the braking one until drive-offs
    /// teach it).
    #[serde(default)]
    pub pitch_per_drive_deg_per_mps2: f64,
    /// Share of that pitch the body shows standing on a grade (1 until stops at
    /// different grades tell).
    pub grade_share: f64,
    /// The body's pitch mode from its swing after the stops: natural frequency, Hz, and
    /// damping ratio (absent until two stops showed it).
    #[serde(default)]
    pub pitch_mode_hz: Option<f64>,
    #[serde(default)]
    pub pitch_mode_damping: Option<f64>,
}

impl std::fmt::Display for Suspension {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "body pitch {:.3} deg per m/s^2 of braking and {:.3} pulling away, {:.2} of the \
             braking one standing on a grade",
            self.pitch_per_braking_deg_per_mps2,
            self.pitch_per_drive_deg_per_mps2,
            self.grade_share
        )?;
        match (self.pitch_mode_hz, self.pitch_mode_damping) {
            (Some(hz), Some(z)) => write!(f, "; pitch mode {hz:.2} Hz, damping {z:.2}"),
            _ => write!(f, "; pitch mode not yet seen"),
        }
    }
}

#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct Counters {
    /// LEVELING frames handed to the sink.
    pub frames_sent: u64,
    /// Frames that are not inputs, or whose timestamp was unusable.
    pub ignored_frames: u64,
    pub windows_accepted: u64,
    pub windows_rejected: u64,
    /// Accepted windows taken back out: their stop was not at rest.
    pub windows_withdrawn: u64,
    pub standstills: u64,
}

/// One of the two frames of an IMU sample: its counter, time and x, y, z.
type ImuHalf = (Option<u8>, f64, [f64; 3]);

/// The pipeline. Build it with [`Pipeline::new`], feed [`Pipeline::on_frame`] and
/// [`Pipeline::tick`], and read what it produced from the [`Sink`].
#[derive(Debug)]
pub struct Pipeline {
    inputs: Inputs,
    names: [String; 3],
    est: Estimator,
    out: OutputCodec,
    leveling: super::config::Leveling,
    reference_pitch_deg: f64,
    /// `reference_pitch_deg` is a floor's raw pitch from a calibration.
    floor_reference: bool,
    fault: bool,
    /// No end-of-line calibration in use (LEVELING `uncalibrated` flag).
    uncalibrated: bool,
    /// The calibration file is unreadable: FAULT.
    calibration_fault: bool,
    clock_s: Option<f64>,
    frame_clock: FrameClock,
    bus_off: bool,
    start_s: f64,
    next_due_s: Option<f64>,
    out_counter: u8,
    counters: Counters,
    /// State changed since last taken (an accepted window or load change).
    dirty: bool,
    /// The IMU half (accelerometer, gyro) waiting for its partner.
    half: [Option<ImuHalf>; 2],
}

impl Pipeline {
    pub fn new(cfg: &Config, db: &Database) -> anyhow::Result<Self> {
        Ok(Self {
            inputs: Inputs::new(cfg, db)?,
            names: [
                cfg.wheels.message.clone(),
                cfg.acc.message.clone(),
                cfg.gyro.message.clone(),
            ],
            est: Estimator::new(cfg.estimator.clone())?,
            out: OutputCodec::build(db, &cfg.output)?,
            leveling: cfg.leveling.clone(),
            reference_pitch_deg: cfg.leveling.reference_pitch_deg,
            floor_reference: false,
            fault: false,
            uncalibrated: false,
            calibration_fault: false,
            clock_s: None,
            frame_clock: FrameClock::new(cfg.leveling.max_clock_step_s),
            bus_off: false,
            start_s: 0.0,
            next_due_s: None,
            out_counter: 0,
            counters: Counters::default(),
            dirty: false,
            half: [None; 2],
        })
    }

    /// IDs to ask the kernel for (filters).
    pub fn input_ids(&self) -> [(u32, bool); 3] {
        [0, 1, 2].map(|i| (self.inputs.codec(i).id, self.inputs.codec(i).extended))
    }

    pub fn output(&self) -> &OutputCodec {
        &self.out
    }

    pub fn message_names(&self) -> &[String; 3] {
        &self.names
    }

    pub fn stats(&self, slot: usize) -> MsgStats {
        self.inputs.stats(slot)
    }

    pub fn counters(&self) -> Counters {
        self.counters
    }

    /// `ok`, `lost` (timed out) or `invalid` (failing its counter or checksum checks).
    pub fn input_state(&self, slot: usize) -> &'static str {
        self.inputs.state(slot)
    }

    pub fn input_codec(&self, slot: usize) -> &MsgCodec {
        self.inputs.codec(slot)
    }

    /// Run with `cal`: a calibrated reference pitch; a missing one leaves the
    /// config's with the `uncalibrated` flag set; an unreadable one is FAULT.
    pub fn set_calibration(&mut self, cal: &Calibration) {
        self.uncalibrated = cal.reference_pitch_deg().is_none();
        self.calibration_fault = matches!(cal, Calibration::Unreadable(_));
        if let Some(r) = cal.reference_pitch_deg() {
            self.reference_pitch_deg = r;
            self.floor_reference = true;
        }
        self.est.set_floor_roll_deg(cal.reference_roll_deg());
    }

    /// Bus-off or another fault outside the inputs: FAULT until cleared.
    pub fn set_fault(&mut self, fault: bool) {
        self.fault = fault;
    }

    /// Restore persisted estimator state.
    pub fn restore(&mut self, st: &EstimatorState) -> Result<(), crate::estimator::StateError> {
        self.est.restore(st)
    }

    /// The estimator state to persist.
    pub fn estimator_state(&self) -> EstimatorState {
        self.est.state()
    }

    /// Seed the estimate with an end-of-line calibration worth `weight` windows.
    pub fn seed_calibration(&mut self, reference_pitch_deg: f64, weight: f64) {
        self.est.seed_calibration(reference_pitch_deg, weight);
    }

    /// The vehicle is at a declared standstill.
    pub fn is_standstill(&self) -> bool {
        self.est.is_standstill()
    }

    /// IMU pitch of the current standstill and how long it has settled, s.
    pub fn standstill_pitch(&self) -> Option<(f64, f64)> {
        self.est.standstill_pitch()
    }

    /// Roll of the settled standstill reference, deg (`Estimator::standstill_roll_deg`).
    pub fn standstill_roll_deg(&self) -> Option<f64> {
        self.est.standstill_roll_deg()
    }

    /// True once after the persisted state changed (an accepted window or a load
    /// change): the caller saves it.
    pub fn take_dirty(&mut self) -> bool {
        std::mem::take(&mut self.dirty)
    }

    /// Clock steps seen in the frame timestamps.
    pub fn clock_steps(&self) -> u64 {
        self.frame_clock.steps
    }

    /// Map a frame timestamp onto the pipeline clock; on a step, restart what spans
    /// time. `None`: the timestamp is unusable and the frame is dropped.
    fn frame_time(&mut self, t_frame_s: f64, sink: &mut dyn Sink) -> Option<f64> {
        match self.frame_clock.map(t_frame_s) {
            Mapped::Time(t) => Some(t),
            Mapped::Invalid => None,
            Mapped::Step { t_s, step_s } => {
                sink.notice(&Notice::ClockStep { t_s, step_s });
                // What was measured before the step cannot be joined to what comes
                // after: the car may have moved meanwhile.
                self.est.wheels_lost();
                self.half = [None; 2];
                self.inputs.restart_timeouts(t_s);
                Some(t_s)
            }
        }
    }

    /// A frame that is not an input (CAN FD, say): time passes, it is counted as ignored.
    pub fn on_other_frame(&mut self, t_frame_s: f64, sink: &mut dyn Sink) {
        if let Some(t) = self.frame_time(t_frame_s, sink) {
            self.tick(t, sink);
        }
        self.counters.ignored_frames += 1;
    }

    /// An error frame (class bits and data of linux/can/error.h), from a socket or a
    /// `candump -e` log: bus-off sets FAULT until the controller reports its restart.
    pub fn on_error_frame(&mut self, t_frame_s: f64, class: u32, sink: &mut dyn Sink) {
        let Some(t_s) = self.frame_time(t_frame_s, sink) else {
            return;
        };
        self.tick(t_s, sink);
        if class & crate::can::CAN_ERR_BUSOFF != 0 && !self.bus_off {
            self.bus_off = true;
            self.fault = true;
            sink.notice(&Notice::BusOff { t_s });
        }
        if class & crate::can::CAN_ERR_RESTARTED != 0 && self.bus_off {
            self.bus_off = false;
            self.fault = false;
            sink.notice(&Notice::BusRestarted { t_s });
        }
    }

    /// Current status as sent.
    pub fn status(&self) -> Status {
        if self.fault || self.calibration_fault {
            return Status::Fault;
        }
        if self.inputs.any_unusable() {
            return Status::HoldInputLost;
        }
        match self.est.estimate() {
            None => Status::NoEstimate,
            Some(e)
                if e.std_err_deg <= self.leveling.valid_max_std_err_deg
                    && e.weight >= self.leveling.valid_min_windows =>
            {
                Status::Valid
            }
            Some(_) => Status::Converging,
        }
    }

    pub fn estimate(&self) -> Option<Estimate> {
        self.est.estimate()
    }

    /// What the estimator learnt of the suspension: the body's pitch per m/s^2 of
    /// braking and of pulling away, deg, and the share of the braking one the body
    /// shows standing on a grade.
    pub fn suspension(&self) -> Suspension {
        let mode = self.est.pitch_mode();
        Suspension {
            pitch_per_braking_deg_per_mps2: self.est.pitch_per_force_deg(),
            pitch_per_drive_deg_per_mps2: self.est.squat_per_force_deg(),
            grade_share: self.est.grade_share(),
            pitch_mode_hz: mode.map(|m| m.freq_hz()),
            pitch_mode_damping: mode.map(|m| m.damping_ratio()),
        }
    }

    /// The road-to-body pitch `LevelCorrection` is measured from, deg. A calibration is
    /// the IMU's raw pitch on the floor, which carries the accelerometer's x bias; the
    /// windows' pitch does not, so the bias the stops have learnt comes off it
    /// (`Estimator::level_reference_deg`). The config's value is taken as it stands.
    pub fn level_reference_deg(&self) -> f64 {
        if self.floor_reference {
            self.est.level_reference_deg(self.reference_pitch_deg)
        } else {
            self.reference_pitch_deg
        }
    }

    /// The LEVELING payload for the current state (the counter is the next to send).
    pub fn payload(&self) -> [u8; 8] {
        let e = self.est.estimate();
        let r2b = e.map_or(0.0, |e| e.road_to_body_deg);
        let reference = self.level_reference_deg();
        let corr = if e.is_some() {
            (-(r2b - reference)).clamp(
                self.leveling.actuator_min_deg,
                self.leveling.actuator_max_deg,
            )
        } else {
            0.0
        };
        let slope = self.est.last_road_slope_deg().unwrap_or(0.0);
        self.out.encode(
            r2b,
            corr,
            slope,
            e.map_or(0, |e| e.windows),
            self.status(),
            self.out_counter,
            self.uncalibrated,
        )
    }

    fn send(&mut self, t_s: f64, sink: &mut dyn Sink) {
        let d = self.payload();
        sink.frame(t_s, self.out.id, self.out.extended, &d);
        self.out_counter = (self.out_counter + 1) & 15;
        self.counters.frames_sent += 1;
    }

    /// Let time pass to `t_s` (frame clock): timeouts and periodic output.
    pub fn tick(&mut self, t_s: f64, sink: &mut dyn Sink) {
        let Some(prev) = self.clock_s else {
            self.clock_s = Some(t_s);
            self.start_s = t_s;
            self.next_due_s = Some(t_s);
            return;
        };
        if t_s < prev {
            return;
        }
        // Periodic frames due up to now, sent with the state as it was then; at most a
        // few at once, then realigned (a gap in the frames is not flooded afterwards).
        let period = self.out.period_s;
        let mut sent = 0;
        while let Some(due) = self.next_due_s {
            if due > t_s {
                break;
            }
            self.check_timeouts(due, sink);
            self.send(due, sink);
            sent += 1;
            let next = due + period;
            let realign = t_s - next > 10.0 * period || sent >= MAX_CATCH_UP_FRAMES || next <= due;
            self.next_due_s = Some(if realign { t_s + period } else { next });
            if sent >= MAX_CATCH_UP_FRAMES || next <= due {
                break;
            }
        }
        self.check_timeouts(t_s, sink);
        self.clock_s = Some(t_s);
    }

    fn check_timeouts(&mut self, t_s: f64, sink: &mut dyn Sink) {
        if self.inputs.check_timeouts(t_s, self.start_s, sink) {
            self.est.wheels_lost();
        }
    }

    /// Handle one received frame (any `embedded_can::Frame`) stamped `t_s`.
    pub fn on_can_frame<F: embedded_can::Frame>(&mut self, t_s: f64, f: &F, sink: &mut dyn Sink) {
        self.on_can_frame_from(0, t_s, f, sink);
    }

    /// As [`Pipeline::on_can_frame`], from interface number `source` (see
    /// [`Inputs::accept`] for how one interface is chosen per message).
    pub fn on_can_frame_from<F: embedded_can::Frame>(
        &mut self,
        source: u32,
        t_s: f64,
        f: &F,
        sink: &mut dyn Sink,
    ) {
        if f.is_remote_frame() {
            self.on_other_frame(t_s, sink);
            return;
        }
        let (id, ext) = match f.id() {
            embedded_can::Id::Standard(id) => (id.as_raw() as u32, false),
            embedded_can::Id::Extended(id) => (id.as_raw(), true),
        };
        self.on_frame_from(source, t_s, id, ext, f.data(), sink);
    }

    /// Handle one received frame stamped `t_s`.
    pub fn on_frame(
        &mut self,
        t_s: f64,
        id: u32,
        extended: bool,
        data: &[u8],
        sink: &mut dyn Sink,
    ) {
        self.on_frame_from(0, t_s, id, extended, data, sink);
    }

    /// As [`Pipeline::on_frame`], from interface number `source`.
    pub fn on_frame_from(
        &mut self,
        source: u32,
        t_s: f64,
        id: u32,
        extended: bool,
        data: &[u8],
        sink: &mut dyn Sink,
    ) {
        let Some(t_s) = self.frame_time(t_s, sink) else {
            self.counters.ignored_frames += 1;
            return;
        };
        self.tick(t_s, sink);
        let Some(slot) = self.inputs.slot_of(id, extended) else {
            self.counters.ignored_frames += 1;
            return;
        };
        let Some(frame) = self.inputs.accept(slot, source, t_s, data, sink) else {
            return;
        };
        let v = frame.values;
        let mut buf = EventBuf::default();
        if slot == WHEELS {
            self.est
                .push_wheels(WheelSpeeds { t_s, kmh: v }, &mut |e| buf.push(e));
        } else {
            // The accelerometer and gyro halves of one sample share their counter.
            let c = frame.counter;
            let other = if slot == ACC { GYR } else { ACC } - 1;
            let mine = slot - 1;
            match self.half[other].take() {
                Some((oc, ot, ov)) if c.is_none() || oc.unwrap_or(0) == c.unwrap_or(0) => {
                    let xyz = [v[0], v[1], v[2]];
                    let (acc, gyr) = if slot == ACC { (xyz, ov) } else { (ov, xyz) };
                    let s = ImuSample::new(t_s.min(ot), acc, gyr);
                    self.est.push_imu(s, &mut |e| buf.push(e));
                }
                _ => self.half[mine] = Some((c, t_s, [v[0], v[1], v[2]])),
            }
        }
        self.handle_events(&buf, t_s, sink);
    }

    fn handle_events(&mut self, buf: &EventBuf, t_s: f64, sink: &mut dyn Sink) {
        if buf.dropped > 0 {
            sink.notice(&Notice::EventsDropped {
                t_s,
                count: buf.dropped,
            });
        }
        let mut changed = false;
        for e in buf.iter() {
            match e {
                Event::WindowAccepted { .. } => {
                    self.counters.windows_accepted += 1;
                    changed = true;
                }
                Event::WindowRejected { .. } => self.counters.windows_rejected += 1,
                Event::WindowWithdrawn { .. } => {
                    self.counters.windows_withdrawn += 1;
                    changed = true;
                }
                Event::LoadChanged { .. }
                | Event::PitchShifted { .. }
                | Event::WindowsRebiased { .. } => changed = true,
                Event::StandstillStarted { .. } => self.counters.standstills += 1,
                _ => {}
            }
            sink.event(e);
        }
        if changed {
            self.dirty = true;
            // On change: send at once and restart the period from here.
            self.send(t_s, sink);
            self.next_due_s = Some(t_s + self.out.period_s);
        }
    }

    /// End of input: evaluate what is pending.
    pub fn finish(&mut self, sink: &mut dyn Sink) {
        let t = self.clock_s.unwrap_or(0.0);
        let mut buf = EventBuf::default();
        self.est.finish(t, &mut |e| buf.push(e));
        self.handle_events(&buf, t, sink);
    }
}
