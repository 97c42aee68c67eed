//! `leveld run`: the pipeline on SocketCAN under systemd.
//!
//! Frames carry their kernel receive time (SO_TIMESTAMPNS); that is the pipeline's
//! clock. When the bus is silent a 10 ms timer advances the clock from the same
//! realtime base, 20 ms behind, so that frames already stamped but not yet read are
//! handled first. Interfaces that vanish are reopened with backoff; sends never block.

use super::pipeline::Pipeline;
use super::sink::{Notice, Sink};
use super::state::{self, Loaded, PersistedState};
use super::status::{self, SaveInfo};
use super::{ConfigSource, load};
use crate::can::{
    CAN_ERR_BUSOFF, CAN_ERR_CRTL, CAN_ERR_CRTL_RX_PASSIVE, CAN_ERR_CRTL_TX_PASSIVE,
    CAN_ERR_RESTARTED,
};
use crate::estimator::Event;
use anyhow::{Context, Result};
use embedded_can::{ExtendedId, Frame as _, Id, StandardId};
use futures_util::stream::{SelectAll, StreamExt};
use socketcan::tokio::CanSocket;
use socketcan::{CanFilter, CanFrame, SocketOptions};
use std::path::{Path, PathBuf};
use std::pin::Pin;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

/// Clock hold-back of the idle timer, s.
const HOLD_BACK_S: f64 = 0.02;

/// A jump of the wall clock against the monotonic clock larger than this between two
/// reads is a step, not a slew, s.
const MAX_WALL_STEP_S: f64 = 0.5;

/// Shortest watchdog petting interval: a WATCHDOG_USEC below twice this cannot be
/// served by a frame loop and is served at this rate instead.
const MIN_WATCHDOG_PET: Duration = Duration::from_millis(20);

/// Pipeline time of a live run. Frames carry the kernel's receive time, a wall-clock
/// time, so that a candump recording of the same frames replays to the same output. The
/// wall clock may be stepped at any moment (GNSS or NTP after boot, a user), so the
/// offset between the wall clock and CLOCK_MONOTONIC is read with every frame and
/// tick: a slow slew is followed, and a jump of more than `MAX_WALL_STEP_S` is a step,
/// taken out of every later stamp and tick. A step of the wall clock therefore changes
/// neither the output period nor the estimate.
struct MonoClock {
    start: Instant,
    /// Wall clock minus monotonic clock as last read, s.
    wall_minus_mono_s: f64,
    /// Sum of the wall-clock steps taken out, s.
    offset_s: f64,
    steps: u64,
}

fn wall_s(t: SystemTime) -> f64 {
    match t.duration_since(UNIX_EPOCH) {
        Ok(d) => d.as_secs_f64(),
        Err(e) => -e.duration().as_secs_f64(),
    }
}

impl MonoClock {
    fn new() -> Self {
        let start = Instant::now();
        Self {
            start,
            wall_minus_mono_s: wall_s(SystemTime::now()),
            offset_s: 0.0,
            steps: 0,
        }
    }

    /// Read both clocks; take a jump of their difference out as a step. Returns the
    /// monotonic time, s.
    fn sample(&mut self) -> f64 {
        let mono = self.start.elapsed().as_secs_f64();
        let d = wall_s(SystemTime::now()) - mono;
        let jump = d - self.wall_minus_mono_s;
        if jump.abs() > MAX_WALL_STEP_S {
            self.offset_s -= jump;
            self.steps += 1;
            tracing::warn!(
                step_s = jump,
                "the wall clock stepped; leveld keeps its own time"
            );
        }
        self.wall_minus_mono_s = d;
        mono
    }

    /// Now, in pipeline time.
    fn now_s(&mut self) -> f64 {
        let mono = self.sample();
        mono + self.wall_minus_mono_s + self.offset_s
    }

    /// Pipeline time of a frame stamped `stamp` by the kernel.
    fn frame_s(&mut self, stamp: SystemTime) -> f64 {
        self.sample();
        wall_s(stamp) + self.offset_s
    }
}

/// Petting interval for the watchdog timeout systemd asked for.
fn watchdog_pet(timeout: Option<Duration>) -> Duration {
    match timeout {
        Some(d) if d / 2 >= MIN_WATCHDOG_PET => d / 2,
        Some(d) => {
            tracing::warn!(
                ?d,
                "watchdog timeout too short to serve; petting every {MIN_WATCHDOG_PET:?}"
            );
            MIN_WATCHDOG_PET
        }
        None => Duration::from_secs(3600),
    }
}

