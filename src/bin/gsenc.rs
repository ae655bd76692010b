//! `gsenc`: the command-line tool, a thin layer over the library.

use clap::{Args, Parser, Subcommand};
use gsenc::backend::cpu::CpuBackend;
use gsenc::encoder::{encode, with_threads, EncodeConfig, Schedule, Target};
use gsenc::field::{Grid, IndexFrame, Transform, ValueRange};
use gsenc::io::{raw, vti, write_atomic};
use gsenc::metrics::{sampled_psnr, voxel_psnr};
use gsenc::model::{Model, ModelMeta};
use gsenc::samples::GridSamples;
use gsenc::{format, Error, Result};
use serde_json::json;
use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::time::Instant;

#[derive(Parser)]
#[command(name = "gsenc", version, about = "Encode 3D scalar fields into fixed budgets of Gaussians, and decode them")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Encode a field into a model file.
    #[command(subcommand)]
    Encode(EncodeInput),
    /// Decode a model to a grid (.raw float32 or .vti).
    Decode(DecodeArgs),
    /// Score a model against a grid: voxel and sampled PSNR.
    Eval(EvalArgs),
    /// Show a model's metadata.
    Info(InfoArgs),
}

#[derive(Subcommand)]
enum EncodeInput {
    /// A regular grid: raw array or VTK ImageData (.vti).
    Grid(EncodeGridArgs),
}

/// How to read a grid from a file.
#[derive(Args, Clone)]
struct GridInput {
    /// Input file: raw array, or .vti.
    #[arg(long)]
    input: PathBuf,
    /// Dims of a raw array, X,Y,Z.
    #[arg(long, value_parser = parse_dims)]
    dims: Option<[usize; 3]>,
    /// Element type of a raw array: u8, u16, f32, f64 (little-endian).
    #[arg(long)]
    dtype: Option<String>,
    /// Memory order of a raw array: xfast (x varies fastest, C [z][y][x]) or zfast.
    #[arg(long, default_value = "xfast")]
    order: String,
    /// Array of a .vti file (default: its active scalars).
    #[arg(long)]
    array: Option<String>,
    /// Mean-downsample by this integer factor first.
    #[arg(long, default_value_t = 1)]
    downsample: usize,
}

#[derive(Args)]
struct EncodeGridArgs {
    #[command(flatten)]
    input: GridInput,
    /// Number of Gaussians.
    #[arg(long)]
    budget: usize,
    /// full (3000 x 16384), matched (1500 x 3072) or short (500 x 8192).
    #[arg(long, default_value = "matched")]
    schedule: String,
    /// Override the schedule's iterations.
    #[arg(long)]
    iters: Option<usize>,
    /// Override the schedule's points per iteration.
    #[arg(long)]
    points: Option<usize>,
    /// Seed of the seeding draws.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Seed of the stratified point sampler.
    #[arg(long, default_value_t = 1)]
    sample_seed: u64,
    /// Skip the relocation passes.
    #[arg(long)]
    no_relocation: bool,
    /// Value range MIN,MAX (after --log10); default: the data's range.
    #[arg(long, value_parser = parse_range)]
    range: Option<[f64; 2]>,
    /// Normalise log10 of the values.
    #[arg(long)]
    log10: bool,
    /// Worker threads (default: all cores).
    #[arg(long)]
    threads: Option<usize>,
    /// CPU backend brick edge in voxels (tuning only; does not change the model
    /// beyond float rounding).
    #[arg(long, hide = true)]
    brick: Option<f32>,
    /// Field name stored in the model.
    #[arg(long, default_value = "scalar")]
    field: String,
    /// Time step stored in the model.
    #[arg(long, default_value_t = 0)]
    step: u64,
    /// Output model file.
    #[arg(short, long)]
    output: PathBuf,
    #[command(flatten)]
    out: OutputFlags,
}

#[derive(Args, Clone, Copy)]
struct OutputFlags {
    /// Print one JSON object instead of text.
    #[arg(long)]
    json: bool,
    /// No progress bar.
    #[arg(long, short)]
    quiet: bool,
}

