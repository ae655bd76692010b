//! One model of a store, `/<field>/<step>/rank_<r>`: its attributes and
//! datasets as written (`write_entry`) and as read back (`read_info`,
//! `read_params`, `read_support`), side by side, and the checksum over what
//! a reader makes of them (`entry_crc`). `docs/FORMAT.md` ("The HDF5
//! store", "The entry checksum") is the reference; `mod.rs` is the file
//! around the entries: creating, appending and committing, listing.

use super::{EntryInfo, EntryKey};
use crate::error::{Error, Result};
use crate::field::{IndexFrame, Transform, ValueRange};
use crate::format::model_file::{packed_bytes, put_header_start, read_packed_payload, Coded};
use crate::format::packed::{Packed, PRECISION_BYTES};
use crate::format::quantize::{Affine, CentreCoding, Centres, Quantized};
use crate::format::Payload;
use crate::math::kernel::Primitive;
use crate::model::{Curve, Model, ModelMeta, Outside, Support, WarmRecord, WarmTaken};
use hdf5::types::VarLenUnicode;
use hdf5::{Dataset, Group, H5Type, Location};
use std::path::Path;

/// An entry's checksum attribute (1.4).
pub(super) const CRC: &str = "crc32";
/// Names of the twelve parameters, in the order of the `params` rows.
pub const PARAMETER_NAMES: [&str; 12] =
    ["mu_x", "mu_y", "mu_z", "l_x", "l_y", "l_z", "q_w", "q_x", "q_y", "q_z", "alpha", "beta"];
/// Most primitives in one chunk of a parameter row (deflate works per chunk).
const CHUNK: usize = 1 << 20;
const DEFLATE_LEVEL: u8 = 6;

/// The text of a string attribute as read, or `None` when its bytes are
/// not UTF-8 (a damaged or foreign file): `VarLenUnicode::as_str` does not
/// check them, and a `String` that is not UTF-8 breaks what every `str`
/// operation relies on (formatting one panicked; anything may happen).
pub(super) fn utf8(v: &VarLenUnicode) -> Option<String> {
    std::str::from_utf8(v.as_bytes()).ok().map(str::to_owned)
}

pub(super) fn scalar_attr<T: H5Type>(loc: &Location, name: &str, v: &T) -> hdf5::Result<()> {
    loc.new_attr::<T>().create(name)?.write_scalar(v)
}

pub(super) fn scalar_str_attr(loc: &Location, name: &str, v: &str) -> hdf5::Result<()> {
    let v: VarLenUnicode = v.parse().map_err(|e| hdf5::Error::from(format!("attribute {name}: {e}")))?;
    scalar_attr(loc, name, &v)
}

fn array_attr<T: H5Type + Copy>(loc: &Location, name: &str, v: &[T]) -> hdf5::Result<()> {
    loc.new_attr::<T>().shape(v.len()).create(name)?.write_raw(v)
}

/// A `rows x n` dataset of one parameter per row, deflated when `compress`.
fn rows_dataset<T: H5Type + Copy>(g: &Group, name: &str, rows: usize, data: &[T], compress: bool) -> hdf5::Result<Dataset> {
    let n = data.len() / rows;
    let mut b = g.new_dataset::<T>().shape((rows, n));
    if compress && n > 0 {
        b = b.chunk((1, n.min(CHUNK))).shuffle().deflate(DEFLATE_LEVEL);
    }
    let ds = b.create(name)?;
    ds.write_raw(data)?;
    Ok(ds)
}

fn maps_attrs(ds: &Dataset, maps: &[Affine]) -> hdf5::Result<()> {
    array_attr(ds, "lo", &maps.iter().map(|m| m.lo).collect::<Vec<_>>())?;
    array_attr(ds, "hi", &maps.iter().map(|m| m.hi).collect::<Vec<_>>())
}

