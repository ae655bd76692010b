//! The packed payload (gsenc's; METHOD.md "Payloads", FORMAT.md "The packed
//! payload"): each parameter group quantised to the bits a [`Precision`]
//! gives it, the primitives in Morton order of their quantised centres so
//! that a centre costs only the gap to the one before it.
//!
//! | group | stored as | with `b` bits |
//! |---|---|---|
//! | centre | `mu` on a lattice of `2^-b_j` voxel from an integer origin per axis, `j` the primitive's centre class ([`centre_class`]: octaves of its smallest scale); the Morton key of the codes on the coarsest lattice of the classes present; the keys sorted, their gaps coded as a class (the gap's bit length, a symbol) and the bits below its highest; then each code's bits below that lattice | `b_j` = 0..=8 |
//! | scale | `l` clamped to `[ln 0.4, ln 8]` (the kernel's band: lossless), uniform | `2^b` levels over the band |
//! | rotation | `q / |q|` in the primitive's canonical pose ([`canonical_pose`]: of the 24 frames that give its kernel, the one nearest the identity), with its largest component made positive: that component's index (2 bits) and the other three, uniform over `[-1/√2, 1/√2]`; none for a sphere (three equal scale codes), fewer bits the closer to one ([`rotation_bits`]) | up to `2^b` levels |
//! | value | `s = sigmoid(alpha)`, the cell `floor(s 2^b)`, read back at its middle | `2^b` cells |
//! | weight | `beta`, uniform over the model's own `[min, max]` | `2^b` levels |
//!
//! ```text
//! layout      u8 0x82 (the first layout, still read, began with its one
//!             centre bit count, 0..=8, and had 5 precision bytes)
//! precision   8 x u8: centre bits of the 4 centre classes, scale,
//!             rotation, value, weight bits
//! origin      3 x f64: the integer origin of the centre lattices per axis
//! weight map  lo f32, hi f32
//! streams     6 x (u32 byte length, body): scale (3N, axis by axis),
//!             rotation index (T: the primitives that are no sphere),
//!             rotation (3T, component by component), value (N), weight
//!             (N), centre gap class (N); each body a zstd frame or a range
//!             coding under contexts, whichever is smaller
//!             ([`streams`]; the precision in [`precision`],
//!             the rotation coding in `rotation.rs`)
//! centre bits to the end: for each gap of class c > 1 its c - 1 low bits;
//!             then each primitive's centre code bits below the keys'
//!             lattice, x, y, z; least significant first; zero padding
//! ```
//! All numbers little-endian.

mod precision;
mod rotation;
pub mod streams;

pub use precision::{Precision, GROUPS, MAX_BITS, MAX_CENTRE_BITS};
pub use rotation::rotation_bits;
use rotation::{axis_turns, canonical_pose, codes_as_read, rotation_codes, rotation_value};
use crate::error::{Error, Result};
use crate::format::bits::{BitReader, BitWriter};
use crate::format::quantize::Affine;
use crate::math::kernel::{layout, morton, unmorton, Primitive, SIGMA_MAX, SIGMA_MIN};
use streams::Stream;

/// Classes of primitives by their smallest scale (one octave each from
/// [`SIGMA_MIN`], the last open above), each with a centre lattice of its
/// own ([`centre_class`]).
pub const CENTRE_CLASSES: usize = 4;

/// Symbol streams of the payload.
pub const STREAMS: usize = 6;
/// Most centre codes per axis: 21 bits, so that a Morton key fits 63.
const AXIS_BITS: u32 = 21;
/// The first byte of the payload's current layout (per-class centre
/// lattices). The first layout began with its one centre bit count,
/// 0..=8, and still reads.
const LAYOUT_CLASSES: u8 = 0x82;
/// The most bytes a stored payload's precision takes (its layout byte first).
pub const PRECISION_BYTES: usize = 1 + CENTRE_CLASSES + 4;
/// One octave of scale as a fraction of the scale band `[ln 0.4, ln 8]`,
/// in units of 2^-16: `round(2^16 ln 2 / ln 20)`. Integer, so that every
/// reader puts a primitive in the same class.
const OCTAVE_OF_BAND: u64 = 15164;

/// The centre class of a primitive with scale codes `scale` (`scale_bits`
/// bits): the octaves its smallest scale lies above [`SIGMA_MIN`], at most
/// `CENTRE_CLASSES - 1` (class 0: sigma below 0.8 voxel, 1: below 1.6,
/// 2: below 3.2, 3: the rest), in exact integer arithmetic on the code.
pub fn centre_class(scale: [u16; 3], scale_bits: u8) -> usize {
    let k = *scale.iter().min().unwrap() as u64;
    let levels = (1u64 << scale_bits) - 1;
    ((k << 16) / (OCTAVE_OF_BAND * levels)).min(CENTRE_CLASSES as u64 - 1) as usize
}

