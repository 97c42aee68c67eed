//! The per-frame path allocates nothing: a counting allocator watches a whole
//! simulated drive go through the pipeline after start-up.

// A counting global allocator is the one place leveld needs unsafe code.
#![allow(unsafe_code)]

use leveld::can::candump::{Line, LogFrame, parse_line};
use leveld::daemon::pipeline::Pipeline;
use leveld::daemon::sink::{Notice, Sink};
use leveld::estimator::Event;
use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

struct Counting;
static COUNTING: AtomicBool = AtomicBool::new(false);
static ALLOCS: AtomicU64 = AtomicU64::new(0);

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        if COUNTING.load(Ordering::Relaxed) {
            ALLOCS.fetch_add(1, Ordering::Relaxed);
        }
        unsafe { System.alloc(l) }
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        unsafe { System.dealloc(p, l) }
    }
    unsafe fn realloc(&self, p: *mut u8, l: Layout, n: usize) -> *mut u8 {
        if COUNTING.load(Ordering::Relaxed) {
            ALLOCS.fetch_add(1, Ordering::Relaxed);
        }
        unsafe { System.realloc(p, l, n) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

struct Counts {
    events: u64,
    frames: u64,
    accepted: u64,
}

impl Sink for Counts {
    fn event(&mut self, e: &Event) {
        self.events += 1;
        if matches!(e, Event::WindowAccepted { .. }) {
            self.accepted += 1;
        }
    }
    fn notice(&mut self, _: &Notice) {}
    fn frame(&mut self, _: f64, _: u32, _: bool, _: &[u8; 8]) {
        self.frames += 1;
    }
}

#[test]
fn whole_drive_through_the_pipeline_without_allocating() {
    let root = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let text = std::fs::read_to_string(root.join("data/sim-multi-stop.log")).unwrap();
    let frames: Vec<LogFrame> = text
        .lines()
        .filter_map(|l| match parse_line(l) {
            Ok(Line::Frame(f)) => Some(f),
            _ => None,
        })
        .collect();
    let (cfg, db, _) = leveld::daemon::load(Some(&root.join("config/leveld.toml"))).unwrap();
    let mut p = Pipeline::new(&cfg, &db).unwrap();
    let mut sink = Counts {
        events: 0,
        frames: 0,
        accepted: 0,
    };
    COUNTING.store(true, Ordering::SeqCst);
    for f in &frames {
        p.on_can_frame(f.t_s, f, &mut sink);
    }
    p.finish(&mut sink);
    // Parsing a log line is on the replay path too.
    for l in text.lines().take(10_000) {
        std::hint::black_box(parse_line(l).ok());
    }
    COUNTING.store(false, Ordering::SeqCst);
    let allocs = ALLOCS.load(Ordering::SeqCst);
    assert!(
        sink.accepted >= 10 && sink.frames > 2000,
        "the drive must exercise every path"
    );
    assert_eq!(allocs, 0, "{allocs} allocations on the per-frame path");
}