#[derive(Args)]
struct DecodeArgs {
    model: PathBuf,
    /// Lattice dims X,Y,Z covering the model's box (default: its reference dims).
    #[arg(long, value_parser = parse_dims)]
    dims: Option<[usize; 3]>,
    /// Write normalised values in [0, 1] instead of data units.
    #[arg(long)]
    normalized: bool,
    /// Output: .vti (VTK ImageData) or anything else for raw float32, x fastest.
    #[arg(short, long)]
    output: PathBuf,
    #[arg(long)]
    threads: Option<usize>,
    #[command(flatten)]
    out: OutputFlags,
}

#[derive(Args)]
struct EvalArgs {
    model: PathBuf,
    #[command(flatten)]
    input: GridInput,
    #[arg(long)]
    threads: Option<usize>,
    #[command(flatten)]
    out: OutputFlags,
}

#[derive(Args)]
struct InfoArgs {
    model: PathBuf,
    #[arg(long)]
    json: bool,
}

fn parse_dims(s: &str) -> std::result::Result<[usize; 3], String> {
    let v: Vec<usize> = s.split(',').map(|x| x.trim().parse::<usize>().map_err(|_| format!("bad dims '{s}'"))).collect::<std::result::Result<_, _>>()?;
    match v[..] {
        [x, y, z] if x > 0 && y > 0 && z > 0 => Ok([x, y, z]),
        [x] if x > 0 => Ok([x, x, x]),
        _ => Err(format!("dims must be X,Y,Z (positive), got '{s}'")),
    }
}

fn parse_range(s: &str) -> std::result::Result<[f64; 2], String> {
    let v: Vec<f64> = s.split(',').map(|x| x.trim().parse::<f64>().map_err(|_| format!("bad range '{s}'"))).collect::<std::result::Result<_, _>>()?;
    match v[..] {
        [a, b] => Ok([a, b]),
        _ => Err(format!("range must be MIN,MAX, got '{s}'")),
    }
}

/// A grid in data units with its world frame.
struct Loaded {
    grid: Grid,
    frame: IndexFrame,
}

fn load_grid(a: &GridInput) -> Result<Loaded> {
    let is_vti = a.input.extension().is_some_and(|e| e.eq_ignore_ascii_case("vti"));
    let (grid, origin, spacing) = if is_vti {
        let v = vti::read_vti(&a.input, a.array.as_deref())?;
        let s = v.spacing;
        if (0..3).any(|i| !(s[i] > 0.0) || ((s[i] - s[0]) / s[0]).abs() > 1e-6) {
            return Err(Error::data(format!("{}: spacing {s:?} is not isotropic; resample the grid to cubic voxels first", a.input.display())));
        }
        (v.grid, v.origin, s[0])
    } else {
        let dims = a.dims.ok_or_else(|| Error::arg("--dims X,Y,Z is required for raw input"))?;
        let dtype = raw::DType::from_name(a.dtype.as_deref().ok_or_else(|| Error::arg("--dtype is required for raw input"))?)?;
        let order = raw::Order::from_name(&a.order)?;
        (raw::read_raw(&a.input, dims, dtype, order)?, [0.0; 3], 1.0)
    };
    let k = a.downsample;
    let grid = grid.downsample(k)?;
    // Block means sit at the centre of each block.
    let shift = 0.5 * (k as f64 - 1.0) * spacing;
    let frame = IndexFrame::for_grid(grid.dims, origin.map(|o| o + shift), spacing * k as f64)?;
    Ok(Loaded { grid, frame })
}

fn progress_bar(quiet: bool, len: u64) -> indicatif::ProgressBar {
    if quiet || !std::io::stderr().is_terminal() {
        return indicatif::ProgressBar::hidden();
    }
    let pb = indicatif::ProgressBar::new(len);
    pb.set_style(
        indicatif::ProgressStyle::with_template("{elapsed_precise} [{bar:40}] {pos}/{len} it  loss {msg}  eta {eta}")
            .unwrap()
            .progress_chars("=> "),
    );
    pb
}