/// Primitives of `params` in each centre class, their scales coded at
/// `scale_bits` bits.
pub fn class_counts(params: &[Primitive], scale_bits: u8) -> [usize; CENTRE_CLASSES] {
    let mut counts = [0; CENTRE_CLASSES];
    params.iter().for_each(|p| counts[class_of(p, scale_bits)] += 1);
    counts
}

/// A primitive's scale code on axis `a` at `bits` bits.
fn scale_code(p: &Primitive, a: usize, bits: u8) -> u16 {
    let (lo, hi) = scale_band();
    uniform_code(p[layout::LOG_SCALE + a] as f64, lo, hi, bits)
}

/// The centre class of a primitive, its scales coded at `scale_bits` bits.
fn class_of(p: &Primitive, scale_bits: u8) -> usize {
    centre_class([0, 1, 2].map(|a| scale_code(p, a, scale_bits)), scale_bits)
}

/// The packed payload's numbers before the lossless stage: every primitive's
/// codes, in the stored (Morton) order. [`Packed::params`] is what a reader
/// of the payload gets, so an encoder scores exactly what it stores.
#[derive(Clone, Debug, PartialEq)]
pub struct Packed {
    pub precision: Precision,
    pub origin: [f64; 3],
    pub weight_map: Affine,
    /// Morton keys of the centre codes on the coarsest lattice of the
    /// centre classes present (`key_bits`), ascending.
    pub keys: Vec<u64>,
    /// Each primitive's centre code bits below that lattice, per axis: the
    /// low `centre[class] - key_bits` bits of its code on its class's lattice.
    pub low: Vec<[u32; 3]>,
    /// Scale codes, three arrays of N (axis by axis).
    pub scale: Vec<u16>,
    /// For each primitive whose scale codes differ (the others are
    /// spheres: their rotation is not stored), which quaternion component
    /// was dropped (0..=3).
    pub rotation_index: Vec<u8>,
    /// The other three components' codes of those primitives, three arrays
    /// (each at the primitive's own [`rotation_bits`]).
    pub rotation: Vec<u16>,
    pub value: Vec<u16>,
    pub weight: Vec<u16>,
}

/// The log scales the kernel distinguishes: it clamps `exp(l)` to this band.
fn scale_band() -> (f64, f64) {
    ((SIGMA_MIN as f64).ln(), (SIGMA_MAX as f64).ln())
}

fn levels(bits: u8) -> f64 {
    ((1u32 << bits) - 1) as f64
}

fn uniform_code(v: f64, lo: f64, hi: f64, bits: u8) -> u16 {
    (((v - lo) / (hi - lo)).clamp(0.0, 1.0) * levels(bits)).round() as u16
}

fn uniform_value(k: u16, lo: f64, hi: f64, bits: u8) -> f64 {
    lo + (hi - lo) * (k as f64 / levels(bits))
}

/// The gap's class: 0 for no gap, else one more than the position of its
/// highest set bit; the bits below that one follow on the bit stream.
fn gap_class(d: u64) -> u8 {
    (64 - d.leading_zeros()) as u8
}

