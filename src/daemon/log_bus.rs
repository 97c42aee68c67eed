//! A candump log (a file or stdin) as a [`Bus`]: lines in, LEVELING frames out as
//! candump lines. Every line, whatever its bytes or length, is either a frame or a
//! counted malformed line; memory stays bounded by `candump::MAX_LINE_BYTES`.

use super::frame_loop::{Bus, FrameKind, Received, RxFrame};
use crate::can::candump::{
    CandumpLine, Line, LogFrame, ParseError, ReadLine, parse_bytes, read_line,
};
use std::collections::HashMap;
use std::io::{BufRead, Write};

/// Most interfaces of one log told apart (a vehicle has a handful); frames of any
/// further interface are counted as ignored.
pub const MAX_INTERFACES: usize = 256;

pub struct LogBus<'a> {
    input: &'a mut dyn BufRead,
    output: Option<&'a mut dyn Write>,
    /// Interface name written on output frames.
    output_interface: String,
    /// Only frames from this interface; every interface when `None`.
    interface: Option<String>,
    line: Vec<u8>,
    lines: u64,
    ifaces: HashMap<String, u32>,
    warned: bool,
    /// The first read or write error; the bus ends at it.
    error: Option<std::io::Error>,
}

impl<'a> LogBus<'a> {
    pub fn new(input: &'a mut dyn BufRead) -> Self {
        Self {
            input,
            output: None,
            output_interface: "can0".into(),
            interface: None,
            line: Vec::with_capacity(256),
            lines: 0,
            ifaces: HashMap::new(),
            warned: false,
            error: None,
        }
    }

    /// Only frames of `interface` are read; the others are skipped uncounted.
    pub fn only(mut self, interface: Option<String>) -> Self {
        self.interface = interface;
        self
    }

    /// LEVELING frames are written to `output` as candump lines on `interface`.
    pub fn output(mut self, output: Option<&'a mut dyn Write>, interface: &str) -> Self {
        self.output = output;
        self.output_interface = interface.to_string();
        self
    }

    /// Lines read so far.
    pub fn lines(&self) -> u64 {
        self.lines
    }

    /// The line read last, as text for a message.
    pub fn last_line(&self) -> String {
        String::from_utf8_lossy(&self.line).trim_end().to_string()
    }

    /// The read or write error the bus ended at, if any.
    pub fn take_error(&mut self) -> Option<std::io::Error> {
        self.error.take()
    }

    fn source_of(&mut self, name: &str) -> Option<u32> {
        if let Some(&i) = self.ifaces.get(name) {
            return Some(i);
        }
        if self.ifaces.len() >= MAX_INTERFACES {
            if !self.warned {
                self.warned = true;
                tracing::warn!(
                    "more than {MAX_INTERFACES} interfaces in the log; frames of the others are ignored"
                );
            }
            return None;
        }
        let i = self.ifaces.len() as u32;
        self.ifaces.insert(name.to_string(), i);
        Some(i)
    }

    fn next_received(&mut self) -> Received {
        loop {
            if self.error.is_some() {
                return Received::End;
            }
            let read = match read_line(self.input, &mut self.line) {
                Ok(ReadLine::Eof) => return Received::End,
                Ok(r) => r,
                Err(e) => {
                    self.error = Some(e);
                    return Received::End;
                }
            };
            self.lines += 1;
            let parsed = match read {
                ReadLine::TooLong => Err(ParseError::TooLong),
                _ => parse_bytes(&self.line),
            };
            let f = match parsed {
                Ok(Line::Skip) => continue,
                Ok(Line::Frame(f)) => f,
                Err(error) => {
                    return Received::Malformed {
                        line: self.lines,
                        error,
                    };
                }
            };
            if self.interface.as_deref().is_some_and(|i| i != f.iface()) {
                continue;
            }
            return Received::Frame(self.rx(&f));
        }
    }

    fn rx(&mut self, f: &LogFrame) -> RxFrame {
        let source = if f.error || f.fd || f.remote {
            None
        } else {
            self.source_of(f.iface())
        };
        let kind = match (f.error, source) {
            (true, _) => FrameKind::Error,
            (false, Some(_)) => FrameKind::Data,
            (false, None) => FrameKind::Other,
        };
        RxFrame {
            source: source.unwrap_or(0),
            t_s: f.t_s,
            id: f.id,
            extended: f.extended,
            kind,
            len: f.len,
            data: f.data,
        }
    }
}

impl Bus for LogBus<'_> {
    async fn recv(&mut self) -> Received {
        self.next_received()
    }

    fn send(&mut self, t_s: f64, id: u32, extended: bool, data: &[u8; 8]) {
        if self.error.is_some() {
            return;
        }
        if let Some(w) = self.output.as_deref_mut() {
            let f = LogFrame::new(t_s, &self.output_interface, id, extended, data);
            if let Err(e) = writeln!(w, "{}", CandumpLine(&f)) {
                self.error = Some(e);
            }
        }
    }
}
