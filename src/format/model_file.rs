//! The model file (`.gsm`), version 1.5. All little-endian.
//!
//! ```text
//! 0   magic        8 bytes  "GSENCMDL"
//! 8   major, minor u16, u16 (1, 2; 1, 1 when the model has no support;
//!                           1, 3 when its encode fell back to the CPU;
//!                           1, 4 when it is an `auto` warm start;
//!                           1, 5 when it holds a target PSNR's curve)
//! 12  header_len   u32      bytes of the header that follows
//! 16  header       header_len bytes:
//!       payload u32 (0 float32, 1 8-bit with float16 centres,
//!                    2 8-bit with uint16 fixed-point centres, 3 packed),
//!       count u64,
//!       dims 3 x u32, bmin 3 x f64, gamma f64,
//!       vmin f64, vmax f64, transform u32 (0 linear, 1 log10),
//!       step u64, iterations u32, points u32, seed_init u64, seed_sample u64,
//!       schedule (u16 length + UTF-8), field (u16 length + UTF-8),
//!       -- 1.1: time f64 (NaN: unknown), rank u32, encode_psnr f64 (NaN: unknown)
//!       -- 1.2: support_len u32, then support_len bytes: the support
//!          (`model::Support`: one bit per reference voxel), as
//!          `support_coding.rs` stores it; 0: no support
//!       -- 1.3: fell_back (u16 length + UTF-8): the device error after
//!          which the encode ran on the CPU (1.4: empty when it did not)
//!       -- 1.4: warm start taken u8 (0 kept, 1 repaired, 2 fresh;
//!          1.5: 0xff no warm start), primitives moved u32
//!       -- 1.5: the target PSNR's curve: dB per budget doubling f64, dB
//!          per iteration doubling f64 (NaN, NaN: none)
//!       -- a newer minor version may append fields; readers skip them.
//! ..  payload      float32: count x 12 x f32, mu[3] l[3] q[4] alpha beta;
//!                  8-bit: one zstd frame of the body in `quantize.rs`;
//!                  packed: the layout in `packed/mod.rs`
//! ..  crc32        u32 over every byte before it
//! ```
//! Readers reject a foreign magic, a newer major version, any size mismatch
//! (truncation or trailing bytes) and a checksum mismatch, and accept 1.0.

use crate::error::{by_name, Error, Result};
use crate::field::{IndexFrame, Transform, ValueRange};
use crate::math::kernel::Primitive;
use crate::model::{Curve, Model, ModelMeta, Support, WarmRecord, WarmTaken};
use crate::format::packed::{Packed, Precision};
use crate::format::quantize::{self, CentreCoding, Quantized};
use crate::format::support_coding;

pub const MAGIC: &[u8; 8] = b"GSENCMDL";
pub const VERSION_MAJOR: u16 = 1;
pub const VERSION_MINOR: u16 = 5;
/// The minor version written for a model with a warm record and no curve:
/// the file is then what gsenc 1.4 wrote.
const MINOR_WARM: u16 = 4;
/// The warm record's code of a model that is no `auto` warm start (1.5).
const NO_WARM: u8 = u8::MAX;
/// The minor version written for a model whose encode fell back to the CPU
/// and that is no `auto` warm start: the file is then what gsenc 1.3 wrote.
const MINOR_FELL_BACK: u16 = 3;
/// The minor version written for a model with a support whose encode ran
/// where it was meant to: the file is then exactly what gsenc 1.2 wrote.
const MINOR_WITH_SUPPORT: u16 = 2;
/// The minor version written for a model without a support (and no
/// fall-back): the file is then exactly what gsenc 1.1 wrote.
const MINOR_WITHOUT_SUPPORT: u16 = 1;
/// Bytes a primitive of the float32 payload.
pub const BYTES_PER_PRIMITIVE: usize = 48;
const PREFIX: usize = 16;
/// A header longer than this is refused before anything else is read (the
/// file must hold it too); 1.1 readers allowed 64 KiB, before supports.
const MAX_HEADER: usize = 1 << 30;
/// zstd level of a stored support.
const SUPPORT_ZSTD_LEVEL: i32 = 19;
/// Most primitives an 8-bit or packed payload may claim (its body is
/// decompressed into memory sized from the count, so the count is bounded
/// before allocating).
const MAX_8BIT_COUNT: u64 = 1 << 32;
/// The most a zstd frame can unpack to per stored byte: an RLE block spends
/// 4 bytes on 128 KiB. A count the stored bytes cannot hold is refused before
/// anything is allocated.
const ZSTD_MAX_RATIO: usize = 1 << 15;
/// zstd level of the 8-bit payload. A model is written once per step, and at
/// this level a 200K-primitive body packs in under a second, a small fraction
/// of its encode (`convert` times in docs/BENCHMARKS.md).
const ZSTD_LEVEL: i32 = 19;

