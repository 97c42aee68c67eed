//! Health of the three input messages: which interface each is taken from, its DLC,
//! checksum and alive-counter checks with invalid/valid hysteresis, and its timeout.

use super::config::Config;
use super::sink::{Notice, Sink};
use crate::can::checks::CounterCheck;
use crate::can::codec::MsgCodec;
use crate::can::dbc::Database;
use serde::Serialize;

pub const WHEELS: usize = 0;
pub const ACC: usize = 1;
pub const GYR: usize = 2;
/// Role names, as the notices and the status report name the inputs.
pub const ROLE_NAMES: [&str; 3] = ["wheels", "acc", "gyro"];

/// Per-message reception statistics.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct MsgStats {
    pub frames: u64,
    pub checksum_errors: u64,
    pub counter_errors: u64,
    pub dlc_errors: u64,
    pub timeouts: u64,
    /// Copies of the message from an interface other than its source.
    pub mirrored: u64,
}

#[derive(Debug, Clone, Copy, Default)]
struct InputState {
    stats: MsgStats,
    counter: CounterCheck,
    fails: u32,
    goods: u32,
    invalid: bool,
    last_good_s: Option<f64>,
    lost: bool,
    /// Interface the message is taken from.
    source: Option<u32>,
}

/// A frame that passed its checks: the decoded values in role order and its counter.
#[derive(Debug, Clone, Copy)]
pub struct Accepted {
    pub values: [f64; 4],
    pub counter: Option<u8>,
}

/// The input messages and their health.
#[derive(Debug)]
pub struct Inputs {
    codecs: [MsgCodec; 3],
    st: [InputState; 3],
    invalid_after: u32,
    valid_after: u32,
}

impl Inputs {
    pub fn new(cfg: &Config, db: &Database) -> anyhow::Result<Self> {
        let codecs = [
            MsgCodec::build(db, &cfg.wheels, ROLE_NAMES[WHEELS])?,
            MsgCodec::build(db, &cfg.acc, ROLE_NAMES[ACC])?,
            MsgCodec::build(db, &cfg.gyro, ROLE_NAMES[GYR])?,
        ];
        for m in &codecs {
            if m.len != 8 {
                anyhow::bail!(
                    "DBC {}: message for `{}` has {} bytes; leveld reads 8-byte messages",
                    db.path.display(),
                    m.name,
                    m.len
                );
            }
        }
        Ok(Self {
            codecs,
            st: [InputState::default(); 3],
            invalid_after: cfg.leveling.invalid_after,
            valid_after: cfg.leveling.valid_after,
        })
    }

    pub fn codec(&self, slot: usize) -> &MsgCodec {
        &self.codecs[slot]
    }

    pub fn stats(&self, slot: usize) -> MsgStats {
        self.st[slot].stats
    }

    /// The input slot of a frame ID, if it is one of the inputs.
    pub fn slot_of(&self, id: u32, extended: bool) -> Option<usize> {
        (0..3).find(|&i| self.codecs[i].id == id && self.codecs[i].extended == extended)
    }

    /// `ok`, `lost` (timed out) or `invalid` (failing its counter or checksum checks).
    pub fn state(&self, slot: usize) -> &'static str {
        let s = &self.st[slot];
        if s.lost {
            "lost"
        } else if s.invalid {
            "invalid"
        } else {
            "ok"
        }
    }

    /// Some input is lost or invalid: the estimate is held.
    pub fn any_unusable(&self) -> bool {
        self.st.iter().any(|s| s.lost || s.invalid)
    }

    /// After a clock step the timeouts count from `t_s`.
    pub fn restart_timeouts(&mut self, t_s: f64) {
        for s in &mut self.st {
            if s.last_good_s.is_some() {
                s.last_good_s = Some(t_s);
            }
        }
    }

    /// Check one received frame of input `slot` from interface `source`. Each input
    /// is taken from one interface; copies from others (a gateway mirroring the ESC
    /// onto a second bus) are counted as mirrored and not used; when the source goes
    /// silent another interface may take over.
    pub fn accept(
        &mut self,
        slot: usize,
        source: u32,
        t_s: f64,
        data: &[u8],
        sink: &mut dyn Sink,
    ) -> Option<Accepted> {
        let s = &mut self.st[slot];
        match s.source {
            None => s.source = Some(source),
            Some(src) if src != source => {
                s.stats.mirrored += 1;
                return None;
            }
            Some(_) => {}
        }
        s.stats.frames += 1;
        let Ok(d) = <[u8; 8]>::try_from(data) else {
            s.stats.dlc_errors += 1;
            self.fail(slot, t_s, "wrong DLC", sink);
            return None;
        };
        let codec = &self.codecs[slot];
        if codec.check_checksum && !codec.checksum_ok(&d) {
            self.st[slot].stats.checksum_errors += 1;
            self.fail(slot, t_s, "checksum", sink);
            return None;
        }
        let counter = codec.counter(&d);
        if codec.check_counter
            && let Some(c) = counter
            && !self.st[slot].counter.accept(c, codec.max_step)
        {
            self.st[slot].stats.counter_errors += 1;
            self.fail(slot, t_s, "alive counter", sink);
            return None;
        }
        self.good(slot, t_s, sink);
        Some(Accepted {
            values: self.codecs[slot].values(&d),
            counter,
        })
    }

    /// Inputs silent past their timeout at `t_s` (counted from `start_s` for one never
    /// seen) become lost. Returns true when the wheels were lost just now.
    pub fn check_timeouts(&mut self, t_s: f64, start_s: f64, sink: &mut dyn Sink) -> bool {
        let mut wheels_lost = false;
        for (i, role) in ROLE_NAMES.iter().enumerate() {
            let timeout = self.codecs[i].timeout_s;
            let s = &mut self.st[i];
            let since = s.last_good_s.unwrap_or(start_s);
            if !s.lost && t_s - since > timeout {
                s.lost = true;
                s.stats.timeouts += 1;
                s.counter.reset();
                s.source = None;
                sink.notice(&Notice::InputLost { t_s, message: role });
                wheels_lost |= i == WHEELS;
            }
        }
        wheels_lost
    }

    fn fail(&mut self, slot: usize, t_s: f64, reason: &'static str, sink: &mut dyn Sink) {
        let s = &mut self.st[slot];
        s.goods = 0;
        s.fails += 1;
        if !s.invalid && s.fails >= self.invalid_after {
            s.invalid = true;
            sink.notice(&Notice::MessageInvalid {
                t_s,
                message: ROLE_NAMES[slot],
                reason,
            });
        }
    }

    fn good(&mut self, slot: usize, t_s: f64, sink: &mut dyn Sink) {
        let s = &mut self.st[slot];
        s.fails = 0;
        s.goods += 1;
        s.last_good_s = Some(t_s);
        let revalidated = s.invalid && s.goods >= self.valid_after;
        let restored = revalidated || s.lost;
        if revalidated {
            s.invalid = false;
        }
        s.lost = false;
        if restored && !s.invalid {
            sink.notice(&Notice::InputRestored {
                t_s,
                message: ROLE_NAMES[slot],
            });
        }
    }
}
