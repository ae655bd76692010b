//! `gsenc info`: every header field of a model file, or every entry of an
//! HDF5 store.

use crate::output::print_result;
use crate::store;
use clap::Args;
use gsenc::{Error, Result};
use serde_json::json;
use std::path::PathBuf;

#[derive(Args)]
pub struct InfoArgs {
    model: PathBuf,
    #[arg(long)]
    json: bool,
}

pub fn info(a: InfoArgs) -> Result<()> {
    if store::is_hdf5_file(&a.model) {
        return store::info(&a.model, a.json);
    }
    let file = gsenc::io::read_model_file(&a.model)?;
    let m = &file.model;
    let bytes = std::fs::metadata(&a.model).map_err(|e| Error::io(&a.model, e))?.len();
    let meta = &m.meta;
    print_result(
        a.json,
        json!({
            "format": format!("gsenc model {}.{}", file.version.0, file.version.1),
            "payload": file.payload.name(),
            "primitives": m.len(),
            "bytes": bytes,
            "bytes_per_primitive": bytes as f64 / m.len().max(1) as f64,
            // The primitives alone, without header, support and checksum.
            "payload_bytes_per_primitive": file.payload_bytes as f64 / m.len().max(1) as f64,
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
            // Reference voxels where the model holds data (null: every voxel).
            "support_voxels": m.support.as_ref().map(|s| s.count()),
        }),
    );
    Ok(())
}

/// The packed payload's bits per parameter group, by group name.
pub fn precision_json(p: gsenc::format::packed::Precision) -> serde_json::Value {
    let groups = gsenc::format::packed::GROUPS.iter().enumerate().map(|(g, name)| (name.to_string(), json!(p.get(g))));
    serde_json::Value::Object(groups.collect())
}

