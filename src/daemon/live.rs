//! `leveld run`: the pipeline as a systemd service.
//!
//! [`serve`] is the daemon with its IO passed in: a [`Bus`] (SocketCAN in
//! production, a list of frames in tests) and a shutdown future (SIGTERM/SIGINT in
//! production). It restores the saved state, runs the frame loop, saves the state
//! off the loop after every change, publishes what `leveld status` reads, serves the
//! systemd notify protocol, and saves once more on shutdown.

use super::calibration::{self, Calibration};
use super::config::Config;
use super::frame_loop::{self, Bus, Ended, LinkEvent, Observer, Received};
use super::pipeline::Pipeline;
use super::saver::{Saver, save_now};
use super::sink::Notice;
use super::socket::{LiveBus, LiveStats, SharedStats};
use super::state::{self, Loaded, PersistedState};
use super::status::{self, SaveInfo};
use super::{ConfigSource, load};
use crate::can::codec::Status;
use crate::estimator::Event;
use anyhow::{Context, Result};
use std::ops::ControlFlow;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// Shortest watchdog petting interval: a WATCHDOG_USEC below twice this cannot be
/// served by a frame loop and is served at this rate instead.
const MIN_WATCHDOG_PET: Duration = Duration::from_millis(20);
/// How often the status file for `leveld status` is rewritten.
const PUBLISH_EVERY: Duration = Duration::from_secs(1);
/// How often systemd's STATUS= line is refreshed.
const NOTIFY_STATUS_EVERY: Duration = Duration::from_secs(5);

/// Petting interval for the watchdog timeout systemd asked for.
fn watchdog_pet(timeout: Option<Duration>) -> Option<Duration> {
    match timeout {
        Some(d) if d / 2 >= MIN_WATCHDOG_PET => Some(d / 2),
        Some(d) => {
            tracing::warn!(
                ?d,
                "watchdog timeout too short to serve; petting every {MIN_WATCHDOG_PET:?}"
            );
            Some(MIN_WATCHDOG_PET)
        }
        None => None,
    }
}

