//! What the running daemon publishes about itself for `leveld status`: a small JSON
//! file (by default `/run/leveld/status.json`, the unit's RuntimeDirectory), replaced
//! atomically once a second and at shutdown. It is written from the timer, never
//! from the frame path.

use super::calibration::Calibration;
use super::inputs::MsgStats;
use super::pipeline::Pipeline;
use super::socket::LiveStats;
use crate::can::codec::Status;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Health of one input message.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct InputHealth {
    pub message: String,
    /// `ok`, `lost` (timed out) or `invalid` (failing counter or checksum checks).
    pub state: String,
    pub frames: u64,
    pub checksum_errors: u64,
    pub counter_errors: u64,
    pub dlc_errors: u64,
    pub timeouts: u64,
}

/// The last attempt to save the state file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SaveInfo {
    /// Wall-clock time of the attempt, seconds since the Unix epoch.
    pub unix_s: f64,
    pub ok: bool,
    /// Why it failed, when it did.
    pub error: Option<String>,
}

/// What `leveld status` reads.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StatusReport {
    pub pid: u32,
    /// False in the last report, written at shutdown.
    pub running: bool,
    /// Wall-clock time of this report, seconds since the Unix epoch.
    pub updated_unix_s: f64,
    pub started_unix_s: f64,
    pub status: Status,
    pub road_to_body_deg: Option<f64>,
    pub std_err_deg: Option<f64>,
    /// Windows accepted under the current load.
    pub windows: Option<u64>,
    /// End-of-line reference pitch from `leveld calibrate`, deg (None: the config's).
    pub reference_pitch_deg: Option<f64>,
    /// The reference `LevelCorrection` is measured from, deg: the calibrated one less
    /// the accelerometer bias learnt since (see `Pipeline::level_reference_deg`), or
    /// the config's.
    #[serde(default)]
    pub level_reference_deg: Option<f64>,
    /// "ok", or why no calibration is in use.
    #[serde(default)]
    pub calibration: String,
    pub inputs: Vec<InputHealth>,
    /// CAN: "open", or why it is not.
    pub can: String,
    pub state_path: String,
    pub last_save: Option<SaveInfo>,
    pub frames_sent: u64,
    pub send_dropped: u64,
    /// Of `send_dropped`, the frames refused by a full send queue.
    #[serde(default)]
    pub send_queue_full: u64,
    pub reconnects: u64,
    pub bus_off: u64,
    pub wall_clock_steps: u64,
    pub windows_accepted: u64,
    pub windows_rejected: u64,
    #[serde(default)]
    pub windows_withdrawn: u64,
    pub standstills: u64,
    /// What the estimator learnt of the suspension (absent in reports of older versions).
    #[serde(default)]
    pub suspension: Option<crate::daemon::pipeline::Suspension>,
}

/// Seconds since the Unix epoch on the wall clock (for people reading the report).
pub fn unix_now_s() -> f64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0.0, |d| d.as_secs_f64())
}

/// Everything the report holds besides the pipeline and the live counters.
pub struct Context<'a> {
    pub started_unix_s: f64,
    pub running: bool,
    pub calibration: &'a Calibration,
    pub can: &'a str,
    pub state_path: &'a Path,
    pub last_save: Option<&'a SaveInfo>,
}

