//! Every header field of a model file as one JSON object: what `gsenc
//! info --json` prints and the Python package's `Model.info` holds.

use crate::format::packed::{Precision, CENTRE_CLASSES, GROUPS};
use crate::format::ModelFile;
use crate::model::{Curve, Model, ModelMeta};
use serde_json::{json, Map, Value};

/// The fields of `file`, whose stored form takes `bytes` bytes.
pub fn model_info(file: &ModelFile, bytes: u64) -> Value {
    let m = &file.model;
    let mut info = keys(json!({
        "format": format!("gsenc model {}.{}", file.version.0, file.version.1),
        "payload": file.payload.name(),
        "primitives": m.len(),
        "bytes": bytes,
        "bytes_per_primitive": bytes as f64 / m.len().max(1) as f64,
        // The primitives alone, without header, support and checksum.
        "payload_bytes_per_primitive": file.payload_bytes as f64 / m.len().max(1) as f64,
    }));
    info.extend(meta_info(m));
    Value::Object(info)
}

/// What a model's header holds beyond its payload: its metadata, and its
/// support's.
pub fn meta_info(m: &Model) -> Map<String, Value> {
    let mut info = metadata_info(&m.meta);
    info.extend(keys(json!({
        // Reference voxels where the model holds data (null: every voxel).
        "support_voxels": m.support.as_ref().map(|s| s.count()),
        // What the decode gives outside the support: `[offset, gain]` of
        // `clamp(offset + gain min(V, 0.005), 0, 0.005)` (null: no support).
        "support_outside": m.support.as_ref().map(|s| [s.outside().offset, s.outside().gain]),
    })));
    info
}

/// A model's metadata (what a store entry lists too, without its support).
pub fn metadata_info(meta: &ModelMeta) -> Map<String, Value> {
    keys(json!({
        // Bits per parameter group of the packed payload (null: another payload).
        "precision": meta.precision.map(precision_json),
        "field": meta.field,
        "step": meta.step,
        "time": meta.time,
        "rank": meta.rank,
        "encode_psnr": meta.encode_psnr,
        "dims": meta.frame.dims,
        "bounds_min": meta.frame.bmin,
        "gamma": meta.frame.gamma,
        "value_min": meta.range.vmin,
        "value_max": meta.range.vmax,
        "transform": meta.range.transform.name(),
        "schedule": meta.schedule,
        "iterations": meta.iterations,
        "points": meta.points,
        "seed_init": meta.seed_init,
        "seed_sample": meta.seed_sample,
        // Why the encode ran on the CPU after the GPU failed (null: it did not).
        "fell_back": meta.fell_back,
        // The start an `auto` warm step took and the primitives its
        // repair moved (null: not an `auto` warm step).
        "warm_start": meta.warm.map(|w| w.taken.name()),
        "warm_moved": meta.warm.map(|w| w.moved),
        // What a target PSNR's search learned: dB per budget doubling and
        // per iteration doubling (null: an encode to a budget).
        "target_curve": meta.curve.as_ref().map(Curve::slopes),
    }))
}

fn keys(v: Value) -> Map<String, Value> {
    match v {
        Value::Object(map) => map,
        _ => unreachable!("an object literal"),
    }
}

/// The packed payload's bits per parameter group, by group name; `centre`
/// an array, one lattice per centre class.
pub fn precision_json(p: Precision) -> Value {
    let others = GROUPS.iter().enumerate().skip(CENTRE_CLASSES).map(|(g, name)| (name.to_string(), json!(p.get(g))));
    Value::Object([("centre".to_string(), json!(p.centre))].into_iter().chain(others).collect())
}
