//! Any bytes as a log: every line is a frame or a counted malformed line, and a frame
//! written back reads back as the same frame.
#![no_main]
use leveld::can::candump::{CandumpLine, Line, ReadLine, parse_bytes, parse_line, read_line};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let mut input = data;
    let mut buf = Vec::new();
    while let Ok(r) = read_line(&mut input, &mut buf) {
        if r == ReadLine::Eof {
            break;
        }
        if let Ok(Line::Frame(f)) = parse_bytes(&buf) {
            if !f.fd && !f.remote && f.t_s < 1e9 {
                let again = CandumpLine(&f).to_string();
                assert!(matches!(parse_line(&again), Ok(Line::Frame(_))), "{again}");
            }
        }
    }
});
