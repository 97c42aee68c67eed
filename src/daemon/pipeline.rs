//! Frames in, leveling frames and events out: the pipeline live runs and replays share.
//!
//! Time is the frame clock (kernel receive stamps live, log stamps in replay); the
//! same frames with the same stamps give the same output. Only configured IDs are
//! decoded, through codecs prepared at start; the per-frame path does not allocate.

use super::config::{ChecksumKind, Config, InputMessage};
use crate::can::checks::{CounterCheck, crc8_bytes0_6};
use crate::can::dbc::{Database, DbcError};
use crate::can::signal::SignalCodec;
use crate::estimator::{Estimate, Estimator, EstimatorState, Event, ImuSample, WheelSpeeds};
use crc::{CRC_8_AUTOSAR, CRC_8_SAE_J1850, Crc};
use serde::{Deserialize, Serialize};

const J1850: Crc<u8> = Crc::<u8>::new(&CRC_8_SAE_J1850);
const AUTOSAR: Crc<u8> = Crc::<u8>::new(&CRC_8_AUTOSAR);

/// Value of the LEVELING `Status` signal.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "SCREAMING_SNAKE_CASE")]
pub enum Status {
    NoEstimate = 0,
    Converging = 1,
    Valid = 2,
    HoldInputLost = 3,
    Fault = 4,
}

impl Status {
    pub fn from_raw(v: u64) -> Option<Self> {
        Some(match v {
            0 => Self::NoEstimate,
            1 => Self::Converging,
            2 => Self::Valid,
            3 => Self::HoldInputLost,
            4 => Self::Fault,
            _ => return None,
        })
    }
}

/// Per-message reception statistics.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct MsgStats {
    pub frames: u64,
    pub checksum_errors: u64,
    pub counter_errors: u64,
    pub dlc_errors: u64,
    pub timeouts: u64,
    /// Copies of the message from an interface other than its source.
    pub mirrored: u64,
}

/// What the pipeline reports besides estimator events.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(tag = "notice", rename_all = "snake_case")]
pub enum Notice {
    InputLost {
        t_s: f64,
        message: &'static str,
    },
    InputRestored {
        t_s: f64,
        message: &'static str,
    },
    MessageInvalid {
        t_s: f64,
        message: &'static str,
        reason: &'static str,
    },
    /// A frame timestamp jumped by `step_s` (forward past the allowed gap, or back):
    /// time goes on from `t_s`; the open standstill and the input timeouts restart.
    ClockStep {
        t_s: f64,
        step_s: f64,
    },
    /// Bus-off: FAULT until the controller reports its restart.
    BusOff {
        t_s: f64,
    },
    BusRestarted {
        t_s: f64,
    },
    /// Events of one frame beyond what the pipeline buffers; they were not reported.
    EventsDropped {
        t_s: f64,
        count: u32,
    },
}

/// Receiver of what the pipeline produces.
pub trait Sink {
    fn event(&mut self, e: &Event);
    fn notice(&mut self, n: &Notice);
    /// A LEVELING frame due at `t_s` (frame clock).
    fn frame(&mut self, t_s: f64, id: u32, extended: bool, data: &[u8; 8]);
}

/// A sink that keeps nothing (tools, fuzzing).
pub struct NullSink;

impl Sink for NullSink {
    fn event(&mut self, _: &Event) {}
    fn notice(&mut self, _: &Notice) {}
    fn frame(&mut self, _: f64, _: u32, _: bool, _: &[u8; 8]) {}
}

/// Fixed-size codec of one input message.
#[derive(Debug, Clone)]
pub struct MsgCodec {
    pub name: &'static str,
    pub id: u32,
    pub extended: bool,
    pub len: u8,
    values: [SignalCodec; 4],
    n_values: usize,
    counter: [SignalCodec; 2],
    n_counter: usize,
    checksum: [SignalCodec; 2],
    n_checksum: usize,
    kind: ChecksumKind,
    /// Bits counted by the popcount checksum.
    popcount_mask: u64,
    /// Bytes covered by a CRC, in order, and how many.
    crc_bytes: [u8; 8],
    n_crc_bytes: usize,
    check_counter: bool,
    check_checksum: bool,
    max_step: u8,
    pub timeout_s: f64,
}