/// An entry's checksum (1.4, attribute `crc32`): CRC-32 (IEEE, as zlib)
/// of its payload's code, count and metadata laid out as a model file's
/// header starts (`put_header_start`), then the metadata the header keeps
/// further on (why the encode fell back to the CPU, as a u64 length and
/// UTF-8 bytes; a warm start's code and moved count, or 0xff; a target
/// PSNR's curve, 1.5, only where there is one), the support's bits and its
/// outside (offset, gain), and last the float32
/// bits of every parameter as a reader gets them, little-endian, primitive
/// by primitive. So whatever a reader makes of the entry is checked, and
/// nothing in it depends on a compressor's version.
pub(super) fn entry_crc(m: &ModelMeta, payload: Payload, params: &[Primitive], support: Option<&Support>) -> Result<u32> {
    // The metadata as a reader gets it: a NaN time or PSNR (of whatever
    // bits) reads as unknown, which the header writes as the one NaN.
    let known = |v: Option<f64>| v.filter(|v| !v.is_nan());
    let m = &ModelMeta { time: known(m.time), encode_psnr: known(m.encode_psnr), ..m.clone() };
    let mut h = Vec::with_capacity(256);
    put_header_start(&mut h, m, payload, params.len())?;
    let fell_back = m.fell_back.as_deref().unwrap_or("");
    h.extend_from_slice(&(fell_back.len() as u64).to_le_bytes());
    h.extend_from_slice(fell_back.as_bytes());
    match m.warm {
        Some(w) => {
            h.push(w.taken.code());
            h.extend_from_slice(&w.moved.to_le_bytes());
        }
        None => h.push(u8::MAX),
    }
    if let Some(c) = m.curve {
        c.slopes().iter().for_each(|s| h.extend_from_slice(&s.to_le_bytes()));
    }
    let mut crc = crc32fast::Hasher::new();
    crc.update(&h);
    if let Some(s) = support {
        crc.update(s.bits());
        crc.update(&s.outside().offset.to_le_bytes());
        crc.update(&s.outside().gain.to_le_bytes());
    }
    let mut bytes = [0u8; 48];
    for p in params {
        for (b, v) in bytes.chunks_exact_mut(4).zip(p) {
            b.copy_from_slice(&v.to_le_bytes());
        }
        crc.update(&bytes);
    }
    Ok(crc.finalize())
}

/// Writes `model`'s datasets and attributes into `g`: its parameters as
/// `coded` (its payload's codes, made once by the append), and `read_back`,
/// what a reader makes of them ([`Coded::params`]), in the checksum.
pub(super) fn write_entry(g: &Group, model: &Model, coded: &Coded, read_back: &[Primitive]) -> hdf5::Result<()> {
    let m = &model.meta;
    let n = model.params.len();
    let payload = coded.payload();
    let lib = |e: Error| hdf5::Error::from(e.to_string());
    match coded {
        Coded::Float32(params) => {
            let rows: Vec<f32> = (0..12).flat_map(|k| params.iter().map(move |p| p[k])).collect();
            rows_dataset(g, "params", 12, &rows, false)?;
        }
        Coded::Bits8(q) => {
            match &q.centres {
                Centres::Float16(bits) => {
                    let half: Vec<half::f16> = bits.iter().map(|&b| half::f16::from_bits(b)).collect();
                    rows_dataset(g, "centres", 3, &half, true)?;
                }
                Centres::Fixed16 { maps, codes } => maps_attrs(&rows_dataset(g, "centres", 3, codes, true)?, maps)?,
            }
            maps_attrs(&rows_dataset(g, "codes", 9, &q.codes, true)?, &q.maps)?;
        }
        Coded::Packed(packed) => {
            // The model file's packed payload as it is (already entropy-coded).
            let bytes = packed_bytes(packed).map_err(lib)?;
            g.new_dataset::<u8>().shape(bytes.len()).create("packed")?.write_raw(&bytes)?;
        }
    }
    scalar_attr(g, CRC, &entry_crc(m, payload, read_back, model.support.as_ref()).map_err(lib)?)?;
    scalar_str_attr(g, "payload", payload.name())?;
    scalar_attr(g, "count", &(n as u64))?;
    scalar_str_attr(g, "field", &m.field)?;
    scalar_attr(g, "step", &m.step)?;
    scalar_attr(g, "time", &m.time.unwrap_or(f64::NAN))?;
    scalar_attr(g, "rank", &m.rank)?;
    array_attr(g, "dims", &m.frame.dims.map(|d| d as u64))?;
    array_attr(g, "bmin", &m.frame.bmin)?;
    scalar_attr(g, "gamma", &m.frame.gamma)?;
    scalar_attr(g, "vmin", &m.range.vmin)?;
    scalar_attr(g, "vmax", &m.range.vmax)?;
    scalar_str_attr(g, "transform", m.range.transform.name())?;
    scalar_str_attr(g, "schedule", &m.schedule)?;
    scalar_attr(g, "iterations", &m.iterations)?;
    scalar_attr(g, "points", &m.points)?;
    scalar_attr(g, "seed_init", &m.seed_init)?;
    scalar_attr(g, "seed_sample", &m.seed_sample)?;
    scalar_attr(g, "encode_psnr", &m.encode_psnr.unwrap_or(f64::NAN))?;
    if let Some(why) = &m.fell_back {
        scalar_str_attr(g, "fell_back", why)?;
    }
    if let Some(w) = &m.warm {
        scalar_str_attr(g, "warm_start", w.taken.name())?;
        scalar_attr(g, "warm_moved", &w.moved)?;
    }
    if let Some(c) = &m.curve {
        array_attr(g, "target_curve", &c.slopes())?;
    }
    if let Some(support) = &model.support {
        // The packed bits, one per reference voxel (x fastest, least
        // significant bit first), deflated like the 8-bit codes.
        let bits = support.bits();
        let ds = g.new_dataset::<u8>().shape(bits.len()).chunk(bits.len().clamp(1, CHUNK)).deflate(DEFLATE_LEVEL).create("support")?;
        ds.write_raw(bits)?;
        let o = support.outside();
        if !o.is_zero() {
            array_attr(&ds, "outside", &[o.offset, o.gain])?;
        }
    }
    scalar_str_attr(g, "parameters", &PARAMETER_NAMES.join(" "))
}

