//! An adaptive binary range coder (the one of LZMA: 11-bit probabilities,
//! each moved a 32nd of the way to the bit it saw) and symbols coded on it
//! as bit trees under a context: the packed payload
//! ([`crate::format::packed::streams`]) codes its symbol streams with it
//! where that is smaller than zstd. Integer arithmetic only, so the bytes
//! are the same on every machine.

use crate::error::{Error, Result};

/// What opens a stored body that this coder wrote (the packed payload's
/// streams, a support), telling it from a zstd frame, which opens with
/// [`ZSTD_MAGIC`].
pub const RANGE_TAG: u8 = 1;
/// What opens a zstd frame.
pub const ZSTD_MAGIC: [u8; 4] = [0x28, 0xB5, 0x2F, 0xFD];

/// Probabilities code in units of `2^-PROB_BITS`.
const PROB_BITS: u32 = 15;
/// They are kept in units of `2^-STATE_BITS`, so that they can come as
/// close to 0 or 1 as the coding allows (a bit that is always the same
/// costs 1/22,700 of a bit).
const STATE_BITS: u32 = 31;
const STATE_ONE: u32 = 1 << STATE_BITS;
/// A probability that has coded `n` bits moves `1 / (n + 2)` of the way to
/// the next (an average of what it saw, as the Krichevsky-Trofimov
/// estimator), and after [`RATE_LIMIT`]` - 2` bits `1 / RATE_LIMIT` (it
/// then follows drift).
const RATE_LIMIT: u16 = 60;
/// The range is renormalised (a byte shifted out) below this.
const TOP: u32 = 1 << 24;

/// The adaptive probability of a 0 bit.
#[derive(Clone, Copy, Debug)]
pub struct Prob {
    zero: u32,
    /// Bits seen, up to `RATE_LIMIT - 2`.
    seen: u16,
}

impl Default for Prob {
    fn default() -> Self {
        Prob { zero: STATE_ONE / 2, seen: 0 }
    }
}

impl Prob {
    /// The probability the coder uses: 1 to `2^PROB_BITS - 1`.
    fn coded(&self) -> u32 {
        (self.zero >> (STATE_BITS - PROB_BITS)).clamp(1, (1 << PROB_BITS) - 1)
    }

    fn saw(&mut self, bit: bool) {
        let rate = (self.seen + 2) as u32;
        self.zero = if bit { self.zero - self.zero / rate } else { self.zero + (STATE_ONE - self.zero) / rate };
        self.seen = (self.seen + 1).min(RATE_LIMIT - 2);
    }
}

/// Encodes bits under adaptive probabilities.
pub struct Encoder {
    low: u64,
    range: u32,
    cache: u8,
    cache_size: u64,
    out: Vec<u8>,
}

impl Default for Encoder {
    fn default() -> Self {
        Encoder { low: 0, range: u32::MAX, cache: 0, cache_size: 1, out: Vec::new() }
    }
}

impl Encoder {
    pub fn bit(&mut self, prob: &mut Prob, bit: bool) {
        let bound = (self.range >> PROB_BITS) * prob.coded();
        if bit {
            self.low += bound as u64;
            self.range -= bound;
        } else {
            self.range = bound;
        }
        prob.saw(bit);
        while self.range < TOP {
            self.range <<= 8;
            self.shift_low();
        }
    }

    /// Writes the top byte of `low`, holding back bytes of 0xFF until a
    /// carry can no longer reach them.
    fn shift_low(&mut self) {
        if (self.low as u32) < 0xFF00_0000 || self.low >> 32 != 0 {
            let carry = (self.low >> 32) as u8;
            let mut held = self.cache;
            loop {
                self.out.push(held.wrapping_add(carry));
                held = 0xFF;
                self.cache_size -= 1;
                if self.cache_size == 0 {
                    break;
                }
            }
            self.cache = (self.low >> 24) as u8;
        }
        self.cache_size += 1;
        self.low = (self.low & 0x00FF_FFFF) << 8;
    }

    /// The coded bytes (the first is always 0).
    pub fn finish(mut self) -> Vec<u8> {
        for _ in 0..5 {
            self.shift_low();
        }
        self.out
    }
}