fn signal_bits(c: &SignalCodec) -> u64 {
    let mut probe = [0u8; 8];
    c.encode_raw(&mut probe, u64::MAX >> (64 - c.size as u32));
    u64::from_le_bytes(probe)
}

fn concat(parts: &[SignalCodec], d: &[u8]) -> u64 {
    parts.iter().fold(0u64, |acc, p| (acc << p.size) | p.raw(d))
}

impl MsgCodec {
    fn build(db: &Database, m: &InputMessage, role: &'static str) -> Result<Self, DbcError> {
        let info = db.message(&m.message)?;
        let get = |n: &String| db.signal(&m.message, n);
        let filler = SignalCodec {
            start_bit: 0,
            size: 1,
            little_endian: true,
            signed: false,
            factor: 1.0,
            offset: 0.0,
        };
        let mut values = [filler; 4];
        for (i, n) in m.signals.iter().enumerate().take(4) {
            values[i] = get(n)?;
        }
        let mut counter = [filler; 2];
        for (i, n) in m.counter.iter().enumerate().take(2) {
            counter[i] = get(n)?;
        }
        let mut checksum = [filler; 2];
        for (i, n) in m.checksum.iter().enumerate().take(2) {
            checksum[i] = get(n)?;
        }
        let (n_counter, n_checksum) = (m.counter.len().min(2), m.checksum.len().min(2));
        let mut excluded = 0u64;
        for c in counter[..n_counter].iter().chain(&checksum[..n_checksum]) {
            excluded |= signal_bits(c);
        }
        let chk_bits = checksum[..n_checksum]
            .iter()
            .fold(0u64, |a, c| a | signal_bits(c));
        let mut crc_bytes = [0u8; 8];
        let mut n_crc_bytes = 0;
        for b in 0..info.len.min(8) as usize {
            if (chk_bits >> (8 * b)) & 0xFF == 0 {
                crc_bytes[n_crc_bytes] = b as u8;
                n_crc_bytes += 1;
            }
        }
        let cycle_ms = db.cycle_time_ms(&m.message).unwrap_or(100);
        Ok(Self {
            name: role,
            id: info.id,
            extended: info.extended,
            len: info.len,
            values,
            n_values: m.signals.len().min(4),
            counter,
            n_counter,
            checksum,
            n_checksum,
            kind: m.checksum_kind,
            popcount_mask: !excluded,
            crc_bytes,
            n_crc_bytes,
            check_counter: m.check_counter && n_counter > 0,
            check_checksum: m.check_checksum && m.checksum_kind != ChecksumKind::None,
            max_step: m.max_counter_step.max(1),
            timeout_s: m.timeout_ms.map_or(10.0 * cycle_ms as f64, |t| t as f64) / 1000.0,
        })
    }

    fn counter(&self, d: &[u8]) -> Option<u8> {
        (self.n_counter > 0).then(|| (concat(&self.counter[..self.n_counter], d) & 0xFF) as u8)
    }

    fn checksum_ok(&self, d: &[u8; 8]) -> bool {
        let carried = concat(&self.checksum[..self.n_checksum], d);
        let expected = match self.kind {
            ChecksumKind::None => return true,
            ChecksumKind::HyundaiWhlSpd => {
                (((u64::from_le_bytes(*d) & self.popcount_mask).count_ones() as u64) ^ 9) & 15
            }
            ChecksumKind::Crc8SaeJ1850 | ChecksumKind::Crc8Autosar => {
                let crc = if self.kind == ChecksumKind::Crc8Autosar {
                    &AUTOSAR
                } else {
                    &J1850
                };
                let mut dig = crc.digest();
                for &b in &self.crc_bytes[..self.n_crc_bytes] {
                    dig.update(&[d[b as usize]]);
                }
                dig.finalize() as u64
            }
        };
        carried == expected
    }

