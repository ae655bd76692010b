//! `gsenc`: the command-line tool, a thin layer over the library.

mod series;
mod store;

use clap::{Args, Parser, Subcommand};
use gsenc::backend::cpu::CpuBackend;
use gsenc::encoder::{encode, with_threads, EncodeConfig, Schedule, Target};
use gsenc::field::{Grid, IndexFrame, Transform, ValueRange};
use gsenc::io::{raw, vti, write_atomic, AtomicFile};
use gsenc::metrics::{occupied_psnr, sampled_psnr, voxel_psnr};
use gsenc::model::{IndexBox, Model, ModelMeta};
use gsenc::cells::{CellSize, Cells};
use gsenc::particles::Particles;
use gsenc::reference::{prepare_cells, prepare_particles, Bounds, Placement, Prepared, RangeSpec};
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
    /// Show the metadata of a model file or of every model of a store.
    Info(InfoArgs),
    /// Rewrite a model with another payload (float32 to 8-bit and back).
    Convert(ConvertArgs),
    /// Write the reference grid that particles or cells are encoded against.
    #[command(subcommand)]
    Deposit(DepositInput),
    /// The HDF5 store of a time series (cargo feature `hdf5`).
    #[command(subcommand)]
    Store(store::StoreCommand),
    /// Decode one field of a store to HDF5 plus XDMF, for ParaView (feature `hdf5`).
    DecodeSeries(store::DecodeSeriesArgs),
    /// Encode every step of a particle time series, warm-starting each step
    /// from the previous one, with a CSV of validation PSNR per iteration.
    EncodeSeries(series::EncodeSeriesArgs),
    /// Draw final validation PSNR against step from encode-series CSVs (PNG).
    PlotSeries(series::PlotSeriesArgs),
}

#[derive(Subcommand)]
enum EncodeInput {
    /// A regular grid: raw array or VTK ImageData (.vti).
    Grid(EncodeGridArgs),
    /// SPH particles (raw arrays), against their particle deposit.
    Particles(EncodeParticlesArgs),
    /// Hexahedral cells (raw arrays), against their volume-weighted deposit.
    Cells(EncodeCellsArgs),
}

#[derive(Subcommand)]
enum DepositInput {
    /// The M4-spline, Shepard-normalised, mass-weighted particle deposit.
    Particles(DepositParticlesArgs),
    /// The volume-weighted cell deposit (the paper's Eq. 6).
    Cells(DepositCellsArgs),
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
    #[command(flatten)]
    values: ValueArgs,
    #[command(flatten)]
    encode: EncodeOptions,
}

/// How values are normalised.
#[derive(Args, Clone)]
pub struct ValueArgs {
    /// Value range MIN,MAX (after --log10); default: the data's range.
    #[arg(long, value_parser = parse_range)]
    range: Option<[f64; 2]>,
    /// Normalise log10 of the values.
    #[arg(long)]
    log10: bool,
}

/// The budget and the optimisation: what every encoding command shares.
#[derive(Args)]
pub struct TrainingArgs {
    /// Number of Gaussians.
    #[arg(long)]
    budget: usize,
    /// full (3000 x 16384; 4000 iterations for particles), matched (1500 x 3072)
    /// or short (500 x 8192).
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
    /// Worker threads (default: all cores).
    #[arg(long)]
    threads: Option<usize>,
}

impl TrainingArgs {
    /// The encoder configuration; `particles` selects the particles' full schedule.
    pub fn config(&self, particles: bool) -> Result<EncodeConfig> {
        let mut cfg = EncodeConfig::new(self.budget, Schedule::from_name(&self.schedule)?);
        cfg.iterations = self.iters;
        cfg.points = self.points;
        cfg.seed_init = self.seed;
        cfg.seed_sample = self.sample_seed;
        cfg.relocation = !self.no_relocation;
        cfg.particles = particles;
        Ok(cfg)
    }
}

