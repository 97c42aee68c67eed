//! Codecs of the messages leveld reads and writes, prepared from the DBC at start so
//! that decoding and encoding a frame neither allocates nor looks anything up.

use super::checks::{ChecksumKind, crc8, hyundai_popcount};
use super::dbc::{Database, DbcError};
use super::signal::SignalCodec;
use serde::{Deserialize, Serialize};

/// One input message and the signals that play each role in it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InputMessage {
    pub message: String,
    /// Value signals in role order: FL, FR, RL, RR for wheels; x, y, z for the IMU.
    pub signals: Vec<String>,
    /// Alive-counter signals, most significant part first (a split counter has two).
    #[serde(default)]
    pub counter: Vec<String>,
    /// Checksum signals, most significant part first.
    #[serde(default)]
    pub checksum: Vec<String>,
    #[serde(default = "default_checksum_kind")]
    pub checksum_kind: ChecksumKind,
    #[serde(default = "yes")]
    pub check_counter: bool,
    #[serde(default = "yes")]
    pub check_checksum: bool,
    /// Largest accepted counter step (lost frames in between are tolerated).
    #[serde(default = "default_counter_step")]
    pub max_counter_step: u8,
    /// Silence after which the input counts as lost; default 10 x the DBC cycle time.
    #[serde(default)]
    pub timeout_ms: Option<u32>,
}

fn default_checksum_kind() -> ChecksumKind {
    ChecksumKind::None
}
fn yes() -> bool {
    true
}
fn default_counter_step() -> u8 {
    2
}

/// Where the leveling result goes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OutputMessage {
    pub message: String,
    #[serde(default = "default_period")]
    pub period_ms: u32,
    pub road_to_body: String,
    pub level_correction: String,
    pub road_slope: String,
    pub estimate_count: String,
    pub status: String,
    pub counter: String,
    pub checksum: String,
    #[serde(default = "default_out_checksum")]
    pub checksum_kind: ChecksumKind,
    /// One-bit flag set while no end-of-line calibration is in use (optional).
    #[serde(default)]
    pub uncalibrated: Option<String>,
}

fn default_period() -> u32 {
    100
}
fn default_out_checksum() -> ChecksumKind {
    ChecksumKind::Crc8SaeJ1850
}

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
    pub(crate) check_counter: bool,
    pub(crate) check_checksum: bool,
    pub(crate) max_step: u8,
    pub timeout_s: f64,
}

/// Mask of the bits of an 8-byte frame a signal occupies.
fn signal_bits(c: &SignalCodec) -> u64 {
    let mut probe = [0u8; 8];
    c.encode_raw(
        &mut probe,
        u64::MAX >> 64u32.saturating_sub(c.size as u32).min(63),
    );
    u64::from_le_bytes(probe)
}

/// The signals that play a role in one message must not share a bit: one signal
/// cannot be two roles, nor a value overlap its counter or checksum.
fn check_disjoint(
    db: &Database,
    message: &str,
    roles: &[(&str, &str, SignalCodec)],
) -> Result<(), DbcError> {
    for (i, (role_a, name_a, a)) in roles.iter().enumerate() {
        for (role_b, name_b, b) in &roles[..i] {
            if signal_bits(a) & signal_bits(b) != 0 {
                let what = if name_a == name_b {
                    format!(
                        "signal `{message}.{name_a}` is given two roles ({role_b} and {role_a}); each role needs its own signal"
                    )
                } else {
                    format!(
                        "signals `{message}.{name_b}` ({role_b}) and `{message}.{name_a}` ({role_a}) share bits; the signals leveld reads must not overlap"
                    )
                };
                return Err(DbcError::Invalid {
                    path: db.path.clone(),
                    line: None,
                    what,
                });
            }
        }
    }
    Ok(())
}

fn concat(parts: &[SignalCodec], d: &[u8]) -> u64 {
    parts.iter().fold(0u64, |acc, p| (acc << p.size) | p.raw(d))
}

