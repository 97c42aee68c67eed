//! State saves off the frame loop. A save (write, fsync, rename, fsync of the folder)
//! can take tens of milliseconds on flash; the loop hands the state to a thread and
//! goes on. Only the newest state matters, so a request replaces one not yet written.

use super::state::{self, PersistedState};
use super::status::{SaveInfo, unix_now_s};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Condvar, Mutex, PoisonError};
use std::thread::JoinHandle;

#[derive(Default)]
struct Slot {
    pending: Option<PersistedState>,
    stop: bool,
    last: Option<SaveInfo>,
}

type Shared = Arc<(Mutex<Slot>, Condvar)>;

/// The saving thread of one state file.
pub struct Saver {
    shared: Shared,
    thread: Option<JoinHandle<()>>,
}

/// Save `st` to `path` now and say how it went.
pub fn save_now(path: &Path, st: &PersistedState) -> SaveInfo {
    let r = state::save(path, st);
    if let Err(e) = &r {
        tracing::error!(path = %path.display(), "cannot save state: {e}");
    }
    SaveInfo {
        unix_s: unix_now_s(),
        ok: r.is_ok(),
        error: r.err().map(|e| e.to_string()),
    }
}

fn lock(shared: &Shared) -> std::sync::MutexGuard<'_, Slot> {
    shared.0.lock().unwrap_or_else(PoisonError::into_inner)
}

impl Saver {
    pub fn start(path: PathBuf) -> Self {
        let shared: Shared = Arc::default();
        let mine = shared.clone();
        let thread = std::thread::Builder::new()
            .name("leveld-save".into())
            .spawn(move || {
                loop {
                    let st = {
                        let mut slot = lock(&mine);
                        while slot.pending.is_none() && !slot.stop {
                            slot = mine.1.wait(slot).unwrap_or_else(PoisonError::into_inner);
                        }
                        match slot.pending.take() {
                            Some(st) => st,
                            None => return,
                        }
                    };
                    let info = save_now(&path, &st);
                    lock(&mine).last = Some(info);
                }
            })
            .map_err(|e| tracing::error!("cannot start the saving thread ({e}); saving in line"))
            .ok();
        Self { shared, thread }
    }

    /// Save `st` soon; replaces a state not yet written.
    pub fn request(&self, st: PersistedState, path: &Path) {
        if self.thread.is_none() {
            lock(&self.shared).last = Some(save_now(path, &st));
            return;
        }
        lock(&self.shared).pending = Some(st);
        self.shared.1.notify_one();
    }

    /// How the last save went.
    pub fn last(&self) -> Option<SaveInfo> {
        lock(&self.shared).last.clone()
    }

    /// Write what is pending, stop the thread, and say how the last save went.
    pub fn finish(mut self) -> Option<SaveInfo> {
        lock(&self.shared).stop = true;
        self.shared.1.notify_one();
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
        self.last()
    }
}

impl Drop for Saver {
    fn drop(&mut self) {
        lock(&self.shared).stop = true;
        self.shared.1.notify_one();
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_newest_state_is_written_and_the_save_reported() {
        let dir = std::env::temp_dir().join(format!("leveld-saver-{}", std::process::id()));
        let path = dir.join("state.json");
        let saver = Saver::start(path.clone());
        let mut st = PersistedState {
            format: PersistedState::FORMAT,
            estimator: crate::estimator::Estimator::new(Default::default())
                .expect("the default estimator config is valid")
                .state(),
            reference_pitch_deg: Some(0.25),
        };
        saver.request(st.clone(), &path);
        st.reference_pitch_deg = Some(0.5);
        saver.request(st, &path);
        let last = saver.finish().expect("a save was attempted");
        assert!(last.ok, "{last:?}");
        match state::read(&path) {
            state::Loaded::State(s) => assert_eq!(s.reference_pitch_deg, Some(0.5)),
            other => panic!("state not readable: {other:?}"),
        }
        let _ = std::fs::remove_dir_all(dir);
    }
}