/// Everything about an encode but its input.
#[derive(Args)]
struct EncodeOptions {
    #[command(flatten)]
    train: TrainingArgs,
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
    /// Simulation time stored in the model.
    #[arg(long)]
    time: Option<f64>,
    /// Payload: f32 (48 bytes a primitive, exact), 8bit (float16 centres,
    /// 8-bit parameters, zstd; about 12 bytes) or 8bit-u16 (uint16 centres).
    #[arg(long, default_value = "f32")]
    payload: String,
    /// Output model file.
    #[arg(short, long)]
    output: PathBuf,
    #[command(flatten)]
    out: OutputFlags,
}

/// Where the reference grid of particles or cells lies.
#[derive(Args, Clone)]
pub struct PlacementArgs {
    /// Reference grid dims X,Y,Z (or one number for a cube).
    #[arg(long, value_parser = parse_dims, required_unless_present = "fit_dims", conflicts_with = "fit_dims")]
    dims: Option<[usize; 3]>,
    /// Instead of --dims: this many voxels along the bounds' longest axis, and
    /// as many as fit along the others (cubic voxels).
    #[arg(long)]
    fit_dims: Option<usize>,
    /// World bounds XMIN,YMIN,ZMIN,XMAX,YMAX,ZMAX (default: the data's box).
    /// Items whose centres lie outside seed nothing; their support is clipped.
    #[arg(long, value_parser = parse_bounds)]
    bounds: Option<Bounds>,
}

/// Raw per-item array files: little-endian, C order, one row per item.
#[derive(Args, Clone)]
pub struct ItemFiles {
    /// Element type of every array file: f32 or f64 (also u8, u16).
    #[arg(long, default_value = "f32")]
    dtype: String,
    /// Items per row, for files holding several steps (one row per step).
    #[arg(long)]
    count: Option<usize>,
    /// Which row to read (0-based; needs --count).
    #[arg(long, default_value_t = 0)]
    row: usize,
}

#[derive(Args, Clone)]
pub struct ParticleInput {
    /// Positions, N x 3.
    #[arg(long)]
    positions: PathBuf,
    /// SPH smoothing lengths hh, N (the kernel's support radius is 2 hh).
    #[arg(long)]
    smoothing_length: PathBuf,
    /// Masses, N (default: equal masses).
    #[arg(long)]
    mass: Option<PathBuf>,
    /// Field values, N.
    #[arg(long)]
    values: PathBuf,
    #[command(flatten)]
    files: ItemFiles,
    #[command(flatten)]
    placement: PlacementArgs,
}

#[derive(Args, Clone)]
struct CellInput {
    /// Cell centres, N x 3.
    #[arg(long)]
    centers: PathBuf,
    /// Cell edge lengths, N x 3.
    #[arg(long, required_unless_present = "volumes", conflicts_with = "volumes")]
    sizes: Option<PathBuf>,
    /// Cell volumes, N (instead of --sizes).
    #[arg(long)]
    volumes: Option<PathBuf>,
    /// Field values, N.
    #[arg(long)]
    values: PathBuf,
    #[command(flatten)]
    files: ItemFiles,
    #[command(flatten)]
    placement: PlacementArgs,
}

#[derive(Args)]
struct EncodeParticlesArgs {
    #[command(flatten)]
    input: ParticleInput,
    #[command(flatten)]
    values: ValueArgs,
    #[command(flatten)]
    encode: EncodeOptions,
}

#[derive(Args)]
struct EncodeCellsArgs {
    #[command(flatten)]
    input: CellInput,
    #[command(flatten)]
    values: ValueArgs,
    #[command(flatten)]
    encode: EncodeOptions,
}

