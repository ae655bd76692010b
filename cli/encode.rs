//! `gsenc encode grid|particles|cells`: one field into one model file,
//! through the library's encode pipeline.

use crate::args::{one_of, CellInput, GridInput, OutputFlags, ParticleInput, TrainingArgs, ValueArgs};
use crate::output::{deposit_keys, gpu_host_seconds, kernel_seconds, keys, peak_rss_bytes, print_result, progress_bar, write_output};
use clap::{Args, Subcommand};
use gsenc::backend::select::BackendChoice;
use gsenc::encode::pipeline::{config_for, encode_prepared, Labels, Request, Start};
use gsenc::threads::with_threads;
use gsenc::format::info::precision_json;
use gsenc::encode::target::report_json;
use gsenc::format::{read_model_file, write_model_as, Payload};
use gsenc::input::{prepare, Input};
use gsenc::model::metrics::{occupied_psnr, sampled_psnr};
use gsenc::Result;
use serde_json::{json, Map, Value};
use std::path::PathBuf;
use std::time::Instant;

#[derive(Subcommand)]
pub enum EncodeInput {
    /// A regular grid: raw array or VTK ImageData (.vti).
    Grid(EncodeGridArgs),
    /// SPH particles (raw arrays), against their particle deposit.
    Particles(EncodeParticlesArgs),
    /// Hexahedral cells (raw arrays), against their volume-weighted deposit.
    Cells(EncodeCellsArgs),
}

#[derive(Args)]
pub struct EncodeGridArgs {
    #[command(flatten)]
    input: GridInput,
    #[command(flatten)]
    values: ValueArgs,
    #[command(flatten)]
    encode: EncodeOptions,
}

#[derive(Args)]
pub struct EncodeParticlesArgs {
    #[command(flatten)]
    input: ParticleInput,
    #[command(flatten)]
    values: ValueArgs,
    #[command(flatten)]
    encode: EncodeOptions,
}

#[derive(Args)]
pub struct EncodeCellsArgs {
    #[command(flatten)]
    input: CellInput,
    #[command(flatten)]
    values: ValueArgs,
    #[command(flatten)]
    encode: EncodeOptions,
}

/// Everything about an encode but its input.
#[derive(Args)]
struct EncodeOptions {
    #[command(flatten)]
    train: TrainingArgs,
    /// Training brick edge in voxels (tuning only; does not change the model
    /// beyond float rounding).
    #[arg(long, hide = true)]
    brick: Option<f32>,
    /// Field name stored in the model.
    #[arg(long, default_value = "scalar")]
    field: String,
    /// Time step stored in the model.
    #[arg(long, default_value_t = 0)]
    step: u64,
    /// Simulation time stored in the model.
    #[arg(long, allow_hyphen_values = true)]
    time: Option<f64>,
    /// Payload: f32 (48 bytes a primitive, exact), 8bit (float16 centres,
    /// 8-bit parameters, zstd; about 12 bytes), 8bit-u16 (uint16 centres) or
    /// packed (the fewest bits per parameter group that keep the PSNR within
    /// 0.1 dB of f32, measured for this model; about 5-6 bytes).
    #[arg(long, default_value = "f32", value_parser = one_of(&Payload::ALL, Payload::name))]
    payload: Payload,
    /// Output model file (`-`: standard output; the results then go to
    /// standard error).
    #[arg(short, long)]
    output: PathBuf,
    #[command(flatten)]
    out: OutputFlags,
}

pub fn encode(input: EncodeInput) -> Result<()> {
    let t_total = Instant::now();
    match input {
        EncodeInput::Grid(a) => {
            let (grid, frame) = a.input.load()?;
            run(Input::Grid { values: &grid, frame }, &a.values, &a.encode, t_total)
        }
        EncodeInput::Particles(a) => {
            let arrays = a.input.load(None)?;
            let particles = arrays.particles();
            let placement = a.input.placement.resolve(|| particles.bounds())?;
            run(Input::Particles { particles: &particles, placement }, &a.values, &a.encode, t_total)
        }
        EncodeInput::Cells(a) => {
            let arrays = a.input.load()?;
            let cells = arrays.cells();
            let placement = a.input.placement.resolve(|| cells.bounds())?;
            run(Input::Cells { cells: &cells, placement }, &a.values, &a.encode, t_total)
        }
    }
}

