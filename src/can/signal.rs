//! Bit-level signal codec precomputed from a DBC signal definition.

/// How one signal sits in a frame. Built once from the DBC; decoding never allocates.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SignalCodec {
    /// DBC start bit: the LSB for little endian (Intel), the MSB for big endian (Motorola).
    pub start_bit: u16,
    pub size: u8,
    pub little_endian: bool,
    pub signed: bool,
    pub factor: f64,
    pub offset: f64,
}

impl SignalCodec {
    /// Bits the signal occupies must fit in `len` bytes.
    pub fn fits(&self, len: usize) -> bool {
        self.bit_positions().all(|b| (b as usize) < len * 8)
    }

    /// Frame bit positions from MSB to LSB of the raw value.
    fn bit_positions(&self) -> impl Iterator<Item = u16> + '_ {
        let mut pos = if self.little_endian {
            self.start_bit + self.size as u16 - 1
        } else {
            self.start_bit
        };
        let le = self.little_endian;
        (0..self.size).map(move |_| {
            let p = pos;
            if le {
                pos = pos.wrapping_sub(1);
            } else if pos % 8 == 0 {
                pos += 15; // Motorola: continue at the MSB of the next byte
            } else {
                pos -= 1;
            }
            p
        })
    }

    /// Raw unsigned bits.
    pub fn raw(&self, data: &[u8]) -> u64 {
        if self.little_endian
            && data.len() >= 8
            && self.start_bit as usize + self.size as usize <= 64
        {
            let w = u64::from_le_bytes(data[..8].try_into().unwrap_or([0; 8]));
            let mask = if self.size >= 64 {
                u64::MAX
            } else {
                (1u64 << self.size) - 1
            };
            return (w >> self.start_bit) & mask;
        }
        let mut raw = 0u64;
        for b in self.bit_positions() {
            let bit = data
                .get(b as usize / 8)
                .map_or(0, |byte| (byte >> (b % 8)) & 1);
            raw = (raw << 1) | bit as u64;
        }
        raw
    }

    /// Raw value with the sign applied.
    pub fn raw_signed(&self, data: &[u8]) -> i64 {
        let raw = self.raw(data);
        if self.signed && self.size < 64 && raw & (1 << (self.size - 1)) != 0 {
            (raw | !((1u64 << self.size) - 1)) as i64
        } else {
            raw as i64
        }
    }

    /// Physical value: raw * factor + offset.
    pub fn decode(&self, data: &[u8]) -> f64 {
        self.raw_signed(data) as f64 * self.factor + self.offset
    }

    /// Write a physical value; it is rounded to the resolution and clamped to the raw range.
    pub fn encode(&self, data: &mut [u8], value: f64) {
        let raw = ((value - self.offset) / self.factor).round();
        let (lo, hi) = if self.signed {
            (
                -(2f64.powi(self.size as i32 - 1)),
                2f64.powi(self.size as i32 - 1) - 1.0,
            )
        } else {
            (0.0, 2f64.powi(self.size as i32) - 1.0)
        };
        let raw = if raw.is_nan() { 0.0 } else { raw.clamp(lo, hi) } as i64 as u64;
        self.encode_raw(data, raw);
    }

    /// Write raw bits.
    pub fn encode_raw(&self, data: &mut [u8], raw: u64) {
        let n = self.size as u32;
        for (i, b) in self.bit_positions().enumerate() {
            let bit = (raw >> (n - 1 - i as u32)) & 1;
            if let Some(byte) = data.get_mut(b as usize / 8) {
                *byte = (*byte & !(1 << (b % 8))) | ((bit as u8) << (b % 8));
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::SignalCodec;

    fn sig(start_bit: u16, size: u8, little_endian: bool, signed: bool) -> SignalCodec {
        SignalCodec {
            start_bit,
            size,
            little_endian,
            signed,
            factor: 1.0,
            offset: 0.0,
        }
    }

    #[test]
    fn whl_spd11_fields_of_a_real_frame() {
        // can1 386#0000C00000400000 style frame: speeds 0, counter and checksum bits set.
        let d = [0x10, 0x40, 0x20, 0x80, 0x00, 0x40, 0x00, 0xC0];
        assert_eq!(sig(0, 14, true, false).raw(&d), 0x10);
        assert_eq!(sig(14, 2, true, false).raw(&d), 1);
        assert_eq!(sig(30, 2, true, false).raw(&d), 2);
        assert_eq!(sig(62, 2, true, false).raw(&d), 3);
    }

    #[test]
    fn motorola_walk_crosses_bytes() {
        // Big-endian 12-bit signal with MSB at bit 7: byte0 all bits, then the top nibble of byte1.
        let s = sig(7, 12, false, false);
        let d = [0xAB, 0xC0, 0, 0, 0, 0, 0, 0];
        assert_eq!(s.raw(&d), 0xABC);
        let mut out = [0u8; 8];
        s.encode_raw(&mut out, 0xABC);
        assert_eq!(out, d);
    }

    #[test]
    fn signed_round_trip_at_odd_positions() {
        for &(start, size, le) in &[
            (3u16, 13u8, true),
            (12, 12, true),
            (21, 10, false),
            (0, 16, true),
        ] {
            let s = SignalCodec {
                start_bit: start,
                size,
                little_endian: le,
                signed: true,
                factor: 0.01,
                offset: 0.5,
            };
            for v in [-3.21, 0.0, 1.5, 4.99] {
                let mut d = [0xFFu8; 8];
                s.encode(&mut d, v);
                assert!(
                    (s.decode(&d) - v).abs() < 0.005 + 1e-12,
                    "{start} {size} {le} {v}"
                );
            }
        }
    }

    #[test]
    fn encode_clamps_to_range() {
        let s = SignalCodec {
            start_bit: 0,
            size: 8,
            little_endian: true,
            signed: true,
            factor: 1.0,
            offset: 0.0,
        };
        let mut d = [0u8; 8];
        s.encode(&mut d, 1000.0);
        assert_eq!(s.decode(&d), 127.0);
        s.encode(&mut d, -1000.0);
        assert_eq!(s.decode(&d), -128.0);
    }
}
