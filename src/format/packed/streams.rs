//! The lossless stage of the packed payload ([`crate::format::packed`]):
//! each symbol stream stored as whichever is smaller of a zstd frame and
//! an adaptive range coding ([`crate::format::range`]) under contexts that
//! the stream's neighbours give (FORMAT.md "The packed payload").
//!
//! | stream | a symbol's context |
//! |---|---|
//! | scale, x | the top bits of the x scale before it (Morton order: a neighbour) |
//! | scale, y | the top bits of its own x scale |
//! | scale, z | the top bits of its own x and y scales |
//! | rotation index | none |
//! | rotation | its own bit count ([`crate::format::packed::rotation_bits`]): the symbol's width |
//! | value | the top bits of the value before it |
//! | weight | whether its own value is 0 (a primitive that carries no value), and the top bits of its own x scale |
//! | centre gap class | the class before it (none in the payload's first layout) |
//!
//! Contexts take at most `CONTEXT_BUDGET` bits together with the symbol,
//! so a stream's probabilities fit in 2 MiB whatever its precision.

use crate::error::{Error, Result};
use crate::format::range::{BitTrees, Decoder, Encoder, RANGE_TAG, ZSTD_MAGIC};

/// Bits of context and symbol together.
const CONTEXT_BUDGET: u8 = 20;
/// Bits of a centre gap class (0..=63).
const CLASS_BITS: u8 = 6;

/// One of the packed payload's symbol streams, with what its contexts read.
pub enum Stream<'a> {
    /// Log scale codes of `bits` bits: all x, then all y, then all z.
    Scale { bits: u8 },
    /// The dropped quaternion component (2 bits) of each turned primitive.
    RotationIndex,
    /// Three arrays of rotation codes, each code `rbits[t]` bits wide.
    Rotation { bits: u8, rbits: &'a [u8] },
    Value { bits: u8 },
    /// Weight codes; `scale_x` the x scale codes (`scale_bits` bits) and
    /// `value` the value codes of the same primitives.
    Weight { bits: u8, scale_x: &'a [u16], scale_bits: u8, value: &'a [u16] },
    /// Classes of the centre keys' gaps (6 bits), each under the class
    /// before it when `by_previous` (the payload's first layout: none).
    GapClass { by_previous: bool },
}

/// The top `k` bits of a `bits`-bit code (the whole code when it has fewer).
fn top(code: u16, bits: u8, k: u8) -> usize {
    (code >> bits.saturating_sub(k)) as usize
}