/// How the primitives are stored.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Payload {
    /// 12 float32 a primitive, exact.
    Float32,
    /// The paper's 8-bit export, then zstd (METHOD.md "Payloads").
    Bits8(CentreCoding),
    /// Each parameter group at the bits its model's encode measured it
    /// needs, in Morton order (`packed/`, METHOD.md "Payloads").
    Packed,
}

impl Payload {
    pub const ALL: [Payload; 4] =
        [Payload::Float32, Payload::Bits8(CentreCoding::Float16), Payload::Bits8(CentreCoding::Fixed16), Payload::Packed];

    pub fn code(self) -> u32 {
        match self {
            Payload::Float32 => 0,
            Payload::Bits8(CentreCoding::Float16) => 1,
            Payload::Bits8(CentreCoding::Fixed16) => 2,
            Payload::Packed => 3,
        }
    }

    pub fn from_code(code: u32) -> Option<Payload> {
        Payload::ALL.into_iter().find(|p| p.code() == code)
    }

    /// The command line's and the C API's name: `f32`, `8bit`, `8bit-u16`, `packed`.
    pub fn name(self) -> &'static str {
        match self {
            Payload::Float32 => "f32",
            Payload::Bits8(CentreCoding::Float16) => "8bit",
            Payload::Bits8(CentreCoding::Fixed16) => "8bit-u16",
            Payload::Packed => "packed",
        }
    }

    pub fn from_name(name: &str) -> Result<Payload> {
        by_name(&Payload::ALL, Payload::name, name, "payload")
    }

    /// The parameters of `model` as a reader of this payload will see them
    /// (in the order stored), so that an encoder can score what it stores.
    pub fn round_trip(self, model: &Model) -> Result<Vec<Primitive>> {
        self.coded(model)?.params()
    }

    /// `model`'s parameters coded by this payload, once, for a writer that
    /// needs both the codes and what a reader makes of them; fails on
    /// parameters the payload cannot store.
    pub fn coded(self, model: &Model) -> Result<Coded<'_>> {
        let params = &model.params;
        if self != Payload::Float32 {
            check_storable(params, self)?;
        }
        Ok(match self {
            Payload::Float32 => Coded::Float32(params),
            Payload::Bits8(c) => Coded::Bits8(Quantized::of(params, c)),
            Payload::Packed => Coded::Packed(Packed::of(params, packed_precision(model))?),
        })
    }
}

/// A model's parameters as a payload codes them ([`Payload::coded`]).
pub enum Coded<'a> {
    Float32(&'a [Primitive]),
    Bits8(Quantized),
    Packed(Packed),
}

impl Coded<'_> {
    pub fn payload(&self) -> Payload {
        match self {
            Coded::Float32(_) => Payload::Float32,
            Coded::Bits8(q) => Payload::Bits8(q.coding()),
            Coded::Packed(_) => Payload::Packed,
        }
    }

    /// The parameters a reader makes of the codes ([`Payload::round_trip`]).
    pub fn params(&self) -> Result<Vec<Primitive>> {
        match self {
            Coded::Float32(p) => Ok(p.to_vec()),
            Coded::Bits8(q) => q.dequantize(),
            Coded::Packed(p) => p.params(),
        }
    }
}

/// The precision a model is packed with: the one its encode measured, else
/// the default (with centres as coarse as a wide domain needs).
pub fn packed_precision(model: &Model) -> Precision {
    model.meta.precision.unwrap_or_else(|| Precision::DEFAULT.fitting(&model.params).unwrap_or(Precision::DEFAULT))
}