/// The entry's support, when it has one.
pub(super) fn read_support(g: &Group, info: &EntryInfo, path: &Path, budget: u64) -> Result<Option<Support>> {
    let Ok(ds) = g.dataset("support") else { return Ok(None) };
    let bad = |what: String| Error::format(format!("{}:{} {what}", path.display(), EntryKey::of(&info.meta).path()));
    let bits: Vec<u8> = read_all(&ds, "support", budget, &bad)?;
    let support = Support::from_bits(info.meta.frame.dims, bits).map_err(|e| bad(e.to_string()))?;
    // 1.2: the decode outside it, when not zero.
    let Ok(a) = ds.attr("outside") else { return Ok(Some(support)) };
    let v: Vec<f32> = read_all(&a, "support attribute outside", budget, &bad)?;
    let [offset, gain] = v[..] else { return Err(bad(format!("support attribute outside holds {} values, not 2", v.len()))) };
    support.with_outside(Outside { offset, gain }).map(Some).map_err(|e| bad(e.to_string()))
}

pub(super) fn read_info(g: &Group, key: &EntryKey, path: &Path, budget: u64) -> Result<EntryInfo> {
    let bad = |what: String| Error::format(format!("{}:{} {what} (an append cut short, or not written by gsenc)", path.display(), key.path()));
    let scalar = |name: &str| -> Result<hdf5::Attribute> { g.attr(name).map_err(|_| bad(format!("has no attribute '{name}'"))) };
    let f64a = |name: &str| scalar(name)?.read_scalar::<f64>().map_err(|e| bad(format!("attribute {name}: {e}")));
    let u64a = |name: &str| scalar(name)?.read_scalar::<u64>().map_err(|e| bad(format!("attribute {name}: {e}")));
    let u32a = |name: &str| scalar(name)?.read_scalar::<u32>().map_err(|e| bad(format!("attribute {name}: {e}")));
    let stra = |name: &str| {
        let v = scalar(name)?.read_scalar::<VarLenUnicode>().map_err(|e| bad(format!("attribute {name}: {e}")))?;
        utf8(&v).ok_or_else(|| bad(format!("attribute {name} is not UTF-8 text")))
    };
    let f64s = |name: &str, len: usize| -> Result<Vec<f64>> {
        let v: Vec<f64> = read_all(&*scalar(name)?, &format!("attribute {name}"), budget, &bad)?;
        if v.len() != len {
            return Err(bad(format!("attribute {name} holds {} values, not {len}", v.len())));
        }
        Ok(v)
    };
    let payload_name = stra("payload")?;
    let payload = Payload::from_name(&payload_name).map_err(|_| bad(format!("has an unknown payload '{payload_name}'")))?;
    let dims_raw: Vec<u64> = read_all(&*scalar("dims")?, "attribute dims", budget, &bad)?;
    let dims: [usize; 3] = match dims_raw.as_slice() {
        [x, y, z] if [x, y, z].iter().all(|&&d| d > 0 && d <= u32::MAX as u64) => [*x as usize, *y as usize, *z as usize],
        _ => return Err(bad(format!("has invalid dims {dims_raw:?}"))),
    };
    let bmin = f64s("bmin", 3)?;
    let frame = IndexFrame { dims, bmin: [bmin[0], bmin[1], bmin[2]], gamma: f64a("gamma")? };
    if !frame.is_valid() {
        return Err(bad("holds an invalid index frame".into()));
    }
    let transform_name = stra("transform")?;
    let transform = Transform::from_name(&transform_name).ok_or_else(|| bad(format!("has an unknown transform '{transform_name}'")))?;
    let range = ValueRange::new(f64a("vmin")?, f64a("vmax")?, transform).map_err(|e| bad(e.to_string()))?;
    let unknown_is_none = |v: f64| (!v.is_nan()).then_some(v);
    let meta = ModelMeta {
        frame,
        range,
        field: stra("field")?,
        step: u64a("step")?,
        schedule: stra("schedule")?,
        iterations: u32a("iterations")?,
        points: u32a("points")?,
        seed_init: u64a("seed_init")?,
        seed_sample: u64a("seed_sample")?,
        time: unknown_is_none(f64a("time")?),
        rank: u32a("rank")?,
        encode_psnr: unknown_is_none(f64a("encode_psnr")?),
        // Only where the encode fell back to the CPU.
        fell_back: if g.attr("fell_back").is_ok() { Some(stra("fell_back")?) } else { None },
        // Only for an `auto` warm-started step.
        warm: if g.attr("warm_start").is_ok() {
            let name = stra("warm_start")?;
            let taken = WarmTaken::from_name(&name).map_err(|_| bad(format!("has an unknown warm start '{name}'")))?;
            Some(WarmRecord { taken, moved: u32a("warm_moved")? })
        } else {
            None
        },
        precision: None, // a packed payload's, below
        // Only for a target PSNR's encode (1.5).
        curve: if g.attr("target_curve").is_ok() {
            let v = f64s("target_curve", 2)?;
            let c = Curve::from_slopes([v[0], v[1]]);
            if !c.is_valid() {
                return Err(bad(format!("has a target curve that no encode makes: {c:?}")));
            }
            Some(c)
        } else {
            None
        },
    };
    if EntryKey::of(&meta) != *key {
        return Err(bad(format!("says it is /{}/{}/rank_{}", meta.field, meta.step, meta.rank)));
    }
    let count = u64a("count")?;
    let names: &[&str] = match payload {
        Payload::Float32 => &["params"],
        Payload::Bits8(_) => &["centres", "codes"],
        Payload::Packed => &["packed"],
    };
    let mut stored_bytes = 0;
    for name in names {
        stored_bytes += g.dataset(name).map_err(|_| bad(format!("has no dataset '{name}'")))?.storage_size();
    }
    let mut meta = meta;
    if payload == Payload::Packed {
        // From the payload's first bytes: a listing reads no more of it.
        let ds = g.dataset("packed").map_err(|_| bad("has no dataset 'packed'".into()))?;
        let head = ds.read_slice_1d::<u8, _>(..ds.size().min(PRECISION_BYTES)).map_err(|e| bad(format!("dataset packed: {e}")))?;
        let (precision, _) = Packed::read_precision(&head.to_vec()).map_err(|e| bad(e.to_string()))?;
        meta.precision = Some(precision);
    }
    Ok(EntryInfo { meta, payload, count, stored_bytes })
}

