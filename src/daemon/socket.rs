//! SocketCAN as a [`Bus`]: the configured input interfaces with kernel filters and
//! receive timestamps, and the output interface.
//!
//! Frames carry their kernel receive time (SO_TIMESTAMPNS), taken onto the monotonic
//! pipeline clock by [`MonoClock`]. When the bus is silent a 10 ms timer lets time
//! pass from the same clock, 20 ms behind. Frames already queued in the sockets are
//! always read before the timer is served: a daemon that was not scheduled for a while
//! (a loaded ECU, SIGSTOP) finds its inputs waiting, stamped when they came, and must
//! not declare them lost first. Interfaces that vanish are reopened with backoff, with
//! the timer running meanwhile; sends never block.

use super::clock::MonoClock;
use super::config::Config;
use super::frame_loop::{Bus, FrameKind, LinkEvent, Received, RxFrame};
use crate::can::{
    CAN_ERR_BUSOFF, CAN_ERR_CRTL, CAN_ERR_CRTL_RX_PASSIVE, CAN_ERR_CRTL_TX_PASSIVE,
    CAN_ERR_RESTARTED,
};
use embedded_can::{ExtendedId, Frame as _, Id, StandardId};
use futures_util::stream::{SelectAll, StreamExt};
use socketcan::tokio::CanSocket;
use socketcan::{CanFilter, CanFrame, SocketOptions};
use std::cell::Cell;
use std::pin::Pin;
use std::rc::Rc;
use std::task::Poll;
use std::time::{Duration, SystemTime};
use tokio::time::Instant;

/// Clock hold-back of the idle timer, s.
const HOLD_BACK_S: f64 = 0.02;
/// Idle timer period.
const TICK: Duration = Duration::from_millis(10);
/// A timer that fires this much after it was due found the process not running
/// (stopped, or not scheduled). The kernel queued the frames meanwhile, but the
/// runtime may not yet have seen the sockets turn readable: before the timer is
/// served, frames get up to `RESUME_GRACE` to show up. 20 ms was once too short on a
/// slow (emulated) machine: every input of `tests/vcan.rs` t9 timed out once more
/// after a SIGSTOP although all their frames were read. The grace costs only a timer
/// that was already late, and only when no frame comes.
const LATE_TICK: Duration = Duration::from_millis(30);
const RESUME_GRACE: Duration = Duration::from_millis(50);
/// Frames read in a row before a due timer goes first: housekeeping (watchdog, status)
/// still runs under a flood of the input IDs.
const MAX_FRAMES_BEFORE_TICK: u32 = 1000;
const FIRST_BACKOFF: Duration = Duration::from_millis(100);
const MAX_BACKOFF: Duration = Duration::from_secs(5);

/// Counters of a live bus.
#[derive(Debug, Default, Clone, Copy)]
pub struct LiveStats {
    pub sent: u64,
    /// Frames not sent, for any reason (no interface, a full queue).
    pub send_dropped: u64,
    /// Of those, the ones the kernel refused with a full queue while the interface
    /// was open: the gaps a receiver sees in the alive counter.
    pub send_queue_full: u64,
    pub reconnects: u64,
    pub bus_off: u64,
    pub error_passive: u64,
    /// Steps of the wall clock taken out of the frame stamps.
    pub wall_clock_steps: u64,
}

/// Live counters shared between the bus and whoever reports them.
pub type SharedStats = Rc<Cell<LiveStats>>;

type FrameStream =
    Pin<Box<dyn futures_util::Stream<Item = (usize, std::io::Result<(CanFrame, SystemTime)>)>>>;

fn open_input(iface: &str, ids: &[(u32, bool)]) -> std::io::Result<CanSocket> {
    let s = CanSocket::open(iface)?;
    let filters: Vec<CanFilter> = ids
        .iter()
        .map(|&(id, ext)| {
            if ext {
                CanFilter::new(
                    id | libc::CAN_EFF_FLAG,
                    libc::CAN_EFF_MASK | libc::CAN_EFF_FLAG | libc::CAN_RTR_FLAG,
                )
            } else {
                CanFilter::new(
                    id,
                    libc::CAN_SFF_MASK | libc::CAN_EFF_FLAG | libc::CAN_RTR_FLAG,
                )
            }
        })
        .collect();
    s.set_filters(&filters)?;
    s.set_error_filter(CAN_ERR_BUSOFF | CAN_ERR_CRTL | CAN_ERR_RESTARTED)?;
    s.set_recv_timestamp(true)?;
    Ok(s)
}

struct Open {
    frames: SelectAll<FrameStream>,
    out: CanSocket,
}