/// Counters of the live loop.
#[derive(Debug, Default, Clone, Copy)]
pub struct LiveStats {
    pub sent: u64,
    pub send_dropped: u64,
    pub reconnects: u64,
    pub bus_off: u64,
    pub error_passive: u64,
    /// Steps of the wall clock taken out of the frame stamps.
    pub wall_clock_steps: u64,
}

struct LiveSink<'a> {
    out: Option<&'a CanSocket>,
    stats: &'a mut LiveStats,
    lost_output: bool,
}

impl Sink for LiveSink<'_> {
    fn event(&mut self, e: &Event) {
        match e {
            Event::WindowAccepted { window, estimate } => tracing::info!(
                condition = ?window.condition,
                imu_pitch_deg = window.imu_pitch_deg,
                road_slope_deg = window.road_slope_deg,
                road_to_body_deg = window.road_to_body_deg,
                estimate_deg = estimate.road_to_body_deg,
                std_err_deg = estimate.std_err_deg,
                "window accepted"
            ),
            Event::WindowRejected {
                condition, reason, ..
            } => tracing::info!(?condition, ?reason, "window rejected"),
            Event::LoadChanged { delta_deg, .. } => {
                tracing::info!(delta_deg, "load change at standstill")
            }
            Event::PitchShifted { delta_deg, .. } => {
                tracing::warn!(
                    delta_deg,
                    "windows in a row disagree with the estimate; restarted from them"
                )
            }
            Event::WheelsStopped { .. } => tracing::info!("wheels stopped"),
            Event::LoadChangeSuspected { delta_deg, .. } => {
                tracing::info!(
                    delta_deg,
                    "pitch step since the saved baseline; confirming with the next window"
                )
            }
            Event::WheelsMoving { .. } => tracing::info!("wheels moving"),
            Event::StandstillStarted { imu_pitch_deg, .. } => {
                tracing::info!(imu_pitch_deg, "standstill")
            }
            other => tracing::debug!(?other),
        }
    }
    fn notice(&mut self, n: &Notice) {
        tracing::warn!(?n, "input");
    }
    fn frame(&mut self, _t_s: f64, id: u32, extended: bool, data: &[u8; 8]) {
        let Some(sock) = self.out else {
            self.stats.send_dropped += 1;
            return;
        };
        let id = if extended {
            ExtendedId::new(id).map(Id::Extended)
        } else {
            StandardId::new(id as u16).map(Id::Standard)
        };
        let Some(frame) = id.and_then(|id| CanFrame::new(id, data)) else {
            return;
        };
        match sock.try_write_frame(frame) {
            Ok(()) => self.stats.sent += 1,
            Err(e) => {
                // ENOBUFS / EAGAIN: the queue is full; drop rather than wait.
                self.stats.send_dropped += 1;
                if !matches!(e.raw_os_error(), Some(libc::ENOBUFS) | Some(libc::EAGAIN)) {
                    self.lost_output = true;
                }
            }
        }
    }
}

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

fn open_all(
    cfg: &super::config::Config,
    ids: &[(u32, bool)],
) -> std::io::Result<(SelectAll<FrameStream>, CanSocket)> {
    let mut all = SelectAll::new();
    for (i, iface) in cfg.can.input_interfaces.iter().enumerate() {
        let s = open_input(iface, ids)
            .map_err(|e| std::io::Error::new(e.kind(), format!("{iface}: {e}")))?;
        let st: FrameStream = Box::pin(futures_util::stream::unfold(s, move |s| async move {
            let r = s.read_frame_with_timestamp().await;
            Some(((i, r), s))
        }));
        all.push(st);
    }
    let out = CanSocket::open(&cfg.can.output_interface)
        .map_err(|e| std::io::Error::new(e.kind(), format!("{}: {e}", cfg.can.output_interface)))?;
    out.set_filter_drop_all()?;
    Ok((all, out))
}

