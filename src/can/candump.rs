//! Reader and writer for can-utils candump log lines (`candump -L`, as canplayer reads them).
//!
//! Accepted: `(sec.frac) iface ID#DATA` with any number of fraction digits, padded
//! interface names, `ID#R`, `ID#R<len>`, `ID##<flags><data>` (CAN FD), `_<dlc>` after
//! classic data, a trailing ` R`/` T` direction, comments (`#` / `;`), blank lines and
//! DROPCOUNT lines. Parsing does not allocate.

use std::fmt;

/// One frame from a log line. Payload up to 64 bytes (CAN FD).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LogFrame {
    pub t_s: f64,
    iface: [u8; 16],
    iface_len: u8,
    pub id: u32,
    pub extended: bool,
    pub remote: bool,
    pub fd: bool,
    pub len: u8,
    pub data: [u8; 64],
}

impl LogFrame {
    pub fn iface(&self) -> &str {
        std::str::from_utf8(&self.iface[..self.iface_len as usize]).unwrap_or("?")
    }
    pub fn payload(&self) -> &[u8] {
        &self.data[..self.len as usize]
    }
    /// A classic data frame.
    pub fn new(t_s: f64, iface: &str, id: u32, extended: bool, payload: &[u8]) -> Self {
        let mut f = LogFrame {
            t_s,
            iface: [0; 16],
            iface_len: iface.len().min(16) as u8,
            id,
            extended,
            remote: false,
            fd: false,
            len: payload.len().min(64) as u8,
            data: [0; 64],
        };
        f.iface[..f.iface_len as usize].copy_from_slice(&iface.as_bytes()[..f.iface_len as usize]);
        f.data[..f.len as usize].copy_from_slice(&payload[..f.len as usize]);
        f
    }
}

impl embedded_can::Frame for LogFrame {
    fn new(id: impl Into<embedded_can::Id>, data: &[u8]) -> Option<Self> {
        if data.len() > 8 {
            return None;
        }
        let (raw, ext) = match id.into() {
            embedded_can::Id::Standard(s) => (s.as_raw() as u32, false),
            embedded_can::Id::Extended(e) => (e.as_raw(), true),
        };
        Some(LogFrame::new(0.0, "", raw, ext, data))
    }
    fn new_remote(id: impl Into<embedded_can::Id>, dlc: usize) -> Option<Self> {
        let mut f = <Self as embedded_can::Frame>::new(id, &[])?;
        f.remote = true;
        f.len = dlc.min(8) as u8;
        Some(f)
    }
    fn is_extended(&self) -> bool {
        self.extended
    }
    fn is_remote_frame(&self) -> bool {
        self.remote
    }
    fn id(&self) -> embedded_can::Id {
        if self.extended {
            embedded_can::ExtendedId::new(self.id).map_or(
                embedded_can::Id::Standard(embedded_can::StandardId::ZERO),
                embedded_can::Id::Extended,
            )
        } else {
            embedded_can::StandardId::new(self.id as u16).map_or(
                embedded_can::Id::Standard(embedded_can::StandardId::ZERO),
                embedded_can::Id::Standard,
            )
        }
    }
    fn dlc(&self) -> usize {
        self.len as usize
    }
    fn data(&self) -> &[u8] {
        if self.remote { &[] } else { self.payload() }
    }
}

/// What a line held.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Line {
    Frame(LogFrame),
    /// Comment, blank, or DROPCOUNT line: nothing to do.
    Skip,
}

/// Why a line could not be read; `Display` says what is wrong and how it should look.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum ParseError {
    #[error("missing '(seconds.fraction)' timestamp")]
    Timestamp,
    #[error("missing interface name after the timestamp")]
    Interface,
    #[error("missing 'ID#DATA' frame field")]
    FrameField,
    #[error("CAN ID is not 3 (standard) or 8 (extended) hex digits in range")]
    Id,
    #[error("payload is not an even number of hex digits (at most 8 bytes classic, 64 FD)")]
    Payload,
    #[error("unknown text after the frame (expected nothing, ' R' or ' T')")]
    Trailing,
}

