//! Any bytes as a config: it is refused with a message, or it builds a pipeline on the
//! reference DBC that runs without panicking.
#![no_main]
use leveld::can::dbc::Database;
use leveld::daemon::config::Config;
use leveld::daemon::pipeline::Pipeline;
use libfuzzer_sys::fuzz_target;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    if let Ok(cfg) = Config::parse(Path::new("config/leveld.toml"), text) {
        let db = Database::parse(Path::new("leveld.dbc"), leveld::daemon::DEFAULT_DBC).unwrap();
        if let Ok(mut p) = Pipeline::new(&cfg, &db) {
            let mut sink = leveld::daemon::sink::NullSink;
            for k in 0..50 {
                for (id, ext) in p.input_ids() {
                    p.on_frame(k as f64 * 0.01, id, ext, &[0; 8], &mut sink);
                }
            }
        }
    }
});
