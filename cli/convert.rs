//! `gsenc convert`: a model rewritten with another payload.

use crate::args::one_of;
use crate::output::{print_result, write_output};
use clap::Args;
use gsenc::format::{self, Payload};
use gsenc::io::read_model_file;
use gsenc::{Error, Result};
use serde_json::json;
use std::path::PathBuf;

#[derive(Args)]
pub struct ConvertArgs {
    model: PathBuf,
    /// Payload of the new file: f32, 8bit, 8bit-u16 or packed (at the
    /// model's own precision when it was packed, else a fixed default:
    /// no reference is at hand to measure one).
    #[arg(long, value_parser = one_of(&Payload::ALL, Payload::name))]
    payload: Payload,
    /// Output model file (may not be the input; `-`: standard output, the
    /// results then going to standard error).
    #[arg(short, long)]
    output: PathBuf,
    #[arg(long)]
    json: bool,
}

pub fn convert(a: ConvertArgs) -> Result<()> {
    let payload = a.payload;
    let same = match (std::fs::canonicalize(&a.model), std::fs::canonicalize(&a.output)) {
        (Ok(x), Ok(y)) => x == y,
        _ => false,
    };
    if same {
        return Err(Error::arg("convert writes a new file; give an output other than the input"));
    }
    let mut file = read_model_file(&a.model)?;
    // The stored encode PSNR stays true only when no precision is lost.
    if payload != file.payload && payload != format::Payload::Float32 {
        file.model.meta.encode_psnr = None;
    }
    let bytes = format::write_model_as(&file.model, payload)?;
    write_output(&a.output, &bytes)?;
    let n = file.model.len().max(1) as f64;
    let before = std::fs::metadata(&a.model).map_err(|e| Error::io(&a.model, e))?.len();
    print_result(
        a.json,
        json!({
            "from": file.payload.name(),
            "to": payload.name(),
            "primitives": file.model.len(),
            "bytes_before": before,
            "bytes": bytes.len(),
            "bytes_per_primitive": bytes.len() as f64 / n,
            "output": a.output.display().to_string(),
        }),
    );
    Ok(())
}