/// The values of a dataset or an attribute, refusing one whose declared
/// size goes beyond `budget` (the reader's share of the memory available,
/// `io/budget.rs`) unread: a foreign file may declare a dataset far larger
/// than it stores (HDF5 reads unwritten chunks as the fill value), whose
/// read would otherwise ask for that much memory.
pub(super) fn read_all<T: H5Type>(c: &hdf5::Container, what: &str, budget: u64, bad: &dyn Fn(String) -> Error) -> Result<Vec<T>> {
    let bytes = (c.size() as u64).saturating_mul(std::mem::size_of::<T>() as u64);
    if bytes > budget {
        return Err(bad(format!("{what} declares {bytes} bytes, more than the {budget} a read of it may take of the memory available")));
    }
    c.read_raw::<T>().map_err(|e| bad(format!("{what}: {e}")))
}

fn read_rows<T: H5Type>(g: &Group, name: &str, rows: usize, n: usize, budget: u64, bad: &dyn Fn(String) -> Error) -> Result<(Dataset, Vec<T>)> {
    let ds = g.dataset(name).map_err(|_| bad(format!("has no dataset '{name}'")))?;
    if ds.shape() != [rows, n] {
        return Err(bad(format!("dataset {name} has shape {:?}, not [{rows}, {n}]", ds.shape())));
    }
    let v = read_all::<T>(&ds, &format!("dataset {name}"), budget, bad)?;
    Ok((ds, v))
}

