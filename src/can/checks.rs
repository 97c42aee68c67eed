//! Counters and checksums of the messages leveld reads and writes.

use crc::{CRC_8_AUTOSAR, CRC_8_SAE_J1850, Crc};
use serde::{Deserialize, Serialize};

/// CRC-8 SAE J1850 (poly 0x1D, init 0xFF, xor-out 0xFF), used by IMU_ACC, IMU_GYR and LEVELING.
pub const J1850: Crc<u8> = Crc::<u8>::new(&CRC_8_SAE_J1850);

/// CRC-8 AUTOSAR (poly 0x2F, init 0xFF, xor-out 0xFF).
pub const AUTOSAR: Crc<u8> = Crc::<u8>::new(&CRC_8_AUTOSAR);

/// How a message's checksum is computed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ChecksumKind {
    None,
    /// Hyundai/Kia WHL_SPD11: popcount of the bits outside counter and checksum, XOR 9, AND 15.
    HyundaiWhlSpd,
    /// CRC-8 SAE J1850 over the bytes not holding the checksum.
    Crc8SaeJ1850,
    /// CRC-8 AUTOSAR (poly 0x2F) over the bytes not holding the checksum.
    Crc8Autosar,
}

/// The CRC of `kind` over `bytes`; `None` for the kinds that are not CRCs.
pub fn crc8(kind: ChecksumKind, bytes: impl IntoIterator<Item = u8>) -> Option<u8> {
    let crc = match kind {
        ChecksumKind::Crc8SaeJ1850 => &J1850,
        ChecksumKind::Crc8Autosar => &AUTOSAR,
        ChecksumKind::None | ChecksumKind::HyundaiWhlSpd => return None,
    };
    let mut dig = crc.digest();
    for b in bytes {
        dig.update(&[b]);
    }
    Some(dig.finalize())
}

/// CRC-8 SAE J1850 over the first seven bytes; the eighth carries it.
pub fn crc8_bytes0_6(data: &[u8]) -> u8 {
    J1850.checksum(&data[..7.min(data.len())])
}

/// The Hyundai/Kia popcount checksum of a payload whose counter and checksum bits are
/// cleared by `mask`: popcount, XOR 9, AND 15.
pub fn hyundai_popcount(payload: u64, mask: u64) -> u8 {
    (((payload & mask).count_ones() as u8) ^ 9) & 15
}

/// Bits of WHL_SPD11 outside its split counter and checksum (the top two bits of
/// bytes 1, 3, 5 and 7).
pub const WHL_SPD11_CHECKED_BITS: u64 =
    !(0b11u64 << 14 | 0b11u64 << 30 | 0b11u64 << 46 | 0b11u64 << 62);

/// WHL_SPD11 checksum computed over a payload.
pub fn whl_spd11_expected(d: &[u8; 8]) -> u8 {
    hyundai_popcount(u64::from_le_bytes(*d), WHL_SPD11_CHECKED_BITS)
}

/// Alive-counter continuity with tolerance for a few lost frames.
#[derive(Debug, Clone, Copy, Default)]
pub struct CounterCheck {
    last: Option<u8>,
}

impl CounterCheck {
    /// True when `c` follows the previous counter (mod 16) by 1..=`max_step`.
    pub fn accept(&mut self, c: u8, max_step: u8) -> bool {
        let ok = match self.last {
            None => true,
            Some(p) => {
                let step = c.wrapping_sub(p) & 0x0F;
                step >= 1 && step <= max_step
            }
        };
        self.last = Some(c);
        ok
    }
    pub fn reset(&mut self) {
        self.last = None;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crc8_j1850_check_value() {
        // Catalogue check value of CRC-8/SAE-J1850 over "123456789".
        assert_eq!(J1850.checksum(b"123456789"), 0x4B);
        // and of CRC-8/AUTOSAR.
        assert_eq!(AUTOSAR.checksum(b"123456789"), 0xDF);
    }

    #[test]
    fn counter_wraps_and_flags_repeats() {
        let mut c = CounterCheck::default();
        assert!(c.accept(14, 1));
        assert!(c.accept(15, 1));
        assert!(c.accept(0, 1));
        assert!(!c.accept(0, 1));
        assert!(!c.accept(5, 2));
    }

    #[test]
    fn whl_spd11_checksum_of_a_real_frame() {
        // WHL_SPD11 (0x386) at 1953.6311 s of the Kona capture: 0 km/h, counter 10,
        // checksum 9 carried in the top bits of bytes 5 and 7.
        let d = [0x00, 0x80, 0x00, 0x80, 0x00, 0x40, 0x00, 0x80];
        let carried = ((d[7] >> 6) << 2) | (d[5] >> 6);
        assert_eq!(carried, 9);
        assert_eq!(whl_spd11_expected(&d), carried);
    }
}