fn open_all(inputs: &[String], output: &str, ids: &[(u32, bool)]) -> std::io::Result<Open> {
    let mut frames = SelectAll::new();
    for (i, iface) in inputs.iter().enumerate() {
        let s = open_input(iface, ids)
            .map_err(|e| std::io::Error::new(e.kind(), format!("{iface}: {e}")))?;
        let st: FrameStream = Box::pin(futures_util::stream::unfold(s, move |s| async move {
            let r = s.read_frame_with_timestamp().await;
            Some(((i, r), s))
        }));
        frames.push(st);
    }
    let out = CanSocket::open(output)
        .map_err(|e| std::io::Error::new(e.kind(), format!("{output}: {e}")))?;
    out.set_filter_drop_all()?;
    Ok(Open { frames, out })
}

/// The configured CAN interfaces.
pub struct LiveBus {
    inputs: Vec<String>,
    output: String,
    ids: [(u32, bool); 3],
    open: Option<Open>,
    clock: MonoClock,
    tick: tokio::time::Interval,
    backoff: Duration,
    retry_at: Instant,
    /// The output socket failed with more than a full queue: reconnect.
    output_failed: bool,
    /// Receive only: LEVELING frames are neither sent nor counted (calibration).
    read_only: bool,
    stats: SharedStats,
    /// Frames returned since the timer was last served.
    frames_since_tick: u32,
    /// The timer fired and is served once no frame is waiting.
    tick_due: bool,
    /// It fired `LATE_TICK` or more after it was due.
    tick_late: bool,
}

impl LiveBus {
    /// A bus on `cfg`'s interfaces, receiving the input `ids`. It opens on the first
    /// [`Bus::recv`]. Must be created inside a tokio runtime.
    pub fn new(cfg: &Config, ids: [(u32, bool); 3], stats: SharedStats) -> Self {
        let mut tick = tokio::time::interval(TICK);
        tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        Self {
            inputs: cfg.can.input_interfaces.clone(),
            output: cfg.can.output_interface.clone(),
            ids,
            open: None,
            clock: MonoClock::new(),
            tick,
            backoff: FIRST_BACKOFF,
            retry_at: Instant::now(),
            output_failed: false,
            read_only: false,
            stats,
            frames_since_tick: 0,
            tick_due: false,
            tick_late: false,
        }
    }

    /// Receive only; LEVELING frames are not sent (calibration).
    pub fn read_only(mut self) -> Self {
        self.read_only = true;
        self
    }

    fn count(&self, f: impl FnOnce(&mut LiveStats)) {
        let mut s = self.stats.get();
        f(&mut s);
        self.stats.set(s);
    }

    fn lost(&mut self, reason: String) -> Received {
        self.open = None;
        self.count(|s| s.reconnects += 1);
        self.retry_at = Instant::now() + self.backoff;
        Received::Link(LinkEvent::Lost(reason))
    }

    fn idle_tick(&mut self) -> Received {
        self.frames_since_tick = 0;
        self.tick_due = false;
        self.tick_late = false;
        let now = self.clock.now_s();
        let steps = self.clock.steps;
        self.count(|s| s.wall_clock_steps = steps);
        Received::Tick(now - HOLD_BACK_S)
    }

    fn frame(&mut self, source: usize, frame: CanFrame, stamp: SystemTime) -> Option<Received> {
        let t_s = self.clock.frame_s(stamp);
        let (kind, id) = match &frame {
            CanFrame::Data(_) => (FrameKind::Data, 0),
            CanFrame::Remote(_) => return None,
            CanFrame::Error(e) => {
                let bits = e.error_bits();
                let d = e.data();
                let passive = bits & CAN_ERR_CRTL != 0
                    && d.len() > 1
                    && d[1] & (CAN_ERR_CRTL_RX_PASSIVE | CAN_ERR_CRTL_TX_PASSIVE) != 0;
                if passive {
                    tracing::warn!("controller error-passive");
                }
                self.count(|s| {
                    s.bus_off += u64::from(bits & CAN_ERR_BUSOFF != 0);
                    s.error_passive += u64::from(passive);
                });
                (FrameKind::Error, bits)
            }
        };
        let (id, extended) = match (kind, frame.id()) {
            (FrameKind::Error, _) => (id, false),
            (_, Id::Standard(i)) => (u32::from(i.as_raw()), false),
            (_, Id::Extended(i)) => (i.as_raw(), true),
        };
        let payload = frame.data();
        let mut data = [0u8; 64];
        data[..payload.len()].copy_from_slice(payload);
        Some(Received::Frame(RxFrame {
            source: source as u32,
            t_s,
            id,
            extended,
            kind,
            len: payload.len() as u8,
            data,
        }))
    }

