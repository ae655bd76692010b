//! `gsenc eval`: a model scored against a grid (voxel, sampled and
//! occupied PSNR).

use crate::args::{BackendArgs, GridInput, OutputFlags};
use crate::output::print_result;
use clap::Args;
use gsenc::threads::with_threads;
use gsenc::field::{Transform, ValueRange};
use gsenc::io::read_model_file;
use gsenc::model::metrics::{occupied_psnr, sampled_psnr, voxel_psnr};
use gsenc::Result;
use serde_json::json;
use std::path::PathBuf;

#[derive(Args)]
pub struct EvalArgs {
    model: PathBuf,
    #[command(flatten)]
    input: GridInput,
    /// The input holds values already normalised to [0, 1] (as written by
    /// `gsenc deposit --normalized`); otherwise the model's range maps them.
    #[arg(long)]
    normalized: bool,
    #[arg(long)]
    threads: Option<usize>,
    #[command(flatten)]
    device: BackendArgs,
    #[command(flatten)]
    out: OutputFlags,
}

pub fn eval(a: EvalArgs) -> Result<()> {
    let model = read_model_file(&a.model)?.model;
    let (grid, _) = a.input.load()?;
    let norm = if a.normalized {
        ValueRange::new(0.0, 1.0, Transform::Linear)?.normalize(&grid.values)?
    } else {
        model.meta.range.normalize(&grid.values)?
    };
    let mut backend = a.device.choice().open()?;
    let decoded = with_threads(a.threads, || model.decode(backend.as_mut(), Some(grid.dims)))??;
    print_result(
        a.out.json,
        json!({
            "voxel_psnr": voxel_psnr(&decoded.values, &norm.values),
            "sampled_psnr": sampled_psnr(&decoded.values, &norm.values),
            "occupied_psnr": occupied_psnr(&decoded.values, &norm.values),
            "dims": grid.dims,
            "clamped_values": norm.clamped,
        }),
    );
    Ok(())
}

