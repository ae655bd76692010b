//! How a model file stores its support ([`crate::model::Support`]): the
//! smaller of a zstd frame of its packed bits and an adaptive range coding
//! ([`crate::format::range`]) of the bits in lattice order, each under the
//! twelve neighbours already coded (FORMAT.md "Header"). The context sees a
//! support's surface, which is all that costs: on the Richtmyer-Meshkov
//! lattices it takes 60-65 % off zstd's frame; zstd stays where it measures
//! better (round shapes that repeat row after row). A support whose outside
//! is not zero ([`crate::model::Outside`]) is stored behind
//! [`OUTSIDE_TAG`] and its two coefficients (float32 each); a zero outside
//! stores nothing, so such a file is byte for byte what an older gsenc
//! wrote.

use crate::error::{Error, Result};
use crate::format::range::{BitTrees, Decoder, Encoder, RANGE_TAG, ZSTD_MAGIC};
use crate::model::{Outside, Support};

/// Opens a stored support whose outside is not zero: then offset and gain
/// (f32 each, little-endian) and the bits as a zstd frame or range-coded.
pub const OUTSIDE_TAG: u8 = 2;
/// Lattices of more voxels are stored as zstd frames only (range coding
/// takes about 10 ns a voxel, each way).
pub const MAX_RANGE_VOXELS: usize = 1 << 27;
/// Neighbours in the context, as offsets (x, y, z) that precede a voxel in
/// lattice order (x fastest).
const TEMPLATE: [[isize; 3]; 12] = [
    [-1, 0, 0],
    [0, -1, 0],
    [0, 0, -1],
    [-1, -1, 0],
    [1, -1, 0],
    [-1, 0, -1],
    [0, -1, -1],
    [1, 0, -1],
    [0, 1, -1],
    [-2, 0, 0],
    [0, -2, 0],
    [0, 0, -2],
];
/// Border each plane keeps around the lattice so that every neighbour is
/// in it (0 there: outside the lattice is outside the support).
const PAD: usize = 2;

/// The last three z planes of the lattice, unpacked one byte a voxel with a
/// border of zeros, so that the template reads without bounds checks.
struct Planes {
    width: usize,
    size: usize,
    /// Planes z, z - 1, z - 2 (each `size` bytes), rolling.
    planes: Vec<u8>,
}

impl Planes {
    fn new(dims: [usize; 3]) -> Planes {
        let width = dims[0] + 2 * PAD;
        let size = width * (dims[1] + 2 * PAD);
        Planes { width, size, planes: vec![0; 3 * size] }
    }

    /// Starts plane `z`: what was plane z - 1 becomes z - 2, and so on.
    fn next_plane(&mut self) {
        self.planes.copy_within(self.size..2 * self.size, 2 * self.size);
        self.planes.copy_within(0..self.size, self.size);
        self.planes[..self.size].fill(0);
    }

    fn at(&self, i: usize, j: usize) -> usize {
        (i + PAD) + self.width * (j + PAD)
    }

    fn context(&self, i: usize, j: usize) -> usize {
        let at = self.at(i, j) as isize;
        TEMPLATE.iter().enumerate().fold(0, |ctx, (b, &[dx, dy, dz])| {
            let v = self.planes[(-dz) as usize * self.size + (at + dx + dy * self.width as isize) as usize];
            ctx | (v as usize) << b
        })
    }

    fn set(&mut self, i: usize, j: usize, bit: bool) {
        let at = self.at(i, j);
        self.planes[at] = bit as u8;
    }
}

fn get(bits: &[u8], v: usize) -> bool {
    bits[v / 8] >> (v % 8) & 1 == 1
}

fn range_code(support: &Support) -> Vec<u8> {
    let dims = support.dims();
    let mut planes = Planes::new(dims);
    let mut trees = BitTrees::new(1 << TEMPLATE.len(), 1);
    let mut e = Encoder::default();
    let mut v = 0;
    for _ in 0..dims[2] {
        planes.next_plane();
        for j in 0..dims[1] {
            for i in 0..dims[0] {
                let bit = get(support.bits(), v);
                trees.encode(&mut e, planes.context(i, j), 1, bit as u32);
                planes.set(i, j, bit);
                v += 1;
            }
        }
    }
    let mut out = vec![RANGE_TAG];
    out.extend(e.finish());
    out
}

fn range_decode(coded: &[u8], dims: [usize; 3], voxels: usize) -> Result<Support> {
    let mut planes = Planes::new(dims);
    let mut trees = BitTrees::new(1 << TEMPLATE.len(), 1);
    let mut d = Decoder::new(coded)?;
    let mut bits = vec![0u8; voxels.div_ceil(8)];
    let mut v = 0;
    for _ in 0..dims[2] {
        planes.next_plane();
        for j in 0..dims[1] {
            for i in 0..dims[0] {
                let bit = trees.decode(&mut d, planes.context(i, j), 1)? == 1;
                planes.set(i, j, bit);
                bits[v / 8] |= (bit as u8) << (v % 8);
                v += 1;
            }
        }
    }
    if !d.at_end() {
        return Err(Error::format("support is corrupted: bytes left after its range coding"));
    }
    Support::from_bits(dims, bits)
}

