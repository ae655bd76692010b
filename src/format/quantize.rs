//! The paper's 8-bit export (METHOD.md "Payloads"): centres in 16 bits, the
//! other nine parameters in 8 bits through per-array min/max affine maps.
//! The body is laid out array by array (all x centres, then all y, ...), which
//! is what lets the lossless compressor in `format.rs` find the redundancy.
//!
//! ```text
//! centres, Float16:  3 arrays of N x u16 (IEEE half bits of mu_x, mu_y, mu_z)
//! centres, Fixed16:  3 x (lo f32, hi f32), then 3 arrays of N x u16,
//!                    mu = lo + k / 65535 (hi - lo)
//! then:              9 x (lo f32, hi f32) for l[3] q[4] alpha beta,
//!                    then 9 arrays of N x u8, p = lo + k / 255 (hi - lo)
//! ```
//! All numbers little-endian.

use crate::error::{Error, Result};
use crate::math::kernel::Primitive;
use half::f16;

/// The largest finite float16.
pub const FLOAT16_MAX: f32 = 65504.0;

/// How centres are stored in the 8-bit export.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CentreCoding {
    /// IEEE float16 of the index-frame coordinate (the paper's choice): steps
    /// of 1/8 voxel above coordinate 128, 1/4 above 256, 1/2 above 512.
    Float16,
    /// uint16 fixed point over the centres' own extent per axis: steps of
    /// extent / 65535 everywhere (1/256 voxel on a 256-voxel axis).
    Fixed16,
}

/// The min/max affine map of one array to `levels + 1` codes:
/// `p = lo + k / levels * (hi - lo)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Affine {
    pub lo: f32,
    pub hi: f32,
}

impl Affine {
    pub(crate) fn of(values: impl Iterator<Item = f32>) -> Affine {
        let (lo, hi) = values.fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), v| (a.min(v), b.max(v)));
        if lo > hi {
            Affine { lo: 0.0, hi: 0.0 }
        } else {
            Affine { lo, hi }
        }
    }

    /// The map whose `hi` is what its top code decodes to (`lo + (hi -
    /// lo)` in float32, which can differ from `hi` by a unit in the last
    /// place of the larger of the two), so that the values it decodes span
    /// the map again: quantised again, they get the same map and the same
    /// codes. A value above the new `hi` takes the top code, as before.
    pub(crate) fn with_exact_top(self) -> Affine {
        let mut hi = self.hi;
        for _ in 0..4 {
            let top = self.lo + (hi - self.lo);
            if top == hi {
                return Affine { lo: self.lo, hi };
            }
            hi = top;
        }
        self
    }

    pub(crate) fn encode(&self, v: f32, levels: f32) -> f32 {
        if self.hi > self.lo {
            ((v - self.lo) / (self.hi - self.lo) * levels).round().clamp(0.0, levels)
        } else {
            0.0
        }
    }

    pub(crate) fn decode(&self, k: f32, levels: f32) -> f32 {
        self.lo + (self.hi - self.lo) * (k / levels)
    }

    pub(crate) fn check(self) -> Result<Affine> {
        if !(self.lo.is_finite() && self.hi.is_finite() && self.hi >= self.lo) {
            return Err(Error::format("8-bit payload has an invalid min/max table"));
        }
        Ok(self)
    }
}

/// Stored centres: three arrays of `n` 16-bit codes (x, then y, then z).
#[derive(Clone, Debug, PartialEq)]
pub enum Centres {
    /// IEEE half bits of each coordinate.
    Float16(Vec<u16>),
    /// Fixed-point codes through one affine map per axis.
    Fixed16 { maps: [Affine; 3], codes: Vec<u16> },
}

/// The 8-bit export of `n` primitives, array by array. The `.gsm` body and
/// the HDF5 store hold exactly these numbers.
#[derive(Clone, Debug, PartialEq)]
pub struct Quantized {
    pub n: usize,
    pub centres: Centres,
    /// Maps of the nine other parameters (`l[3] q[4] alpha beta`).
    pub maps: [Affine; 9],
    /// Nine arrays of `n` codes, in the order of `maps`.
    pub codes: Vec<u8>,
}

/// Bytes of the uncompressed body for `n` primitives.
pub fn body_len(n: usize, centres: CentreCoding) -> usize {
    let table = match centres {
        CentreCoding::Float16 => 0,
        CentreCoding::Fixed16 => 3 * 8,
    };
    table + 3 * 2 * n + 9 * 8 + 9 * n
}

impl Quantized {
    /// Quantises primitives (all finite).
    pub fn of(params: &[Primitive], coding: CentreCoding) -> Quantized {
        let n = params.len();
        let centres = match coding {
            CentreCoding::Float16 => {
                Centres::Float16((0..3).flat_map(|a| params.iter().map(move |p| f16::from_f32(p[a]).to_bits())).collect())
            }
            CentreCoding::Fixed16 => {
                let maps = [0, 1, 2].map(|a| Affine::of(params.iter().map(|p| p[a])));
                let codes = (0..3).flat_map(|a| params.iter().map(move |p| maps[a].encode(p[a], 65535.0) as u16)).collect();
                Centres::Fixed16 { maps, codes }
            }
        };
        let maps: [Affine; 9] = std::array::from_fn(|k| Affine::of(params.iter().map(|p| p[3 + k])));
        let codes = (0..9).flat_map(|k| params.iter().map(move |p| maps[k].encode(p[3 + k], 255.0) as u8)).collect();
        Quantized { n, centres, maps, codes }
    }

