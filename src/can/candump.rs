//! Reader and writer for can-utils candump log lines (`candump -L`, as canplayer reads them).
//!
//! Accepted: `(sec.frac) iface ID#DATA` with any number of fraction digits, padded
//! interface names, `ID#R`, `ID#R<len>`, `ID##<flags><data>` (CAN FD), `_<dlc>` after
//! classic data, a trailing ` R`/` T` direction, error frames (`candump -e`: an
//! 8-digit ID with the error flag 0x20000000), comments (`#` / `;`), blank lines and
//! DROPCOUNT lines. Nothing else: IDs and lengths are exactly the digits candump
//! writes. Lines are read as bytes, at most [`MAX_LINE_BYTES`] of them; parsing does
//! not allocate.

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
    /// An error frame: `id` holds the error class bits (linux/can/error.h).
    pub error: bool,
    pub len: u8,
    pub data: [u8; 64],
}

/// Longest line read, bytes. A CAN FD line with a 16-byte interface name and a
/// 20-digit timestamp is under 200; the rest of a longer line is skipped unread.
pub const MAX_LINE_BYTES: usize = 4096;

/// Error flag of an error frame's CAN ID.
pub const CAN_ERR_FLAG: u32 = 0x2000_0000;

/// Timestamps at or above this are refused, s (about the year 5000; a log clock this
/// far off is corrupt, and f64 keeps microseconds only below 2^33 s).
pub const MAX_TIMESTAMP_S: f64 = 1e11;

/// What [`read_line`] read.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ReadLine {
    /// A line of at most `MAX_LINE_BYTES` (its newline removed) is in the buffer.
    Line,
    /// The line was longer; its first `MAX_LINE_BYTES` are in the buffer.
    TooLong,
    Eof,
}

/// Read one line into `buf` as bytes, whatever they are, keeping at most
/// `MAX_LINE_BYTES` of it: memory stays bounded on any input.
pub fn read_line(input: &mut dyn std::io::BufRead, buf: &mut Vec<u8>) -> std::io::Result<ReadLine> {
    buf.clear();
    let mut any = false;
    let mut too_long = false;
    loop {
        let chunk = match input.fill_buf() {
            Ok(c) => c,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            Err(e) => return Err(e),
        };
        if chunk.is_empty() {
            break;
        }
        any = true;
        let (take, done) = match chunk.iter().position(|&b| b == b'\n') {
            Some(i) => (i, true),
            None => (chunk.len(), false),
        };
        let room = MAX_LINE_BYTES.saturating_sub(buf.len());
        if take > room {
            too_long = true;
        }
        buf.extend_from_slice(&chunk[..take.min(room)]);
        input.consume(if done { take + 1 } else { take });
        if done {
            break;
        }
    }
    Ok(match (any, too_long) {
        (false, _) => ReadLine::Eof,
        (true, true) => ReadLine::TooLong,
        (true, false) => ReadLine::Line,
    })
}