/// A model as read from a file, with how it was stored.
#[derive(Clone, Debug, PartialEq)]
pub struct ModelFile {
    pub model: Model,
    pub payload: Payload,
    /// Major and minor version of the file.
    pub version: (u16, u16),
    /// Bytes of its payload (the primitives), without header and checksum.
    pub payload_bytes: usize,
}

fn check_storable(params: &[Primitive], payload: Payload) -> Result<()> {
    if let Some(i) = params.iter().position(|p| p.iter().any(|v| !v.is_finite())) {
        return Err(Error::data(format!("primitive {i} holds a non-finite parameter; the model cannot be stored")));
    }
    if payload == Payload::Bits8(CentreCoding::Float16) {
        if let Some(i) = params.iter().position(|p| p[..3].iter().any(|&c| c.abs() > quantize::FLOAT16_MAX)) {
            return Err(Error::data(format!(
                "primitive {i}'s centre {:?} is beyond float16's range; use the 8bit-u16 payload",
                &params[i][..3]
            )));
        }
    }
    Ok(())
}

fn put_str(out: &mut Vec<u8>, s: &str) -> Result<()> {
    let len = u16::try_from(s.len()).map_err(|_| Error::arg(format!("name of {} bytes is too long", s.len())))?;
    out.extend_from_slice(&len.to_le_bytes());
    out.extend_from_slice(s.as_bytes());
    Ok(())
}

/// `s` cut to at most `max` bytes, at a character boundary.
fn clip(s: &str, max: usize) -> &str {
    let mut end = s.len().min(max);
    while !s.is_char_boundary(end) {
        end -= 1;
    }
    &s[..end]
}

/// Serialises a model with the float32 payload.
pub fn write_model(model: &Model) -> Result<Vec<u8>> {
    write_model_as(model, Payload::Float32)
}

/// The first fields of a model file's header, as laid out from its
/// version 1.0 on: the payload's code, the count, then `m`'s frame, range,
/// step, schedule, seeds, field, time, rank and encode PSNR. The store's
/// entry checksum lays the metadata out the same way (`io::store`).
pub(crate) fn put_header_start(h: &mut Vec<u8>, m: &ModelMeta, payload: Payload, count: usize) -> Result<()> {
    h.extend_from_slice(&payload.code().to_le_bytes());
    h.extend_from_slice(&(count as u64).to_le_bytes());
    for d in m.frame.dims {
        let d = u32::try_from(d).map_err(|_| Error::arg("dims exceed u32"))?;
        h.extend_from_slice(&d.to_le_bytes());
    }
    for b in m.frame.bmin {
        h.extend_from_slice(&b.to_le_bytes());
    }
    h.extend_from_slice(&m.frame.gamma.to_le_bytes());
    h.extend_from_slice(&m.range.vmin.to_le_bytes());
    h.extend_from_slice(&m.range.vmax.to_le_bytes());
    h.extend_from_slice(&(m.range.transform as u32).to_le_bytes());
    h.extend_from_slice(&m.step.to_le_bytes());
    h.extend_from_slice(&m.iterations.to_le_bytes());
    h.extend_from_slice(&m.points.to_le_bytes());
    h.extend_from_slice(&m.seed_init.to_le_bytes());
    h.extend_from_slice(&m.seed_sample.to_le_bytes());
    put_str(h, &m.schedule)?;
    put_str(h, &m.field)?;
    h.extend_from_slice(&m.time.unwrap_or(f64::NAN).to_le_bytes());
    h.extend_from_slice(&m.rank.to_le_bytes());
    h.extend_from_slice(&m.encode_psnr.unwrap_or(f64::NAN).to_le_bytes());
    Ok(())
}