    pub fn coding(&self) -> CentreCoding {
        match self.centres {
            Centres::Float16(_) => CentreCoding::Float16,
            Centres::Fixed16 { .. } => CentreCoding::Fixed16,
        }
    }

    /// The primitives these codes stand for. Fails on arrays of the wrong
    /// length, an invalid min/max table or a non-finite centre.
    pub fn dequantize(&self) -> Result<Vec<Primitive>> {
        let n = self.n;
        let centre_codes = match &self.centres {
            Centres::Float16(c) => c,
            Centres::Fixed16 { codes, .. } => codes,
        };
        if centre_codes.len() != 3 * n || self.codes.len() != 9 * n {
            return Err(Error::format(format!(
                "8-bit payload holds {} centre and {} parameter codes, {n} primitives need {} and {}",
                centre_codes.len(),
                self.codes.len(),
                3 * n,
                9 * n
            )));
        }
        let mut params = vec![[0f32; 12]; n];
        match &self.centres {
            Centres::Float16(c) => {
                for (i, p) in params.iter_mut().enumerate() {
                    for a in 0..3 {
                        p[a] = f16::from_bits(c[a * n + i]).to_f32();
                    }
                }
                if params.iter().any(|p| !(p[0].is_finite() && p[1].is_finite() && p[2].is_finite())) {
                    return Err(Error::format("8-bit payload holds a non-finite centre"));
                }
            }
            Centres::Fixed16 { maps, codes } => {
                for a in 0..3 {
                    let m = maps[a].check()?;
                    for (i, p) in params.iter_mut().enumerate() {
                        p[a] = m.decode(codes[a * n + i] as f32, 65535.0);
                    }
                }
            }
        }
        for k in 0..9 {
            let m = self.maps[k].check()?;
            for (i, p) in params.iter_mut().enumerate() {
                p[3 + k] = m.decode(self.codes[k * n + i] as f32, 255.0);
            }
        }
        Ok(params)
    }

    /// The body laid out as in the module documentation.
    pub fn to_body(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity(body_len(self.n, self.coding()));
        let put_map = |out: &mut Vec<u8>, m: &Affine| {
            out.extend_from_slice(&m.lo.to_le_bytes());
            out.extend_from_slice(&m.hi.to_le_bytes());
        };
        match &self.centres {
            Centres::Float16(c) => out.extend(c.iter().flat_map(|k| k.to_le_bytes())),
            Centres::Fixed16 { maps, codes } => {
                maps.iter().for_each(|m| put_map(&mut out, m));
                out.extend(codes.iter().flat_map(|k| k.to_le_bytes()));
            }
        }
        self.maps.iter().for_each(|m| put_map(&mut out, m));
        out.extend_from_slice(&self.codes);
        out
    }

    /// Parses a body of `n` primitives; fails on a wrong length.
    pub fn from_body(body: &[u8], n: usize, coding: CentreCoding) -> Result<Quantized> {
        if body.len() != body_len(n, coding) {
            return Err(Error::format(format!("8-bit payload holds {} bytes, {n} primitives need {}", body.len(), body_len(n, coding))));
        }
        let f32_at = |at: usize| f32::from_le_bytes(body[at..at + 4].try_into().unwrap());
        let map_at = |at: usize| Affine { lo: f32_at(at), hi: f32_at(at + 4) };
        let u16s = |b: &[u8]| b.chunks_exact(2).map(|k| u16::from_le_bytes([k[0], k[1]])).collect::<Vec<u16>>();
        let (centres, at) = match coding {
            CentreCoding::Float16 => (Centres::Float16(u16s(&body[..6 * n])), 6 * n),
            CentreCoding::Fixed16 => {
                let maps = [map_at(0), map_at(8), map_at(16)];
                (Centres::Fixed16 { maps, codes: u16s(&body[24..24 + 6 * n]) }, 24 + 6 * n)
            }
        };
        let maps = std::array::from_fn(|k| map_at(at + 8 * k));
        Ok(Quantized { n, centres, maps, codes: body[at + 72..].to_vec() })
    }
}

/// Quantises primitives (all finite) into the body above.
pub fn quantize(params: &[Primitive], centres: CentreCoding) -> Vec<u8> {
    Quantized::of(params, centres).to_body()
}

