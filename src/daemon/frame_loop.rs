//! The one frame loop of leveld. Every command that runs the pipeline (`run`,
//! `replay`, `calibrate`) is a thin caller of [`run`]: a [`Bus`] gives timestamped
//! frames and takes LEVELING frames, an [`Observer`] sees what the pipeline reports
//! and decides when to stop, and a shutdown future ends the loop from outside.
//!
//! Buses: SocketCAN (`socket::LiveBus`), a candump log or stdin (`sources::LogBus`)
//! and an in-memory list ([`MemoryBus`], for tests and tools).

use super::pipeline::Pipeline;
use super::sink::{Notice, Sink};
use crate::can::candump::ParseError;
use crate::estimator::Event;
use std::future::Future;
use std::ops::ControlFlow;

/// What a frame is, as far as the pipeline cares.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FrameKind {
    /// A classic data frame: one of the inputs, or counted as ignored.
    Data,
    /// Remote, CAN FD or from an interface the bus does not tell apart: time passes,
    /// the frame is counted as ignored.
    Other,
    /// An error frame; `id` holds the error class bits (linux/can/error.h).
    Error,
}

/// One received frame.
#[derive(Debug, Clone, Copy)]
pub struct RxFrame {
    /// Interface number, in the order the bus first saw them.
    pub source: u32,
    /// Receive time on the frame clock, s.
    pub t_s: f64,
    pub id: u32,
    pub extended: bool,
    pub kind: FrameKind,
    pub len: u8,
    pub data: [u8; 64],
}

impl RxFrame {
    /// A classic data frame from interface 0.
    pub fn data(t_s: f64, id: u32, extended: bool, payload: &[u8]) -> Self {
        let len = payload.len().min(64);
        let mut data = [0u8; 64];
        data[..len].copy_from_slice(&payload[..len]);
        Self {
            source: 0,
            t_s,
            id,
            extended,
            kind: FrameKind::Data,
            len: len as u8,
            data,
        }
    }

    pub fn payload(&self) -> &[u8] {
        &self.data[..self.len as usize]
    }
}

/// A change of the link to the bus (live buses only).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum LinkEvent {
    Open,
    /// The interfaces cannot be opened; retrying.
    Waiting(String),
    /// The interfaces were lost; reconnecting.
    Lost(String),
}

/// What a bus hands to the loop.
#[derive(Debug, Clone)]
pub enum Received {
    Frame(RxFrame),
    /// Time passed without a frame (a live bus's idle timer), frame clock, s.
    Tick(f64),
    /// A log line that is not a frame, with its number.
    Malformed {
        line: u64,
        error: ParseError,
    },
    Link(LinkEvent),
    /// No more input.
    End,
}

/// Where frames come from and LEVELING frames go.
pub trait Bus {
    /// The next input. A bus that never waits (a log, a list) returns a ready future.
    fn recv(&mut self) -> impl Future<Output = Received>;
    /// Send one LEVELING frame due at `t_s` (frame clock). Never blocks: a bus that
    /// cannot send counts a drop.
    fn send(&mut self, t_s: f64, id: u32, extended: bool, data: &[u8; 8]);
}

/// What a caller does with the loop's output.
pub trait Observer {
    fn event(&mut self, _e: &Event) {}
    fn notice(&mut self, _n: &Notice) {}
    /// After each input has gone through the pipeline; `Break` ends the loop.
    fn after(&mut self, p: &mut Pipeline, r: &Received) -> ControlFlow<()>;
}

/// Why the loop ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Ended {
    /// The bus had no more input.
    Input,
    /// The shutdown future completed.
    Shutdown,
    /// The observer asked to stop.
    Observer,
}

struct LoopSink<'a, B, O> {
    bus: &'a mut B,
    obs: &'a mut O,
}

impl<B: Bus, O: Observer> Sink for LoopSink<'_, B, O> {
    fn event(&mut self, e: &Event) {
        self.obs.event(e);
    }
    fn notice(&mut self, n: &Notice) {
        self.obs.notice(n);
    }
    fn frame(&mut self, t_s: f64, id: u32, extended: bool, data: &[u8; 8]) {
        self.bus.send(t_s, id, extended, data);
    }
}