fn read_maps(ds: &Dataset, len: usize, budget: u64, bad: &dyn Fn(String) -> Error) -> Result<Vec<Affine>> {
    let get = |name: &str| -> Result<Vec<f32>> {
        let what = format!("{} attribute {name}", ds.name());
        let a = ds.attr(name).map_err(|e| bad(format!("{what}: {e}")))?;
        let v: Vec<f32> = read_all(&a, &what, budget, bad)?;
        if v.len() != len {
            return Err(bad(format!("{} attribute {name} holds {} values, not {len}", ds.name(), v.len())));
        }
        Ok(v)
    };
    let (lo, hi) = (get("lo")?, get("hi")?);
    Ok(lo.into_iter().zip(hi).map(|(lo, hi)| Affine { lo, hi }).collect())
}

/// The entry's primitives (a packed payload's precision is `read_info`'s).
pub(super) fn read_params(g: &Group, info: &EntryInfo, path: &Path, budget: u64) -> Result<Vec<Primitive>> {
    let key = EntryKey::of(&info.meta);
    let bad = |what: String| Error::format(format!("{}:{} {what}", path.display(), key.path()));
    let n = usize::try_from(info.count).map_err(|_| bad("count exceeds this machine's memory".into()))?;
    let params = match info.payload {
        Payload::Packed => {
            let ds = g.dataset("packed").map_err(|_| bad("has no dataset 'packed'".into()))?;
            let bytes: Vec<u8> = read_all(&ds, "dataset packed", budget, &bad)?;
            let packed = read_packed_payload(&bytes, n).map_err(|e| bad(e.to_string()))?;
            packed.params().map_err(|e| bad(e.to_string()))?
        }
        Payload::Float32 => {
            let (_, rows) = read_rows::<f32>(g, "params", 12, n, budget, &bad)?;
            (0..n).map(|i| std::array::from_fn(|k| rows[k * n + i])).collect()
        }
        Payload::Bits8(coding) => {
            let centres = match coding {
                CentreCoding::Float16 => {
                    let (_, half) = read_rows::<half::f16>(g, "centres", 3, n, budget, &bad)?;
                    Centres::Float16(half.into_iter().map(|h| h.to_bits()).collect())
                }
                CentreCoding::Fixed16 => {
                    let (ds, codes) = read_rows::<u16>(g, "centres", 3, n, budget, &bad)?;
                    let m = read_maps(&ds, 3, budget, &bad)?;
                    Centres::Fixed16 { maps: [m[0], m[1], m[2]], codes }
                }
            };
            let (ds, codes) = read_rows::<u8>(g, "codes", 9, n, budget, &bad)?;
            let m = read_maps(&ds, 9, budget, &bad)?;
            let q = Quantized { n, centres, maps: std::array::from_fn(|k| m[k]), codes };
            q.dequantize().map_err(|e| bad(e.to_string()))?
        }
    };
    if params.iter().any(|p: &Primitive| p.iter().any(|v| !v.is_finite())) {
        return Err(bad("holds non-finite parameters".into()));
    }
    Ok(params)
}