impl Packed {
    /// Quantises primitives (all finite) at `precision`, each in its
    /// `canonical_pose`, but for those read from this payload at this
    /// precision, which keep their codes (`codes_as_read`): packing a
    /// model read from a packed payload gives the same codes again. Fails
    /// when the centres span more than 2^21 lattice steps on an axis.
    pub fn of(params: &[Primitive], precision: Precision) -> Result<Packed> {
        let precision = precision.check().map_err(|e| Error::arg(e.to_string()))?;
        let turns = axis_turns();
        let as_read: Vec<Option<(u8, [u16; 3])>> = params.iter().map(|p| codes_as_read(p, &precision)).collect();
        let posed: Vec<Primitive> = params.iter().zip(&as_read).map(|(p, read)| if read.is_some() { *p } else { canonical_pose(p, &turns) }).collect();
        let params = &posed[..];
        let n = params.len();
        let class: Vec<u8> = params.iter().map(|p| class_of(p, precision.scale) as u8).collect();
        let base = key_bits(&precision, &class);
        // Each centre on its class's lattice of 2^-bits voxel (the same
        // lattice from any integer origin), in units of that lattice.
        let cells = |i: usize| (1u64 << precision.centre[class[i] as usize]) as f64;
        let on_lattice = |i: usize, a: usize| (params[i][layout::MU + a] as f64 * cells(i)).round();
        // The origin below the lowest centre as stored (not as given, which
        // can lie below the integer its code rounds up to): a model read
        // back gets the same origin, and so the same codes.
        let mut origin = [0f64; 3];
        for (a, o) in origin.iter_mut().enumerate() {
            let lo = (0..n).map(|i| on_lattice(i, a) / cells(i)).fold(f64::INFINITY, f64::min);
            *o = if lo.is_finite() { lo.floor() + 0.0 } else { 0.0 }; // + 0.0: no -0
        }
        let mut keyed = Vec::with_capacity(n);
        let mut low = Vec::with_capacity(n);
        for i in 0..n {
            let (bits, cells) = (precision.centre[class[i] as usize], cells(i));
            let (mut coarse, mut below) = ([0u64; 3], [0u32; 3]);
            for a in 0..3 {
                let code = on_lattice(i, a) - origin[a] * cells;
                if !(code >= 0.0 && code < (1u64 << AXIS_BITS) as f64) {
                    return Err(Error::data(format!(
                        "primitive {i}'s centre is {:.0} voxels from the others on axis {a}: beyond the packed payload's 2^{} steps of 2^-{} voxel; use the 8bit-u16 payload",
                        code / cells,
                        AXIS_BITS,
                        bits
                    )));
                }
                let code = code as u64;
                coarse[a] = code >> (bits - base);
                below[a] = (code & ((1 << (bits - base)) - 1)) as u32;
            }
            keyed.push((morton(coarse), i));
            low.push(below);
        }
        keyed.sort_unstable(); // the index breaks ties: deterministic
        let order: Vec<usize> = keyed.iter().map(|&(_, i)| i).collect();
        let sorted = |f: &dyn Fn(&Primitive) -> u16| -> Vec<u16> { order.iter().map(|&i| f(&params[i])).collect() };

        let mut scale = Vec::with_capacity(3 * n);
        for a in 0..3 {
            scale.extend(sorted(&|p| scale_code(p, a, precision.scale)));
        }
        let mut rotation_index = Vec::new();
        let mut rotation: [Vec<u16>; 3] = Default::default();
        for (j, &i) in order.iter().enumerate() {
            let bits = rotation_bits([scale[j], scale[n + j], scale[2 * n + j]], precision.scale, precision.rotation);
            if bits > 0 {
                let (m, codes) = as_read[i].unwrap_or_else(|| rotation_codes(&params[i], bits));
                rotation_index.push(m);
                (0..3).for_each(|c| rotation[c].push(codes[c]));
            }
        }
        let top = (1u32 << precision.value) - 1;
        let value = sorted(&|p| {
            let s = 1.0 / (1.0 + (-(p[layout::ALPHA] as f64)).exp());
            ((s * (1u64 << precision.value) as f64).floor() as u32).min(top) as u16
        });
        let weight_map = Affine::of(params.iter().map(|p| p[layout::BETA])).with_exact_top();
        let wl = levels(precision.weight) as f32;
        let weight = sorted(&|p| weight_map.encode(p[layout::BETA], wl) as u16);
        let keys = keyed.iter().map(|k| k.0).collect();
        let low = order.iter().map(|&i| low[i]).collect();
        Ok(Packed { precision, origin, weight_map, keys, low, scale, rotation_index, rotation: rotation.concat(), value, weight })
    }

    pub fn len(&self) -> usize {
        self.keys.len()
    }

    pub fn is_empty(&self) -> bool {
        self.keys.is_empty()
    }

    /// Rotation bits of every primitive, in the stored order.
    fn rotation_bits(&self) -> Vec<u8> {
        let n = self.len();
        let p = self.precision;
        (0..n).map(|j| rotation_bits([self.scale[j], self.scale[n + j], self.scale[2 * n + j]], p.scale, p.rotation)).collect()
    }

    /// The centre class of every primitive, in the stored order.
    fn classes(&self) -> Vec<u8> {
        classes_of(&self.scale, self.len(), self.precision.scale)
    }

