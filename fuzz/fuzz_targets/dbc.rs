//! Any bytes as a DBC: loading and building the configured codecs either works or
//! says why; nothing panics or overflows.
#![no_main]
use leveld::can::dbc::{Database, decode_text};
use leveld::daemon::config::{Config, DEFAULT_TOML};
use leveld::daemon::pipeline::Pipeline;
use libfuzzer_sys::fuzz_target;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let text = decode_text(data);
    if let Ok(db) = Database::parse(Path::new("fuzz.dbc"), &text) {
        let cfg = Config::parse(Path::new("config/leveld.toml"), DEFAULT_TOML).unwrap();
        if let Ok(mut p) = Pipeline::new(&cfg, &db) {
            let mut sink = leveld::daemon::sink::NullSink;
            for (i, (id, ext)) in p.input_ids().into_iter().enumerate() {
                p.on_frame(i as f64 * 0.01, id, ext, &[0xA5; 8], &mut sink);
            }
            let _ = p.payload();
        }
    }
});
