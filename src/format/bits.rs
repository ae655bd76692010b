//! A bit stream, least significant bit first: the packed payload
//! ([`crate::format::packed`]) writes the low bits of its centres' gaps on it.

use crate::error::{Error, Result};

/// Appends bits to a byte vector, least significant bit first.
#[derive(Default)]
pub struct BitWriter {
    bytes: Vec<u8>,
    acc: u64,
    filled: u32,
}

impl BitWriter {
    /// Writes the `n` low bits of `v` (`n` at most 64).
    pub fn put(&mut self, v: u64, n: u32) {
        let mut v = if n < 64 { v & ((1u64 << n) - 1) } else { v };
        let mut n = n;
        while n > 0 {
            let take = n.min(64 - self.filled).min(32);
            self.acc |= (v & ((1u64 << take) - 1)) << self.filled;
            self.filled += take;
            v = if take < 64 { v >> take } else { 0 };
            n -= take;
            while self.filled >= 8 {
                self.bytes.push(self.acc as u8);
                self.acc >>= 8;
                self.filled -= 8;
            }
        }
    }

    /// The bytes written, the last one padded with zero bits.
    pub fn finish(mut self) -> Vec<u8> {
        if self.filled > 0 {
            self.bytes.push(self.acc as u8);
        }
        self.bytes
    }
}

/// Reads what a [`BitWriter`] wrote; running past the end is an error.
pub struct BitReader<'a> {
    bytes: &'a [u8],
    /// Bits read so far.
    at: usize,
}

impl<'a> BitReader<'a> {
    pub fn new(bytes: &'a [u8]) -> BitReader<'a> {
        BitReader { bytes, at: 0 }
    }

    fn bit(&mut self) -> Result<u64> {
        let byte = self.bytes.get(self.at / 8).ok_or_else(|| Error::format("bit stream ends early (truncated or corrupted)"))?;
        let b = (byte >> (self.at % 8)) & 1;
        self.at += 1;
        Ok(b as u64)
    }

    /// Reads `n` bits (at most 64) written by [`BitWriter::put`].
    pub fn get(&mut self, n: u32) -> Result<u64> {
        let mut v = 0u64;
        for i in 0..n {
            v |= self.bit()? << i;
        }
        Ok(v)
    }

    /// Whether what is left is only the zero padding of the last byte.
    pub fn only_padding_left(&self) -> bool {
        let byte = self.at.div_ceil(8);
        if byte < self.bytes.len() {
            return false;
        }
        self.at.is_multiple_of(8) || self.bytes[self.at / 8] >> (self.at % 8) == 0
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::rng::Rng;

    #[test]
    fn fields_of_every_width_read_back() {
        let mut rng = Rng::new(7);
        let fields: Vec<(u64, u32)> = (0..2000).map(|_| (rng.next_u64(), rng.below(65) as u32)).collect();
        let mut w = BitWriter::default();
        for &(v, n) in &fields {
            w.put(v, n);
        }
        let bytes = w.finish();
        let total: u32 = fields.iter().map(|f| f.1).sum();
        assert_eq!(bytes.len(), (total as usize).div_ceil(8));
        let mut r = BitReader::new(&bytes);
        for &(v, n) in &fields {
            let want = if n == 64 { v } else { v & ((1u64 << n) - 1) };
            assert_eq!(r.get(n).unwrap(), want);
        }
        assert!(r.only_padding_left());
    }

    #[test]
    fn a_truncated_stream_is_an_error_not_a_panic() {
        let mut w = BitWriter::default();
        (0..100).for_each(|d| w.put(d * 1000, 17));
        let bytes = w.finish();
        let mut r = BitReader::new(&bytes[..bytes.len() / 2]);
        let got: Result<Vec<u64>> = (0..100).map(|_| r.get(17)).collect();
        assert!(got.unwrap_err().to_string().contains("ends early"));
        // Bits beyond the padding are seen, a set padding bit too.
        let mut longer = bytes.clone();
        longer.push(0);
        let mut r = BitReader::new(&longer);
        (0..100).for_each(|_| assert!(r.get(17).is_ok()));
        assert!(!r.only_padding_left());
        let mut set = bytes.clone();
        *set.last_mut().unwrap() |= 0x80;
        let mut r = BitReader::new(&set);
        (0..100).for_each(|_| assert!(r.get(17).is_ok()));
        assert!(!r.only_padding_left());
    }
}