    /// The primitives these codes stand for, in the stored order.
    pub fn params(&self) -> Result<Vec<Primitive>> {
        let n = self.len();
        let p = self.precision.check()?;
        let bad_len = || Error::format(format!("packed payload: arrays of the wrong length for {n} primitives"));
        if self.scale.len() != 3 * n || self.low.len() != n || self.value.len() != n || self.weight.len() != n {
            return Err(bad_len());
        }
        let too_big = |v: &[u16], bits: u8| v.iter().any(|&k| (k as u32) >= 1 << bits);
        if too_big(&self.scale, p.scale) || too_big(&self.value, p.value) || too_big(&self.weight, p.weight) {
            return Err(Error::format("packed payload: a code beyond its group's bits"));
        }
        let rbits = self.rotation_bits();
        let turned = rbits.iter().filter(|&&b| b > 0).count();
        if self.rotation_index.len() != turned || self.rotation.len() != 3 * turned {
            return Err(bad_len());
        }
        if self.origin.iter().any(|o| !o.is_finite()) {
            return Err(Error::format("packed payload: non-finite centre origin"));
        }
        let wmap = self.weight_map.check().map_err(|_| Error::format("packed payload: invalid weight map"))?;
        let classes = self.classes();
        let base = key_bits(&p, &classes);
        let (llo, lhi) = scale_band();
        let mut out = vec![[0f32; 12]; n];
        let mut t = 0; // rotations read
        for (i, prim) in out.iter_mut().enumerate() {
            let bits = p.centre[classes[i] as usize];
            let shift = bits - base;
            if self.low[i].iter().any(|&l| l >> shift != 0) {
                return Err(Error::format("packed payload: centre bits beyond its class's lattice"));
            }
            let c = unmorton(self.keys[i]);
            let step = 1.0 / (1u64 << bits) as f64;
            for a in 0..3 {
                let code = c[a] << shift | self.low[i][a] as u64;
                prim[layout::MU + a] = (self.origin[a] + code as f64 * step) as f32;
                prim[layout::LOG_SCALE + a] = uniform_value(self.scale[a * n + i], llo, lhi, p.scale) as f32;
            }
            let mut q = [1.0, 0.0, 0.0, 0.0];
            if rbits[i] > 0 {
                let m = self.rotation_index[t] as usize;
                let codes = [self.rotation[t], self.rotation[turned + t], self.rotation[2 * turned + t]];
                t += 1;
                if m > 3 || codes.iter().any(|&k| (k as u32) >= 1 << rbits[i]) {
                    return Err(Error::format("packed payload: a rotation code beyond its bits"));
                }
                q = rotation_value(m, codes, rbits[i]);
            }
            for (k, qk) in q.iter().enumerate() {
                prim[layout::QUAT + k] = *qk as f32;
            }
            let s = (self.value[i] as f64 + 0.5) / (1u64 << p.value) as f64;
            prim[layout::ALPHA] = (s / (1.0 - s)).ln() as f32;
            prim[layout::BETA] = wmap.decode(self.weight[i] as f32, levels(p.weight) as f32);
        }
        Ok(out)
    }

