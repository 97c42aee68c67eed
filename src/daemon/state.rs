//! Persisted state: the estimator's evidence and the end-of-line reference pitch.
//!
//! Saved atomically (temp file, fsync, rename, fsync of the folder). A file that cannot
//! be read back is moved aside, never deleted, and leveld starts fresh.

use crate::estimator::EstimatorState;
use serde::{Deserialize, Serialize};
use std::io::Write;
use std::path::{Path, PathBuf};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PersistedState {
    pub format: u32,
    pub estimator: EstimatorState,
    /// Road-to-body pitch measured by `leveld calibrate` on a level floor, deg.
    pub reference_pitch_deg: Option<f64>,
}

impl PersistedState {
    pub const FORMAT: u32 = 1;
}

/// What loading found.
#[derive(Debug)]
pub enum Loaded {
    State(Box<PersistedState>),
    /// No file yet: a first start.
    Missing,
    /// Unreadable or incompatible: moved to `moved_to`; start fresh.
    Corrupt {
        reason: String,
        moved_to: Option<PathBuf>,
    },
}

/// Load the state file; a bad file is moved aside (`<name>.corrupt-<n>`).
pub fn load(path: &Path) -> Loaded {
    read_then(path, move_aside)
}

/// Read the state file and leave it where it is, whatever it holds.
pub fn read(path: &Path) -> Loaded {
    read_then(path, |_| None)
}

/// Read and parse; a file that does not parse is handed to `bad`, which says where it went.
fn read_then(path: &Path, bad: impl FnOnce(&Path) -> Option<PathBuf>) -> Loaded {
    match std::fs::read(path) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Loaded::Missing,
        Err(e) => Loaded::Corrupt {
            reason: format!("cannot read {}: {e}", path.display()),
            moved_to: None,
        },
        Ok(bytes) => match parse(&bytes) {
            Ok(st) => Loaded::State(Box::new(st)),
            Err(reason) => Loaded::Corrupt {
                moved_to: bad(path),
                reason,
            },
        },
    }
}

/// Read a state file's bytes; the error says what is wrong with them.
pub fn parse(bytes: &[u8]) -> Result<PersistedState, String> {
    match serde_json::from_slice::<PersistedState>(bytes) {
        Ok(st) if st.format != PersistedState::FORMAT => Err(format!(
            "format {} is not the supported {}",
            st.format,
            PersistedState::FORMAT
        )),
        Ok(st) => match st.reference_pitch_deg {
            Some(r) if !r.is_finite() || r.abs() > 10.0 => {
                Err(format!("reference pitch {r} is implausible"))
            }
            _ => Ok(st),
        },
        Err(e) => Err(format!("not valid state JSON: {e}")),
    }
}

/// Move a bad file to the first free `<name>.corrupt-<n>`.
pub fn move_aside(path: &Path) -> Option<PathBuf> {
    for n in 1..1000 {
        let mut name = path.file_name()?.to_os_string();
        name.push(format!(".corrupt-{n}"));
        let to = path.with_file_name(name);
        if !to.exists() {
            return std::fs::rename(path, &to).ok().map(|_| to);
        }
    }
    None
}

/// Write the state atomically.
pub fn save(path: &Path, st: &PersistedState) -> std::io::Result<()> {
    write_json_atomic(path, st)
}

/// Write `value` as JSON to `path` atomically: a temp file of this process and
/// thread next to it, fsync, rename, fsync of the folder. Two writers of one path
/// (the daemon and `leveld calibrate`) never share a temp file.
pub fn write_json_atomic<T: Serialize>(path: &Path, value: &T) -> std::io::Result<()> {
    let dir = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    std::fs::create_dir_all(dir)?;
    let mut tmp_name = std::ffi::OsString::from(".");
    tmp_name.push(path.file_name().unwrap_or_default());
    tmp_name.push(format!(
        ".tmp-{}-{:?}",
        std::process::id(),
        std::thread::current().id()
    ));
    let tmp = path.with_file_name(tmp_name);
    let written = (|| {
        let mut f = std::fs::File::create(&tmp)?;
        serde_json::to_writer_pretty(&mut f, value).map_err(std::io::Error::other)?;
        f.write_all(b"\n")?;
        f.sync_all()?;
        std::fs::rename(&tmp, path)
    })();
    if written.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    written?;
    // Make the rename itself durable.
    std::fs::File::open(dir)?.sync_all()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::estimator::{Estimator, EstimatorConfig};

    fn tmpdir(tag: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("leveld-state-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    fn sample() -> PersistedState {
        PersistedState {
            format: PersistedState::FORMAT,
            estimator: Estimator::new(EstimatorConfig::default()).unwrap().state(),
            reference_pitch_deg: Some(0.42),
        }
    }

    #[test]
    fn round_trip() {
        let d = tmpdir("rt");
        let p = d.join("state.json");
        save(&p, &sample()).unwrap();
        match load(&p) {
            Loaded::State(s) => assert_eq!(*s, sample()),
            other => panic!("{other:?}"),
        }
        assert!(!d.join("state.json.tmp").exists());
    }

    #[test]
    fn corrupt_file_is_moved_aside_not_deleted() {
        let d = tmpdir("corrupt");
        let p = d.join("state.json");
        std::fs::write(&p, b"{ this is not json").unwrap();
        match load(&p) {
            Loaded::Corrupt {
                reason,
                moved_to: Some(to),
            } => {
                assert!(reason.contains("not valid state JSON"), "{reason}");
                assert_eq!(std::fs::read(&to).unwrap(), b"{ this is not json");
                assert!(!p.exists());
            }
            other => panic!("{other:?}"),
        }
        // A second bad file gets the next free name.
        std::fs::write(&p, b"[]").unwrap();
        match load(&p) {
            Loaded::Corrupt {
                moved_to: Some(to), ..
            } => assert!(to.to_string_lossy().ends_with(".corrupt-2")),
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn other_format_is_incompatible() {
        let d = tmpdir("fmt");
        let p = d.join("state.json");
        let mut s = sample();
        s.format = 99;
        std::fs::write(&p, serde_json::to_vec(&s).unwrap()).unwrap();
        assert!(matches!(load(&p), Loaded::Corrupt { .. }));
    }

    #[test]
    fn read_reports_a_bad_file_and_leaves_it_in_place() {
        let d = tmpdir("read");
        let p = d.join("state.json");
        std::fs::write(&p, b"{ half").unwrap();
        match read(&p) {
            Loaded::Corrupt {
                reason,
                moved_to: None,
            } => assert!(reason.contains("not valid state JSON"), "{reason}"),
            other => panic!("{other:?}"),
        }
        assert_eq!(std::fs::read(&p).unwrap(), b"{ half");
    }

    #[test]
    fn missing_is_a_first_start() {
        assert!(matches!(
            load(&tmpdir("none").join("state.json")),
            Loaded::Missing
        ));
    }
}