fn hex_nibble(c: u8) -> Option<u8> {
    match c {
        b'0'..=b'9' => Some(c - b'0'),
        b'a'..=b'f' => Some(c - b'a' + 10),
        b'A'..=b'F' => Some(c - b'A' + 10),
        _ => None,
    }
}

/// Parse one line.
pub fn parse_line(line: &str) -> Result<Line, ParseError> {
    let s = line.trim();
    if s.is_empty() || s.starts_with('#') || s.starts_with(';') || s.starts_with("DROPCOUNT") {
        return Ok(Line::Skip);
    }
    let rest = s.strip_prefix('(').ok_or(ParseError::Timestamp)?;
    let close = rest.find(')').ok_or(ParseError::Timestamp)?;
    let ts = &rest[..close];
    if ts.is_empty()
        || !ts.bytes().all(|b| b.is_ascii_digit() || b == b'.')
        || ts.matches('.').count() != 1
    {
        return Err(ParseError::Timestamp);
    }
    let t_s: f64 = ts.parse().map_err(|_| ParseError::Timestamp)?;
    let rest = rest[close + 1..].trim_start();
    let sp = rest
        .find(char::is_whitespace)
        .ok_or(ParseError::Interface)?;
    let iface = &rest[..sp];
    if iface.is_empty() || iface.len() > 16 {
        return Err(ParseError::Interface);
    }
    let rest = rest[sp..].trim_start();
    let (field, trailing) = match rest.find(char::is_whitespace) {
        Some(i) => (&rest[..i], rest[i..].trim()),
        None => (rest, ""),
    };
    if !matches!(trailing, "" | "R" | "T") {
        return Err(ParseError::Trailing);
    }
    let hash = field.find('#').ok_or(ParseError::FrameField)?;
    let id_s = &field[..hash];
    let extended = match id_s.len() {
        3 => false,
        8 => true,
        _ => return Err(ParseError::Id),
    };
    let id = u32::from_str_radix(id_s, 16).map_err(|_| ParseError::Id)?;
    if (!extended && id > 0x7FF) || id > 0x1FFF_FFFF {
        return Err(ParseError::Id);
    }
    let mut f = LogFrame::new(t_s, iface, id, extended, &[]);
    let mut body = &field[hash + 1..];
    if let Some(fd_body) = body.strip_prefix('#') {
        // CAN FD: one hex digit of flags, then data.
        let mut ch = fd_body.bytes();
        ch.next().and_then(hex_nibble).ok_or(ParseError::Payload)?;
        f.fd = true;
        body = &fd_body[1..];
    } else if let Some(r) = body.strip_prefix(['R', 'r']) {
        f.remote = true;
        if !r.is_empty() {
            let n: u8 = r.parse().map_err(|_| ParseError::Payload)?;
            if n > 8 {
                return Err(ParseError::Payload);
            }
            f.len = n;
        }
        return Ok(Line::Frame(f));
    }
    // Classic frames may end in `_<dlc>` (a DLC above 8 for an 8-byte payload).
    if !f.fd {
        if let Some(u) = body.find('_') {
            let dlc = &body[u + 1..];
            if dlc.len() != 1 || hex_nibble(dlc.as_bytes()[0]).is_none() {
                return Err(ParseError::Payload);
            }
            body = &body[..u];
        }
    }
    let b = body.as_bytes();
    let max = if f.fd { 64 } else { 8 };
    if b.len() % 2 != 0 || b.len() / 2 > max {
        return Err(ParseError::Payload);
    }
    for (i, pair) in b.chunks(2).enumerate() {
        let hi = hex_nibble(pair[0]).ok_or(ParseError::Payload)?;
        let lo = hex_nibble(pair[1]).ok_or(ParseError::Payload)?;
        f.data[i] = (hi << 4) | lo;
    }
    f.len = (b.len() / 2) as u8;
    Ok(Line::Frame(f))
}

