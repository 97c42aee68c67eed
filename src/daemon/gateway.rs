//! Frames in, estimator events out: the part of the pipeline that live runs and
//! replays share. Only configured IDs are decoded; nothing here allocates per frame.

use crate::can::checks::{
    CounterCheck, crc8_bytes0_6, whl_spd11_checksum, whl_spd11_counter, whl_spd11_expected,
};
use crate::can::dbc::{Database, DbcError, MessageInfo};
use crate::can::signal::SignalCodec;
use crate::estimator::{Estimator, EstimatorConfig, Event, ImuSample, WheelSpeeds};
use serde::Serialize;

/// Per-message reception statistics.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct MsgStats {
    pub frames: u64,
    pub checksum_errors: u64,
    pub counter_errors: u64,
    pub dlc_errors: u64,
    pub timeouts: u64,
}

#[derive(Debug, Clone)]
struct Wheels {
    info: MessageInfo,
    speeds: [SignalCodec; 4],
}

#[derive(Debug, Clone)]
struct Imu3 {
    info: MessageInfo,
    axes: [SignalCodec; 3],
    counter: SignalCodec,
    crc: SignalCodec,
}

/// Which input messages to decode, resolved from the DBC by name.
#[derive(Debug, Clone)]
pub struct InputCodecs {
    wheels: Wheels,
    acc: Imu3,
    gyr: Imu3,
}

impl InputCodecs {
    /// The reference layout of `dbc/leveld.dbc`.
    pub fn reference(db: &Database) -> Result<Self, DbcError> {
        let imu =
            |msg: &str, axes: [&str; 3], counter: &str, crc: &str| -> Result<Imu3, DbcError> {
                Ok(Imu3 {
                    info: db.message(msg)?,
                    axes: [
                        db.signal(msg, axes[0])?,
                        db.signal(msg, axes[1])?,
                        db.signal(msg, axes[2])?,
                    ],
                    counter: db.signal(msg, counter)?,
                    crc: db.signal(msg, crc)?,
                })
            };
        let w = "WHL_SPD11";
        Ok(Self {
            wheels: Wheels {
                info: db.message(w)?,
                speeds: [
                    db.signal(w, "WHL_SPD_FL")?,
                    db.signal(w, "WHL_SPD_FR")?,
                    db.signal(w, "WHL_SPD_RL")?,
                    db.signal(w, "WHL_SPD_RR")?,
                ],
            },
            acc: imu(
                "IMU_ACC",
                ["IMU_AccX", "IMU_AccY", "IMU_AccZ"],
                "IMU_AccCounter",
                "IMU_AccCRC",
            )?,
            gyr: imu(
                "IMU_GYR",
                ["IMU_RateX", "IMU_RateY", "IMU_RateZ"],
                "IMU_GyrCounter",
                "IMU_GyrCRC",
            )?,
        })
    }

    pub fn ids(&self) -> [u32; 3] {
        [self.wheels.info.id, self.acc.info.id, self.gyr.info.id]
    }

    pub fn names(&self) -> [&str; 3] {
        [
            &self.wheels.info.name,
            &self.acc.info.name,
            &self.gyr.info.name,
        ]
    }
}

/// Message slots in the statistics.
pub const WHEELS: usize = 0;
pub const ACC: usize = 1;
pub const GYR: usize = 2;

/// Decoder plus estimator.
#[derive(Debug)]
pub struct Gateway {
    codecs: InputCodecs,
    pub est: Estimator,
    pub stats: [MsgStats; 3],
    pub ignored_frames: u64,
    counters: [CounterCheck; 3],
    /// Half of an IMU sample waiting for its partner: (counter, time, values).
    half_acc: Option<(u8, f64, [f64; 3])>,
    half_gyr: Option<(u8, f64, [f64; 3])>,
    pub windows_accepted: u64,
    pub windows_rejected: u64,
    last_t_s: f64,
}

impl Gateway {
    pub fn new(
        codecs: InputCodecs,
        cfg: EstimatorConfig,
    ) -> Result<Self, crate::estimator::ConfigError> {
        Ok(Self {
            codecs,
            est: Estimator::new(cfg)?,
            stats: [MsgStats::default(); 3],
            ignored_frames: 0,
            counters: [CounterCheck::default(); 3],
            half_acc: None,
            half_gyr: None,
            windows_accepted: 0,
            windows_rejected: 0,
            last_t_s: 0.0,
        })
    }