    fn values(&self, d: &[u8]) -> [f64; 4] {
        let mut out = [0.0; 4];
        for (o, c) in out.iter_mut().zip(&self.values[..self.n_values]) {
            *o = c.decode(d);
        }
        out
    }
}

/// Encoder of the LEVELING message.
#[derive(Debug, Clone)]
pub struct OutputCodec {
    pub id: u32,
    pub extended: bool,
    pub period_s: f64,
    road_to_body: SignalCodec,
    correction: SignalCodec,
    slope: SignalCodec,
    count: SignalCodec,
    status: SignalCodec,
    counter: SignalCodec,
    crc: SignalCodec,
    crc_autosar: bool,
}

/// Decoded LEVELING frame.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Leveling {
    pub road_to_body_deg: f64,
    pub level_correction_deg: f64,
    pub road_slope_deg: f64,
    pub estimate_count: u64,
    pub status: u64,
    pub counter: u64,
    pub crc: u64,
    pub crc_ok: bool,
}

impl OutputCodec {
    pub fn build(db: &Database, cfg: &Config) -> Result<Self, DbcError> {
        let o = &cfg.output;
        let info = db.message(&o.message)?;
        let s = |n: &str| db.signal(&o.message, n);
        Ok(Self {
            id: info.id,
            extended: info.extended,
            period_s: o.period_ms as f64 / 1000.0,
            road_to_body: s(&o.road_to_body)?,
            correction: s(&o.level_correction)?,
            slope: s(&o.road_slope)?,
            count: s(&o.estimate_count)?,
            status: s(&o.status)?,
            counter: s(&o.counter)?,
            crc: s(&o.checksum)?,
            crc_autosar: o.checksum_kind == ChecksumKind::Crc8Autosar,
        })
    }

    fn crc_of(&self, d: &[u8; 8]) -> u8 {
        if self.crc_autosar {
            AUTOSAR.checksum(&d[..7])
        } else {
            crc8_bytes0_6(d)
        }
    }

    #[allow(clippy::too_many_arguments)]
    pub fn encode(
        &self,
        r2b: f64,
        corr: f64,
        slope: f64,
        count: u64,
        status: Status,
        counter: u8,
    ) -> [u8; 8] {
        let mut d = [0u8; 8];
        self.road_to_body.encode(&mut d, r2b);
        self.correction.encode(&mut d, corr);
        self.slope.encode(&mut d, slope);
        self.count
            .encode_raw(&mut d, count.min((1u64 << self.count.size) - 1));
        self.status.encode_raw(&mut d, status as u64);
        self.counter.encode_raw(&mut d, (counter & 15) as u64);
        let c = self.crc_of(&d);
        self.crc.encode_raw(&mut d, c as u64);
        d
    }

    pub fn decode(&self, d: &[u8; 8]) -> Leveling {
        Leveling {
            road_to_body_deg: self.road_to_body.decode(d),
            level_correction_deg: self.correction.decode(d),
            road_slope_deg: self.slope.decode(d),
            estimate_count: self.count.raw(d),
            status: self.status.raw(d),
            counter: self.counter.raw(d),
            crc: self.crc.raw(d),
            crc_ok: self.crc.raw(d) == self.crc_of(d) as u64,
        }
    }
}

#[derive(Debug, Clone, Copy, Default)]
struct InputState {
    stats: MsgStats,
    counter: CounterCheck,
    fails: u32,
    goods: u32,
    invalid: bool,
    last_good_s: Option<f64>,
    lost: bool,
}

pub const WHEELS: usize = 0;
pub const ACC: usize = 1;
pub const GYR: usize = 2;
const ROLE_NAMES: [&str; 3] = ["wheels", "acc", "gyro"];

