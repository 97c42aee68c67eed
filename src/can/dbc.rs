//! Loading a DBC and turning named signals into precomputed codecs.

use super::signal::SignalCodec;
use can_dbc::{ByteOrder, Dbc, MessageId, ValueType};
use std::path::{Path, PathBuf};

/// A DBC problem, naming the file and what to fix.
#[derive(Debug, thiserror::Error)]
pub enum DbcError {
    #[error("cannot read DBC {path}: {source}")]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error(
        "DBC {path} does not parse: {msg}; check the line against the DBC grammar (BO_/SG_ syntax)"
    )]
    Parse { path: PathBuf, msg: String },
    #[error("DBC {path} has no message named `{message}`; the messages are: {known}")]
    NoMessage {
        path: PathBuf,
        message: String,
        known: String,
    },
    #[error("DBC {path}: message `{message}` has no signal `{signal}`; its signals are: {known}")]
    NoSignal {
        path: PathBuf,
        message: String,
        signal: String,
        known: String,
    },
    #[error("DBC {path}{}: {what}", line.map_or(String::new(), |l| format!(" line {l}")))]
    Invalid {
        path: PathBuf,
        line: Option<usize>,
        what: String,
    },
    #[error("DBC {path}: signal `{message}.{signal}` does not fit in the message's {len} bytes")]
    DoesNotFit {
        path: PathBuf,
        message: String,
        signal: String,
        len: u64,
    },
}

/// A parsed DBC with the path it came from.
#[derive(Debug)]
pub struct Database {
    pub path: PathBuf,
    pub dbc: Dbc,
    /// Each `BO_` line as written: line number, ID as written, message name. The
    /// parser keeps standard IDs in 16 bits, so an ID out of range is seen only here.
    bo_lines: Vec<(usize, u64, String)>,
}

/// Largest standard (11-bit) and extended (29-bit) identifiers.
const MAX_STANDARD_ID: u64 = 0x7FF;
const MAX_EXTENDED_ID: u64 = 0x1FFF_FFFF;
/// Bit 31 of a `BO_` ID marks it extended.
const EXTENDED_FLAG: u64 = 1 << 31;

/// `BO_ <id> <name>:` lines of a DBC text.
fn bo_lines(text: &str) -> Vec<(usize, u64, String)> {
    text.lines()
        .enumerate()
        .filter_map(|(i, l)| {
            let mut it = l.trim_start().strip_prefix("BO_ ")?.split_whitespace();
            let id = it.next()?.parse::<u64>().ok()?;
            let name = it.next()?.trim_end_matches(':').to_string();
            Some((i + 1, id, name))
        })
        .collect()
}

/// A message resolved from the DBC.
#[derive(Debug, Clone, PartialEq)]
pub struct MessageInfo {
    pub name: String,
    pub id: u32,
    pub extended: bool,
    pub len: u8,
}

/// Text of a DBC file: UTF-8 without its byte-order mark, else Windows-1252 (which
/// covers Latin-1 but for 0x80-0x9F).
pub fn decode_text(bytes: &[u8]) -> std::borrow::Cow<'_, str> {
    let b = bytes.strip_prefix(b"\xEF\xBB\xBF").unwrap_or(bytes);
    match std::str::from_utf8(b) {
        Ok(s) => std::borrow::Cow::Borrowed(s),
        Err(_) => std::borrow::Cow::Owned(b.iter().map(|&c| cp1252(c)).collect()),
    }
}

fn cp1252(c: u8) -> char {
    const HIGH: [u16; 32] = [
        0x20AC, 0xFFFD, 0x201A, 0x0192, 0x201E, 0x2026, 0x2020, 0x2021, 0x02C6, 0x2030, 0x0160,
        0x2039, 0x0152, 0xFFFD, 0x017D, 0xFFFD, 0xFFFD, 0x2018, 0x2019, 0x201C, 0x201D, 0x2022,
        0x2013, 0x2014, 0x02DC, 0x2122, 0x0161, 0x203A, 0x0153, 0xFFFD, 0x017E, 0x0178,
    ];
    match c {
        0x80..=0x9F => char::from_u32(HIGH[(c - 0x80) as usize] as u32).unwrap_or('\u{FFFD}'),
        _ => c as char,
    }
}

impl Database {
    /// Load a DBC file: UTF-8 (with or without a byte-order mark) or, as many tools
    /// write them, Windows-1252.
    pub fn load(path: &Path) -> Result<Self, DbcError> {
        let bytes = std::fs::read(path).map_err(|source| DbcError::Read {
            path: path.into(),
            source,
        })?;
        Self::parse(path, &decode_text(&bytes))
    }

    pub fn parse(path: &Path, text: &str) -> Result<Self, DbcError> {
        let dbc = Dbc::try_from(text).map_err(|e| DbcError::Parse {
            path: path.into(),
            msg: e.to_string(),
        })?;
        Ok(Self {
            path: path.into(),
            dbc,
            bo_lines: bo_lines(text),
        })
    }

    fn invalid(&self, line: Option<usize>, what: String) -> DbcError {
        DbcError::Invalid {
            path: self.path.clone(),
            line,
            what,
        }
    }

