//! The paper's 8-bit export (SPEC.md "Exports"): centres in 16 bits, the
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
use crate::kernel::Primitive;
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

/// The min/max affine map of one array to `levels + 1` codes.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Affine {
    lo: f32,
    hi: f32,
}

impl Affine {
    fn of(values: impl Iterator<Item = f32>) -> Affine {
        let (lo, hi) = values.fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), v| (a.min(v), b.max(v)));
        if lo > hi {
            Affine { lo: 0.0, hi: 0.0 }
        } else {
            Affine { lo, hi }
        }
    }

    fn encode(&self, v: f32, levels: f32) -> f32 {
        if self.hi > self.lo {
            ((v - self.lo) / (self.hi - self.lo) * levels).round().clamp(0.0, levels)
        } else {
            0.0
        }
    }

    fn decode(&self, k: f32, levels: f32) -> f32 {
        self.lo + (self.hi - self.lo) * (k / levels)
    }
}

/// Bytes of the uncompressed body for `n` primitives.
pub fn body_len(n: usize, centres: CentreCoding) -> usize {
    let table = match centres {
        CentreCoding::Float16 => 0,
        CentreCoding::Fixed16 => 3 * 8,
    };
    table + 3 * 2 * n + 9 * 8 + 9 * n
}

/// Quantises primitives (all finite) into the body above.
pub fn quantize(params: &[Primitive], centres: CentreCoding) -> Vec<u8> {
    let n = params.len();
    let mut out = Vec::with_capacity(body_len(n, centres));
    match centres {
        CentreCoding::Float16 => {
            for a in 0..3 {
                out.extend(params.iter().flat_map(|p| f16::from_f32(p[a]).to_bits().to_le_bytes()));
            }
        }
        CentreCoding::Fixed16 => {
            let maps: Vec<Affine> = (0..3).map(|a| Affine::of(params.iter().map(|p| p[a]))).collect();
            for m in &maps {
                out.extend_from_slice(&m.lo.to_le_bytes());
                out.extend_from_slice(&m.hi.to_le_bytes());
            }
            for (a, m) in maps.iter().enumerate() {
                out.extend(params.iter().flat_map(|p| (m.encode(p[a], 65535.0) as u16).to_le_bytes()));
            }
        }
    }
    let maps: Vec<Affine> = (3..12).map(|k| Affine::of(params.iter().map(|p| p[k]))).collect();
    for m in &maps {
        out.extend_from_slice(&m.lo.to_le_bytes());
        out.extend_from_slice(&m.hi.to_le_bytes());
    }
    for (i, m) in maps.iter().enumerate() {
        out.extend(params.iter().map(|p| m.encode(p[3 + i], 255.0) as u8));
    }
    debug_assert_eq!(out.len(), body_len(n, centres));
    out
}

/// Rebuilds `n` primitives from a body; fails on a wrong length or a
/// non-finite table entry.
pub fn dequantize(body: &[u8], n: usize, centres: CentreCoding) -> Result<Vec<Primitive>> {
    if body.len() != body_len(n, centres) {
        return Err(Error::format(format!("8-bit payload holds {} bytes, {n} primitives need {}", body.len(), body_len(n, centres))));
    }
    let f32_at = |at: usize| f32::from_le_bytes(body[at..at + 4].try_into().unwrap());
    let u16_at = |at: usize| u16::from_le_bytes([body[at], body[at + 1]]);
    let affine_at = |at: usize| -> Result<Affine> {
        let m = Affine { lo: f32_at(at), hi: f32_at(at + 4) };
        if !(m.lo.is_finite() && m.hi.is_finite() && m.hi >= m.lo) {
            return Err(Error::format("8-bit payload has an invalid min/max table"));
        }
        Ok(m)
    };
    let mut params = vec![[0f32; 12]; n];
    let mut at = 0;
    match centres {
        CentreCoding::Float16 => {
            for a in 0..3 {
                for p in params.iter_mut() {
                    p[a] = f16::from_bits(u16_at(at)).to_f32();
                    at += 2;
                }
            }
            if params.iter().any(|p| !(p[0].is_finite() && p[1].is_finite() && p[2].is_finite())) {
                return Err(Error::format("8-bit payload holds a non-finite centre"));
            }
        }
        CentreCoding::Fixed16 => {
            let maps = [affine_at(0)?, affine_at(8)?, affine_at(16)?];
            at = 24;
            for (a, m) in maps.iter().enumerate() {
                for p in params.iter_mut() {
                    p[a] = m.decode(u16_at(at) as f32, 65535.0);
                    at += 2;
                }
            }
        }
    }
    let mut maps = Vec::with_capacity(9);
    for i in 0..9 {
        maps.push(affine_at(at + 8 * i)?);
    }
    at += 72;
    for (i, m) in maps.iter().enumerate() {
        for p in params.iter_mut() {
            p[3 + i] = m.decode(body[at] as f32, 255.0);
            at += 1;
        }
    }
    Ok(params)
}
