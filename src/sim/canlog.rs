//! Writing a simulated drive as CAN frames through the reference DBC.

use super::drive::{Drive, Input};
use crate::can::candump::{CandumpLine, LogFrame};
use crate::can::checks::{crc8_bytes0_6, whl_spd11_expected};
use crate::can::dbc::{Database, DbcError, MessageInfo};
use crate::can::signal::SignalCodec;
use std::io::Write;

/// Encoders for the input messages of `dbc/leveld.dbc`.
#[derive(Debug, Clone)]
pub struct InputEncoder {
    whl: MessageInfo,
    speeds: [SignalCodec; 4],
    whl_cnt: [SignalCodec; 2],
    whl_chk: [SignalCodec; 2],
    acc: MessageInfo,
    acc_axes: [SignalCodec; 3],
    acc_cnt: SignalCodec,
    acc_crc: SignalCodec,
    gyr: MessageInfo,
    gyr_axes: [SignalCodec; 3],
    gyr_cnt: SignalCodec,
    gyr_crc: SignalCodec,
    whl_counter: u8,
    imu_counter: u8,
}

impl InputEncoder {
    pub fn new(db: &Database) -> Result<Self, DbcError> {
        let s = |m: &str, n: &str| db.signal(m, n);
        Ok(Self {
            whl: db.message("WHL_SPD11")?,
            speeds: [
                s("WHL_SPD11", "WHL_SPD_FL")?,
                s("WHL_SPD11", "WHL_SPD_FR")?,
                s("WHL_SPD11", "WHL_SPD_RL")?,
                s("WHL_SPD11", "WHL_SPD_RR")?,
            ],
            whl_cnt: [
                s("WHL_SPD11", "WHL_SPD_AliveCounter_MSB")?,
                s("WHL_SPD11", "WHL_SPD_AliveCounter_LSB")?,
            ],
            whl_chk: [
                s("WHL_SPD11", "WHL_SPD_Checksum_MSB")?,
                s("WHL_SPD11", "WHL_SPD_Checksum_LSB")?,
            ],
            acc: db.message("IMU_ACC")?,
            acc_axes: [
                s("IMU_ACC", "IMU_AccX")?,
                s("IMU_ACC", "IMU_AccY")?,
                s("IMU_ACC", "IMU_AccZ")?,
            ],
            acc_cnt: s("IMU_ACC", "IMU_AccCounter")?,
            acc_crc: s("IMU_ACC", "IMU_AccCRC")?,
            gyr: db.message("IMU_GYR")?,
            gyr_axes: [
                s("IMU_GYR", "IMU_RateX")?,
                s("IMU_GYR", "IMU_RateY")?,
                s("IMU_GYR", "IMU_RateZ")?,
            ],
            gyr_cnt: s("IMU_GYR", "IMU_GyrCounter")?,
            gyr_crc: s("IMU_GYR", "IMU_GyrCRC")?,
            whl_counter: 0,
            imu_counter: 0,
        })
    }

    /// WHL_SPD11 payload with the next alive counter and its checksum.
    pub fn wheels(&mut self, kmh: [f64; 4]) -> [u8; 8] {
        let mut d = [0u8; 8];
        for (c, v) in self.speeds.iter().zip(kmh) {
            c.encode(&mut d, v);
        }
        let n = self.whl_counter;
        self.whl_counter = (n + 1) & 15;
        self.whl_cnt[0].encode_raw(&mut d, (n >> 2) as u64);
        self.whl_cnt[1].encode_raw(&mut d, (n & 3) as u64);
        let chk = whl_spd11_expected(&d);
        self.whl_chk[0].encode_raw(&mut d, (chk >> 2) as u64);
        self.whl_chk[1].encode_raw(&mut d, (chk & 3) as u64);
        d
    }

    /// IMU_ACC and IMU_GYR payloads of one sample, sharing the alive counter.
    pub fn imu(&mut self, acc: [f64; 3], gyro: [f64; 3]) -> ([u8; 8], [u8; 8]) {
        let n = self.imu_counter;
        self.imu_counter = (n + 1) & 15;
        let mut a = [0u8; 8];
        let mut g = [0u8; 8];
        for i in 0..3 {
            self.acc_axes[i].encode(&mut a, acc[i]);
            self.gyr_axes[i].encode(&mut g, gyro[i]);
        }
        self.acc_cnt.encode_raw(&mut a, n as u64);
        self.gyr_cnt.encode_raw(&mut g, n as u64);
        let (ca, cg) = (crc8_bytes0_6(&a), crc8_bytes0_6(&g));
        self.acc_crc.encode_raw(&mut a, ca as u64);
        self.gyr_crc.encode_raw(&mut g, cg as u64);
        (a, g)
    }

    pub fn ids(&self) -> (u32, u32, u32) {
        (self.whl.id, self.acc.id, self.gyr.id)
    }
}

/// Write `drive` as `candump -L` lines on `iface`, with `t0_s` added to simulation time.
/// IMU_GYR follows IMU_ACC by 250 us, as two frames of one sample would on a bus.
pub fn write_candump(
    drive: &Drive,
    enc: &mut InputEncoder,
    iface: &str,
    t0_s: f64,
    out: &mut dyn Write,
) -> std::io::Result<u64> {
    let (whl, acc, gyr) = enc.ids();
    let mut n = 0;
    for input in drive.merged() {
        match input {
            Input::Wheels(w) => {
                let d = enc.wheels(w.kmh);
                writeln!(
                    out,
                    "{}",
                    CandumpLine(&LogFrame::new(t0_s + w.t_s, iface, whl, false, &d))
                )?;
                n += 1;
            }
            Input::Imu(s) => {
                let (a, g) = enc.imu(s.acc_mps2, s.gyro_dps);
                writeln!(
                    out,
                    "{}",
                    CandumpLine(&LogFrame::new(t0_s + s.t_s, iface, acc, false, &a))
                )?;
                writeln!(
                    out,
                    "{}",
                    CandumpLine(&LogFrame::new(
                        t0_s + s.t_s + 0.00025,
                        iface,
                        gyr,
                        false,
                        &g
                    ))
                )?;
                n += 2;
            }
        }
    }
    Ok(n)
}
