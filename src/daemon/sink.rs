//! What the pipeline hands out: estimator events, notices about its inputs and
//! clock, and LEVELING frames, through a [`Sink`] the caller provides.

use crate::estimator::Event;
use serde::Serialize;

/// What the pipeline reports besides estimator events.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(tag = "notice", rename_all = "snake_case")]
pub enum Notice {
    InputLost {
        t_s: f64,
        message: &'static str,
    },
    InputRestored {
        t_s: f64,
        message: &'static str,
    },
    MessageInvalid {
        t_s: f64,
        message: &'static str,
        reason: &'static str,
    },
    /// A frame timestamp jumped by `step_s` (forward past the allowed gap, or back):
    /// time goes on from `t_s`; the open standstill and the input timeouts restart.
    ClockStep {
        t_s: f64,
        step_s: f64,
    },
    /// Bus-off: FAULT until the controller reports its restart.
    BusOff {
        t_s: f64,
    },
    BusRestarted {
        t_s: f64,
    },
    /// Events of one frame beyond what the pipeline buffers; they were not reported.
    EventsDropped {
        t_s: f64,
        count: u32,
    },
}

/// Receiver of what the pipeline produces.
pub trait Sink {
    fn event(&mut self, e: &Event);
    fn notice(&mut self, n: &Notice);
    /// A LEVELING frame due at `t_s` (frame clock).
    fn frame(&mut self, t_s: f64, id: u32, extended: bool, data: &[u8; 8]);
}

/// A sink that keeps nothing (tools, fuzzing).
pub struct NullSink;

impl Sink for NullSink {
    fn event(&mut self, _: &Event) {}
    fn notice(&mut self, _: &Notice) {}
    fn frame(&mut self, _: f64, _: u32, _: bool, _: &[u8; 8]) {}
}

/// The events of one frame without allocating (one frame gives at most a few); any
/// beyond its capacity are counted and reported as a notice.
#[derive(Default)]
pub(crate) struct EventBuf {
    ev: [Option<Event>; 16],
    n: usize,
    pub(crate) dropped: u32,
}

impl EventBuf {
    pub(crate) fn push(&mut self, e: Event) {
        if self.n < self.ev.len() {
            self.ev[self.n] = Some(e);
            self.n += 1;
        } else {
            self.dropped = self.dropped.saturating_add(1);
        }
    }
    pub(crate) fn iter(&self) -> impl Iterator<Item = &Event> {
        self.ev[..self.n].iter().flatten()
    }
}