/// Formats a classic frame as a `candump -L` line (without newline).
pub struct CandumpLine<'a>(pub &'a LogFrame);

impl fmt::Display for CandumpLine<'_> {
    fn fmt(&self, out: &mut fmt::Formatter<'_>) -> fmt::Result {
        let f = self.0;
        let micros = (f.t_s * 1e6).round() as i64;
        write!(
            out,
            "({}.{:06}) {} ",
            micros.div_euclid(1_000_000),
            micros.rem_euclid(1_000_000),
            f.iface()
        )?;
        if f.extended {
            write!(out, "{:08X}#", f.id)?
        } else {
            write!(out, "{:03X}#", f.id)?
        }
        for b in f.payload() {
            write!(out, "{b:02X}")?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(l: &str) -> LogFrame {
        match parse_line(l).unwrap() {
            Line::Frame(f) => f,
            Line::Skip => panic!("skipped {l}"),
        }
    }

    #[test]
    fn real_kona_line() {
        let f = frame("(1953.613500) can1 386#0000C00000400000");
        assert_eq!(
            (f.iface(), f.id, f.len, f.extended),
            ("can1", 0x386, 8, false)
        );
        assert_eq!(f.t_s, 1953.6135);
        assert_eq!(f.payload()[2], 0xC0);
    }

    #[test]
    fn variants_of_real_candump_output() {
        assert_eq!(
            frame("(1700000000.123456789)   vcan0  3E0#0102").t_s,
            1700000000.123456789
        );
        assert!(frame("(0.000001) can0 12345678#DEADBEEF").extended);
        let r = frame("(1.5) can0 123#R");
        assert!(r.remote && r.len == 0);
        assert_eq!(frame("(1.5) can0 123#R3").len, 3);
        let fd = frame("(1.5) can0 123##1001122334455667788");
        assert!(fd.fd && fd.len == 9);
        assert_eq!(frame("(1.5) can0 123#1122334455667788_C").len, 8);
        assert_eq!(frame("(1.5) can0 123#11 R").len, 1);
        assert_eq!(frame("(1.5) can0 123#11 T").len, 1);
        for skip in ["", "   ", "# comment", "; comment", "DROPCOUNT: can0 3"] {
            assert_eq!(parse_line(skip), Ok(Line::Skip));
        }
    }

    #[test]
    fn malformed_lines_say_what_is_wrong() {
        assert_eq!(parse_line("1.5 can0 123#00"), Err(ParseError::Timestamp));
        assert_eq!(parse_line("(1.5x) can0 123#00"), Err(ParseError::Timestamp));
        assert_eq!(parse_line("(1.5)"), Err(ParseError::Interface));
        assert_eq!(parse_line("(1.5) can0 12300"), Err(ParseError::FrameField));
        assert_eq!(parse_line("(1.5) can0 1234#00"), Err(ParseError::Id));
        assert_eq!(parse_line("(1.5) can0 800#00"), Err(ParseError::Id));
        assert_eq!(parse_line("(1.5) can0 123#0"), Err(ParseError::Payload));
        assert_eq!(
            parse_line("(1.5) can0 123#001122334455667788"),
            Err(ParseError::Payload)
        );
        assert_eq!(parse_line("(1.5) can0 123#zz"), Err(ParseError::Payload));
        assert_eq!(parse_line("(1.5) can0 123#00 X"), Err(ParseError::Trailing));
    }

    #[test]
    fn writes_candump_l_and_reads_it_back() {
        let f = LogFrame::new(
            12.000345,
            "vcan0",
            0x3E8,
            false,
            &[1, 2, 3, 4, 5, 6, 7, 0xAB],
        );
        let s = CandumpLine(&f).to_string();
        assert_eq!(s, "(12.000345) vcan0 3E8#01020304050607AB");
        assert_eq!(frame(&s), f);
    }
}