/// Restore persisted state into the pipeline; returns the end-of-line reference pitch.
/// The reference survives an estimator part that cannot be used: the calibration is
/// kept in the next save even though the file itself is moved aside.
pub fn restore(p: &mut Pipeline, path: &Path) -> Option<f64> {
    match state::load(path) {
        Loaded::State(st) => {
            if let Some(r) = st.reference_pitch_deg {
                p.set_reference_pitch_deg(r);
            }
            match p.restore(&st.estimator) {
                Ok(()) => {
                    tracing::info!(path = %path.display(), estimate = ?p.estimate(), "state restored")
                }
                Err(e) => {
                    let moved = state::move_aside(path);
                    tracing::warn!(path = %path.display(), moved_to = ?moved, "estimator state not usable ({e}); starting fresh, keeping the reference pitch");
                }
            }
            st.reference_pitch_deg
        }
        Loaded::Missing => {
            tracing::info!(path = %path.display(), "no saved state; first start");
            None
        }
        Loaded::Corrupt { reason, moved_to } => {
            tracing::warn!(path = %path.display(), ?moved_to, "state file unusable ({reason}); moved aside, starting fresh");
            None
        }
    }
}

fn persisted(p: &Pipeline, reference: Option<f64>) -> PersistedState {
    PersistedState {
        format: PersistedState::FORMAT,
        estimator: p.estimator_state(),
        reference_pitch_deg: reference,
    }
}

fn notify(states: &[sd_notify::NotifyState]) {
    if let Err(e) = sd_notify::notify(states) {
        tracing::debug!("sd_notify: {e}");
    }
}

/// `leveld run`.
pub fn run(config: Option<&Path>) -> Result<i32> {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .context("starting the runtime")?;
    rt.block_on(run_async(config))
}