/// Where a decoded or deposited grid goes.
#[derive(Args)]
struct GridOutput {
    /// Write normalised values in [0, 1] (what the encoder is fitted to)
    /// instead of data units.
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
struct DepositParticlesArgs {
    #[command(flatten)]
    input: ParticleInput,
    #[command(flatten)]
    values: ValueArgs,
    #[command(flatten)]
    output: GridOutput,
}

#[derive(Args)]
struct DepositCellsArgs {
    #[command(flatten)]
    input: CellInput,
    #[command(flatten)]
    values: ValueArgs,
    #[command(flatten)]
    output: GridOutput,
}

#[derive(Args, Clone, Copy)]
pub struct OutputFlags {
    /// Print one JSON object instead of text.
    #[arg(long)]
    json: bool,
    /// No progress bar.
    #[arg(long, short)]
    quiet: bool,
}

#[derive(Args)]
struct DecodeArgs {
    /// A model; or the models of a domain's pieces (per-rank models of one
    /// step on one lattice), or the step index (`FIELD_STEP.gsi`) that names
    /// them: decoded together as one global field.
    #[arg(required = true)]
    model: Vec<PathBuf>,
    /// With several models or an index: decode only the region of the I-th
    /// (0-based; the rank, for an index) of the global field.
    #[arg(long, conflicts_with = "sub_box")]
    piece: Option<usize>,
    /// With a step index: decode every rank's primitives together
    /// (`sum n / max(sum rho, eps)`) instead of blending each piece's own
    /// decode across the halos; kernels that reach past a piece's box then
    /// leak into its neighbours (for comparison).
    #[arg(long)]
    additive: bool,
    /// Lattice dims X,Y,Z covering the model's box (default: its reference dims).
    #[arg(long, value_parser = parse_dims)]
    dims: Option<[usize; 3]>,
    /// Decode only the voxels X0,Y0,Z0,X1,Y1,Z1 (half-open index ranges of
    /// that lattice); the .vti keeps their world position.
    #[arg(long = "box", value_parser = parse_box)]
    sub_box: Option<[usize; 6]>,
    /// Voxels decoded at once (memory: 4 bytes each, twice).
    #[arg(long, default_value_t = gsenc::model::DEFAULT_SLAB_VOXELS, hide = true)]
    slab_voxels: usize,
    #[command(flatten)]
    output: GridOutput,
}

#[derive(Args)]
struct EvalArgs {
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
    out: OutputFlags,
}

#[derive(Args)]
struct InfoArgs {
    model: PathBuf,
    #[arg(long)]
    json: bool,
}

#[derive(Args)]
struct ConvertArgs {
    model: PathBuf,
    /// Payload of the new file: f32, 8bit or 8bit-u16.
    #[arg(long)]
    payload: String,
    /// Output model file (may not be the input).
    #[arg(short, long)]
    output: PathBuf,
    #[arg(long)]
    json: bool,
}

fn parse_box(s: &str) -> std::result::Result<[usize; 6], String> {
    let v: Vec<usize> = s.split(',').map(|x| x.trim().parse::<usize>().map_err(|_| format!("bad box '{s}'"))).collect::<std::result::Result<_, _>>()?;
    v.try_into().map_err(|_| format!("a box is X0,Y0,Z0,X1,Y1,Z1, got '{s}'"))
}

fn parse_dims(s: &str) -> std::result::Result<[usize; 3], String> {
    let v: Vec<usize> = s.split(',').map(|x| x.trim().parse::<usize>().map_err(|_| format!("bad dims '{s}'"))).collect::<std::result::Result<_, _>>()?;
    match v[..] {
        [x, y, z] if x > 0 && y > 0 && z > 0 => Ok([x, y, z]),
        [x] if x > 0 => Ok([x, x, x]),
        _ => Err(format!("dims must be X,Y,Z (positive), got '{s}'")),
    }
}

fn parse_bounds(s: &str) -> std::result::Result<Bounds, String> {
    let v: Vec<f64> = s.split(',').map(|x| x.trim().parse::<f64>().map_err(|_| format!("bad bounds '{s}'"))).collect::<std::result::Result<_, _>>()?;
    match v[..] {
        [a, b, c, d, e, f] => Ok(Bounds { min: [a, b, c], max: [d, e, f] }),
        _ => Err(format!("bounds must be XMIN,YMIN,ZMIN,XMAX,YMAX,ZMAX, got '{s}'")),
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

pub fn progress_bar(quiet: bool, len: u64) -> indicatif::ProgressBar {
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

pub fn print_result(json_out: bool, value: serde_json::Value) {
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
    gsenc::io::read_model_file(path).map(|f| f.model)
}

impl ValueArgs {
    pub fn spec(&self) -> Result<RangeSpec> {
        let transform = if self.log10 { Transform::Log10 } else { Transform::Linear };
        Ok(match self.range {
            Some([lo, hi]) => RangeSpec::Fixed(ValueRange::new(lo, hi, transform)?),
            None => RangeSpec::FromData(transform),
        })
    }
}

/// An encode's input in the index frame: the target and how to place it.
struct EncodeInputData<'a> {
    target: Target<'a>,
    frame: IndexFrame,
    range: ValueRange,
    particles: bool,
}

/// Encodes, writes the model and returns the result keys every encode prints.
fn run_encode(input: &EncodeInputData, o: &EncodeOptions, t_total: Instant) -> Result<serde_json::Map<String, serde_json::Value>> {
    let reference = input.target.reference;
    let cfg = o.train.config(input.particles)?;
    gsenc::encoder::validate(&input.target, &cfg, None)?;
    let payload = format::Payload::from_name(&o.payload)?;
    let pb = progress_bar(o.out.quiet, cfg.iterations() as u64);
    let (out, decoded, evals) = with_threads(o.train.threads, || -> Result<_> {
        let mut backend = CpuBackend::new();
        if let Some(b) = o.brick {
            backend.brick = b;
        }
        let out = encode(&input.target, &cfg, None, &mut backend, &mut |p| {
            pb.set_position(p.iteration as u64);
            if p.iteration % 20 == 0 {
                pb.set_message(format!("{:.3e}", p.loss));
            }
        })?;
        let evals = backend.kernel_evaluations();
        // Score the parameters as they will be stored.
        let t_dec = Instant::now();
        let decoded = gsenc::metrics::decode_as_stored(payload, &out.params, reference.dims, &mut CpuBackend::new())?;
        Ok((out, (decoded, t_dec.elapsed().as_secs_f64()), evals))
    })??;
    pb.finish_and_clear();
    let (decoded, decode_seconds) = decoded;
    let psnr = voxel_psnr(&decoded, &reference.values);
    let model = Model {
        meta: ModelMeta {
            frame: input.frame,
            range: input.range,
            field: o.field.clone(),
            step: o.step,
            schedule: cfg.schedule.name().into(),
            iterations: out.iterations as u32,
            points: out.points as u32,
            seed_init: cfg.seed_init,
            seed_sample: cfg.seed_sample,
            time: o.time,
            rank: 0,
            encode_psnr: Some(psnr),
        },
        params: out.params,
    };
    let bytes = format::write_model_as(&model, payload)?;
    write_atomic(&o.output, &bytes)?;
    let value = json!({
        "primitives": model.len(),
        "bytes": bytes.len(),
        "payload": payload.name(),
        "voxel_psnr": psnr,
        "sampled_psnr": sampled_psnr(&decoded, &reference.values),
        "occupied_psnr": occupied_psnr(&decoded, &reference.values),
        "seconds": out.loop_seconds,
        "total_seconds": t_total.elapsed().as_secs_f64(),
        "seed_seconds": out.seed_seconds,
        "decode_seconds": decode_seconds,
        "iterations": out.iterations,
        "points": out.points,
        "kernel_evals_per_second": evals as f64 / out.loop_seconds.max(1e-9),
        "dims": reference.dims,
        "output": o.output.display().to_string(),
    });
    match value {
        serde_json::Value::Object(map) => Ok(map),
        _ => unreachable!(),
    }
}

fn cmd_encode_grid(a: EncodeGridArgs) -> Result<()> {
    let t_total = Instant::now();
    let loaded = load_grid(&a.input)?;
    let range = a.values.spec()?.resolve(&loaded.grid.values)?;
    let norm = range.normalize(&loaded.grid.values)?;
    let reference = Grid::new(loaded.grid.dims, norm.values)?;
    let samples = GridSamples { grid: &reference };
    let input = EncodeInputData { target: Target { reference: &reference, samples: &samples }, frame: loaded.frame, range, particles: false };
    let mut result = run_encode(&input, &a.encode, t_total)?;
    result.insert("clamped_values".into(), json!(norm.clamped));
    print_result(a.encode.out.json, serde_json::Value::Object(result));
    Ok(())
}

impl ItemFiles {
    fn read(&self, path: &Path, comps: usize) -> Result<Vec<f64>> {
        raw::read_items(path, raw::DType::from_name(&self.dtype)?, comps, raw::Rows { count: self.count, row: self.row })
    }
}

fn triples(v: Vec<f64>) -> Vec<[f64; 3]> {
    v.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect()
}

fn to_f32(v: Vec<f64>) -> Vec<f32> {
    v.into_iter().map(|x| x as f32).collect()
}

impl PlacementArgs {
    /// The placement, with --fit-dims resolved against the given or the data's bounds.
    pub fn resolve(&self, data_bounds: impl FnOnce() -> Bounds) -> Result<Placement> {
        let dims = match (self.dims, self.fit_dims) {
            (Some(d), _) => d,
            (None, Some(n)) => self.bounds.unwrap_or_else(data_bounds).fitted_dims(n)?,
            (None, None) => return Err(Error::arg("give --dims or --fit-dims")),
        };
        Ok(Placement { dims, bounds: self.bounds })
    }
}

/// Particle arrays read from files, owned (a [`Particles`] borrows them).
pub struct ParticleArrays {
    positions: Vec<[f64; 3]>,
    smoothing_length: Vec<f64>,
    mass: Vec<f32>,
    values: Vec<f32>,
}

impl ParticleArrays {
    pub fn particles(&self) -> Particles<'_> {
        Particles { positions: &self.positions, smoothing_length: &self.smoothing_length, mass: &self.mass, values: &self.values }
    }
}

impl ParticleInput {
    /// The arrays of row `row` (the files' row when `None`).
    pub fn load(&self, row: Option<usize>) -> Result<ParticleArrays> {
        let mut f = self.files.clone();
        f.row = row.unwrap_or(f.row);
        let positions = triples(f.read(&self.positions, 3)?);
        let smoothing_length = f.read(&self.smoothing_length, 1)?;
        let values = to_f32(f.read(&self.values, 1)?);
        let mass = match &self.mass {
            Some(p) => to_f32(f.read(p, 1)?),
            None => vec![1.0; positions.len()],
        };
        Ok(ParticleArrays { positions, smoothing_length, mass, values })
    }

    fn prepare(&self, values: &ValueArgs) -> Result<Prepared> {
        let arrays = self.load(None)?;
        let p = arrays.particles();
        let placement = self.placement.resolve(|| p.bounds())?;
        prepare_particles(&p, &placement, &values.spec()?)
    }
}

impl CellInput {
    fn prepare(&self, values: &ValueArgs) -> Result<Prepared> {
        let f = &self.files;
        let centres = triples(f.read(&self.centers, 3)?);
        let field = to_f32(f.read(&self.values, 1)?);
        let (edges, volumes) = match (&self.sizes, &self.volumes) {
            (Some(p), _) => (triples(f.read(p, 3)?), vec![]),
            (None, Some(p)) => (vec![], f.read(p, 1)?),
            (None, None) => return Err(Error::arg("give --sizes or --volumes")),
        };
        let size = if self.sizes.is_some() { CellSize::Edges(&edges) } else { CellSize::Volumes(&volumes) };
        let c = Cells { centres: &centres, size, values: &field };
        let placement = self.placement.resolve(|| c.bounds())?;
        prepare_cells(&c, &placement, &values.spec()?)
    }
}

/// The process's peak resident memory (Linux `VmHWM`), when known.
pub fn peak_rss_bytes() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

/// The keys particle and cell commands add: what the deposit saw and cost.
fn deposit_keys(p: &Prepared) -> serde_json::Map<String, serde_json::Value> {
    let d = &p.deposit;
    let value = json!({
        "items": d.items,
        "samples": p.samples.q.len(),
        "outside": d.outside,
        "outside_dropped": d.outside_dropped,
        "nearest_voxel": d.nearest_voxel,
        "empty_voxels": d.empty_voxels,
        "clamped_values": p.clamped_values,
        "deposit_seconds": d.seconds,
        "deposit_peak_bytes": d.peak_bytes,
        "bounds_min": p.frame.bmin,
        "gamma": p.frame.gamma,
        "value_min": p.range.vmin,
        "value_max": p.range.vmax,
    });
    match value {
        serde_json::Value::Object(map) => map,
        _ => unreachable!(),
    }
}

fn encode_prepared(p: Prepared, particles: bool, o: &EncodeOptions, t_total: Instant) -> Result<()> {
    let input = EncodeInputData { target: p.target(), frame: p.frame, range: p.range, particles };
    let mut result = run_encode(&input, o, t_total)?;
    result.extend(deposit_keys(&p));
    result.insert("peak_rss_bytes".into(), json!(peak_rss_bytes()));
    print_result(o.out.json, serde_json::Value::Object(result));
    Ok(())
}

fn cmd_encode_particles(a: EncodeParticlesArgs) -> Result<()> {
    let t_total = Instant::now();
    let p = with_threads(a.encode.train.threads, || a.input.prepare(&a.values))??;
    encode_prepared(p, true, &a.encode, t_total)
}

fn cmd_encode_cells(a: EncodeCellsArgs) -> Result<()> {
    let t_total = Instant::now();
    let p = with_threads(a.encode.train.threads, || a.input.prepare(&a.values))??;
    encode_prepared(p, false, &a.encode, t_total)
}

fn write_deposit(p: Prepared, o: &GridOutput, field: &str) -> Result<()> {
    let unit = output_unit(&p.range, o.normalized);
    let values: Vec<f32> = p.reference.values.iter().map(|&v| unit(v)).collect();
    let spacing = 1.0 / p.frame.gamma;
    write_grid(&o.output, &Grid::new(p.reference.dims, values)?, p.frame.bmin.map(|b| b + 0.5 * spacing), [spacing; 3], field)?;
    let mut result = serde_json::Map::new();
    result.insert("dims".into(), json!(p.reference.dims));
    result.insert("voxels".into(), json!(p.reference.len()));
    result.extend(deposit_keys(&p));
    result.insert("peak_rss_bytes".into(), json!(peak_rss_bytes()));
    result.insert("output".into(), json!(o.output.display().to_string()));
    print_result(o.out.json, serde_json::Value::Object(result));
    Ok(())
}

fn cmd_deposit_particles(a: DepositParticlesArgs) -> Result<()> {
    let p = with_threads(a.output.threads, || a.input.prepare(&a.values))??;
    write_deposit(p, &a.output, "deposit")
}

fn cmd_deposit_cells(a: DepositCellsArgs) -> Result<()> {
    let p = with_threads(a.output.threads, || a.input.prepare(&a.values))??;
    write_deposit(p, &a.output, "deposit")
}

/// How a normalised value is written: kept, or mapped back to data units.
fn output_unit(range: &ValueRange, normalized: bool) -> impl Fn(f32) -> f32 + '_ {
    move |v| if normalized { v } else { range.denormalize(v) as f32 }
}

/// Writes a grid as .vti (when the name says so) or raw float32, atomically.
fn write_grid(path: &Path, grid: &Grid, origin: [f64; 3], spacing: [f64; 3], name: &str) -> Result<()> {
    let is_vti = path.extension().is_some_and(|e| e.eq_ignore_ascii_case("vti"));
    let bytes = if is_vti { vti::write_vti_bytes(grid, origin, spacing, name) } else { raw::to_f32_bytes(&grid.values) };
    write_atomic(path, &bytes)
}

fn cmd_decode(a: DecodeArgs) -> Result<()> {
    let t = Instant::now();
    // One step index names every rank's model of a step; else the models given.
    let (index, pieces) = match a.model.as_slice() {
        [index] if index.extension().is_some_and(|e| e == "gsi") => {
            let (index, pieces) = gsenc::io::read_step(index)?;
            (Some(index), pieces)
        }
        models => (None, models.iter().map(|p| read_model(p)).collect::<Result<Vec<_>>>()?),
    };
    let model = gsenc::global::merge(&pieces)?;
    let f = &model.meta.frame;
    let dims = a.dims.unwrap_or(f.dims);
    let region = match (a.sub_box, a.piece) {
        (Some([x0, y0, z0, x1, y1, z1]), _) => IndexBox { lo: [x0, y0, z0], hi: [x1, y1, z1] },
        (None, Some(i)) => {
            let piece = pieces.get(i).ok_or_else(|| Error::arg(format!("--piece {i}: only {} models given", pieces.len())))?;
            if dims != f.dims {
                return Err(Error::arg("--piece decodes on the models' own lattice; leave out --dims"));
            }
            gsenc::global::piece_box(f, &piece.meta.frame)?
        }
        (None, None) => IndexBox::whole(dims),
    };
    let spacing = [0, 1, 2].map(|i| f.dims[i] as f64 / dims[i] as f64 / f.gamma);
    let origin = [0, 1, 2].map(|i| f.bmin[i] + (region.lo[i] as f64 + 0.5) * spacing[i]);
    let out_path = &a.output.output;
    let is_vti = out_path.extension().is_some_and(|e| e.eq_ignore_ascii_case("vti"));
    let mut file = AtomicFile::create(out_path)?;
    if is_vti {
        file.write(&vti::vti_prefix(region.dims(), origin, spacing, &model.meta.field))?;
    }
    let mut bytes = Vec::new();
    let unit = output_unit(&model.meta.range, a.output.normalized);
    let mut write = |slab: &[f32]| {
        bytes.clear();
        bytes.extend(slab.iter().flat_map(|&v| unit(v).to_le_bytes()));
        file.write(&bytes)
    };
    with_threads(a.output.threads, || match index.as_ref().filter(|_| !a.additive) {
        // A step's pieces, each decoded on its own box and blended, in slabs of z layers.
        Some(index) => {
            let (global, boxes) = index.layout();
            let layers = (a.slab_voxels / (region.dims()[0] * region.dims()[1]).max(1)).max(1);
            let mut z = region.lo[2];
            while z < region.hi[2] {
                let slab = IndexBox { lo: [region.lo[0], region.lo[1], z], hi: [region.hi[0], region.hi[1], (z + layers).min(region.hi[2])] };
                write(&gsenc::global::blend(&global, &pieces, &boxes, index.halo, dims, slab, &mut CpuBackend::new())?.values)?;
                z = slab.hi[2];
            }
            Ok(())
        }
        None => model.decode_streaming(&mut CpuBackend::new(), dims, region, a.slab_voxels, &mut write),
    })??;
    if is_vti {
        file.write(vti::VTI_SUFFIX)?;
    }
    file.commit()?;
    let seconds = t.elapsed().as_secs_f64();
    let voxels: usize = region.dims().iter().product();
    print_result(
        a.output.out.json,
        json!({
            "dims": dims,
            "box_min": region.lo,
            "box_max": region.hi,
            "voxels": voxels,
            "seconds": seconds,
            "voxels_per_second": voxels as f64 / seconds.max(1e-9),
            "peak_rss_bytes": peak_rss_bytes(),
            "output": out_path.display().to_string(),
        }),
    );
    Ok(())
}

fn cmd_eval(a: EvalArgs) -> Result<()> {
    let model = read_model(&a.model)?;
    let loaded = load_grid(&a.input)?;
    let norm = if a.normalized {
        ValueRange::new(0.0, 1.0, Transform::Linear)?.normalize(&loaded.grid.values)?
    } else {
        model.meta.range.normalize(&loaded.grid.values)?
    };
    let decoded = with_threads(a.threads, || model.decode(&mut CpuBackend::new(), Some(loaded.grid.dims)))??;
    print_result(
        a.out.json,
        json!({
            "voxel_psnr": voxel_psnr(&decoded.values, &norm.values),
            "sampled_psnr": sampled_psnr(&decoded.values, &norm.values),
            "occupied_psnr": occupied_psnr(&decoded.values, &norm.values),
            "dims": loaded.grid.dims,
            "clamped_values": norm.clamped,
        }),
    );
    Ok(())
}

fn cmd_info(a: InfoArgs) -> Result<()> {
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
        }),
    );
    Ok(())
}