/// Restore persisted state into the pipeline. Returns the reference pitch an earlier
/// leveld kept in the state file, if any: it survives an estimator part that cannot be
/// used, and is carried in the next saves until `leveld calibrate` writes the
/// calibration file.
pub fn restore(p: &mut Pipeline, path: &Path) -> Option<f64> {
    match state::load(path) {
        Loaded::State(st) => {
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
    rt.block_on(async {
        let (cfg, db, src) = load(config)?;
        if let ConfigSource::BuiltIn = src {
            tracing::warn!(
                "no config given and {} missing: using the built-in default",
                super::SYSTEM_CONFIG
            );
        }
        let mut p = Pipeline::new(&cfg, &db)?;
        let stats = SharedStats::default();
        let mut bus = LiveBus::new(&cfg, p.input_ids(), stats.clone());
        use tokio::signal::unix::{SignalKind, signal};
        let mut sigterm = signal(SignalKind::terminate())?;
        let mut sigint = signal(SignalKind::interrupt())?;
        let stop = async move {
            tokio::select! {
                _ = sigterm.recv() => {}
                _ = sigint.recv() => {}
            }
        };
        serve(&cfg, &mut p, &mut bus, stats, stop).await
    })
}

/// The daemon over `bus` until `shutdown` completes (or the bus ends): state restored
/// from and saved to `cfg.state.path`, status published to `cfg.state.status_path`.
/// Returns the exit code: 0, or 1 when the state could not be saved at shutdown.
pub async fn serve<B: Bus>(
    cfg: &Config,
    p: &mut Pipeline,
    bus: &mut B,
    stats: SharedStats,
    shutdown: impl std::future::Future<Output = ()>,
) -> Result<i32> {
    let legacy = restore(p, &cfg.state.path);
    let calibration = match (calibration::load(&cfg.state.calibration_path), legacy) {
        (Calibration::Missing, Some(r)) => Calibration::Calibrated {
            reference_pitch_deg: r,
            reference_roll_deg: None,
            legacy: true,
        },
        (c, _) => c,
    };
    match &calibration {
        Calibration::Calibrated { .. } => {
            tracing::info!(reference_pitch_deg = ?calibration.reference_pitch_deg(), "calibration: {}", calibration.describe())
        }
        Calibration::Missing => tracing::warn!(
            path = %cfg.state.calibration_path.display(),
            "no end-of-line calibration: using the configured reference pitch {:+.3} deg, LEVELING flags it uncalibrated",
            cfg.leveling.reference_pitch_deg
        ),
        Calibration::Unreadable(why) => tracing::error!(
            "end-of-line calibration unreadable ({why}): FAULT until `leveld calibrate` writes a new one"
        ),
    }
    p.set_calibration(&calibration);
    let mut d = Daemon::new(cfg, calibration, legacy, stats);
    let ended = frame_loop::run(p, bus, &mut d, shutdown).await;
    if ended == Ended::Input {
        tracing::warn!("the input ended; stopping");
    }
    Ok(d.shutdown(p))
}

/// The daemon's side of the frame loop.
struct Daemon {
    state_path: PathBuf,
    calibration: Calibration,
    /// A reference pitch from an earlier leveld's state file, carried in every save.
    reference: Option<f64>,
    saver: Saver,
    publisher: Publisher,
    stats: SharedStats,
    ready_sent: bool,
    watchdog: Option<Duration>,
    last_pet: Instant,
    last_publish: Instant,
    last_notify: Instant,
    last_status: Option<Status>,
}

impl Daemon {
    fn new(
        cfg: &Config,
        calibration: Calibration,
        reference: Option<f64>,
        stats: SharedStats,
    ) -> Self {
        let now = Instant::now();
        Self {
            state_path: cfg.state.path.clone(),
            calibration,
            reference,
            saver: Saver::start(cfg.state.path.clone()),
            publisher: Publisher {
                path: cfg.state.status_path.clone(),
                state_path: cfg.state.path.clone(),
                started_unix_s: status::unix_now_s(),
                can: "opening".into(),
                warned: false,
            },
            stats,
            ready_sent: false,
            watchdog: watchdog_pet(sd_notify::watchdog_enabled()),
            last_pet: now,
            last_publish: now,
            last_notify: now,
            last_status: None,
        }
    }

    fn ready(&mut self) {
        if !self.ready_sent {
            notify(&[sd_notify::NotifyState::Ready]);
            self.ready_sent = true;
        }
    }

    fn link(&mut self, ev: &LinkEvent) {
        match ev {
            LinkEvent::Open => {
                tracing::info!("CAN open");
                self.publisher.can = "open".into();
                self.ready();
            }
            LinkEvent::Waiting(e) => {
                tracing::warn!("cannot open CAN ({e}); retrying");
                self.publisher.can = format!("waiting: {e}");
                self.ready();
                notify(&[sd_notify::NotifyState::Status(&format!(
                    "waiting for CAN: {e}"
                ))]);
            }
            LinkEvent::Lost(reason) => {
                tracing::warn!("CAN lost ({reason}); reconnecting");
                self.publisher.can = format!("lost: {reason}");
                notify(&[sd_notify::NotifyState::Status(&format!(
                    "CAN lost: {reason}; reconnecting"
                ))]);
            }
        }
    }

    /// Watchdog, STATUS= and the status file, on the idle timer.
    fn housekeeping(&mut self, p: &Pipeline) {
        let now = Instant::now();
        if let Some(pet) = self.watchdog
            && now - self.last_pet >= pet
        {
            notify(&[sd_notify::NotifyState::Watchdog]);
            self.last_pet = now;
        }
        if now - self.last_publish >= PUBLISH_EVERY {
            self.last_publish = now;
            let live = self.stats.get();
            let last = self.saver.last();
            self.publisher
                .publish(p, &live, &self.calibration, last.as_ref(), true);
        }
        if now - self.last_notify >= NOTIFY_STATUS_EVERY {
            self.last_notify = now;
            let live = self.stats.get();
            let st = p.status();
            let text = match p.estimate() {
                Some(e) => format!(
                    "{st:?}: road-to-body {:+.2} deg +- {:.2} ({} windows); sent {}, dropped {}",
                    e.road_to_body_deg, e.std_err_deg, e.windows, live.sent, live.send_dropped
                ),
                None => format!(
                    "{st:?}: no estimate yet; sent {}, dropped {}",
                    live.sent, live.send_dropped
                ),
            };
            notify(&[sd_notify::NotifyState::Status(&text)]);
            if self.last_status != Some(st) {
                tracing::info!(status = ?st, "status");
                self.last_status = Some(st);
            }
        }
    }

    fn shutdown(self, p: &Pipeline) -> i32 {
        notify(&[sd_notify::NotifyState::Stopping]);
        let live = self.stats.get();
        tracing::info!("final stats {}", stats_json(p, &live));
        self.saver.finish();
        let saved = save_now(&self.state_path, &persisted(p, self.reference));
        let mut publisher = self.publisher;
        publisher.can = "closed: stopped".into();
        publisher.publish(p, &live, &self.calibration, Some(&saved), false);
        if saved.ok {
            tracing::info!(path = %self.state_path.display(), status = ?p.status(), "state saved; exiting");
            0
        } else {
            tracing::error!(path = %self.state_path.display(), "cannot save state at shutdown");
            1
        }
    }
}

impl Observer for Daemon {
    fn event(&mut self, e: &Event) {
        log_event(e);
    }

    fn notice(&mut self, n: &Notice) {
        tracing::warn!(?n, "input");
    }

    fn after(&mut self, p: &mut Pipeline, r: &Received) -> ControlFlow<()> {
        match r {
            Received::Link(ev) => self.link(ev),
            Received::Tick(_) => self.housekeeping(p),
            _ => {}
        }
        if p.take_dirty() {
            self.saver
                .request(persisted(p, self.reference), &self.state_path);
        }
        ControlFlow::Continue(())
    }
}

fn log_event(e: &Event) {
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
        Event::WindowsRebiased {
            acc_bias_x_mps2,
            delta_deg,
            ..
        } => tracing::debug!(
            acc_bias_x_mps2,
            delta_deg,
            "windows read with the accelerometer bias the stops learnt"
        ),
        Event::WindowWithdrawn {
            road_to_body_deg,
            imu_mps,
            wheel_mps,
            ..
        } => tracing::warn!(
            road_to_body_deg,
            imu_mps,
            wheel_mps,
            "the stop was not at rest (speed after drive-off); its window withdrawn"
        ),
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
    let c = p.counters();
    serde_json::json!({
        "messages": messages,
        "ignored_frames": c.ignored_frames,
        "windows_accepted": c.windows_accepted,
        "windows_rejected": c.windows_rejected,
        "windows_withdrawn": c.windows_withdrawn,
        "standstills": c.standstills,
        "sent": live.sent,
        "send_dropped": live.send_dropped,
        "send_queue_full": live.send_queue_full,
        "reconnects": live.reconnects,
        "bus_off": live.bus_off,
        "wall_clock_steps": live.wall_clock_steps,
        "error_passive": live.error_passive,
        "status": p.status(),
        "road_to_body_deg": p.estimate().map(|e| e.road_to_body_deg),
    })
}

/// What `leveld status` reads.
struct Publisher {
    path: PathBuf,
    state_path: PathBuf,
    started_unix_s: f64,
    can: String,
    warned: bool,
}

impl Publisher {
    fn publish(
        &mut self,
        p: &Pipeline,
        live: &LiveStats,
        calibration: &Calibration,
        last_save: Option<&SaveInfo>,
        running: bool,
    ) {
        if self.path.as_os_str().is_empty() {
            return;
        }
        let cx = status::Context {
            started_unix_s: self.started_unix_s,
            running,
            calibration,
            can: &self.can,
            state_path: &self.state_path,
            last_save,
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

/// Live end-of-line calibration: read the bus until a standstill has settled.
pub fn calibrate_live(
    cfg: &Config,
    p: &mut Pipeline,
    duration_s: f64,
) -> Result<super::calibrate::Calibration> {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    rt.block_on(async {
        let limit_s = duration_s + 30.0;
        let mut bus = LiveBus::new(cfg, p.input_ids(), SharedStats::default()).read_only();
        let mut settle = super::calibrate::Settle::new(duration_s);
        let limit = tokio::time::sleep(Duration::from_secs_f64(limit_s));
        frame_loop::run(p, &mut bus, &mut settle, limit).await;
        if let Some(e) = settle.link_error {
            anyhow::bail!("opening CAN for calibration: {e}");
        }
        settle.done().ok_or_else(|| {
            anyhow::anyhow!(
                "no settled standstill of {duration_s:.1} s within {limit_s:.0} s (best {:.1} s): keep the vehicle still with the wheels stopped",
                settle.best.map_or(0.0, |c| c.settled_s)
            )
        })
    })
}