    /// The gaps between consecutive keys (the first from 0).
    fn gaps(&self) -> impl Iterator<Item = u64> + '_ {
        self.keys.iter().scan(0u64, |prev, &k| Some(k - std::mem::replace(prev, k)))
    }

    /// The stored payload: the layout in the module documentation.
    pub fn to_bytes(&self, zstd_level: i32) -> Result<Vec<u8>> {
        let p = self.precision;
        let mut out = Vec::new();
        out.push(LAYOUT_CLASSES);
        out.extend_from_slice(&p.centre);
        out.extend_from_slice(&[p.scale, p.rotation, p.value, p.weight]);
        self.origin.iter().for_each(|o| out.extend_from_slice(&o.to_le_bytes()));
        out.extend_from_slice(&self.weight_map.lo.to_le_bytes());
        out.extend_from_slice(&self.weight_map.hi.to_le_bytes());
        let turned: Vec<u8> = self.rotation_bits().into_iter().filter(|&b| b > 0).collect();
        for (stream, symbols) in self.streams(&turned) {
            let stored = stream.encode(&symbols, zstd_level)?;
            let len = u32::try_from(stored.len()).map_err(|_| Error::arg("a packed symbol array does not fit a model file"))?;
            out.extend_from_slice(&len.to_le_bytes());
            out.extend_from_slice(&stored);
        }
        let mut w = BitWriter::default();
        for d in self.gaps() {
            let class = gap_class(d) as u32;
            if class > 1 {
                w.put(d, class - 1); // the bits below the highest
            }
        }
        let classes = self.classes();
        let base = key_bits(&p, &classes);
        for (low, class) in self.low.iter().zip(classes) {
            low.iter().for_each(|&l| w.put(l as u64, (p.centre[class as usize] - base) as u32));
        }
        out.extend_from_slice(&w.finish());
        Ok(out)
    }

    /// The symbol streams, in the stored order, each with what its
    /// contexts read; `turned` the rotation bits of the primitives whose
    /// rotation is stored.
    fn streams<'a>(&'a self, turned: &'a [u8]) -> [(Stream<'a>, Vec<u16>); STREAMS] {
        let p = self.precision;
        let n = self.len();
        let scale_x = &self.scale[..n];
        [
            (Stream::Scale { bits: p.scale }, self.scale.clone()),
            (Stream::RotationIndex, self.rotation_index.iter().map(|&m| m as u16).collect()),
            (Stream::Rotation { bits: p.rotation, rbits: turned }, self.rotation.clone()),
            (Stream::Value { bits: p.value }, self.value.clone()),
            (Stream::Weight { bits: p.weight, scale_x, scale_bits: p.scale, value: &self.value }, self.weight.clone()),
            (Stream::GapClass { by_previous: true }, self.gaps().map(|d| gap_class(d) as u16).collect()),
        ]
    }

    /// A stored payload's precision, from at most its first
    /// [`PRECISION_BYTES`], and where its fixed fields begin.
    pub fn read_precision(stored: &[u8]) -> Result<(Precision, usize)> {
        let short = || Error::format("packed payload is truncated");
        // The first layout: five precision bytes, its centre bits first.
        let (bits, at) = match stored.first() {
            Some(&b) if b <= MAX_CENTRE_BITS => ([[b; CENTRE_CLASSES].as_slice(), stored.get(1..5).ok_or_else(short)?].concat(), 5),
            Some(&LAYOUT_CLASSES) => (stored.get(1..PRECISION_BYTES).ok_or_else(short)?.to_vec(), PRECISION_BYTES),
            Some(&b) => return Err(Error::format(format!("packed payload: unknown layout (first byte {b:#04x})"))),
            None => return Err(short()),
        };
        Ok(((0..GROUPS.len()).fold(Precision::FINEST, |p, g| p.with(g, bits[g])).check()?, at))
    }

    /// Parses a stored payload of `n` primitives, in either layout (the
    /// first, of one centre lattice, reads as all classes on it). `unpack`
    /// inflates a zstd frame to exactly the length it is given, or fails.
    pub fn from_bytes(stored: &[u8], n: usize, unpack: &dyn Fn(&[u8], usize) -> Result<Vec<u8>>) -> Result<Packed> {
        let short = || Error::format("packed payload is truncated");
        let (precision, at) = Packed::read_precision(stored)?;
        // The first layout: five precision bytes, its centre bits first.
        let first_layout = at == 5;
        let fixed = at + 24 + 8;
        if stored.len() < fixed {
            return Err(short());
        }
        let f64_at = |at: usize| f64::from_le_bytes(stored[at..at + 8].try_into().unwrap());
        let f32_at = |at: usize| f32::from_le_bytes(stored[at..at + 4].try_into().unwrap());
        let origin = [f64_at(at), f64_at(at + 8), f64_at(at + 16)];
        let weight_map = Affine { lo: f32_at(at + 24), hi: f32_at(at + 28) };
        let mut rest = &stored[fixed..];
        let mut next = |stream: Stream, count: usize| -> Result<Vec<u16>> {
            let len = rest.get(..4).ok_or_else(short)?;
            let len = u32::from_le_bytes(len.try_into().unwrap()) as usize;
            let body = rest.get(4..4 + len).ok_or_else(short)?;
            rest = &rest[4 + len..];
            stream.decode(body, count, unpack)
        };
        let p = precision;
        let scale = next(Stream::Scale { bits: p.scale }, 3 * n)?;
        if scale.iter().any(|&k| (k as u32) >= 1 << p.scale) {
            return Err(Error::format("packed payload: a scale code beyond its bits"));
        }
        let turned: Vec<u8> = (0..n).map(|j| rotation_bits([scale[j], scale[n + j], scale[2 * n + j]], p.scale, p.rotation)).filter(|&b| b > 0).collect();
        let rotation_index = next(Stream::RotationIndex, turned.len())?.into_iter().map(|m| m as u8).collect();
        let rotation = next(Stream::Rotation { bits: p.rotation, rbits: &turned }, 3 * turned.len())?;
        let value = next(Stream::Value { bits: p.value }, n)?;
        let weight = next(Stream::Weight { bits: p.weight, scale_x: &scale[..n], scale_bits: p.scale, value: &value }, n)?;
        let classes = next(Stream::GapClass { by_previous: !first_layout }, n)?;
        let mut r = BitReader::new(rest);
        let mut keys = Vec::with_capacity(n);
        let mut key = 0u64;
        for class in classes {
            let gap = match class {
                0 => 0,
                c @ 1..=63 => 1 << (c - 1) | r.get(c as u32 - 1)?,
                c => return Err(Error::format(format!("packed payload: centre gap class {c}"))),
            };
            key = key.checked_add(gap).filter(|&k| k < 1 << (3 * AXIS_BITS)).ok_or_else(|| Error::format("packed payload: a centre key beyond its range"))?;
            keys.push(key);
        }
        let centre_classes = classes_of(&scale, n, p.scale);
        let base = key_bits(&p, &centre_classes);
        let mut low = Vec::with_capacity(n);
        for class in centre_classes {
            let shift = (p.centre[class as usize] - base) as u32;
            low.push([r.get(shift)? as u32, r.get(shift)? as u32, r.get(shift)? as u32]);
        }
        if !r.only_padding_left() {
            return Err(Error::format("packed payload: bytes left after the centres"));
        }
        Ok(Packed { precision, origin, weight_map, keys, low, scale, rotation_index, rotation, value, weight })
    }
}

/// The centre class of each of `n` primitives from their scale codes
/// (three arrays of `n`, `scale_bits` bits).
fn classes_of(scale: &[u16], n: usize, scale_bits: u8) -> Vec<u8> {
    (0..n).map(|j| centre_class([scale[j], scale[n + j], scale[2 * n + j]], scale_bits) as u8).collect()
}