/// The pipeline. Build it with [`Pipeline::new`], feed [`Pipeline::on_frame`] and
/// [`Pipeline::tick`], and read what it produced from the [`Sink`].
#[derive(Debug)]
pub struct Pipeline {
    inputs: [MsgCodec; 3],
    names: [String; 3],
    st: [InputState; 3],
    pub est: Estimator,
    out: OutputCodec,
    leveling: super::config::Leveling,
    reference_pitch_deg: f64,
    fault: bool,
    clock_s: Option<f64>,
    frame_clock: super::clock::FrameClock,
    bus_off: bool,
    start_s: f64,
    next_due_s: Option<f64>,
    out_counter: u8,
    pub frames_sent: u64,
    pub ignored_frames: u64,
    pub windows_accepted: u64,
    pub windows_rejected: u64,
    pub standstills: u64,
    /// State changed since last save (an accepted window or load change).
    pub dirty: bool,
    half: [Option<(u8, f64, [f64; 3])>; 2],
    /// Interface each input message is taken from.
    source: [Option<u32>; 3],
}

impl Pipeline {
    pub fn new(cfg: &Config, db: &Database) -> anyhow::Result<Self> {
        let inputs = [
            MsgCodec::build(db, &cfg.wheels, ROLE_NAMES[WHEELS])?,
            MsgCodec::build(db, &cfg.acc, ROLE_NAMES[ACC])?,
            MsgCodec::build(db, &cfg.gyro, ROLE_NAMES[GYR])?,
        ];
        for m in &inputs {
            if m.len != 8 {
                anyhow::bail!(
                    "DBC {}: message for `{}` has {} bytes; leveld reads 8-byte messages",
                    db.path.display(),
                    m.name,
                    m.len
                );
            }
        }
        let out = OutputCodec::build(db, cfg)?;
        Ok(Self {
            inputs,
            names: [
                cfg.wheels.message.clone(),
                cfg.acc.message.clone(),
                cfg.gyro.message.clone(),
            ],
            st: [InputState::default(); 3],
            est: Estimator::new(cfg.estimator.clone())?,
            out,
            leveling: cfg.leveling.clone(),
            reference_pitch_deg: cfg.leveling.reference_pitch_deg,
            fault: false,
            clock_s: None,
            frame_clock: super::clock::FrameClock::new(cfg.leveling.max_clock_step_s),
            bus_off: false,
            start_s: 0.0,
            next_due_s: None,
            out_counter: 0,
            frames_sent: 0,
            ignored_frames: 0,
            windows_accepted: 0,
            windows_rejected: 0,
            standstills: 0,
            dirty: false,
            half: [None; 2],
            source: [None; 3],
        })
    }

    /// IDs to ask the kernel for (filters).
    pub fn input_ids(&self) -> [(u32, bool); 3] {
        [0, 1, 2].map(|i| (self.inputs[i].id, self.inputs[i].extended))
    }

    pub fn output(&self) -> &OutputCodec {
        &self.out
    }

    pub fn message_names(&self) -> &[String; 3] {
        &self.names
    }

    pub fn stats(&self, slot: usize) -> MsgStats {
        self.st[slot].stats
    }