/// Decodes what an [`Encoder`] wrote; running past the end is an error.
pub struct Decoder<'a> {
    bytes: &'a [u8],
    at: usize,
    range: u32,
    code: u32,
}

fn truncated() -> Error {
    Error::format("range-coded stream ends early (truncated or corrupted)")
}

impl<'a> Decoder<'a> {
    pub fn new(bytes: &'a [u8]) -> Result<Decoder<'a>> {
        if bytes.len() < 5 {
            return Err(truncated());
        }
        if bytes[0] != 0 {
            return Err(Error::format("range-coded stream does not start with its zero byte (corrupted)"));
        }
        let code = u32::from_be_bytes(bytes[1..5].try_into().unwrap());
        Ok(Decoder { bytes, at: 5, range: u32::MAX, code })
    }

    pub fn bit(&mut self, prob: &mut Prob) -> Result<bool> {
        let bound = (self.range >> PROB_BITS) * prob.coded();
        let bit = if self.code < bound {
            self.range = bound;
            false
        } else {
            self.code -= bound;
            self.range -= bound;
            true
        };
        prob.saw(bit);
        while self.range < TOP {
            let byte = *self.bytes.get(self.at).ok_or_else(truncated)?;
            self.at += 1;
            self.range <<= 8;
            self.code = self.code << 8 | byte as u32;
        }
        Ok(bit)
    }

    /// Whether every byte was read: what the encoder wrote, no more.
    pub fn at_end(&self) -> bool {
        self.at == self.bytes.len()
    }
}

/// Symbols of up to `bits` bits, each coded most significant bit first
/// down a binary tree of adaptive probabilities, one tree per context.
pub struct BitTrees {
    bits: u8,
    probs: Vec<Prob>,
}

impl BitTrees {
    /// Trees for `contexts` contexts of symbols of at most `bits` (1..=16) bits.
    pub fn new(contexts: usize, bits: u8) -> BitTrees {
        assert!((1..=16).contains(&bits), "bit trees of {bits} bits");
        BitTrees { bits, probs: vec![Prob::default(); contexts << bits] }
    }

    /// The probabilities of context `ctx`.
    fn tree(&mut self, ctx: usize) -> &mut [Prob] {
        let size = 1 << self.bits;
        &mut self.probs[ctx * size..(ctx + 1) * size]
    }

    /// Codes the `bits` (at most the trees') low bits of `symbol` under `ctx`.
    pub fn encode(&mut self, e: &mut Encoder, ctx: usize, bits: u8, symbol: u32) {
        let tree = self.tree(ctx);
        let mut node = 1;
        for i in (0..bits).rev() {
            let bit = symbol >> i & 1 == 1;
            e.bit(&mut tree[node], bit);
            node = node << 1 | bit as usize;
        }
    }