/// Rebuilds `n` primitives from a body; fails on a wrong length or a
/// non-finite table entry.
pub fn dequantize(body: &[u8], n: usize, centres: CentreCoding) -> Result<Vec<Primitive>> {
    Quantized::from_body(body, n, centres)?.dequantize()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::rng::Rng;

    /// With an exact top, the values a map decodes span the map again: the
    /// map of the decoded values is the map, and their codes are theirs.
    /// Without it, the top code of some maps decodes a unit in the last
    /// place below `hi`.
    #[test]
    fn a_map_with_an_exact_top_is_the_map_of_what_it_decodes() {
        let mut rng = Rng::new(4);
        let mut inexact = 0;
        for _ in 0..2000 {
            let (a, b) = (rng.range(-40.0, 10.0) as f32, rng.range(-5.0, 40.0) as f32);
            let (lo, hi) = (a.min(b), a.max(b));
            let levels = [1.0, 15.0, 255.0, 2047.0][rng.below(4) as usize];
            inexact += (Affine { lo, hi }.decode(levels, levels) != hi) as usize;
            let map = Affine::of([lo, hi].into_iter()).with_exact_top();
            assert!(map.lo == lo && (map.hi - hi).abs() <= hi.abs().max(lo.abs()) * f32::EPSILON, "{map:?} from {hi}");
            assert_eq!(map.decode(levels, levels), map.hi, "{map:?}");
            let decoded: Vec<f32> = (0..=levels as u32).map(|k| map.decode(k as f32, levels)).collect();
            assert_eq!(Affine::of(decoded.iter().copied()), map);
            assert!(decoded.iter().enumerate().all(|(k, &v)| map.encode(v, levels) == k as f32), "{map:?}");
        }
        assert!(inexact > 100, "only {inexact} of 2000 maps have an inexact top");
    }

    /// A body whose tables or centres a writer cannot have made is refused
    /// by `dequantize` itself, whichever table or axis holds the fault (the
    /// readers' later check for non-finite parameters would not see a map
    /// whose `hi` is below its `lo`: it decodes finite values).
    #[test]
    fn a_body_with_an_invalid_table_or_centre_is_refused() {
        let mut rng = Rng::new(9);
        let params: Vec<Primitive> = (0..5).map(|_| std::array::from_fn(|_| rng.range(-3.0, 30.0) as f32)).collect();
        for coding in [CentreCoding::Float16, CentreCoding::Fixed16] {
            let body = quantize(&params, coding);
            assert!(dequantize(&body, 5, coding).is_ok());
            // Where each map starts: Fixed16's three centre maps, then the
            // first and the last of the nine parameter maps (after the
            // centres' codes).
            let params_at = body_len(5, coding) - 9 * 8 - 9 * 5;
            let maps: Vec<usize> = match coding {
                CentreCoding::Float16 => vec![params_at, params_at + 8 * 8],
                CentreCoding::Fixed16 => vec![0, 8, 16, params_at, params_at + 8 * 8],
            };
            for &at in &maps {
                let put = |lo: f32, hi: f32| {
                    let mut b = body.clone();
                    b[at..at + 4].copy_from_slice(&lo.to_le_bytes());
                    b[at + 4..at + 8].copy_from_slice(&hi.to_le_bytes());
                    b
                };
                for (lo, hi) in [(2.0, 1.0), (f32::NAN, 1.0), (f32::NEG_INFINITY, 1.0), (0.0, f32::INFINITY), (0.0, f32::NAN)] {
                    let e = dequantize(&put(lo, hi), 5, coding).expect_err("an invalid map");
                    assert!(e.to_string().contains("invalid min/max table"), "{coding:?} at {at}, ({lo}, {hi}): {e}");
                }
                assert!(dequantize(&put(1.0, 1.0), 5, coding).is_ok(), "a constant array's map is valid");
            }
        }
        // A float16 centre that is infinite or NaN, on each axis.
        let body = quantize(&params, CentreCoding::Float16);
        for axis in 0..3 {
            for bits in [f16::INFINITY.to_bits(), f16::NAN.to_bits()] {
                let mut b = body.clone();
                let at = 2 * (axis * 5 + 3);
                b[at..at + 2].copy_from_slice(&bits.to_le_bytes());
                let e = dequantize(&b, 5, CentreCoding::Float16).expect_err("a non-finite centre");
                assert!(e.to_string().contains("non-finite centre"), "axis {axis}: {e}");
            }
        }
    }

    /// Arrays built by hand (the HDF5 store reads them one by one) whose
    /// lengths do not match the count are refused, centres or codes.
    #[test]
    fn arrays_of_the_wrong_length_are_refused() {
        let params: Vec<Primitive> = (0..4).map(|i| std::array::from_fn(|k| (i * 12 + k) as f32)).collect();
        for coding in [CentreCoding::Float16, CentreCoding::Fixed16] {
            let q = Quantized::of(&params, coding);
            assert_eq!(q.dequantize().unwrap().len(), 4);
            let mut short_codes = q.clone();
            short_codes.codes.pop();
            let mut long_centres = q.clone();
            match &mut long_centres.centres {
                Centres::Float16(c) | Centres::Fixed16 { codes: c, .. } => c.push(0),
            }
            for (what, bad) in [("codes", short_codes), ("centres", long_centres)] {
                let e = bad.dequantize().expect_err(what);
                assert!(e.to_string().contains("4 primitives need 12 and 36"), "{coding:?} {what}: {e}");
            }
        }
    }
}
