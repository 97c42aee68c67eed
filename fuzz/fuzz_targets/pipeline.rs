//! Arbitrary frames, error frames and idle ticks with arbitrary timestamps through the
//! frame loop every command shares and the reference pipeline: no panic, no hang, and
//! time never runs backwards in what it sends.
#![no_main]
use leveld::daemon::frame_loop::{self, FrameKind, MemoryBus, Observer, Received, RxFrame};
use leveld::daemon::pipeline::Pipeline;
use libfuzzer_sys::fuzz_target;
use std::ops::ControlFlow;

struct Quiet;
impl Observer for Quiet {
    fn after(&mut self, _: &mut Pipeline, _: &Received) -> ControlFlow<()> {
        ControlFlow::Continue(())
    }
}

fuzz_target!(|data: &[u8]| {
    let (cfg, db, _) = leveld::daemon::load(None).unwrap();
    let mut p = Pipeline::new(&cfg, &db).unwrap();
    let ids = p.input_ids();
    // Each record: 8 bytes of timestamp, 1 selector, 1 length, up to 8 of payload.
    let mut frames = Vec::new();
    for rec in data.chunks(18) {
        if rec.len() < 10 {
            break;
        }
        let t = f64::from_le_bytes(rec[..8].try_into().unwrap());
        let (id, ext) = ids[rec[8] as usize % 3];
        let id = if rec[8] >= 0xF0 { u32::from(rec[8]) } else { id };
        let n = (rec[9] as usize % 9).min(rec.len() - 10);
        let mut f = RxFrame::data(t, id, ext, &rec[10..10 + n]);
        f.source = u32::from(rec[9] >> 6);
        f.kind = match rec[8] {
            0xEE => FrameKind::Error,
            0xED => FrameKind::Other,
            _ => FrameKind::Data,
        };
        if f.kind == FrameKind::Error {
            f.id = 0x40 | 0x100 * u32::from(rec[9] & 1);
        }
        frames.push(f);
    }
    let n_in = frames.len() as u64;
    let finite = || frames.iter().map(|f| f.t_s).filter(|t| t.is_finite());
    let (lo, hi) = (finite().fold(f64::MAX, f64::min), finite().fold(f64::MIN, f64::max));
    // Idle ticks every 50 ms when the stamps span at most a minute (so a run stays short).
    let span_s = if hi >= lo && hi - lo <= 60.0 { hi - lo } else { 0.0 };
    let ticked = span_s > 0.0;
    let mut bus = MemoryBus::new(frames);
    if ticked {
        bus = bus.with_ticks(0.05, hi);
    }
    frame_loop::block_on(frame_loop::run(&mut p, &mut bus, &mut Quiet, std::future::pending()));
    let mut prev = f64::NEG_INFINITY;
    for s in &bus.sent {
        assert!(s.0.is_finite() && s.0 >= prev, "{} after {prev}", s.0);
        prev = s.0;
    }
    // The output may not flood: a few frames per input frame or tick.
    let ticks = if ticked { (span_s / 0.05) as u64 + 1 } else { 0 };
    assert!(bus.sent.len() as u64 <= 20 * (n_in + ticks + 1));
});