/// The lattice the Morton keys are on: the coarsest of the centre classes
/// present (`classes`); 0 when there is none.
fn key_bits(p: &Precision, classes: &[u8]) -> u8 {
    let mut present = [false; CENTRE_CLASSES];
    classes.iter().for_each(|&c| present[c as usize] = true);
    (0..CENTRE_CLASSES).filter(|&c| present[c]).map(|c| p.centre[c]).min().unwrap_or(0)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The integer class rule agrees with the octaves of the decoded
    /// smallest scale above 0.4 voxel, at every code of every width up to
    /// 14 bits (but within 1e-4 octave of a border), and only the smallest
    /// of the three codes counts.
    #[test]
    fn centre_classes_are_octaves_of_the_smallest_scale() {
        let (lo, hi) = scale_band();
        let mut seen = [0usize; CENTRE_CLASSES];
        for bits in 1..=14u8 {
            for k in 0..=(1u16 << bits) - 1 {
                let octaves = (uniform_value(k, lo, hi, bits) - lo) / std::f64::consts::LN_2;
                let class = centre_class([k, u16::MAX >> (16 - bits), k], bits);
                if (octaves - octaves.round()).abs() > 1e-4 {
                    assert_eq!(class, (octaves.floor() as usize).min(CENTRE_CLASSES - 1), "{bits} bits, code {k}");
                }
                seen[class] += 1;
            }
        }
        assert!(seen.iter().all(|&n| n > 0), "{seen:?}");
    }
}

#[cfg(test)]
mod round_trip_tests {
    use super::*;
    use crate::format::test_support::unpack;
    use crate::math::rng::Rng;

    /// Every stored rotation is in its canonical pose: the dropped
    /// component is always w.
    #[test]
    fn stored_rotations_drop_w() {
        let mut rng = Rng::new(3);
        let params: Vec<Primitive> = (0..300).map(|_| std::array::from_fn(|k| if k < 3 { rng.range(0.0, 20.0) as f32 } else { rng.normal() as f32 })).collect();
        let packed = Packed::of(&params, Precision::DEFAULT).unwrap();
        assert!(packed.rotation_index.len() > 250);
        assert!(packed.rotation_index.iter().all(|&m| m == 0));
    }

    #[test]
    fn bytes_read_back_to_the_same_codes() {
        let mut rng = Rng::new(1);
        let params: Vec<Primitive> = (0..500).map(|_| std::array::from_fn(|k| if k < 3 { rng.range(-3.0, 60.0) as f32 } else { rng.normal() as f32 })).collect();
        for p in [Precision::DEFAULT, Precision::FINEST, Precision { centre: [0; CENTRE_CLASSES], scale: 1, rotation: 1, value: 1, weight: 1 }, Precision { centre: [3, 0, 5, 8], ..Precision::DEFAULT }] {
            let packed = Packed::of(&params, p).unwrap();
            let bytes = packed.to_bytes(3).unwrap();
            let back = Packed::from_bytes(&bytes, params.len(), &unpack).unwrap();
            assert_eq!(back, packed);
            back.params().unwrap();
        }
    }

    /// A model read from the payload and packed again at its precision is
    /// the same bytes (so that rewriting a packed model, `gsenc convert`,
    /// changes nothing), though rounding leaves some of its rotations
    /// outside the pose nearest the identity, where posing them anew would
    /// store another frame's codes; its top weight need not decode to the
    /// top of the map as computed; and its lowest centre, just below an
    /// integer, rounds up to it on a lattice of a whole voxel.
    #[test]
    fn a_model_read_back_packs_to_the_same_bytes() {
        let mut rng = Rng::new(7);
        let turns = axis_turns();
        let mut params: Vec<Primitive> = (0..800).map(|_| std::array::from_fn(|k| if k < 3 { rng.range(0.0, 60.0) as f32 } else { rng.normal() as f32 })).collect();
        for p in params.iter_mut().step_by(7) {
            p[layout::LOG_SCALE + 1] = p[layout::LOG_SCALE];
            p[layout::LOG_SCALE + 2] = p[layout::LOG_SCALE]; // spheres
        }
        params[5][layout::MU..layout::MU + 3].copy_from_slice(&[-0.3, -0.2, -0.45]);
        // Weights whose top, decoded, is not the top (an ulp of the bottom apart).
        params.iter_mut().for_each(|p| p[layout::BETA] = rng.range(-34.0, -0.01) as f32);
        (params[9][layout::BETA], params[10][layout::BETA]) = (-34.11607, -0.0057657673);
        let mut reposed = 0;
        for precision in [
            Precision::DEFAULT,
            Precision::FINEST,
            Precision { centre: [0; CENTRE_CLASSES], scale: 1, rotation: 1, value: 1, weight: 1 },
            Precision { centre: [0, 2, 1, 0], scale: 5, rotation: 5, value: 7, weight: 4 },
            Precision { centre: [3, 0, 5, 8], scale: 9, rotation: 3, value: 5, weight: 11 },
        ] {
            let first = Packed::of(&params, precision).unwrap();
            let read = first.params().unwrap();
            reposed += read.iter().filter(|p| canonical_pose(p, &turns) != **p).count();
            let again = Packed::of(&read, precision).unwrap();
            let (a, b) = (first.to_bytes(3).unwrap(), again.to_bytes(3).unwrap());
            assert!(a == b, "{precision:?}: {} bytes, then {}, from byte {:?}", a.len(), b.len(), a.iter().zip(&b).position(|(x, y)| x != y));
            assert_eq!(again.params().unwrap(), read);
        }
        assert!(reposed > 20, "only {reposed} read-back primitives lie outside their canonical pose");
    }

