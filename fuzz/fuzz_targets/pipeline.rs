//! Arbitrary frames with arbitrary timestamps through the reference pipeline: no panic,
//! no hang, and time never runs backwards in what it sends.
#![no_main]
use leveld::daemon::pipeline::Pipeline;
use leveld::daemon::sink::{Notice, Sink};
use leveld::estimator::Event;
use libfuzzer_sys::fuzz_target;

struct Check {
    last_t: f64,
    frames: u64,
}

impl Sink for Check {
    fn event(&mut self, _: &Event) {}
    fn notice(&mut self, _: &Notice) {}
    fn frame(&mut self, t_s: f64, _: u32, _: bool, _: &[u8; 8]) {
        assert!(t_s.is_finite() && t_s >= self.last_t, "{t_s} after {}", self.last_t);
        self.last_t = t_s;
        self.frames += 1;
    }
}

fuzz_target!(|data: &[u8]| {
    let (cfg, db, _) = leveld::daemon::load(None).unwrap();
    let mut p = Pipeline::new(&cfg, &db).unwrap();
    let ids = p.input_ids();
    let mut sink = Check { last_t: f64::NEG_INFINITY, frames: 0 };
    // Each record: 8 bytes of timestamp, 1 selector, 1 length, up to 8 of payload.
    for rec in data.chunks(18) {
        if rec.len() < 10 {
            break;
        }
        let t = f64::from_le_bytes(rec[..8].try_into().unwrap());
        let (id, ext) = ids[rec[8] as usize % 3];
        let id = if rec[8] >= 0xF0 { u32::from(rec[8]) } else { id };
        let n = (rec[9] as usize % 9).min(rec.len() - 10);
        p.on_frame(t, id, ext, &rec[10..10 + n], &mut sink);
        if rec[8] == 0xEE {
            p.on_error_frame(t, 0x40, &mut sink);
        }
    }
    p.finish(&mut sink);
    // The output may not flood: at most 11 frames per input frame plus events.
    assert!(sink.frames <= 20 * (data.len() as u64 / 18 + 1));
});
