//! Counters and checksums of the messages leveld reads and writes.

use crc::{CRC_8_SAE_J1850, Crc};

/// CRC-8 SAE J1850 (poly 0x1D, init 0xFF, xor-out 0xFF), used by IMU_ACC, IMU_GYR and LEVELING.
pub const CRC8: Crc<u8> = Crc::<u8>::new(&CRC_8_SAE_J1850);

/// CRC-8 over the first seven bytes; the eighth carries it.
pub fn crc8_bytes0_6(data: &[u8]) -> u8 {
    CRC8.checksum(&data[..7.min(data.len())])
}

/// Hyundai/Kia WHL_SPD11 alive counter: MSB half in the top bits of byte 3, LSB half in byte 1.
pub fn whl_spd11_counter(d: &[u8; 8]) -> u8 {
    ((d[3] >> 6) << 2) | (d[1] >> 6)
}

/// WHL_SPD11 checksum as carried: MSB half in the top bits of byte 7, LSB half in byte 5.
pub fn whl_spd11_checksum(d: &[u8; 8]) -> u8 {
    ((d[7] >> 6) << 2) | (d[5] >> 6)
}

/// WHL_SPD11 checksum computed: popcount of all bits except the top two of bytes 1, 3,
/// 5 and 7, XOR 9, AND 15.
pub fn whl_spd11_expected(d: &[u8; 8]) -> u8 {
    let mut w = u64::from_le_bytes(*d);
    for byte in [1, 3, 5, 7] {
        w &= !(0b11u64 << (byte * 8 + 6));
    }
    ((w.count_ones() as u8) ^ 9) & 15
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
        assert_eq!(CRC8.checksum(b"123456789"), 0x4B);
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
}