    fn random_params(n: usize, seed: u64) -> Vec<Primitive> {
        let mut rng = Rng::new(seed);
        (0..n).map(|_| std::array::from_fn(|k| if k < 3 { rng.range(0.0, 30.0) as f32 } else { rng.normal() as f32 })).collect()
    }

    /// A stored payload of the current layout with stream `which`'s body
    /// replaced by `body`.
    fn with_stream(stored: &[u8], which: usize, body: &[u8]) -> Vec<u8> {
        // The streams follow the precision, the origin (3 x f64) and the weight map (2 x f32).
        let mut at = PRECISION_BYTES + 24 + 8;
        let len = |at: usize| u32::from_le_bytes(stored[at..at + 4].try_into().unwrap()) as usize;
        for _ in 0..which {
            at += 4 + len(at);
        }
        let end = at + 4 + len(at);
        [&stored[..at], &(body.len() as u32).to_le_bytes(), body, &stored[end..]].concat()
    }

    /// A `Packed` built or changed by hand (its fields are public, and a
    /// zstd-coded stream may hold any code) whose arrays do not fit its
    /// count, or whose codes, origin or weight map no writer makes, is
    /// refused by `params`: none is read as other primitives, and none
    /// indexes past an array (a dropped component of 4 did).
    #[test]
    fn codes_no_writer_makes_are_refused() {
        let sound = Packed::of(&random_params(200, 4), Precision::DEFAULT).unwrap();
        sound.params().unwrap();
        let p = sound.precision;
        let first_turned_bits = sound.rotation_bits().into_iter().find(|&b| b > 0).expect("a turned primitive");
        let cases: [(&str, &dyn Fn(&mut Packed)); 11] = [
            ("wrong length", &|k| k.low.truncate(k.low.len() - 1)),
            ("wrong length", &|k| k.value.truncate(k.value.len() - 1)),
            ("wrong length", &|k| k.weight.truncate(k.weight.len() - 1)),
            ("wrong length", &|k| k.rotation.truncate(k.rotation.len() - 1)),
            ("a code beyond its group's bits", &|k| k.value[3] = 1 << p.value),
            ("a code beyond its group's bits", &|k| k.weight[3] = 1 << p.weight),
            ("non-finite centre origin", &|k| k.origin[1] = f64::NAN),
            ("invalid weight map", &|k| k.weight_map.lo = k.weight_map.hi + 1.0),
            ("invalid weight map", &|k| k.weight_map.hi = f32::INFINITY),
            ("a rotation code beyond its bits", &|k| k.rotation_index[0] = 4),
            ("a rotation code beyond its bits", &|k| k.rotation[0] = 1 << first_turned_bits),
        ];
        for (want, change) in cases {
            let mut k = sound.clone();
            change(&mut k);
            let e = k.params().unwrap_err();
            assert!(e.to_string().contains(want), "{want}: {e}");
        }
    }

    /// Values whose sigmoid rounds to 0 or 1 keep a code within their bits
    /// (the cell of s = 1 is past the last), and read back finite.
    #[test]
    fn saturated_values_keep_codes_within_their_bits() {
        let mut params = random_params(20, 5);
        params.iter_mut().enumerate().for_each(|(i, p)| p[layout::ALPHA] = if i % 2 == 0 { 1e3 } else { -1e3 });
        for value in [1, 4, 9] {
            let packed = Packed::of(&params, Precision { value, ..Precision::DEFAULT }).unwrap();
            assert!(packed.value.iter().all(|&v| v == 0 || v == (1 << value) - 1), "{value} bits: {:?}", packed.value);
            let read = packed.params().unwrap();
            assert!(read.iter().all(|p| p[layout::ALPHA].is_finite()), "{value} bits");
        }
    }