fn cmd_convert(a: ConvertArgs) -> Result<()> {
    let payload = format::Payload::from_name(&a.payload)?;
    let same = match (std::fs::canonicalize(&a.model), std::fs::canonicalize(&a.output)) {
        (Ok(x), Ok(y)) => x == y,
        _ => false,
    };
    if same {
        return Err(Error::arg("convert writes a new file; give an output other than the input"));
    }
    let mut file = gsenc::io::read_model_file(&a.model)?;
    // The stored encode PSNR stays true only when no precision is lost.
    if payload != file.payload && payload != format::Payload::Float32 {
        file.model.meta.encode_psnr = None;
    }
    let bytes = format::write_model_as(&file.model, payload)?;
    write_atomic(&a.output, &bytes)?;
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

fn main() {
    tracing_subscriber::fmt()
        .with_env_filter(tracing_subscriber::EnvFilter::from_default_env())
        .with_writer(std::io::stderr)
        .init();
    let cli = Cli::parse();
    let r = match cli.command {
        Command::Encode(EncodeInput::Grid(a)) => cmd_encode_grid(a),
        Command::Encode(EncodeInput::Particles(a)) => cmd_encode_particles(a),
        Command::Encode(EncodeInput::Cells(a)) => cmd_encode_cells(a),
        Command::Deposit(DepositInput::Particles(a)) => cmd_deposit_particles(a),
        Command::Deposit(DepositInput::Cells(a)) => cmd_deposit_cells(a),
        Command::Decode(a) => cmd_decode(a),
        Command::Eval(a) => cmd_eval(a),
        Command::Info(a) => cmd_info(a),
        Command::Convert(a) => cmd_convert(a),
        Command::Store(c) => store::store(c),
        Command::DecodeSeries(a) => store::decode_series(a),
        Command::EncodeSeries(a) => series::encode_series(a),
        Command::PlotSeries(a) => series::plot_series(a),
    };
    if let Err(e) = r {
        eprintln!("gsenc: {e}");
        std::process::exit(match e {
            Error::InvalidArgument(_) => 2,
            Error::InvalidData(_) => 3,
            Error::Format(_) | Error::Version(_) => 4,
            Error::Io { .. } | Error::Hdf5 { .. } => 5,
            Error::Cancelled(_) | Error::Mpi(_) => 6,
        });
    }
}