    pub fn codecs(&self) -> &InputCodecs {
        &self.codecs
    }

    /// Handle one received frame stamped `t_s` (receive or log time).
    pub fn on_frame(
        &mut self,
        t_s: f64,
        id: u32,
        extended: bool,
        data: &[u8],
        emit: &mut dyn FnMut(Event),
    ) {
        self.last_t_s = t_s;
        let c = &self.codecs;
        let slot = if id == c.wheels.info.id && extended == c.wheels.info.extended {
            WHEELS
        } else if id == c.acc.info.id && extended == c.acc.info.extended {
            ACC
        } else if id == c.gyr.info.id && extended == c.gyr.info.extended {
            GYR
        } else {
            self.ignored_frames += 1;
            return;
        };
        self.stats[slot].frames += 1;
        let want = [c.wheels.info.len, c.acc.info.len, c.gyr.info.len][slot] as usize;
        if data.len() != want || want != 8 {
            self.stats[slot].dlc_errors += 1;
            return;
        }
        let d: [u8; 8] = data.try_into().unwrap_or([0; 8]);
        let tally = |s: &mut Self, est_emit: &mut dyn FnMut(Event), e: Event| {
            match e {
                Event::WindowAccepted { .. } => s.windows_accepted += 1,
                Event::WindowRejected { .. } => s.windows_rejected += 1,
                _ => {}
            }
            est_emit(e);
        };
        match slot {
            WHEELS => {
                if whl_spd11_checksum(&d) != whl_spd11_expected(&d) {
                    self.stats[WHEELS].checksum_errors += 1;
                    return;
                }
                if !self.counters[WHEELS].accept(whl_spd11_counter(&d), 1) {
                    self.stats[WHEELS].counter_errors += 1;
                }
                let w = &self.codecs.wheels.speeds;
                let kmh = [
                    w[0].decode(&d),
                    w[1].decode(&d),
                    w[2].decode(&d),
                    w[3].decode(&d),
                ];
                let mut evs: [Option<Event>; 4] = [None; 4];
                let mut k = 0;
                self.est.push_wheels(WheelSpeeds { t_s, kmh }, &mut |e| {
                    if k < evs.len() {
                        evs[k] = Some(e);
                        k += 1;
                    }
                });
                for e in evs.into_iter().flatten() {
                    tally(self, emit, e);
                }
            }
            _ => {
                let m = if slot == ACC {
                    &self.codecs.acc
                } else {
                    &self.codecs.gyr
                };
                if m.crc.raw(&d) as u8 != crc8_bytes0_6(&d) {
                    self.stats[slot].checksum_errors += 1;
                    return;
                }
                let counter = m.counter.raw(&d) as u8;
                if !self.counters[slot].accept(counter, 3) {
                    self.stats[slot].counter_errors += 1;
                }
                let v = [
                    m.axes[0].decode(&d),
                    m.axes[1].decode(&d),
                    m.axes[2].decode(&d),
                ];
                let (mine, other) = if slot == ACC {
                    (&mut self.half_acc, &mut self.half_gyr)
                } else {
                    (&mut self.half_gyr, &mut self.half_acc)
                };
                match other.take() {
                    Some((oc, ot, ov)) if oc == counter => {
                        let (acc, gyr) = if slot == ACC { (v, ov) } else { (ov, v) };
                        let sample = ImuSample::new(t_s.min(ot), acc, gyr);
                        let mut evs: [Option<Event>; 8] = [None; 8];
                        let mut k = 0;
                        self.est.push_imu(sample, &mut |e| {
                            if k < evs.len() {
                                evs[k] = Some(e);
                                k += 1;
                            }
                        });
                        for e in evs.into_iter().flatten() {
                            tally(self, emit, e);
                        }
                    }
                    _ => *mine = Some((counter, t_s, v)),
                }
            }
        }
    }

    /// End of input: flush what the estimator still waits for.
    pub fn finish(&mut self, emit: &mut dyn FnMut(Event)) {
        let t = self.last_t_s;
        let mut evs: [Option<Event>; 4] = [None; 4];
        let mut k = 0;
        self.est.finish(t, &mut |e| {
            if k < evs.len() {
                evs[k] = Some(e);
                k += 1;
            }
        });
        for e in evs.into_iter().flatten() {
            match e {
                Event::WindowAccepted { .. } => self.windows_accepted += 1,
                Event::WindowRejected { .. } => self.windows_rejected += 1,
                _ => {}
            }
            emit(e);
        }
    }
}