/// Serialises a model with the given payload. Fails on non-finite parameters
/// (and, for float16 centres, on centres beyond its range).
pub fn write_model_as(model: &Model, payload: Payload) -> Result<Vec<u8>> {
    check_storable(&model.params, payload)?;
    let m = &model.meta;
    let mut h = Vec::with_capacity(256);
    put_header_start(&mut h, m, payload, model.params.len())?;
    let mut minor = match &model.support {
        None => MINOR_WITHOUT_SUPPORT,
        Some(support) => {
            if support.dims() != m.frame.dims {
                return Err(Error::arg(format!("the support's lattice {:?} is not the model's {:?}", support.dims(), m.frame.dims)));
            }
            let packed = support_coding::encode(support, SUPPORT_ZSTD_LEVEL)?;
            let len = u32::try_from(packed.len()).map_err(|_| Error::arg("the support does not fit a model file"))?;
            h.extend_from_slice(&len.to_le_bytes());
            h.extend_from_slice(&packed);
            MINOR_WITH_SUPPORT
        }
    };
    if m.fell_back.is_some() || m.warm.is_some() || m.curve.is_some() {
        if minor == MINOR_WITHOUT_SUPPORT {
            h.extend_from_slice(&0u32.to_le_bytes()); // no support
        }
        put_str(&mut h, clip(m.fell_back.as_deref().unwrap_or(""), u16::MAX as usize))?;
        minor = MINOR_FELL_BACK;
    }
    if m.warm.is_some() || m.curve.is_some() {
        let (code, moved) = m.warm.map_or((NO_WARM, 0), |w| (w.taken.code(), w.moved));
        h.push(code);
        h.extend_from_slice(&moved.to_le_bytes());
        minor = MINOR_WARM;
    }
    if let Some(c) = m.curve {
        if !c.is_valid() {
            return Err(Error::arg(format!("the model's target curve {c:?} is not one an encode makes")));
        }
        c.slopes().iter().for_each(|s| h.extend_from_slice(&s.to_le_bytes()));
        minor = VERSION_MINOR;
    }

    let mut out = Vec::with_capacity(PREFIX + h.len() + model.params.len() * BYTES_PER_PRIMITIVE + 4);
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(&VERSION_MAJOR.to_le_bytes());
    out.extend_from_slice(&minor.to_le_bytes());
    out.extend_from_slice(&(h.len() as u32).to_le_bytes());
    out.extend_from_slice(&h);
    match payload {
        Payload::Float32 => {
            for p in &model.params {
                for v in p {
                    out.extend_from_slice(&v.to_le_bytes());
                }
            }
        }
        Payload::Bits8(c) => {
            let body = quantize::quantize(&model.params, c);
            let packed = zstd::bulk::compress(&body, ZSTD_LEVEL).map_err(|e| Error::format(format!("zstd: {e}")))?;
            out.extend_from_slice(&packed);
        }
        Payload::Packed => out.extend_from_slice(&packed_payload(model)?),
    }
    let crc = crc32fast::hash(&out);
    out.extend_from_slice(&crc.to_le_bytes());
    Ok(out)
}

/// Reads fields from a byte slice, failing on short input.
struct Cursor<'a> {
    b: &'a [u8],
    at: usize,
}

impl<'a> Cursor<'a> {
    fn take(&mut self, n: usize) -> Result<&'a [u8]> {
        let end = self.at.checked_add(n).filter(|&e| e <= self.b.len());
        let end = end.ok_or_else(|| Error::format("model header is truncated"))?;
        let s = &self.b[self.at..end];
        self.at = end;
        Ok(s)
    }
    fn u16(&mut self) -> Result<u16> {
        Ok(u16::from_le_bytes(self.take(2)?.try_into().unwrap()))
    }
    fn u32(&mut self) -> Result<u32> {
        Ok(u32::from_le_bytes(self.take(4)?.try_into().unwrap()))
    }
    fn u64(&mut self) -> Result<u64> {
        Ok(u64::from_le_bytes(self.take(8)?.try_into().unwrap()))
    }
    fn f64(&mut self) -> Result<f64> {
        Ok(f64::from_le_bytes(self.take(8)?.try_into().unwrap()))
    }
    fn string(&mut self) -> Result<String> {
        let n = self.u16()? as usize;
        String::from_utf8(self.take(n)?.to_vec()).map_err(|_| Error::format("model header holds a name that is not UTF-8"))
    }
}

/// Parses a model file, validating everything before trusting any size.
pub fn read_model(bytes: &[u8]) -> Result<Model> {
    read_model_file(bytes).map(|f| f.model)
}