    /// A centre key past the 63 bits of three 21-bit axes is refused as the
    /// payload is parsed (the gaps' classes are each within 63).
    #[test]
    fn a_centre_key_beyond_its_range_is_refused() {
        let mut packed = Packed::of(&random_params(50, 6), Precision::DEFAULT).unwrap();
        let n = packed.len();
        (packed.keys[n - 2], packed.keys[n - 1]) = (1 << 62, 1 << 63);
        let bytes = packed.to_bytes(3).unwrap();
        let e = Packed::from_bytes(&bytes, n, &unpack).unwrap_err();
        assert!(e.to_string().contains("a centre key beyond its range"), "{e}");
    }

    /// A scale code beyond its bits, which a zstd-coded stream can hold
    /// (one byte a code of up to 8 bits), is refused as the payload is
    /// parsed, before the rotations and classes it would select are read.
    #[test]
    fn a_scale_code_beyond_its_bits_is_refused_as_the_payload_is_parsed() {
        let packed = Packed::of(&random_params(40, 7), Precision { scale: 6, ..Precision::DEFAULT }).unwrap();
        let now = packed.to_bytes(3).unwrap();
        let mut codes: Vec<u8> = packed.scale.iter().map(|&k| k as u8).collect();
        codes[5] = 1 << 6;
        let bytes = with_stream(&now, 0, &zstd::bulk::compress(&codes, 3).unwrap());
        let e = Packed::from_bytes(&bytes, packed.len(), &unpack).unwrap_err();
        assert!(e.to_string().contains("a scale code beyond its bits"), "{e}");
        // The same frame with the code in range reads.
        codes[5] = packed.scale[5] as u8;
        let bytes = with_stream(&now, 0, &zstd::bulk::compress(&codes, 3).unwrap());
        assert_eq!(Packed::from_bytes(&bytes, packed.len(), &unpack).unwrap(), packed);
    }

    /// The keys are on the coarsest lattice of the classes present: the bits
    /// of a class no primitive is in change nothing but their own byte of
    /// the precision.
    #[test]
    fn an_empty_class_changes_only_its_precision_byte() {
        let mut params = random_params(300, 8);
        // Every smallest scale below 0.8 voxel: class 0 alone.
        params.iter_mut().for_each(|p| p[layout::LOG_SCALE + 1] = 0.6f32.ln());
        let at = |centre: [u8; CENTRE_CLASSES]| Packed::of(&params, Precision { centre, ..Precision::DEFAULT }).unwrap().to_bytes(3).unwrap();
        let (coarse, same) = (at([3, 0, 1, 2]), at([3, 3, 3, 3]));
        assert_eq!(coarse[..1 + CENTRE_CLASSES], [LAYOUT_CLASSES, 3, 0, 1, 2]);
        assert_eq!(coarse[1 + CENTRE_CLASSES..], same[1 + CENTRE_CLASSES..]);
    }

    /// The first layout (one centre bit count, 0..=8, in the first byte; its
    /// gaps' classes coded without the previous class as context) still
    /// reads, at every bit count, as every class on that lattice.
    #[test]
    fn the_first_layout_reads_at_every_centre_bit_count() {
        let params = random_params(150, 9);
        for bits in 0..=MAX_CENTRE_BITS {
            let packed = Packed::of(&params, Precision { centre: [bits; CENTRE_CLASSES], ..Precision::DEFAULT }).unwrap();
            // The first layout's bytes: its one count, then the four other
            // precision bytes and the rest as they are, but for the gaps'
            // classes, coded anew.
            let classes: Vec<u16> = packed.gaps().map(|d| gap_class(d) as u16).collect();
            let coded = Stream::GapClass { by_previous: false }.encode(&classes, 3).unwrap();
            let first = [&[bits], &with_stream(&packed.to_bytes(3).unwrap(), STREAMS - 1, &coded)[1 + CENTRE_CLASSES..]].concat();
            assert_eq!(Packed::from_bytes(&first, params.len(), &unpack).unwrap(), packed, "{bits} bits");
        }
    }

    /// Codes beyond their class's lattice (a `Packed` built by hand; the
    /// reader takes exactly the bits a class has) are refused, not read as
    /// another centre.
    #[test]
    fn centre_bits_beyond_a_class_lattice_are_refused() {
        let mut rng = Rng::new(2);
        let params: Vec<Primitive> = (0..200).map(|_| std::array::from_fn(|k| if k < 3 { rng.range(0.0, 30.0) as f32 } else { rng.normal() as f32 })).collect();
        let mut packed = Packed::of(&params, Precision { centre: [2, 4, 4, 4], ..Precision::DEFAULT }).unwrap();
        let classes = packed.classes();
        let base = key_bits(&packed.precision, &classes);
        let fine = classes.iter().position(|&c| packed.precision.centre[c as usize] > base).expect("a class finer than the keys' lattice");
        packed.params().unwrap();
        packed.low[fine][1] = 1 << (packed.precision.centre[classes[fine] as usize] - base);
        let e = packed.params().unwrap_err();
        assert!(e.to_string().contains("beyond its class's lattice"), "{e}");
    }
}