/// Feed one input to the pipeline.
pub fn dispatch(p: &mut Pipeline, r: &Received, sink: &mut dyn Sink) {
    match r {
        Received::Frame(f) => match f.kind {
            FrameKind::Data => {
                p.on_frame_from(f.source, f.t_s, f.id, f.extended, f.payload(), sink)
            }
            FrameKind::Other => p.on_other_frame(f.t_s, sink),
            FrameKind::Error => p.on_error_frame(f.t_s, f.id, sink),
        },
        Received::Tick(t_s) => p.tick(*t_s, sink),
        Received::Malformed { .. } | Received::Link(_) | Received::End => {}
    }
}

/// Run the pipeline over `bus` until the input ends, `shutdown` completes or the
/// observer stops it. At the end of input the pipeline evaluates what is pending.
pub async fn run<B: Bus, O: Observer>(
    p: &mut Pipeline,
    bus: &mut B,
    obs: &mut O,
    shutdown: impl Future<Output = ()>,
) -> Ended {
    let mut shutdown = std::pin::pin!(shutdown);
    loop {
        let r = tokio::select! {
            biased;
            _ = &mut shutdown => return Ended::Shutdown,
            r = bus.recv() => r,
        };
        let mut sink = LoopSink {
            bus: &mut *bus,
            obs: &mut *obs,
        };
        if let Received::End = r {
            p.finish(&mut sink);
            let _ = obs.after(p, &r);
            return Ended::Input;
        }
        dispatch(p, &r, &mut sink);
        if obs.after(p, &r).is_break() {
            return Ended::Observer;
        }
    }
}

/// Drive a future whose bus never waits (a log or a list) to completion on this
/// thread, without a runtime.
pub fn block_on<F: Future>(f: F) -> F::Output {
    let mut f = std::pin::pin!(f);
    let mut cx = std::task::Context::from_waker(std::task::Waker::noop());
    loop {
        if let std::task::Poll::Ready(v) = f.as_mut().poll(&mut cx) {
            return v;
        }
        std::thread::yield_now();
    }
}

/// A bus over a list of frames, in memory. Between frames it lets time pass in
/// ticks of `tick_s` (as a live bus's idle timer does), and after the last frame
/// until `end_s`; what is sent is kept.
#[derive(Debug, Default)]
pub struct MemoryBus {
    frames: Vec<RxFrame>,
    next: usize,
    tick_s: Option<f64>,
    end_s: f64,
    clock_s: Option<f64>,
    /// Fired when the list is exhausted; the bus then waits instead of ending.
    at_end: Option<tokio::sync::oneshot::Sender<()>>,
    /// LEVELING frames sent: time, ID, extended, payload.
    pub sent: Vec<(f64, u32, bool, [u8; 8])>,
}

impl MemoryBus {
    pub fn new(frames: Vec<RxFrame>) -> Self {
        let end_s = frames.last().map_or(0.0, |f| f.t_s);
        Self {
            frames,
            end_s,
            ..Self::default()
        }
    }

    /// Let time pass in steps of `tick_s` between frames and on to `end_s`.
    pub fn with_ticks(mut self, tick_s: f64, end_s: f64) -> Self {
        if tick_s > 0.0 {
            self.tick_s = Some(tick_s);
        }
        self.end_s = end_s;
        self
    }

    /// When the list is exhausted, fire `tx` and wait (as a live bus would) instead
    /// of ending the input: the caller's shutdown future ends the loop.
    pub fn then_notify(mut self, tx: tokio::sync::oneshot::Sender<()>) -> Self {
        self.at_end = Some(tx);
        self
    }
}

impl Bus for MemoryBus {
    async fn recv(&mut self) -> Received {
        let due = self.frames.get(self.next).map_or(self.end_s, |f| f.t_s);
        if let (Some(tick), Some(now)) = (self.tick_s, self.clock_s)
            && now + tick > now
            && now + tick < due
        {
            self.clock_s = Some(now + tick);
            return Received::Tick(now + tick);
        }
        match self.frames.get(self.next) {
            Some(f) => {
                self.next += 1;
                self.clock_s = Some(f.t_s);
                Received::Frame(*f)
            }
            None => match self.at_end.take() {
                Some(tx) => {
                    let _ = tx.send(());
                    std::future::pending().await
                }
                None => Received::End,
            },
        }
    }

    fn send(&mut self, t_s: f64, id: u32, extended: bool, data: &[u8; 8]) {
        self.sent.push((t_s, id, extended, *data));
    }
}