/// Parse one line read as bytes: text that is not UTF-8 is a malformed line.
pub fn parse_bytes(line: &[u8]) -> Result<Line, ParseError> {
    parse_line(std::str::from_utf8(line).map_err(|_| ParseError::NotText)?)
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
            error: false,
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
    #[error("line is not UTF-8 text")]
    NotText,
    #[error("line longer than 4096 bytes")]
    TooLong,
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
    if !(t_s < MAX_TIMESTAMP_S) {
        return Err(ParseError::Timestamp);
    }
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
    if !id_s.bytes().all(|b| b.is_ascii_hexdigit()) {
        return Err(ParseError::Id);
    }
    let id = u32::from_str_radix(id_s, 16).map_err(|_| ParseError::Id)?;
    // An error frame: 8 digits with the error flag, the class bits below it.
    let error = extended && id & !0x1FFF_FFFF == CAN_ERR_FLAG;
    if (!extended && id > 0x7FF) || (id > 0x1FFF_FFFF && !error) {
        return Err(ParseError::Id);
    }
    let mut f = LogFrame::new(t_s, iface, id & 0x1FFF_FFFF, extended, &[]);
    f.error = error;
    let mut body = &field[hash + 1..];
    if let Some(fd_body) = body.strip_prefix('#') {
        // CAN FD: one hex digit of flags, then data.
        let mut ch = fd_body.bytes();
        ch.next().and_then(hex_nibble).ok_or(ParseError::Payload)?;
        f.fd = true;
        body = &fd_body[1..];
    } else if let Some(r) = body.strip_prefix(['R', 'r']) {
        if f.error {
            return Err(ParseError::Payload);
        }
        f.remote = true;
        // `R` alone or with the one DLC digit candump writes.
        match r.as_bytes() {
            [] => {}
            [d @ b'0'..=b'8'] => f.len = d - b'0',
            _ => return Err(ParseError::Payload),
        }
        return Ok(Line::Frame(f));
    }
    // Classic frames may end in `_<dlc>` (a DLC above 8 for an 8-byte payload).
    if !f.fd
        && let Some(u) = body.find('_')
    {
        let dlc = &body[u + 1..];
        if dlc.len() != 1 || hex_nibble(dlc.as_bytes()[0]).is_none() {
            return Err(ParseError::Payload);
        }
        body = &body[..u];
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
        if f.error {
            write!(out, "{:08X}#", f.id | CAN_ERR_FLAG)?
        } else if f.extended {
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
            1_700_000_000.123_456_7
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
        // What candump never writes.
        assert_eq!(parse_line("(1.5) can0 +86#00"), Err(ParseError::Id));
        assert_eq!(parse_line("(1.5) can0 +0000386#00"), Err(ParseError::Id));
        assert_eq!(parse_line("(1.5) can0 123#R+5"), Err(ParseError::Payload));
        assert_eq!(parse_line("(1.5) can0 123#R08"), Err(ParseError::Payload));
        assert_eq!(parse_line("(1.5) can0 123#R9"), Err(ParseError::Payload));
        assert_eq!(parse_line("(1e3) can0 123#00"), Err(ParseError::Timestamp));
        assert_eq!(
            parse_line("(1125899906842624.0) can0 3E0#00"),
            Err(ParseError::Timestamp)
        );
        assert_eq!(
            parse_bytes(b"(1.0) can0 3E0#D5\xff"),
            Err(ParseError::NotText)
        );
    }

    #[test]
    fn error_frames_as_candump_e_writes_them() {
        let f = frame("(1.5) can0 20000040#0000000000000000");
        assert!(f.error && f.extended);
        assert_eq!(f.id, 0x40);
        assert_eq!(
            CandumpLine(&f).to_string(),
            "(1.500000) can0 20000040#0000000000000000"
        );
        assert_eq!(parse_line("(1.5) can0 40000040#00"), Err(ParseError::Id));
    }

    #[test]
    fn lines_are_read_as_bounded_bytes() {
        let mut long = vec![b'x'; 3 * MAX_LINE_BYTES];
        long.extend_from_slice(b"\n(1.0) can0 3E0#\xff\n(2.0) can0 3E0#00");
        let mut r = std::io::BufReader::with_capacity(64, &long[..]);
        let mut buf = Vec::new();
        assert_eq!(read_line(&mut r, &mut buf).unwrap(), ReadLine::TooLong);
        assert_eq!(buf.len(), MAX_LINE_BYTES);
        assert_eq!(read_line(&mut r, &mut buf).unwrap(), ReadLine::Line);
        assert_eq!(parse_bytes(&buf), Err(ParseError::NotText));
        assert_eq!(read_line(&mut r, &mut buf).unwrap(), ReadLine::Line);
        assert!(matches!(parse_bytes(&buf), Ok(Line::Frame(_))));
        assert_eq!(read_line(&mut r, &mut buf).unwrap(), ReadLine::Eof);
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