/// Like [`read_model`], also telling the payload and version.
pub fn read_model_file(bytes: &[u8]) -> Result<ModelFile> {
    if bytes.len() < MAGIC.len() || &bytes[..MAGIC.len()] != MAGIC {
        return Err(Error::format("not a gsenc model file (bad magic)"));
    }
    if bytes.len() < PREFIX {
        return Err(Error::format("model file is truncated (no header)"));
    }
    let mut c = Cursor { b: bytes, at: MAGIC.len() };
    let major = c.u16()?;
    let minor = c.u16()?;
    if major > VERSION_MAJOR {
        return Err(Error::Version(format!(
            "model file version {major}.{minor} is newer than this gsenc reads ({VERSION_MAJOR}.x); upgrade gsenc"
        )));
    }
    if major == 0 {
        return Err(Error::format(format!("model file version {major}.{minor} is not a released version")));
    }
    let header_len = c.u32()? as usize;
    if header_len > MAX_HEADER || PREFIX + header_len + 4 > bytes.len() {
        return Err(Error::format(format!("model file is truncated (header of {header_len} bytes, file of {})", bytes.len())));
    }
    let mut h = Cursor { b: &bytes[PREFIX..PREFIX + header_len], at: 0 };
    let pcode = h.u32()?;
    let payload = Payload::from_code(pcode)
        .ok_or_else(|| Error::format(format!("unknown payload kind {pcode} (corrupted, or written by a newer gsenc)")))?;
    let count = h.u64()?;
    let dims = [h.u32()? as usize, h.u32()? as usize, h.u32()? as usize];
    let bmin = [h.f64()?, h.f64()?, h.f64()?];
    let gamma = h.f64()?;
    let (vmin, vmax) = (h.f64()?, h.f64()?);
    let tcode = h.u32()?;
    let transform = Transform::from_code(tcode).ok_or_else(|| Error::format(format!("unknown value transform {tcode}")))?;
    let step = h.u64()?;
    let iterations = h.u32()?;
    let points = h.u32()?;
    let seed_init = h.u64()?;
    let seed_sample = h.u64()?;
    let schedule = h.string()?;
    let field = h.string()?;
    let unknown_is_none = |v: f64| (!v.is_nan()).then_some(v);
    let (time, rank, encode_psnr) =
        if minor >= 1 { (unknown_is_none(h.f64()?), h.u32()?, unknown_is_none(h.f64()?)) } else { (None, 0, None) };
    let packed_support = if minor >= 2 {
        let n = h.u32()? as usize;
        Some(h.take(n)?).filter(|b| !b.is_empty())
    } else {
        None
    };
    let fell_back = if minor >= 3 { Some(h.string()?).filter(|s| minor == 3 || !s.is_empty()) } else { None };
    let warm = if minor >= 4 {
        let (code, moved) = (h.take(1)?[0], h.u32()?);
        match WarmTaken::from_code(code) {
            Some(taken) => Some(WarmRecord { taken, moved }),
            None if code == NO_WARM && minor >= 5 => None,
            None => return Err(Error::format(format!("unknown warm start {code}"))),
        }
    } else {
        None
    };
    let curve = if minor >= 5 {
        let c = Curve::from_slopes([h.f64()?, h.f64()?]);
        match c.slopes().iter().all(|s| s.is_nan()) {
            true => None,
            false if c.is_valid() => Some(c),
            false => return Err(Error::format(format!("model header holds a target curve that no encode makes: {c:?}"))),
        }
    } else {
        None
    };

    let body = bytes.len() - PREFIX - header_len - 4;
    match payload {
        Payload::Float32 => {
            let expected = (count as u128) * BYTES_PER_PRIMITIVE as u128;
            if expected != body as u128 {
                return Err(Error::format(format!(
                    "model file size does not match its header: {count} primitives need {expected} payload bytes, found {body} (truncated or corrupted)"
                )));
            }
        }
        Payload::Bits8(_) | Payload::Packed if count > MAX_8BIT_COUNT => {
            return Err(Error::format(format!("model header claims {count} primitives (corrupted)")));
        }
        Payload::Bits8(_) | Payload::Packed => {}
    }
    let stored_crc = u32::from_le_bytes(bytes[bytes.len() - 4..].try_into().unwrap());
    if crc32fast::hash(&bytes[..bytes.len() - 4]) != stored_crc {
        return Err(Error::format("model file checksum mismatch (corrupted)"));
    }
    let frame = IndexFrame { dims, bmin, gamma };
    if !frame.is_valid() {
        return Err(Error::format("model header holds an invalid index frame"));
    }
    let range = ValueRange::new(vmin, vmax, transform).map_err(|e| Error::format(format!("model header: {e}")))?;
    let support = packed_support.map(|b| read_support(b, dims)).transpose()?;
    let start = PREFIX + header_len;
    let stored = &bytes[start..start + body];
    let (params, precision) = match payload {
        Payload::Float32 => (read_f32_payload(stored), None),
        Payload::Bits8(c) => (read_8bit_payload(stored, count as usize, c)?, None),
        Payload::Packed => {
            let packed = read_packed_payload(stored, count as usize)?;
            (packed.params()?, Some(packed.precision))
        }
    };
    if params.iter().any(|p| p.iter().any(|v| !v.is_finite())) {
        return Err(Error::format("model file holds non-finite parameters"));
    }
    let model = Model {
        meta: ModelMeta {
            frame,
            range,
            field,
            step,
            schedule,
            iterations,
            points,
            seed_init,
            seed_sample,
            time,
            rank,
            encode_psnr,
            fell_back,
            warm,
            precision,
            curve,
        },
        params,
        support,
    };
    Ok(ModelFile { model, payload, version: (major, minor), payload_bytes: body })
}