/// The stored support: its outside when not zero ([`OUTSIDE_TAG`]), then
/// the smaller of a zstd frame (at `zstd_level`) of its bits and their
/// range coding (lattices of up to [`MAX_RANGE_VOXELS`]).
pub fn encode(support: &Support, zstd_level: i32) -> Result<Vec<u8>> {
    let mut out = Vec::new();
    let o = support.outside();
    if !o.is_zero() {
        out.push(OUTSIDE_TAG);
        out.extend_from_slice(&o.offset.to_le_bytes());
        out.extend_from_slice(&o.gain.to_le_bytes());
    }
    let frame = zstd::bulk::compress(support.bits(), zstd_level).map_err(|e| Error::format(format!("zstd: {e}")))?;
    let voxels: usize = support.dims().iter().product();
    let ranged = (voxels <= MAX_RANGE_VOXELS).then(|| range_code(support)).filter(|r| r.len() < frame.len());
    out.extend(ranged.unwrap_or(frame));
    Ok(out)
}

/// Reads a stored support of the lattice `dims`. `unpack` inflates a zstd
/// frame to exactly the length it is given, or fails.
pub fn decode(stored: &[u8], dims: [usize; 3], unpack: &dyn Fn(&[u8], usize) -> Result<Vec<u8>>) -> Result<Support> {
    match stored.split_first() {
        Some((&OUTSIDE_TAG, rest)) if rest.len() >= 8 => {
            let f = |b: &[u8]| f32::from_le_bytes(b.try_into().unwrap());
            let outside = Outside { offset: f(&rest[..4]), gain: f(&rest[4..8]) };
            if outside.is_zero() {
                return Err(Error::format("support is corrupted: a zero outside is never stored"));
            }
            decode_bits(&rest[8..], dims, unpack)?.with_outside(outside).map_err(|e| Error::format(format!("support is corrupted: {e}")))
        }
        Some((&OUTSIDE_TAG, _)) => Err(Error::format("support is corrupted: its outside is cut short")),
        _ => decode_bits(stored, dims, unpack),
    }
}

