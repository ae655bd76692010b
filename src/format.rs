//! The model file (`.gsm`), version 1.0, float32 payload. All little-endian.
//!
//! ```text
//! 0   magic        8 bytes  "GSENCMDL"
//! 8   major, minor u16, u16 (1, 0)
//! 12  header_len   u32      bytes of the header that follows
//! 16  header       header_len bytes:
//!       payload u32 (0 = float32), count u64,
//!       dims 3 x u32, bmin 3 x f64, gamma f64,
//!       vmin f64, vmax f64, transform u32 (0 linear, 1 log10),
//!       step u64, iterations u32, points u32, seed_init u64, seed_sample u64,
//!       schedule (u16 length + UTF-8), field (u16 length + UTF-8)
//!       -- a newer minor version may append fields; readers skip them.
//! ..  payload      count x 12 x f32: mu[3] l[3] q[4] alpha beta per primitive
//! ..  crc32        u32 over every byte before it
//! ```
//! Readers reject a foreign magic, a newer major version, any size mismatch
//! (truncation or trailing bytes) and a checksum mismatch.

use crate::error::{Error, Result};
use crate::field::{IndexFrame, Transform, ValueRange};
use crate::kernel::Primitive;
use crate::model::{Model, ModelMeta};

pub const MAGIC: &[u8; 8] = b"GSENCMDL";
pub const VERSION_MAJOR: u16 = 1;
pub const VERSION_MINOR: u16 = 0;
pub const PAYLOAD_F32: u32 = 0;
pub const BYTES_PER_PRIMITIVE: usize = 48;
const PREFIX: usize = 16;
const MAX_HEADER: usize = 1 << 16;

fn put_str(out: &mut Vec<u8>, s: &str) -> Result<()> {
    let len = u16::try_from(s.len()).map_err(|_| Error::arg(format!("name of {} bytes is too long", s.len())))?;
    out.extend_from_slice(&len.to_le_bytes());
    out.extend_from_slice(s.as_bytes());
    Ok(())
}

/// Serialises a model (float32 payload).
pub fn write_model(model: &Model) -> Result<Vec<u8>> {
    let m = &model.meta;
    let mut h = Vec::with_capacity(256);
    h.extend_from_slice(&PAYLOAD_F32.to_le_bytes());
    h.extend_from_slice(&(model.params.len() as u64).to_le_bytes());
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
    put_str(&mut h, &m.schedule)?;
    put_str(&mut h, &m.field)?;

    let mut out = Vec::with_capacity(PREFIX + h.len() + model.params.len() * BYTES_PER_PRIMITIVE + 4);
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(&VERSION_MAJOR.to_le_bytes());
    out.extend_from_slice(&VERSION_MINOR.to_le_bytes());
    out.extend_from_slice(&(h.len() as u32).to_le_bytes());
    out.extend_from_slice(&h);
    for p in &model.params {
        for v in p {
            out.extend_from_slice(&v.to_le_bytes());
        }
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
    let payload = h.u32()?;
    if payload != PAYLOAD_F32 {
        return Err(Error::format(format!("unknown payload kind {payload}")));
    }
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

    let body = bytes.len() - PREFIX - header_len - 4;
    let expected = (count as u128) * BYTES_PER_PRIMITIVE as u128;
    if expected != body as u128 {
        return Err(Error::format(format!(
            "model file size does not match its header: {count} primitives need {expected} payload bytes, found {body} (truncated or corrupted)"
        )));
    }
    let stored_crc = u32::from_le_bytes(bytes[bytes.len() - 4..].try_into().unwrap());
    if crc32fast::hash(&bytes[..bytes.len() - 4]) != stored_crc {
        return Err(Error::format("model file checksum mismatch (corrupted)"));
    }
    if dims.iter().any(|&d| d == 0) || !(gamma.is_finite() && gamma > 0.0) || bmin.iter().any(|b| !b.is_finite()) {
        return Err(Error::format("model header holds an invalid index frame"));
    }
    let range = ValueRange::new(vmin, vmax, transform).map_err(|e| Error::format(format!("model header: {e}")))?;
    let start = PREFIX + header_len;
    let params: Vec<Primitive> = bytes[start..start + body]
        .chunks_exact(BYTES_PER_PRIMITIVE)
        .map(|p| {
            let mut out = [0f32; 12];
            for (i, v) in p.chunks_exact(4).enumerate() {
                out[i] = f32::from_le_bytes(v.try_into().unwrap());
            }
            out
        })
        .collect();
    Ok(Model {
        meta: ModelMeta {
            frame: IndexFrame { dims, bmin, gamma },
            range,
            field,
            step,
            schedule,
            iterations,
            points,
            seed_init,
            seed_sample,
        },
        params,
    })
}