fn print_result(json_out: bool, value: serde_json::Value) {
    if json_out {
        println!("{value}");
    } else if let serde_json::Value::Object(map) = value {
        for (k, v) in map {
            match v {
                serde_json::Value::Number(n) if n.is_f64() => println!("{k:>24}: {:.4}", n.as_f64().unwrap()),
                serde_json::Value::String(s) => println!("{k:>24}: {s}"),
                other => println!("{k:>24}: {other}"),
            }
        }
    }
}

fn read_model(path: &Path) -> Result<Model> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    format::read_model(&bytes).map_err(|e| match e {
        Error::Format(m) => Error::Format(format!("{}: {m}", path.display())),
        Error::Version(m) => Error::Version(format!("{}: {m}", path.display())),
        other => other,
    })
}

fn cmd_encode_grid(a: EncodeGridArgs) -> Result<()> {
    let t_total = Instant::now();
    let loaded = load_grid(&a.input)?;
    let transform = if a.log10 { Transform::Log10 } else { Transform::Linear };
    let range = match a.range {
        Some([lo, hi]) => ValueRange::new(lo, hi, transform)?,
        None => ValueRange::from_data(&loaded.grid.values, transform)?,
    };
    let norm = range.normalize(&loaded.grid.values)?;
    let reference = Grid::new(loaded.grid.dims, norm.values)?;
    let samples = GridSamples { grid: &reference };
    let target = Target { reference: &reference, samples: &samples };
    let mut cfg = EncodeConfig::new(a.budget, Schedule::from_name(&a.schedule)?);
    cfg.iterations = a.iters;
    cfg.points = a.points;
    cfg.seed_init = a.seed;
    cfg.seed_sample = a.sample_seed;
    cfg.relocation = !a.no_relocation;
    gsenc::encoder::validate(&target, &cfg, None)?;
    let pb = progress_bar(a.out.quiet, cfg.iterations() as u64);
    let (out, decoded, evals) = with_threads(a.threads, || -> Result<_> {
        let mut backend = CpuBackend::new();
        if let Some(b) = a.brick {
            backend.brick = b;
        }
        let out = encode(&target, &cfg, None, &mut backend, &mut |p| {
            pb.set_position(p.iteration as u64);
            if p.iteration % 20 == 0 {
                pb.set_message(format!("{:.3e}", p.loss));
            }
        })?;
        let evals = backend.kernel_evaluations();
        let t_dec = Instant::now();
        let mut model_backend = CpuBackend::new();
        let lattice = gsenc::backend::Lattice::reference(reference.dims);
        let mut decoded = vec![0f32; reference.len()];
        gsenc::backend::Backend::decode_lattice(&mut model_backend, &out.params, &lattice, &mut decoded);
        Ok((out, (decoded, t_dec.elapsed().as_secs_f64()), evals))
    })??;
    pb.finish_and_clear();
    let model = Model {
        meta: ModelMeta {
            frame: loaded.frame,
            range,
            field: a.field.clone(),
            step: a.step,
            schedule: cfg.schedule.name().into(),
            iterations: out.iterations as u32,
            points: out.points as u32,
            seed_init: cfg.seed_init,
            seed_sample: cfg.seed_sample,
        },
        params: out.params,
    };
    let bytes = format::write_model(&model)?;
    write_atomic(&a.output, &bytes)?;
    let (decoded, decode_seconds) = decoded;
    let vpsnr = voxel_psnr(&decoded, &reference.values);
    let spsnr = sampled_psnr(&decoded, &reference.values);
    print_result(
        a.out.json,
        json!({
            "primitives": model.len(),
            "bytes": bytes.len(),
            "voxel_psnr": vpsnr,
            "sampled_psnr": spsnr,
            "seconds": out.loop_seconds,
            "total_seconds": t_total.elapsed().as_secs_f64(),
            "seed_seconds": out.seed_seconds,
            "decode_seconds": decode_seconds,
            "iterations": out.iterations,
            "points": out.points,
            "kernel_evals_per_second": evals as f64 / out.loop_seconds.max(1e-9),
            "dims": reference.dims,
            "clamped_values": norm.clamped,
            "output": a.output.display().to_string(),
        }),
    );
    Ok(())
}