impl Stream<'_> {
    /// Widest symbol.
    fn bits(&self) -> u8 {
        match *self {
            Stream::Scale { bits } | Stream::Rotation { bits, .. } | Stream::Value { bits } | Stream::Weight { bits, .. } => bits,
            Stream::RotationIndex => 2,
            Stream::GapClass { .. } => CLASS_BITS,
        }
    }

    /// Context bits of one context feature (`features` of them).
    fn feature_bits(&self, want: u8, features: u8) -> u8 {
        want.min((CONTEXT_BUDGET - self.bits()) / features)
    }

    fn contexts(&self) -> usize {
        match *self {
            Stream::Scale { .. } => {
                let (k1, k2) = (self.feature_bits(4, 1), self.feature_bits(4, 2));
                (2 << k1) + (1 << (2 * k2))
            }
            Stream::Rotation { bits, .. } => bits as usize + 1,
            Stream::Value { .. } => 1 << self.feature_bits(8, 1),
            Stream::Weight { .. } => 2 << self.feature_bits(4, 1),
            Stream::GapClass { by_previous: true } => 1 << CLASS_BITS,
            Stream::RotationIndex | Stream::GapClass { by_previous: false } => 1,
        }
    }

    /// The context and width of symbol `i`; `done` holds the symbols
    /// before it (read only below `i`).
    fn context(&self, i: usize, done: &[u16], count: usize) -> (usize, u8) {
        match *self {
            Stream::Scale { bits } => {
                let n = count / 3;
                let (k1, k2) = (self.feature_bits(4, 1), self.feature_bits(4, 2));
                let ctx = match i / n.max(1) {
                    0 => i.checked_sub(1).map_or(0, |j| top(done[j], bits, k1)),
                    1 => (1 << k1) + top(done[i - n], bits, k1),
                    _ => (2 << k1) + (top(done[i - 2 * n], bits, k2) << k2 | top(done[i - n], bits, k2)),
                };
                (ctx, bits)
            }
            Stream::Rotation { rbits, .. } => {
                let b = rbits[i % rbits.len()];
                (b as usize, b)
            }
            Stream::Value { bits } => (i.checked_sub(1).map_or(0, |j| top(done[j], bits, self.feature_bits(8, 1))), bits),
            Stream::Weight { bits, scale_x, scale_bits, value } => {
                let k = self.feature_bits(4, 1);
                (((value[i] == 0) as usize) << k | top(scale_x[i], scale_bits, k), bits)
            }
            Stream::GapClass { by_previous: true } => (i.checked_sub(1).map_or(0, |j| done[j] as usize), CLASS_BITS),
            Stream::RotationIndex | Stream::GapClass { by_previous: false } => (0, self.bits()),
        }
    }

    /// Checks what a context reads against the stream's length.
    fn check(&self, count: usize) -> Result<()> {
        let ok = match *self {
            Stream::Scale { .. } => count.is_multiple_of(3),
            Stream::Rotation { rbits, bits } => count == 3 * rbits.len() && rbits.iter().all(|&b| (1..=bits).contains(&b)),
            Stream::Weight { scale_x, value, .. } => scale_x.len() == count && value.len() == count,
            _ => true,
        };
        if ok {
            Ok(())
        } else {
            Err(Error::format("packed payload: a stream's length does not match its context"))
        }
    }

    fn range_code(&self, symbols: &[u16]) -> Vec<u8> {
        let mut trees = BitTrees::new(self.contexts(), self.bits());
        let mut e = Encoder::default();
        for i in 0..symbols.len() {
            let (ctx, bits) = self.context(i, symbols, symbols.len());
            trees.encode(&mut e, ctx, bits, symbols[i] as u32);
        }
        let mut out = vec![RANGE_TAG];
        out.extend(e.finish());
        out
    }

    fn range_decode(&self, coded: &[u8], count: usize) -> Result<Vec<u16>> {
        let mut trees = BitTrees::new(self.contexts(), self.bits());
        let mut d = Decoder::new(coded)?;
        let mut out = Vec::with_capacity(count);
        for i in 0..count {
            let (ctx, bits) = self.context(i, &out, count);
            out.push(trees.decode(&mut d, ctx, bits)? as u16);
        }
        if !d.at_end() {
            return Err(Error::format("packed payload: bytes left after a range-coded stream"));
        }
        Ok(out)
    }

    /// The stored stream: the smaller of the two codings of `symbols`
    /// (each below `1 << bits` of its context).
    pub fn encode(&self, symbols: &[u16], zstd_level: i32) -> Result<Vec<u8>> {
        self.check(symbols.len()).map_err(|e| Error::arg(e.to_string()))?;
        let frame = zstd::bulk::compress(&self.bytes(symbols), zstd_level).map_err(|e| Error::format(format!("zstd: {e}")))?;
        let ranged = self.range_code(symbols);
        Ok(if ranged.len() < frame.len() { ranged } else { frame })
    }

    /// Reads `count` symbols of a stored stream. `unpack` inflates a zstd
    /// frame to exactly the length it is given, or fails.
    pub fn decode(&self, stored: &[u8], count: usize, unpack: &dyn Fn(&[u8], usize) -> Result<Vec<u8>>) -> Result<Vec<u16>> {
        self.check(count)?;
        if stored.starts_with(&ZSTD_MAGIC) {
            let wide = self.bits() > 8;
            let b = unpack(stored, count * if wide { 2 } else { 1 })?;
            return Ok(if wide { (0..count).map(|i| b[i] as u16 | (b[count + i] as u16) << 8).collect() } else { b.iter().map(|&v| v as u16).collect() });
        }
        match stored.split_first() {
            Some((&RANGE_TAG, coded)) => {
                // A coded bit costs at least 1/22,700 of a bit: a count
                // beyond what the bytes can hold is refused before decoding.
                if count.saturating_mul(self.bits() as usize) > (coded.len() + 8) << 18 {
                    return Err(Error::format(format!("packed payload: {} range-coded bytes cannot hold {count} symbols", coded.len())));
                }
                self.range_decode(coded, count)
            }
            _ => Err(Error::format("packed payload: a stream is neither a zstd frame nor range-coded")),
        }
    }

    /// The bytes a zstd frame holds: a symbol of up to 8 bits is one byte,
    /// of 9 to 16 two (all the low bytes first, then the high ones).
    fn bytes(&self, symbols: &[u16]) -> Vec<u8> {
        let mut out: Vec<u8> = symbols.iter().map(|&k| k as u8).collect();
        if self.bits() > 8 {
            out.extend(symbols.iter().map(|&k| (k >> 8) as u8));
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::format::test_support::unpack;
    use crate::math::rng::Rng;


    /// Both codings of every stream kind read back, at every width.
    #[test]
    fn both_codings_read_back_at_every_width() {
        let mut rng = Rng::new(4);
        let n = 700;
        for bits in [1u8, 5, 8, 9, 12, 16] {
            let mut codes = |count: usize, b: u8| -> Vec<u16> { (0..count).map(|_| ((rng.uniform() * rng.uniform() * (1u32 << b) as f64) as u32).min((1 << b) - 1) as u16).collect() };
            let scale_x = codes(n, 7);
            let rbits: Vec<u8> = (0..n / 2).map(|i| 1 + (i % bits as usize) as u8).collect();
            let mut rotation: Vec<u16> = codes(3 * rbits.len(), bits);
            rotation.iter_mut().enumerate().for_each(|(i, r)| *r &= ((1u32 << rbits[i % rbits.len()]) - 1) as u16);
            let cases: Vec<(Stream, Vec<u16>)> = vec![
                (Stream::Scale { bits }, codes(3 * n, bits)),
                (Stream::RotationIndex, codes(n, 2)),
                (Stream::Rotation { bits, rbits: &rbits }, rotation),
                (Stream::Value { bits }, codes(n, bits)),
                (Stream::Weight { bits, scale_x: &scale_x, scale_bits: 7, value: &scale_x }, codes(n, bits)),
                (Stream::GapClass { by_previous: false }, codes(n, CLASS_BITS)),
                (Stream::GapClass { by_previous: true }, codes(n, CLASS_BITS)),
            ];
            for (stream, symbols) in &cases {
                let ranged = stream.range_code(symbols);
                assert_eq!(&stream.decode(&ranged, symbols.len(), &unpack).unwrap(), symbols, "{bits} bits, range");
                let frame = zstd::bulk::compress(&stream.bytes(symbols), 3).unwrap();
                assert_eq!(&stream.decode(&frame, symbols.len(), &unpack).unwrap(), symbols, "{bits} bits, zstd");
                let stored = stream.encode(symbols, 3).unwrap();
                assert_eq!(stored.len(), ranged.len().min(frame.len()));
                // Damage: a foreign tag, a cut, a byte too many.
                assert!(stream.decode(&[9, 0, 0, 0, 0, 0], symbols.len(), &unpack).unwrap_err().to_string().contains("neither"));
                if symbols.len() > 10 {
                    assert!(stream.decode(&ranged[..ranged.len() / 2], symbols.len(), &unpack).is_err());
                }
                let mut longer = ranged.clone();
                longer.push(0);
                assert!(stream.decode(&longer, symbols.len(), &unpack).is_err());
            }
        }
    }

    /// The contexts pay where neighbours agree: y and z scales equal to
    /// the x scale cost far less than independent ones.
    #[test]
    fn correlated_scales_cost_less_under_their_contexts() {
        let mut rng = Rng::new(8);
        let n = 20_000;
        let mut level = || rng.below(16) as u16 * 8;
        let x: Vec<u16> = (0..n).map(|_| level()).collect();
        let same: Vec<u16> = x.iter().chain(&x).chain(&x).copied().collect();
        let independent: Vec<u16> = x.iter().copied().chain((0..2 * n).map(|_| level())).collect();
        let (same, independent) = (Stream::Scale { bits: 7 }.range_code(&same).len(), Stream::Scale { bits: 7 }.range_code(&independent).len());
        // Independent: 4 bits a symbol, 1.5 bytes a primitive.
        assert!(independent > 3 * n / 2, "{independent} bytes for {n} independent");
        assert!(same * 2 < independent, "{same} bytes for {n} equal, {independent} independent");
    }

    /// What a stream's contexts read must fit its length, and a count is
    /// refused before decoding when the bytes cannot hold it: each an
    /// error, never a read past an array.
    #[test]
    fn contexts_that_do_not_fit_and_counts_beyond_the_bytes_are_refused() {
        let values = [3u16; 6];
        let ranged = Stream::Value { bits: 8 }.range_code(&values);
        let e = Stream::Value { bits: 8 }.decode(&ranged, 200_000_000, &unpack).unwrap_err();
        assert!(e.to_string().contains("cannot hold 200000000 symbols"), "{e}");
        // Rotation codes wider than the stream's, or of no bits.
        for rbits in [[3u8, 5], [0, 2]] {
            let stream = Stream::Rotation { bits: 4, rbits: &rbits };
            assert!(matches!(stream.encode(&[1; 6], 3), Err(Error::InvalidArgument(_))), "{rbits:?}");
            assert!(matches!(stream.decode(&ranged, 6, &unpack), Err(Error::Format(_))), "{rbits:?}");
        }
        // Weights whose values (or scales) are fewer than they.
        let (scale_x, value) = ([1u16; 6], [1u16; 5]);
        for (s, v) in [(&scale_x[..], &value[..]), (&value[..], &scale_x[..])] {
            let stream = Stream::Weight { bits: 4, scale_x: s, scale_bits: 7, value: v };
            assert!(matches!(stream.encode(&[1; 6], 3), Err(Error::InvalidArgument(_))));
            assert!(matches!(stream.decode(&ranged, 6, &unpack), Err(Error::Format(_))));
        }
    }
}