    /// One item of the input streams: a frame to hand on, a lost link, or `None` for a
    /// frame that is not passed on.
    fn item(
        &mut self,
        item: Option<(usize, std::io::Result<(CanFrame, SystemTime)>)>,
    ) -> Option<Received> {
        match item {
            None => Some(self.lost("no input stream".into())),
            Some((_, Err(e))) => Some(self.lost(format!("read failed: {e}"))),
            Some((source, Ok((frame, stamp)))) => {
                self.frames_since_tick = self.frames_since_tick.saturating_add(1);
                self.frame(source, frame, stamp)
            }
        }
    }

    async fn next(&mut self) -> Received {
        loop {
            if self.output_failed {
                self.output_failed = false;
                return self.lost("output socket failed".into());
            }
            if self.open.is_none() && Instant::now() >= self.retry_at {
                match open_all(&self.inputs, &self.output, &self.ids) {
                    Ok(open) => {
                        self.open = Some(open);
                        self.backoff = FIRST_BACKOFF;
                        return Received::Link(LinkEvent::Open);
                    }
                    Err(e) => {
                        self.retry_at = Instant::now() + self.backoff;
                        self.backoff = (self.backoff * 2).min(MAX_BACKOFF);
                        self.count(|s| s.reconnects += 1);
                        return Received::Link(LinkEvent::Waiting(e.to_string()));
                    }
                }
            }
            if self.frames_since_tick >= MAX_FRAMES_BEFORE_TICK && !self.tick_due {
                // Frames keep coming: look at the timer before the next one.
                let tick = &mut self.tick;
                self.tick_due =
                    std::future::poll_fn(|cx| Poll::Ready(tick.poll_tick(cx).is_ready())).await;
            }
            match self.open.as_mut() {
                Some(open) if self.tick_due => {
                    // The timer fired. Frames that came meanwhile are stamped earlier
                    // than the tick's time and go first, unless a flood of them has
                    // held the timer back long enough.
                    let item = if self.frames_since_tick >= MAX_FRAMES_BEFORE_TICK {
                        None
                    } else {
                        // A late timer waits once: after it, the runtime has looked at
                        // the sockets. An on-time one does not wait at all.
                        let late = std::mem::take(&mut self.tick_late);
                        let grace = async move {
                            if late {
                                tokio::time::sleep(RESUME_GRACE).await;
                            }
                        };
                        tokio::select! {
                            biased;
                            item = open.frames.next() => Some(item),
                            _ = grace => None,
                        }
                    };
                    match item {
                        Some(item) => {
                            if let Some(r) = self.item(item) {
                                return r;
                            }
                        }
                        None => return self.idle_tick(),
                    }
                }
                Some(open) => {
                    let item = tokio::select! {
                        biased;
                        item = open.frames.next() => item,
                        due = self.tick.tick() => {
                            self.tick_due = true;
                            self.tick_late = due.elapsed() >= LATE_TICK;
                            // A process resumed after SIGSTOP (or not scheduled for a
                            // while) can have its timer expire before the runtime has
                            // seen the sockets turn readable: epoll_wait returns EINTR
                            // without events after SIGCONT. Yielding lets the runtime
                            // poll for I/O before the tick is served.
                            tokio::task::yield_now().await;
                            continue;
                        }
                    };
                    if let Some(r) = self.item(item) {
                        return r;
                    }
                }
                None => {
                    tokio::select! {
                        _ = tokio::time::sleep_until(self.retry_at) => {}
                        _ = self.tick.tick() => return self.idle_tick(),
                    }
                }
            }
        }
    }
}

impl Bus for LiveBus {
    async fn recv(&mut self) -> Received {
        self.next().await
    }

    fn send(&mut self, _t_s: f64, id: u32, extended: bool, data: &[u8; 8]) {
        if self.read_only {
            return;
        }
        let Some(open) = self.open.as_ref() else {
            self.count(|s| s.send_dropped += 1);
            return;
        };
        let id = if extended {
            ExtendedId::new(id).map(Id::Extended)
        } else {
            u16::try_from(id)
                .ok()
                .and_then(StandardId::new)
                .map(Id::Standard)
        };
        let Some(frame) = id.and_then(|id| CanFrame::new(id, data)) else {
            return;
        };
        match open.out.try_write_frame(frame) {
            Ok(()) => self.count(|s| s.sent += 1),
            Err(e) => {
                // ENOBUFS / EAGAIN: the queue is full; drop rather than wait.
                if matches!(e.raw_os_error(), Some(libc::ENOBUFS) | Some(libc::EAGAIN)) {
                    self.count(|s| {
                        s.send_dropped += 1;
                        s.send_queue_full += 1;
                    });
                } else {
                    self.count(|s| s.send_dropped += 1);
                    self.output_failed = true;
                }
            }
        }
    }
}