pub fn report(p: &Pipeline, live: &LiveStats, cx: &Context) -> StatusReport {
    let est = p.estimate();
    let inputs = p
        .message_names()
        .iter()
        .enumerate()
        .map(|(slot, name)| {
            let MsgStats {
                frames,
                checksum_errors,
                counter_errors,
                dlc_errors,
                timeouts,
                ..
            } = p.stats(slot);
            InputHealth {
                message: name.clone(),
                state: p.input_state(slot).to_string(),
                frames,
                checksum_errors,
                counter_errors,
                dlc_errors,
                timeouts,
            }
        })
        .collect();
    StatusReport {
        pid: std::process::id(),
        running: cx.running,
        updated_unix_s: unix_now_s(),
        started_unix_s: cx.started_unix_s,
        status: p.status(),
        road_to_body_deg: est.map(|e| e.road_to_body_deg),
        std_err_deg: est.map(|e| e.std_err_deg),
        windows: est.map(|e| e.windows),
        reference_pitch_deg: cx.calibration.reference_pitch_deg(),
        level_reference_deg: Some(p.level_reference_deg()),
        calibration: cx.calibration.describe(),
        inputs,
        can: cx.can.to_string(),
        state_path: cx.state_path.display().to_string(),
        last_save: cx.last_save.cloned(),
        frames_sent: live.sent,
        send_dropped: live.send_dropped,
        send_queue_full: live.send_queue_full,
        reconnects: live.reconnects,
        bus_off: live.bus_off,
        wall_clock_steps: live.wall_clock_steps,
        windows_accepted: p.counters().windows_accepted,
        windows_rejected: p.counters().windows_rejected,
        windows_withdrawn: p.counters().windows_withdrawn,
        standstills: p.counters().standstills,
        suspension: Some(p.suspension()),
    }
}

/// Replace the status file atomically (write a sibling, rename over). The folder must
/// exist: under systemd it is the unit's RuntimeDirectory.
pub fn publish(path: &Path, r: &StatusReport) -> std::io::Result<()> {
    let mut tmp_name = path.file_name().unwrap_or_default().to_os_string();
    tmp_name.push(".tmp");
    let tmp = path.with_file_name(tmp_name);
    let text = serde_json::to_vec_pretty(r).map_err(std::io::Error::other)?;
    std::fs::write(&tmp, text)?;
    // Readable by `leveld status` run by any user (the unit's UMask would hide it).
    std::fs::set_permissions(&tmp, std::os::unix::fs::PermissionsExt::from_mode(0o644))?;
    std::fs::rename(&tmp, path)
}

/// Read a published report. A file that is not a report is an error that names it.
pub fn read(path: &Path) -> Result<Option<StatusReport>, String> {
    let bytes = match std::fs::read(path) {
        Ok(b) => b,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        Err(e) => return Err(format!("cannot read {}: {e}", path.display())),
    };
    serde_json::from_slice(&bytes)
        .map(Some)
        .map_err(|e| format!("{} is not a leveld status report: {e}", path.display()))
}

/// Whether process `pid` is alive and is a leveld (a reused pid is not).
pub fn pid_is_leveld(pid: u32) -> bool {
    std::fs::read(format!("/proc/{pid}/comm"))
        .map(|c| c.trim_ascii() == b"leveld")
        .unwrap_or(false)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_published_report_reads_back_and_a_foreign_file_is_named() {
        let d = std::env::temp_dir().join(format!("leveld-status-{}", std::process::id()));
        std::fs::create_dir_all(&d).unwrap();
        let path = d.join("status.json");
        assert_eq!(read(&path), Ok(None));
        let cfg = crate::daemon::config::Config::parse(
            Path::new("config/leveld.toml"),
            crate::daemon::config::DEFAULT_TOML,
        )
        .unwrap();
        let db =
            crate::can::dbc::Database::parse(Path::new("leveld.dbc"), crate::daemon::DEFAULT_DBC)
                .unwrap();
        let p = Pipeline::new(&cfg, &db).unwrap();
        let cal = Calibration::Calibrated {
            reference_pitch_deg: 0.25,
            reference_roll_deg: None,
            legacy: false,
        };
        let cx = Context {
            started_unix_s: 1.0,
            running: true,
            calibration: &cal,
            can: "open",
            state_path: Path::new("/var/lib/leveld/state.json"),
            last_save: None,
        };
        let r = report(&p, &LiveStats::default(), &cx);
        assert_eq!(r.status, Status::NoEstimate);
        assert_eq!(r.inputs.len(), 3);
        publish(&path, &r).unwrap();
        assert_eq!(read(&path), Ok(Some(r)));
        std::fs::write(&path, b"\xff\xfe not json").unwrap();
        let e = read(&path).unwrap_err();
        assert!(e.contains("not a leveld status report"), "{e}");
        std::fs::remove_dir_all(&d).unwrap();
    }
}