async fn run_async(config: Option<&Path>) -> Result<i32> {
    let (cfg, db, src) = load(config)?;
    if let ConfigSource::BuiltIn = src {
        tracing::warn!(
            "no config given and {} missing: using the built-in default",
            super::SYSTEM_CONFIG
        );
    }
    let mut p = Pipeline::new(&cfg, &db)?;
    let state_path = cfg.state.path.clone();
    let reference = restore(&mut p, &state_path);
    let ids = p.input_ids();
    let mut stats = LiveStats::default();
    let mut sigterm = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate())?;
    let mut sigint = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::interrupt())?;
    let mut tick = tokio::time::interval(Duration::from_millis(10));
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let wd = sd_notify::watchdog_enabled();
    let mut watchdog = tokio::time::interval(watchdog_pet(wd));
    let mut clock = MonoClock::new();
    let mut status_every = tokio::time::interval(Duration::from_secs(5));
    let mut publish_every = tokio::time::interval(Duration::from_secs(1));
    publish_every.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let mut publisher = Publisher {
        path: cfg.state.status_path.clone(),
        state_path: state_path.clone(),
        started_unix_s: status::unix_now_s(),
        last_save: None,
        can: "opening".into(),
        warned: false,
    };
    let mut backoff = Duration::from_millis(100);
    let mut ready_sent = false;
    let mut last_status = None;

    loop {
        let (mut frames, out) = match open_all(&cfg, &ids) {
            Ok(x) => {
                if stats.reconnects > 0 || !ready_sent {
                    tracing::info!(inputs = ?cfg.can.input_interfaces, output = %cfg.can.output_interface, "CAN open");
                }
                backoff = Duration::from_millis(100);
                publisher.can = "open".into();
                x
            }
            Err(e) => {
                tracing::warn!("cannot open CAN ({e}); retrying in {:?}", backoff);
                publisher.can = format!("waiting: {e}");
                if !ready_sent {
                    notify(&[sd_notify::NotifyState::Ready]);
                    ready_sent = true;
                }
                notify(&[sd_notify::NotifyState::Status(&format!(
                    "waiting for CAN: {e}"
                ))]);
                let deadline = tokio::time::sleep(backoff);
                tokio::pin!(deadline);
                loop {
                    tokio::select! {
                        _ = &mut deadline => break,
                        _ = tick.tick() => {
                            let mut sink = LiveSink { out: None, stats: &mut stats, lost_output: false };
                            p.tick(clock.now_s() - HOLD_BACK_S, &mut sink);
                        }
                        _ = watchdog.tick() => if wd.is_some() { notify(&[sd_notify::NotifyState::Watchdog]) },
                        _ = publish_every.tick() => publisher.publish(&p, &stats, reference, true),
                        _ = sigterm.recv() => return shutdown(&p, &state_path, reference, &stats, &mut publisher),
                        _ = sigint.recv() => return shutdown(&p, &state_path, reference, &stats, &mut publisher),
                    }
                }
                backoff = (backoff * 2).min(Duration::from_secs(5));
                stats.reconnects += 1;
                continue;
            }
        };
        if !ready_sent {
            notify(&[sd_notify::NotifyState::Ready]);
            ready_sent = true;
        }
        let reason = loop {
            tokio::select! {
                item = frames.next() => {
                    let Some((source, r)) = item else { break "no input stream".to_string() };
                    match r {
                        Ok((CanFrame::Data(f), ts)) => {
                            let mut sink = LiveSink { out: Some(&out), stats: &mut stats, lost_output: false };
                            let t = clock.frame_s(ts);
                            sink.stats.wall_clock_steps = clock.steps;
                            p.on_can_frame_from(source as u32, t, &f, &mut sink);
                            if sink.lost_output { break "output socket failed".to_string() }
                        }
                        Ok((CanFrame::Remote(_), _)) => {}
                        Ok((CanFrame::Error(e), ts)) => {
                            let bits = e.error_bits();
                            let d = e.data();
                            if bits & CAN_ERR_BUSOFF != 0 {
                                stats.bus_off += 1;
                            }
                            let mut sink = LiveSink { out: Some(&out), stats: &mut stats, lost_output: false };
                            p.on_error_frame(clock.frame_s(ts), bits, &mut sink);
                            if bits & CAN_ERR_CRTL != 0 && d.len() > 1 && d[1] & (CAN_ERR_CRTL_RX_PASSIVE | CAN_ERR_CRTL_TX_PASSIVE) != 0 {
                                stats.error_passive += 1;
                                tracing::warn!("controller error-passive");
                            }
                        }
                        Err(e) => break format!("read failed: {e}"),
                    }
                    if p.take_dirty() {
                        save_state(&p, &state_path, reference, &mut publisher.last_save);
                    }
                }
                _ = tick.tick() => {
                    let now = clock.now_s();
                    stats.wall_clock_steps = clock.steps;
                    let mut sink = LiveSink { out: Some(&out), stats: &mut stats, lost_output: false };
                    p.tick(now - HOLD_BACK_S, &mut sink);
                    if sink.lost_output { break "output socket failed".to_string() }
                }
                _ = watchdog.tick() => if wd.is_some() { notify(&[sd_notify::NotifyState::Watchdog]) },
                _ = status_every.tick() => {
                    let st = p.status();
                    let text = match p.estimate() {
                        Some(e) => format!("{st:?}: road-to-body {:+.2} deg +- {:.2} ({} windows); sent {}, dropped {}", e.road_to_body_deg, e.std_err_deg, e.windows, stats.sent, stats.send_dropped),
                        None => format!("{st:?}: no estimate yet; sent {}, dropped {}", stats.sent, stats.send_dropped),
                    };
                    notify(&[sd_notify::NotifyState::Status(&text)]);
                    if last_status != Some(st) {
                        tracing::info!(status = ?st, "status");
                        last_status = Some(st);
                    }
                }
                _ = publish_every.tick() => publisher.publish(&p, &stats, reference, true),
                _ = sigterm.recv() => return shutdown(&p, &state_path, reference, &stats, &mut publisher),
                _ = sigint.recv() => return shutdown(&p, &state_path, reference, &stats, &mut publisher),
            }
        };
        tracing::warn!("CAN lost ({reason}); reconnecting");
        publisher.can = format!("lost: {reason}");
        notify(&[sd_notify::NotifyState::Status(&format!(
            "CAN lost: {reason}; reconnecting"
        ))]);
        stats.reconnects += 1;
        drop(frames);
        drop(out);
        tokio::time::sleep(backoff).await;
    }
}

/// One JSON line with what was received and sent, for logs and tests.
pub fn stats_json(p: &Pipeline, live: &LiveStats) -> serde_json::Value {
    let names = p.message_names();
    let mut messages = serde_json::Map::new();
    for (slot, name) in names.iter().enumerate() {
        messages.insert(
            name.clone(),
            serde_json::to_value(p.stats(slot)).unwrap_or_default(),
        );
    }
    serde_json::json!({
        "messages": messages,
        "ignored_frames": p.counters().ignored_frames,
        "windows_accepted": p.counters().windows_accepted,
        "windows_rejected": p.counters().windows_rejected,
        "standstills": p.counters().standstills,
        "sent": live.sent,
        "send_dropped": live.send_dropped,
        "reconnects": live.reconnects,
        "bus_off": live.bus_off,
        "wall_clock_steps": live.wall_clock_steps,
        "error_passive": live.error_passive,
        "status": p.status(),
        "road_to_body_deg": p.estimate().map(|e| e.road_to_body_deg),
    })
}