fn cmd_decode(a: DecodeArgs) -> Result<()> {
    let t = Instant::now();
    let model = read_model(&a.model)?;
    let grid = with_threads(a.threads, || model.decode(&mut CpuBackend::new(), a.dims))??;
    let seconds = t.elapsed().as_secs_f64();
    let values: Vec<f32> = if a.normalized {
        grid.values.clone()
    } else {
        grid.values.iter().map(|&v| model.meta.range.denormalize(v) as f32).collect()
    };
    let f = &model.meta.frame;
    let spacing: Vec<f64> = (0..3).map(|i| f.dims[i] as f64 / grid.dims[i] as f64 / f.gamma).collect();
    let is_vti = a.output.extension().is_some_and(|e| e.eq_ignore_ascii_case("vti"));
    let bytes = if is_vti {
        let origin = [0, 1, 2].map(|i| f.bmin[i] + 0.5 * spacing[i]);
        vti::write_vti_bytes(&Grid::new(grid.dims, values)?, origin, [spacing[0], spacing[1], spacing[2]], &model.meta.field)
    } else {
        raw::to_f32_bytes(&values)
    };
    write_atomic(&a.output, &bytes)?;
    print_result(
        a.out.json,
        json!({
            "dims": grid.dims,
            "voxels": grid.len(),
            "seconds": seconds,
            "voxels_per_second": grid.len() as f64 / seconds.max(1e-9),
            "output": a.output.display().to_string(),
        }),
    );
    Ok(())
}

fn cmd_eval(a: EvalArgs) -> Result<()> {
    let model = read_model(&a.model)?;
    let loaded = load_grid(&a.input)?;
    let norm = model.meta.range.normalize(&loaded.grid.values)?;
    let decoded = with_threads(a.threads, || model.decode(&mut CpuBackend::new(), Some(loaded.grid.dims)))??;
    print_result(
        a.out.json,
        json!({
            "voxel_psnr": voxel_psnr(&decoded.values, &norm.values),
            "sampled_psnr": sampled_psnr(&decoded.values, &norm.values),
            "dims": loaded.grid.dims,
            "clamped_values": norm.clamped,
        }),
    );
    Ok(())
}

fn cmd_info(a: InfoArgs) -> Result<()> {
    let m = read_model(&a.model)?;
    let bytes = std::fs::metadata(&a.model).map_err(|e| Error::io(&a.model, e))?.len();
    let meta = &m.meta;
    print_result(
        a.json,
        json!({
            "format": format!("gsenc model {}.{}", format::VERSION_MAJOR, format::VERSION_MINOR),
            "payload": "float32",
            "primitives": m.len(),
            "bytes": bytes,
            "field": meta.field,
            "step": meta.step,
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
        }),
    );
    Ok(())
}

fn main() {
    tracing_subscriber::fmt()
        .with_env_filter(tracing_subscriber::EnvFilter::from_default_env())
        .with_writer(std::io::stderr)
        .init();
    let cli = Cli::parse();
    let r = match cli.command {
        Command::Encode(EncodeInput::Grid(a)) => cmd_encode_grid(a),
        Command::Decode(a) => cmd_decode(a),
        Command::Eval(a) => cmd_eval(a),
        Command::Info(a) => cmd_info(a),
    };
    if let Err(e) = r {
        eprintln!("gsenc: {e}");
        std::process::exit(match e {
            Error::InvalidArgument(_) => 2,
            Error::InvalidData(_) => 3,
            Error::Format(_) | Error::Version(_) => 4,
            Error::Io { .. } => 5,
        });
    }
}