impl MsgCodec {
    pub fn build(db: &Database, m: &InputMessage, role: &'static str) -> Result<Self, DbcError> {
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
        let mut roles = Vec::new();
        for (i, n) in m.signals.iter().enumerate().take(4) {
            roles.push(("value", n.as_str(), values[i]));
        }
        for (i, n) in m.counter.iter().enumerate().take(2) {
            roles.push(("counter", n.as_str(), counter[i]));
        }
        for (i, n) in m.checksum.iter().enumerate().take(2) {
            roles.push(("checksum", n.as_str(), checksum[i]));
        }
        check_disjoint(db, &m.message, &roles)?;
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

    pub(crate) fn counter(&self, d: &[u8]) -> Option<u8> {
        (self.n_counter > 0).then(|| (concat(&self.counter[..self.n_counter], d) & 0xFF) as u8)
    }

    pub(crate) fn checksum_ok(&self, d: &[u8; 8]) -> bool {
        let carried = concat(&self.checksum[..self.n_checksum], d);
        let expected = match self.kind {
            ChecksumKind::None => return true,
            ChecksumKind::HyundaiWhlSpd => {
                hyundai_popcount(u64::from_le_bytes(*d), self.popcount_mask) as u64
            }
            kind => {
                let bytes = self.crc_bytes[..self.n_crc_bytes].iter();
                crc8(kind, bytes.map(|&b| d[b as usize])).unwrap_or(0) as u64
            }
        };
        carried == expected
    }

    pub(crate) fn values(&self, d: &[u8]) -> [f64; 4] {
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
    uncalibrated: Option<SignalCodec>,
    kind: ChecksumKind,
}

/// A decoded LEVELING frame.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct LevelingFrame {
    pub road_to_body_deg: f64,
    pub level_correction_deg: f64,
    pub road_slope_deg: f64,
    pub estimate_count: u64,
    pub status: u64,
    pub counter: u64,
    pub crc: u64,
    pub crc_ok: bool,
    /// The `uncalibrated` flag, when the message carries it.
    pub uncalibrated: Option<bool>,
}

impl OutputCodec {
    pub fn build(db: &Database, o: &OutputMessage) -> Result<Self, DbcError> {
        let info = db.message(&o.message)?;
        let s = |n: &str| db.signal(&o.message, n);
        let invalid = |what: String| DbcError::Invalid {
            path: db.path.clone(),
            line: None,
            what,
        };
        if info.len != 8 {
            return Err(invalid(format!(
                "output message `{}` has {} bytes; LEVELING is an 8-byte message",
                o.message, info.len
            )));
        }
        let codec = Self {
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
            uncalibrated: o.uncalibrated.as_deref().map(s).transpose()?,
            kind: o.checksum_kind,
        };
        if signal_bits(&codec.crc) != 0xFF << 56 {
            return Err(invalid(format!(
                "output checksum `{}.{}` must be the 8 bits of byte 7: the CRC covers bytes 0-6",
                o.message, o.checksum
            )));
        }
        let mut roles = vec![
            ("road_to_body", o.road_to_body.as_str(), codec.road_to_body),
            ("level_correction", &o.level_correction, codec.correction),
            ("road_slope", &o.road_slope, codec.slope),
            ("estimate_count", &o.estimate_count, codec.count),
            ("status", &o.status, codec.status),
            ("counter", &o.counter, codec.counter),
            ("checksum", &o.checksum, codec.crc),
        ];
        if let (Some(n), Some(u)) = (&o.uncalibrated, codec.uncalibrated) {
            roles.push(("uncalibrated", n, u));
        }
        check_disjoint(db, &o.message, &roles)?;
        Ok(codec)
    }

    /// The CRC over bytes 0-6 (the config allows only CRC kinds for the output).
    fn crc_of(&self, d: &[u8; 8]) -> u8 {
        crc8(self.kind, d[..7].iter().copied()).unwrap_or(0)
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
        uncalibrated: bool,
    ) -> [u8; 8] {
        let mut d = [0u8; 8];
        if let Some(u) = &self.uncalibrated {
            u.encode_raw(&mut d, u64::from(uncalibrated));
        }
        self.road_to_body.encode(&mut d, r2b);
        self.correction.encode(&mut d, corr);
        self.slope.encode(&mut d, slope);
        self.count
            .encode_raw(&mut d, count.min(u64::MAX >> (64 - self.count.size as u32)));
        self.status.encode_raw(&mut d, status as u64);
        self.counter.encode_raw(&mut d, (counter & 15) as u64);
        let c = self.crc_of(&d);
        self.crc.encode_raw(&mut d, c as u64);
        d
    }

    pub fn decode(&self, d: &[u8; 8]) -> LevelingFrame {
        LevelingFrame {
            road_to_body_deg: self.road_to_body.decode(d),
            level_correction_deg: self.correction.decode(d),
            road_slope_deg: self.slope.decode(d),
            estimate_count: self.count.raw(d),
            status: self.status.raw(d),
            counter: self.counter.raw(d),
            crc: self.crc.raw(d),
            crc_ok: self.crc.raw(d) == self.crc_of(d) as u64,
            uncalibrated: self.uncalibrated.as_ref().map(|u| u.raw(d) != 0),
        }
    }
}