/// The bits of a stored support: a zstd frame or range-coded.
fn decode_bits(stored: &[u8], dims: [usize; 3], unpack: &dyn Fn(&[u8], usize) -> Result<Vec<u8>>) -> Result<Support> {
    let voxels = dims.iter().try_fold(1usize, |a, &d| a.checked_mul(d)).filter(|&n| n > 0 && n <= 1 << 36);
    let voxels = voxels.ok_or_else(|| Error::format(format!("model header holds a support of dims {dims:?}")))?;
    let corrupt = |e: Error| Error::format(format!("support is corrupted: {e}"));
    if stored.starts_with(&ZSTD_MAGIC) {
        let bits = unpack(stored, voxels.div_ceil(8))?;
        return Support::from_bits(dims, bits).map_err(corrupt);
    }
    match stored.split_first() {
        Some((&RANGE_TAG, coded)) => {
            // No writer range-codes more, and a bit costs at least 1/22,700
            // of a bit: a claim beyond either is refused before decoding.
            if voxels > MAX_RANGE_VOXELS || voxels > (coded.len() + 8) << 18 {
                return Err(Error::format(format!("support is corrupted: {} range-coded bytes cannot hold {voxels} voxels", coded.len())));
            }
            range_decode(coded, dims, voxels).map_err(corrupt)
        }
        _ => Err(Error::format("support is corrupted: neither a zstd frame nor range-coded")),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::format::test_support::unpack;
    use crate::math::rng::Rng;


    fn of_bits(dims: [usize; 3], inside: impl Fn(usize, usize, usize) -> bool) -> Support {
        let n: usize = dims.iter().product();
        let mut bits = vec![0u8; n.div_ceil(8)];
        for v in 0..n {
            if inside(v % dims[0], v / dims[0] % dims[1], v / dims[0] / dims[1]) {
                bits[v / 8] |= 1 << (v % 8);
            }
        }
        Support::from_bits(dims, bits).unwrap()
    }

    /// A ball and a noisy slab (bits past the last whole byte on odd lattices).
    fn support(dims: [usize; 3], seed: u64) -> Support {
        let mut rng = Rng::new(seed);
        let noise: Vec<bool> = (0..dims.iter().product()).map(|_| rng.below(4) != 0).collect();
        of_bits(dims, |i, j, k| {
            let r2 = [i, j, k].iter().zip(dims).map(|(&c, d)| (c as f64 - d as f64 / 2.0).powi(2)).sum::<f64>();
            r2 < (dims[0] as f64 / 3.0).powi(2) || (k < 3 && noise[i + dims[0] * (j + dims[1] * k)])
        })
    }

    /// A mixing layer: below a rough surface `z = h(x, y)` (a sum of waves
    /// of many lengths), as in the Richtmyer-Meshkov field.
    fn rough_layer(dims: [usize; 3]) -> Support {
        let h = |i: usize, j: usize| -> f64 {
            let (x, y) = (i as f64, j as f64);
            (1..12).map(|m| (x * 0.37 * m as f64 + m as f64).sin() * (y * 0.29 * m as f64 + 2.0 * m as f64).cos() * 6.0 / m as f64).sum::<f64>()
        };
        of_bits(dims, |i, j, k| (k as f64) < dims[2] as f64 / 2.0 + h(i, j))
    }
    #[test]
    fn both_codings_read_back() {
        for (dims, seed) in [([1, 1, 2], 1), ([7, 5, 3], 2), ([33, 20, 17], 3)] {
            let s = support(dims, seed);
            assert!(s.count() > 0);
            let ranged = range_code(&s);
            assert_eq!(decode(&ranged, dims, &unpack).unwrap(), s, "{dims:?} range");
            let frame = zstd::bulk::compress(s.bits(), 3).unwrap();
            assert_eq!(decode(&frame, dims, &unpack).unwrap(), s, "{dims:?} zstd");
            assert_eq!(encode(&s, 3).unwrap().len(), ranged.len().min(frame.len()));
        }
    }

    /// The context pays on a rough surface, whose rows all differ: range
    /// coding costs far less than a zstd frame there.
    #[test]
    fn a_rough_surface_costs_less_range_coded() {
        let s = rough_layer([96, 80, 64]);
        let (ranged, frame) = (range_code(&s).len(), zstd::bulk::compress(s.bits(), 19).unwrap().len());
        assert!(ranged * 3 < frame * 2, "range {ranged} bytes, zstd {frame}");
    }

    #[test]
    fn an_outside_is_stored_ahead_of_the_bits_and_a_zero_one_not_at_all() {
        let dims = [33, 20, 17];
        let s = support(dims, 7);
        let bare = encode(&s, 3).unwrap();
        assert_ne!(bare[0], OUTSIDE_TAG);
        let o = Outside { offset: 0.0043, gain: -0.25 };
        let with = s.clone().with_outside(o).unwrap();
        let stored = encode(&with, 3).unwrap();
        assert_eq!(stored[0], OUTSIDE_TAG);
        assert_eq!(&stored[9..], &bare[..], "the bits as a zero outside stores them");
        let back = decode(&stored, dims, &unpack).unwrap();
        assert_eq!((back.outside(), back.bits()), (o, s.bits()));
        // Behind a zstd frame too.
        let framed = [&stored[..9], &zstd::bulk::compress(s.bits(), 3).unwrap()[..]].concat();
        assert_eq!(decode(&framed, dims, &unpack).unwrap(), with);
        let bad = |stored: &[u8], why: &str| {
            let e = decode(stored, dims, &unpack).unwrap_err();
            assert!(matches!(&e, Error::Format(m) if m.contains(why)), "{why}: {e}");
        };
        bad(&stored[..5], "cut short");
        bad(&[&stored[..1], &[0; 8], &bare[..]].concat(), "zero outside");
        bad(&[&stored[..1], &f32::NAN.to_le_bytes(), &[0; 4], &bare[..]].concat(), "not finite");
        bad(&[&stored[..9], &stored[..]].concat(), "neither");
    }

    #[test]
    fn damaged_range_codings_are_format_errors() {
        let dims = [33, 20, 17];
        let ranged = range_code(&support(dims, 5));
        let bad = |stored: &[u8], why: &str| {
            let e = decode(stored, dims, &unpack).unwrap_err();
            assert!(matches!(&e, Error::Format(m) if m.contains(why)), "{why}: {e}");
        };
        bad(&ranged[..ranged.len() - 1], "ends early");
        bad(&[ranged.as_slice(), &[0]].concat(), "bytes left");
        bad(&[9, 0, 0, 0, 0, 0], "neither");
        // A lattice beyond what the bytes can hold, or beyond what a
        // writer range-codes (though the bytes could hold it), or beyond
        // any support, is refused at once.
        let e = decode(&ranged, [4096, 4096, 4096], &unpack).unwrap_err();
        assert!(e.to_string().contains("cannot hold"), "{e}");
        assert!(ranged.len() < 500, "{} bytes", ranged.len());
        let e = decode(&ranged, [512, 512, 512], &unpack).unwrap_err();
        assert!(e.to_string().contains("cannot hold 134217728 voxels"), "{e}");
        let long = [ranged.as_slice(), &[0; 600]].concat();
        let e = decode(&long, [1024, 1024, 129], &unpack).unwrap_err();
        assert!(e.to_string().contains("cannot hold 135266304 voxels"), "{e}");
        let e = decode(&ranged, [1 << 13, 1 << 13, 1 << 11], &unpack).unwrap_err();
        assert!(e.to_string().contains("holds a support of dims"), "{e}");
        // Garbage after the tag decodes to some support or fails; never panics.
        let mut rng = Rng::new(6);
        for _ in 0..30 {
            let mut junk: Vec<u8> = (0..ranged.len()).map(|_| rng.below(256) as u8).collect();
            (junk[0], junk[1]) = (RANGE_TAG, 0);
            let _ = decode(&junk, dims, &unpack);
        }
    }
}
