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
        })
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
        let codec = SignalCodec {
            start_bit: s.start_bit as u16,
            size: s.size.clamp(1, 64) as u8,
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