    /// `ok`, `lost` (timed out) or `invalid` (failing its counter or checksum checks).
    pub fn input_state(&self, slot: usize) -> &'static str {
        let s = &self.st[slot];
        if s.lost {
            "lost"
        } else if s.invalid {
            "invalid"
        } else {
            "ok"
        }
    }

    pub fn input_codec(&self, slot: usize) -> &MsgCodec {
        &self.inputs[slot]
    }

    pub fn set_reference_pitch_deg(&mut self, v: f64) {
        self.reference_pitch_deg = v;
    }

    /// Bus-off or another fault outside the inputs: FAULT until cleared.
    pub fn set_fault(&mut self, fault: bool) {
        self.fault = fault;
    }

    /// Restore persisted estimator state.
    pub fn restore(&mut self, st: &EstimatorState) -> Result<(), crate::estimator::StateError> {
        self.est.restore(st)
    }

    /// Clock steps seen in the frame timestamps.
    pub fn clock_steps(&self) -> u64 {
        self.frame_clock.steps
    }

    /// Map a frame timestamp onto the pipeline clock; on a step, restart what spans
    /// time. `None`: the timestamp is unusable and the frame is dropped.
    fn frame_time(&mut self, t_frame_s: f64, sink: &mut dyn Sink) -> Option<f64> {
        match self.frame_clock.map(t_frame_s) {
            super::clock::Mapped::Time(t) => Some(t),
            super::clock::Mapped::Invalid => None,
            super::clock::Mapped::Step { t_s, step_s } => {
                sink.notice(&Notice::ClockStep { t_s, step_s });
                // What was measured before the step cannot be joined to what comes
                // after: the car may have moved meanwhile.
                self.est.wheels_lost();
                self.half = [None; 2];
                for s in &mut self.st {
                    if s.last_good_s.is_some() {
                        s.last_good_s = Some(t_s);
                    }
                }
                Some(t_s)
            }
        }
    }

    /// A frame that is not an input (CAN FD, say): time passes, it is counted as ignored.
    pub fn on_other_frame(&mut self, t_frame_s: f64, sink: &mut dyn Sink) {
        if let Some(t) = self.frame_time(t_frame_s, sink) {
            self.tick(t, sink);
        }
        self.ignored_frames += 1;
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
        if self.fault {
            return Status::Fault;
        }
        if self.st.iter().any(|s| s.lost || s.invalid) {
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

    /// The LEVELING payload for the current state (the counter is the next to send).
    pub fn payload(&self) -> [u8; 8] {
        let e = self.est.estimate();
        let r2b = e.map_or(0.0, |e| e.road_to_body_deg);
        let corr = if e.is_some() {
            (-(r2b - self.reference_pitch_deg)).clamp(
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
        )
    }

    fn send(&mut self, t_s: f64, sink: &mut dyn Sink) {
        let d = self.payload();
        sink.frame(t_s, self.out.id, self.out.extended, &d);
        self.out_counter = (self.out_counter + 1) & 15;
        self.frames_sent += 1;
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
            self.next_due_s = Some(if t_s - next > 10.0 * period || sent >= 11 || next <= due {
                t_s + period
            } else {
                next
            });
            if sent >= 11 || next <= due {
                break;
            }
        }
        self.check_timeouts(t_s, sink);
        self.clock_s = Some(t_s);
    }

    fn check_timeouts(&mut self, t_s: f64, sink: &mut dyn Sink) {
        for (i, role) in ROLE_NAMES.iter().enumerate() {
            let timeout = self.inputs[i].timeout_s;
            let s = &mut self.st[i];
            let since = s.last_good_s.unwrap_or(self.start_s);
            if !s.lost && t_s - since > timeout {
                s.lost = true;
                s.stats.timeouts += 1;
                s.counter.reset();
                self.source[i] = None;
                sink.notice(&Notice::InputLost { t_s, message: role });
                if i == WHEELS {
                    self.est.wheels_lost();
                }
            }
        }
    }

    fn fail(&mut self, slot: usize, t_s: f64, reason: &'static str, sink: &mut dyn Sink) {
        let s = &mut self.st[slot];
        s.goods = 0;
        s.fails += 1;
        if !s.invalid && s.fails >= self.leveling.invalid_after {
            s.invalid = true;
            sink.notice(&Notice::MessageInvalid {
                t_s,
                message: ROLE_NAMES[slot],
                reason,
            });
        }
    }

    fn good(&mut self, slot: usize, t_s: f64, sink: &mut dyn Sink) {
        let s = &mut self.st[slot];
        s.fails = 0;
        s.goods += 1;
        s.last_good_s = Some(t_s);
        let restored = (s.invalid && s.goods >= self.leveling.valid_after) || s.lost;
        if s.invalid && s.goods >= self.leveling.valid_after {
            s.invalid = false;
        }
        if s.lost {
            s.lost = false;
        }
        if restored && !s.invalid {
            sink.notice(&Notice::InputRestored {
                t_s,
                message: ROLE_NAMES[slot],
            });
        }
    }

    /// Handle one received frame (any `embedded_can::Frame`) stamped `t_s`.
    pub fn on_can_frame<F: embedded_can::Frame>(&mut self, t_s: f64, f: &F, sink: &mut dyn Sink) {
        self.on_can_frame_from(0, t_s, f, sink);
    }

    /// As [`Pipeline::on_can_frame`], from interface number `source`. Each input message
    /// is taken from one interface; copies from others (a gateway mirroring the ESC onto
    /// a second bus) are counted as mirrored and not used. When the source goes silent
    /// another interface may take over.
    pub fn on_can_frame_from<F: embedded_can::Frame>(
        &mut self,
        source: u32,
        t_s: f64,
        f: &F,
        sink: &mut dyn Sink,
    ) {
        if f.is_remote_frame() {
            if let Some(t) = self.frame_time(t_s, sink) {
                self.tick(t, sink);
            }
            self.ignored_frames += 1;
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

    fn on_frame_from(
        &mut self,
        source: u32,
        t_s: f64,
        id: u32,
        extended: bool,
        data: &[u8],
        sink: &mut dyn Sink,
    ) {
        let Some(t_s) = self.frame_time(t_s, sink) else {
            self.ignored_frames += 1;
            return;
        };
        self.tick(t_s, sink);
        let Some(slot) =
            (0..3).find(|&i| self.inputs[i].id == id && self.inputs[i].extended == extended)
        else {
            self.ignored_frames += 1;
            return;
        };
        match self.source[slot] {
            None => self.source[slot] = Some(source),
            Some(s) if s != source => {
                self.st[slot].stats.mirrored += 1;
                return;
            }
            Some(_) => {}
        }
        self.st[slot].stats.frames += 1;
        if data.len() != 8 {
            self.st[slot].stats.dlc_errors += 1;
            self.fail(slot, t_s, "wrong DLC", sink);
            return;
        }
        let d: [u8; 8] = data.try_into().unwrap_or([0; 8]);
        let codec = &self.inputs[slot];
        if codec.check_checksum && !codec.checksum_ok(&d) {
            self.st[slot].stats.checksum_errors += 1;
            self.fail(slot, t_s, "checksum", sink);
            return;
        }
        let counter = codec.counter(&d);
        if codec.check_counter {
            let step = codec.max_step;
            if let Some(c) = counter
                && !self.st[slot].counter.accept(c, step)
            {
                self.st[slot].stats.counter_errors += 1;
                self.fail(slot, t_s, "alive counter", sink);
                return;
            }
        }
        self.good(slot, t_s, sink);
        let v = self.inputs[slot].values(&d);
        let mut buf = EventBuf::default();
        if slot == WHEELS {
            self.est
                .push_wheels(WheelSpeeds { t_s, kmh: v }, &mut |e| buf.push(e));
        } else {
            let c = counter.unwrap_or(0);
            let other = if slot == ACC { GYR } else { ACC } - 1;
            let mine = slot - 1;
            match self.half[other].take() {
                Some((oc, ot, ov)) if oc == c || self.inputs[slot].n_counter == 0 => {
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
                    self.windows_accepted += 1;
                    changed = true;
                }
                Event::WindowRejected { .. } => self.windows_rejected += 1,
                Event::LoadChanged { .. } | Event::PitchShifted { .. } => changed = true,
                Event::StandstillStarted { .. } => self.standstills += 1,
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

/// The events of one frame without allocating (one frame gives at most a few); any
/// beyond its capacity are counted and reported as a notice.
#[derive(Default)]
struct EventBuf {
    ev: [Option<Event>; 16],
    n: usize,
    dropped: u32,
}

impl EventBuf {
    fn push(&mut self, e: Event) {
        if self.n < self.ev.len() {
            self.ev[self.n] = Some(e);
            self.n += 1;
        } else {
            self.dropped = self.dropped.saturating_add(1);
        }
    }
    fn iter(&self) -> impl Iterator<Item = &Event> {
        self.ev[..self.n].iter().flatten()
    }
}