/// Save the state file and remember how it went for the status report.
fn save_state(
    p: &Pipeline,
    path: &Path,
    reference: Option<f64>,
    last: &mut Option<SaveInfo>,
) -> bool {
    let r = state::save(path, &persisted(p, reference));
    if let Err(e) = &r {
        tracing::error!(path = %path.display(), "cannot save state: {e}");
    }
    *last = Some(SaveInfo {
        unix_s: status::unix_now_s(),
        ok: r.is_ok(),
        error: r.err().map(|e| e.to_string()),
    });
    last.as_ref().is_some_and(|s| s.ok)
}

/// What `leveld status` reads, published from the timer.
struct Publisher {
    path: PathBuf,
    state_path: PathBuf,
    started_unix_s: f64,
    last_save: Option<SaveInfo>,
    can: String,
    warned: bool,
}

impl Publisher {
    fn publish(&mut self, p: &Pipeline, live: &LiveStats, reference: Option<f64>, running: bool) {
        if self.path.as_os_str().is_empty() {
            return;
        }
        let cx = status::Context {
            started_unix_s: self.started_unix_s,
            running,
            reference_pitch_deg: reference,
            can: &self.can,
            state_path: &self.state_path,
            last_save: self.last_save.as_ref(),
        };
        let r = status::report(p, live, &cx);
        match status::publish(&self.path, &r) {
            Ok(()) => self.warned = false,
            Err(e) if !self.warned => {
                tracing::warn!(path = %self.path.display(), "cannot publish the status for `leveld status` ({e}); the folder must exist (RuntimeDirectory=leveld)");
                self.warned = true;
            }
            Err(_) => {}
        }
    }
}

fn shutdown(
    p: &Pipeline,
    path: &Path,
    reference: Option<f64>,
    live: &LiveStats,
    publisher: &mut Publisher,
) -> Result<i32> {
    notify(&[sd_notify::NotifyState::Stopping]);
    tracing::info!("final stats {}", stats_json(p, live));
    let ok = save_state(p, path, reference, &mut publisher.last_save);
    publisher.can = "closed: stopped".into();
    publisher.publish(p, live, reference, false);
    if ok {
        tracing::info!(path = %path.display(), status = ?p.status(), "state saved; exiting");
        Ok(0)
    } else {
        tracing::error!(path = %path.display(), "cannot save state at shutdown");
        Ok(1)
    }
}

/// Live end-of-line calibration: read the bus until a standstill has settled.
pub fn calibrate_live(
    cfg: &super::config::Config,
    p: &mut Pipeline,
    duration_s: f64,
) -> Result<super::calibrate::Calibration> {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    rt.block_on(async {
        let ids = p.input_ids();
        let (mut frames, _out) = open_all(cfg, &ids).context("opening CAN for calibration")?;
        let mut stats = LiveStats::default();
        let mut clock = MonoClock::new();
        let limit = tokio::time::sleep(Duration::from_secs_f64(duration_s + 30.0));
        tokio::pin!(limit);
        let mut best = None;
        loop {
            tokio::select! {
                item = frames.next() => {
                    let Some((source, r)) = item else { anyhow::bail!("CAN input ended") };
                    if let Ok((CanFrame::Data(f), ts)) = r {
                        let mut sink = LiveSink { out: None, stats: &mut stats, lost_output: false };
                        p.on_can_frame_from(source as u32, clock.frame_s(ts), &f, &mut sink);
                        if let Some((pitch, settled)) = p.standstill_pitch() {
                            best = Some(settled);
                            if settled >= duration_s {
                                return Ok(super::calibrate::Calibration { reference_pitch_deg: pitch, settled_s: settled });
                            }
                        }
                    }
                }
                _ = &mut limit => anyhow::bail!(
                    "no settled standstill of {duration_s:.1} s within {:.0} s (best {:.1} s): keep the vehicle still with the wheels stopped",
                    duration_s + 30.0, best.unwrap_or(0.0)
                ),
            }
        }
    })
}