/// Prepares and encodes `input`, writes the model and prints what every
/// encode prints (and, for particles and cells, what their deposit did).
fn run(input: Input, values: &ValueArgs, o: &EncodeOptions, t_total: Instant) -> Result<()> {
    let threads = o.train.threads;
    let range = values.spec()?;
    let prepared = with_threads(threads, || prepare(&input, &range))??;
    let request = Request {
        config: o.train.config()?,
        start: Start::Seeded,
        payload: o.payload,
        store_support: o.train.support,
        labels: Labels { field: o.field.clone(), step: o.step, time: o.time, rank: 0 },
        validation: None,
    };
    let iterations = config_for(&request.config, prepared.form, &request.start).iterations();
    let pb = progress_bar(o.out.quiet, iterations as u64);
    let mut backend = BackendChoice { brick: o.brick, ..o.train.device.choice() }.open()?;
    let encoded = with_threads(threads, || {
        encode_prepared(&prepared, &request, backend.as_mut(), &mut |p| {
            pb.set_length(p.iterations as u64); // a target's search runs several encodes
            pb.set_position(p.iteration as u64);
            if p.iteration % 20 == 0 {
                pb.set_message(format!("{:.3e}", p.loss));
            }
        })
    })??;
    pb.finish_and_clear();
    let bytes = write_model_as(&encoded.model, o.payload)?;
    write_output(&o.output, &bytes)?;
    let payload_bytes = read_model_file(&bytes)?.payload_bytes;

    let (out, reference) = (&encoded.output, &prepared.reference);
    let mut result: Map<String, Value> = keys(json!({
        "primitives": encoded.model.len(),
        "bytes": bytes.len(),
        "payload": o.payload.name(),
        "voxel_psnr": encoded.psnr,
        // The float32 model's, where the payload's precision was measured against it (packed).
        "float32_psnr": encoded.float32_psnr,
        "precision": encoded.model.meta.precision.map(precision_json),
        "payload_bytes": payload_bytes,
        "sampled_psnr": sampled_psnr(&encoded.decoded, &reference.values),
        "occupied_psnr": occupied_psnr(&encoded.decoded, &reference.values),
        // The chosen model's loop; with a target, `target.seconds` is the search's.
        "seconds": out.loop_seconds,
        "total_seconds": t_total.elapsed().as_secs_f64(),
        "seed_seconds": out.seed_seconds,
        // Where the loop's host thread spent `seconds` (refine.rs `LoopPhases`).
        "loop_phases": {"draw": out.phases.draw, "submit": out.phases.submit, "wait": out.phases.wait},
        "decode_seconds": encoded.decode_seconds,
        "iterations": out.iterations,
        "points": out.points,
        "kernel_evals_per_second": out.kernel_evaluations as f64 / out.loop_seconds.max(1e-9),
        "backend": out.backend,
        // The build of the CPU backend's loops (math/simd.rs), for reading timings.
        "simd": gsenc::math::simd::build(),
        "fell_back": out.fell_back,
        "kernel_seconds": kernel_seconds(backend.as_ref()),
        "gpu_host_seconds": gpu_host_seconds(backend.as_ref()),
        "dims": reference.dims,
        "target": report_json(encoded.target.as_ref()),
        "output": o.output.display().to_string(),
    }));
    match prepared.deposit {
        None => {
            result.insert("clamped_values".into(), json!(prepared.clamped_values));
        }
        Some(_) => {
            result.extend(deposit_keys(&prepared));
            result.insert("peak_rss_bytes".into(), json!(peak_rss_bytes()));
        }
    }
    print_result(o.out.json, Value::Object(result));
    Ok(())
}