    /// The ID of message `name` as written must be a CAN ID (standard up to 0x7FF, or
    /// extended with bit 31 set) that no other message of the file uses.
    fn check_id(&self, name: &str) -> Result<(), DbcError> {
        let Some(&(line, raw, _)) = self.bo_lines.iter().find(|b| b.2 == name) else {
            return Ok(());
        };
        let id = |raw: u64| {
            if raw & EXTENDED_FLAG != 0 {
                (raw & !EXTENDED_FLAG, true)
            } else {
                (raw, false)
            }
        };
        let (value, extended) = id(raw);
        let max = if extended {
            MAX_EXTENDED_ID
        } else {
            MAX_STANDARD_ID
        };
        if value > max {
            return Err(self.invalid(
                Some(line),
                format!(
                    "message `{name}` has ID {raw} (0x{raw:X}), out of range: a standard ID is at most 0x7FF; an extended one is written with bit 31 set (0x80000000 + ID, ID at most 0x1FFFFFFF)"
                ),
            ));
        }
        if let Some((other, _, other_name)) = self
            .bo_lines
            .iter()
            .find(|b| b.0 != line && id(b.1) == (value, extended))
        {
            return Err(self.invalid(
                Some(line),
                format!(
                    "message `{name}` has ID 0x{value:X}, as has `{other_name}` on line {other}; each ID must name one message"
                ),
            ));
        }
        Ok(())
    }

    fn message_by_name(&self, name: &str) -> Result<&can_dbc::Message, DbcError> {
        self.dbc
            .messages
            .iter()
            .find(|m| m.name == name)
            .ok_or_else(|| DbcError::NoMessage {
                path: self.path.clone(),
                message: name.into(),
                known: self
                    .dbc
                    .messages
                    .iter()
                    .map(|m| m.name.as_str())
                    .collect::<Vec<_>>()
                    .join(", "),
            })
    }

    pub fn message(&self, name: &str) -> Result<MessageInfo, DbcError> {
        let m = self.message_by_name(name)?;
        self.check_id(name)?;
        if m.size > 64 {
            return Err(self.invalid(
                self.line_of(name),
                format!(
                    "message `{name}` is {} bytes long; a CAN frame has at most 64",
                    m.size
                ),
            ));
        }
        let (id, extended) = match m.id {
            MessageId::Standard(id) => (id as u32, false),
            MessageId::Extended(id) => (id, true),
        };
        Ok(MessageInfo {
            name: m.name.clone(),
            id,
            extended,
            len: m.size.min(64) as u8,
        })
    }

    /// Line of the `BO_` of message `name`.
    fn line_of(&self, name: &str) -> Option<usize> {
        self.bo_lines.iter().find(|b| b.2 == name).map(|b| b.0)
    }

    /// `GenMsgCycleTime` of a message, ms, when the DBC gives one above zero.
    pub fn cycle_time_ms(&self, message: &str) -> Option<u64> {
        let m = self.dbc.messages.iter().find(|m| m.name == message)?;
        let v = match self.dbc.message_attribute(m.id, "GenMsgCycleTime")? {
            can_dbc::AttributeValue::Uint(v) => *v as f64,
            can_dbc::AttributeValue::Int(v) => *v as f64,
            can_dbc::AttributeValue::Double(v) => *v,
            can_dbc::AttributeValue::String(_) => return None,
        };
        (v > 0.0).then_some(v as u64)
    }

    pub fn signal(&self, message: &str, signal: &str) -> Result<SignalCodec, DbcError> {
        let m = self.message_by_name(message)?;
        let s = m
            .signals
            .iter()
            .find(|s| s.name == signal)
            .ok_or_else(|| DbcError::NoSignal {
                path: self.path.clone(),
                message: message.into(),
                signal: signal.into(),
                known: m
                    .signals
                    .iter()
                    .map(|s| s.name.as_str())
                    .collect::<Vec<_>>()
                    .join(", "),
            })?;
        let bad = |what: String| {
            Err(self.invalid(
                self.line_of(message),
                format!("signal `{message}.{signal}` {what}"),
            ))
        };
        if !(1..=64).contains(&s.size) {
            return bad(format!("has {} bits; a signal has 1 to 64", s.size));
        }
        if s.start_bit >= 512 {
            return bad(format!(
                "starts at bit {}, past any frame (64 bytes end at bit 511)",
                s.start_bit
            ));
        }
        if !s.factor.is_finite() || s.factor == 0.0 || !s.offset.is_finite() {
            return bad(format!(
                "has factor {} and offset {}; the factor must be finite and not 0, the offset finite",
                s.factor, s.offset
            ));
        }
        if !matches!(
            s.multiplexer_indicator,
            can_dbc::MultiplexIndicator::Plain | can_dbc::MultiplexIndicator::Multiplexor
        ) {
            return bad(
                "is multiplexed: it is only present for one value of its multiplexor, which leveld does not read; give leveld a plain signal".into(),
            );
        }
        let codec = SignalCodec {
            start_bit: s.start_bit as u16,
            size: s.size as u8,
            little_endian: matches!(s.byte_order, ByteOrder::LittleEndian),
            signed: matches!(s.value_type, ValueType::Signed),
            factor: s.factor,
            offset: s.offset,
        };
        if !codec.fits(m.size as usize) {
            return Err(DbcError::DoesNotFit {
                path: self.path.clone(),
                message: message.into(),
                signal: signal.into(),
                len: m.size,
            });
        }
        Ok(codec)
    }
}