fn read_f32_payload(stored: &[u8]) -> Vec<Primitive> {
    stored
        .chunks_exact(BYTES_PER_PRIMITIVE)
        .map(|p| {
            let mut out = [0f32; 12];
            for (i, v) in p.chunks_exact(4).enumerate() {
                out[i] = f32::from_le_bytes(v.try_into().unwrap());
            }
            out
        })
        .collect()
}

fn read_8bit_payload(stored: &[u8], count: usize, centres: CentreCoding) -> Result<Vec<Primitive>> {
    let body = unpack(stored, quantize::body_len(count, centres), &format!("8-bit payload of {count} primitives"))?;
    quantize::dequantize(&body, count, centres)
}

/// The packed payload of `model` (at its measured precision, else the
/// default), as a model file and an HDF5 store hold it.
pub fn packed_payload(model: &Model) -> Result<Vec<u8>> {
    packed_bytes(&Packed::of(&model.params, packed_precision(model))?)
}

/// A packed payload's bytes (entropy-coded), as a model file and an HDF5
/// store hold them.
pub fn packed_bytes(packed: &Packed) -> Result<Vec<u8>> {
    packed.to_bytes(ZSTD_LEVEL)
}

/// The packed payload's codes; each symbol frame must unpack to
/// exactly the length its count and precision give.
pub fn read_packed_payload(stored: &[u8], count: usize) -> Result<Packed> {
    Packed::from_bytes(stored, count, &|frame, want| unpack(frame, want, &format!("packed payload of {count} primitives")))
}

fn read_support(stored: &[u8], dims: [usize; 3]) -> Result<Support> {
    support_coding::decode(stored, dims, &|frame, want| unpack(frame, want, "support"))
}

/// One zstd frame that must unpack to exactly `want` bytes. A length the
/// stored bytes cannot hold is refused before anything is allocated.
fn unpack(stored: &[u8], want: usize, what: &str) -> Result<Vec<u8>> {
    let corrupt = |why: String| Error::format(format!("{what} is corrupted: {why}"));
    if want > stored.len().saturating_mul(ZSTD_MAX_RATIO) {
        return Err(corrupt(format!("{} stored bytes cannot hold {want}", stored.len())));
    }
    let mut body = Vec::new();
    body.try_reserve_exact(want).map_err(|_| Error::format(format!("cannot allocate the {what}")))?;
    let mut dec = zstd::bulk::Decompressor::new().map_err(|e| corrupt(e.to_string()))?;
    let got = dec.decompress_to_buffer(stored, &mut body).map_err(|e| corrupt(e.to_string()))?;
    if got != want {
        return Err(corrupt(format!("{got} bytes unpacked, {want} expected")));
    }
    Ok(body)
}
