//! The end-of-line calibration, in its own file. Only `leveld calibrate` writes it;
//! the daemon reads it at start and never rewrites it, so a state file that is lost
//! or rewritten cannot take the factory calibration with it.
//!
//! What the daemon makes of it (see `Pipeline::set_calibration`):
//! - calibrated: the reference pitch is the calibrated one;
//! - missing (a vehicle not yet calibrated): the config's `leveling.reference_pitch_deg`,
//!   with the LEVELING `Uncalibrated` flag set;
//! - unreadable: FAULT with the flag set; the file is left where it is for a person.

use super::state::write_json_atomic;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Largest plausible reference pitch of a vehicle on a level floor, deg.
pub const MAX_REFERENCE_PITCH_DEG: f64 = 10.0;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CalibrationFile {
    pub format: u32,
    /// Road-to-body pitch measured on a level floor, deg.
    pub reference_pitch_deg: f64,
    /// The IMU's roll on that floor (elevation of its y axis, left side up), deg. Files
    /// written before it was measured lack it; windows then keep a lane's roll in.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reference_roll_deg: Option<f64>,
    /// Settled standstill it was measured over, s.
    pub settled_s: f64,
    /// When it was written, seconds since the Unix epoch.
    pub written_unix_s: f64,
}

impl CalibrationFile {
    pub const FORMAT: u32 = 1;
}

/// What the daemon runs with.
#[derive(Debug, Clone, PartialEq)]
pub enum Calibration {
    /// From the calibration file, or (`legacy`) from a state file of an earlier
    /// leveld that kept it there.
    Calibrated {
        reference_pitch_deg: f64,
        reference_roll_deg: Option<f64>,
        legacy: bool,
    },
    /// No calibration file.
    Missing,
    /// The file exists but cannot be used; why.
    Unreadable(String),
}

impl Calibration {
    pub fn reference_pitch_deg(&self) -> Option<f64> {
        match self {
            Self::Calibrated {
                reference_pitch_deg,
                ..
            } => Some(*reference_pitch_deg),
            _ => None,
        }
    }

    pub fn reference_roll_deg(&self) -> Option<f64> {
        match self {
            Self::Calibrated {
                reference_roll_deg, ..
            } => *reference_roll_deg,
            _ => None,
        }
    }

    /// One word or phrase for the status report.
    pub fn describe(&self) -> String {
        match self {
            Self::Calibrated { legacy: false, .. } => "ok".into(),
            Self::Calibrated { legacy: true, .. } => {
                "ok, kept in the state file by an earlier leveld (run leveld calibrate to move it)"
                    .into()
            }
            Self::Missing => "missing: not calibrated (run leveld calibrate)".into(),
            Self::Unreadable(why) => format!("unreadable: {why}"),
        }
    }
}

/// Parse a calibration file's bytes; the error says what is wrong with them.
pub fn parse(bytes: &[u8]) -> Result<CalibrationFile, String> {
    let c: CalibrationFile =
        serde_json::from_slice(bytes).map_err(|e| format!("not valid calibration JSON: {e}"))?;
    if c.format != CalibrationFile::FORMAT {
        return Err(format!(
            "format {} is not the supported {}",
            c.format,
            CalibrationFile::FORMAT
        ));
    }
    if !c.reference_pitch_deg.is_finite() || c.reference_pitch_deg.abs() > MAX_REFERENCE_PITCH_DEG {
        return Err(format!(
            "reference pitch {} deg is implausible (at most {MAX_REFERENCE_PITCH_DEG} deg)",
            c.reference_pitch_deg
        ));
    }
    if let Some(r) = c.reference_roll_deg
        && (!r.is_finite() || r.abs() > MAX_REFERENCE_PITCH_DEG)
    {
        return Err(format!(
            "reference roll {r} deg is implausible (at most {MAX_REFERENCE_PITCH_DEG} deg)"
        ));
    }
    Ok(c)
}

/// Read the calibration file. It is never moved or rewritten here.
pub fn load(path: &Path) -> Calibration {
    match std::fs::read(path) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Calibration::Missing,
        Err(e) => Calibration::Unreadable(format!("cannot read {}: {e}", path.display())),
        Ok(bytes) => match parse(&bytes) {
            Ok(c) => Calibration::Calibrated {
                reference_pitch_deg: c.reference_pitch_deg,
                reference_roll_deg: c.reference_roll_deg,
                legacy: false,
            },
            Err(why) => Calibration::Unreadable(format!("{}: {why}", path.display())),
        },
    }
}

/// Write the calibration file atomically (`leveld calibrate` only).
pub fn save(path: &Path, c: &CalibrationFile) -> std::io::Result<()> {
    write_json_atomic(path, c)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn calibration_files_read_back_and_bad_ones_say_why() {
        let d = std::env::temp_dir().join(format!("leveld-cal-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        let path = d.join("calibration.json");
        assert_eq!(load(&path), Calibration::Missing);
        let c = CalibrationFile {
            format: CalibrationFile::FORMAT,
            reference_pitch_deg: 0.62,
            reference_roll_deg: Some(-0.4),
            settled_s: 30.0,
            written_unix_s: 1.8e9,
        };
        save(&path, &c).unwrap();
        assert_eq!(load(&path).reference_pitch_deg(), Some(0.62));
        assert_eq!(load(&path).reference_roll_deg(), Some(-0.4));
        // A file from before the roll was measured still reads, without it.
        std::fs::write(
            &path,
            br#"{"format":1,"reference_pitch_deg":0.5,"settled_s":30.0,"written_unix_s":0.0}"#,
        )
        .unwrap();
        assert_eq!(load(&path).reference_pitch_deg(), Some(0.5));
        assert_eq!(load(&path).reference_roll_deg(), None);
        for (bytes, why) in [
            (&b""[..], "not valid calibration JSON"),
            (b"null", "not valid calibration JSON"),
            (
                br#"{"format":1,"reference_pitch_deg":45.0,"settled_s":30.0,"written_unix_s":0.0}"#,
                "implausible",
            ),
            (
                br#"{"format":1,"reference_pitch_deg":0.5,"reference_roll_deg":80.0,"settled_s":30.0,"written_unix_s":0.0}"#,
                "reference roll 80 deg is implausible",
            ),
            (
                br#"{"format":7,"reference_pitch_deg":0.5,"settled_s":30.0,"written_unix_s":0.0}"#,
                "format 7",
            ),
        ] {
            std::fs::write(&path, bytes).unwrap();
            match load(&path) {
                Calibration::Unreadable(w) => assert!(w.contains(why), "{w}"),
                other => panic!("{bytes:?} gave {other:?}"),
            }
            // Left in place for a person to look at.
            assert_eq!(std::fs::read(&path).unwrap(), bytes);
        }
        let _ = std::fs::remove_dir_all(&d);
    }
}