    /// Reads a symbol of `bits` bits coded by [`BitTrees::encode`] under `ctx`.
    pub fn decode(&mut self, d: &mut Decoder, ctx: usize, bits: u8) -> Result<u32> {
        let tree = self.tree(ctx);
        let mut node = 1;
        for _ in 0..bits {
            node = node << 1 | d.bit(&mut tree[node])? as usize;
        }
        Ok((node - (1 << bits)) as u32)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::rng::Rng;

    /// (context, bits, symbol) triples: skewed symbols in a few contexts.
    fn symbols(seed: u64, count: usize) -> Vec<(usize, u8, u32)> {
        let mut rng = Rng::new(seed);
        (0..count)
            .map(|_| {
                let ctx = rng.below(5) as usize;
                let bits = 1 + rng.below(12) as u8;
                let skewed = (rng.uniform() * rng.uniform() * (1u64 << bits) as f64) as u32;
                (ctx, bits, skewed.min((1 << bits) - 1))
            })
            .collect()
    }

    fn encode(syms: &[(usize, u8, u32)]) -> Vec<u8> {
        let mut trees = BitTrees::new(5, 12);
        let mut e = Encoder::default();
        syms.iter().for_each(|&(c, b, s)| trees.encode(&mut e, c, b, s));
        e.finish()
    }

    fn decode(bytes: &[u8], syms: &[(usize, u8, u32)]) -> Result<(Vec<u32>, bool)> {
        let mut trees = BitTrees::new(5, 12);
        let mut d = Decoder::new(bytes)?;
        let got = syms.iter().map(|&(c, b, _)| trees.decode(&mut d, c, b)).collect::<Result<Vec<u32>>>()?;
        Ok((got, d.at_end()))
    }

    #[test]
    fn symbols_read_back_and_every_byte_is_read() {
        for (seed, count) in [(1, 0), (2, 1), (3, 7), (4, 20_000)] {
            let syms = symbols(seed, count);
            let bytes = encode(&syms);
            let (got, at_end) = decode(&bytes, &syms).unwrap();
            assert_eq!(got, syms.iter().map(|s| s.2).collect::<Vec<_>>());
            assert!(at_end, "{count} symbols: bytes left over");
        }
    }

    #[test]
    fn a_skewed_source_costs_about_its_entropy() {
        // Bits that are 1 with probability 1/16: 0.337 bits each.
        let mut rng = Rng::new(11);
        let bits: Vec<bool> = (0..80_000).map(|_| rng.below(16) == 0).collect();
        let mut p = Prob::default();
        let mut e = Encoder::default();
        bits.iter().for_each(|&b| e.bit(&mut p, b));
        let len = e.finish().len() as f64;
        let entropy = 80_000.0 * (-(1.0 / 16.0) * (1.0f64 / 16.0).log2() - (15.0 / 16.0) * (15.0f64 / 16.0).log2()) / 8.0;
        assert!(len < entropy * 1.05 && len > entropy * 0.95, "{len} bytes for {entropy:.0} bytes of entropy");
    }

    #[test]
    fn runs_of_carries_read_back() {
        // Long runs of certain bits push `low` to 0xFF.. bytes that a later
        // carry must reach.
        let mut rng = Rng::new(5);
        let bits: Vec<bool> = (0..50_000).map(|i| if i % 5000 < 4000 { true } else { rng.below(2) == 0 }).collect();
        let mut p = Prob::default();
        let mut e = Encoder::default();
        bits.iter().for_each(|&b| e.bit(&mut p, b));
        let bytes = e.finish();
        let mut p = Prob::default();
        let mut d = Decoder::new(&bytes).unwrap();
        let got: Vec<bool> = (0..bits.len()).map(|_| d.bit(&mut p).unwrap()).collect();
        assert_eq!(got, bits);
        assert!(d.at_end());
    }

    #[test]
    fn truncated_or_corrupted_streams_are_errors_not_panics() {
        let syms = symbols(9, 3000);
        let bytes = encode(&syms);
        for cut in [0, 3, 4, 5, bytes.len() / 2, bytes.len() - 1] {
            let e = decode(&bytes[..cut], &syms).unwrap_err();
            assert!(e.to_string().contains("range-coded stream"), "{e}");
        }
        let mut flipped = bytes.clone();
        flipped[0] = 1;
        assert!(decode(&flipped, &syms).unwrap_err().to_string().contains("zero byte"));
        // Garbage decodes to something or fails, never panics; bytes
        // after the end are seen.
        let mut rng = Rng::new(3);
        for _ in 0..50 {
            let mut junk: Vec<u8> = (0..bytes.len()).map(|_| rng.below(256) as u8).collect();
            junk[0] = 0;
            let _ = decode(&junk, &syms);
        }
        let mut longer = bytes;
        longer.push(7);
        assert!(!decode(&longer, &syms).unwrap().1);
    }

    /// The encoder writes `low`'s top byte as `range` shrinks, holding back
    /// a byte of 0xFF (and those after it) until a carry can no longer
    /// reach it: a carry that comes after one reaches the byte before it.
    /// `low`'s bytes, as numbers: 0x12, then 0xFF, then a carry of 1
    /// into that 0xFF make 0x13 0x00.
    #[test]
    fn a_carry_reaches_the_bytes_held_back_before_it() {
        // The next byte out is 0xFF, with nothing below it.
        let mut e = Encoder { cache: 0x12, low: 0xFF00_0000, ..Encoder::default() };
        e.shift_low();
        assert!(e.out.is_empty(), "0x12 went out before a carry could reach it: {:02x?}", e.out);
        e.low = 1 << 32; // a carry into the 0xFF held back
        e.shift_low();
        assert_eq!(e.out, [0x13, 0x00]);
    }
}
