//! The arguments several commands share, how clap parses them, and how they
//! turn into the library's inputs and settings.

use clap::builder::{PossibleValuesParser, TypedValueParser};
use clap::Args;
use gsenc::backend::select::{BackendChoice, BackendKind};
use gsenc::encode::{EncodeConfig, Schedule, TargetPsnr};
use gsenc::field::{Bounds, Grid, IndexFrame};
use gsenc::input::cells::{CellSize, Cells};
use gsenc::input::particles::Particles;
use gsenc::input::{Placement, RangeSpec};
use gsenc::io::{raw, vti};
use gsenc::{Error, Result};
use std::path::{Path, PathBuf};

/// A parser for one of a library enum's values by name: clap lists the names
/// in `--help` and refuses any other before the command does any work.
pub fn one_of<T: Copy + Send + Sync + 'static>(all: &'static [T], name: fn(T) -> &'static str) -> impl TypedValueParser<Value = T> {
    PossibleValuesParser::new(all.iter().map(|&v| name(v))).map(move |s| *all.iter().find(|&&v| name(v) == s).expect("clap checked the name"))
}

/// `--support stored|none`, as whether the support is stored.
const SUPPORT: [bool; 2] = [true, false];

fn support_name(stored: bool) -> &'static str {
    if stored {
        "stored"
    } else {
        "none"
    }
}

/// A parser through a library `from_name` (names with aliases).
pub fn named<T: 'static>(from_name: fn(&str) -> Result<T>) -> impl Fn(&str) -> std::result::Result<T, String> + Clone + Send + Sync + 'static {
    move |s| from_name(s).map_err(|e| e.to_string())
}

/// How to read a grid from a file.
#[derive(Args, Clone)]
pub struct GridInput {
    /// Input file: raw array (`.zst`: zstd-compressed), or .vti.
    #[arg(long)]
    pub input: PathBuf,
    /// Dims of a raw array, X,Y,Z.
    #[arg(long, value_parser = parse_dims)]
    pub dims: Option<[usize; 3]>,
    /// Element type of a raw array: u8, u16, f32, f64 (little-endian).
    #[arg(long, value_parser = named(raw::DType::from_name))]
    pub dtype: Option<raw::DType>,
    /// Memory order of a raw array: xfast (x varies fastest, C [z][y][x]) or zfast.
    #[arg(long, default_value = "xfast", value_parser = named(raw::Order::from_name))]
    pub order: raw::Order,
    /// Array of a .vti file (default: its active scalars).
    #[arg(long)]
    pub array: Option<String>,
    /// Mean-downsample by this integer factor first.
    #[arg(long, default_value_t = 1)]
    pub downsample: usize,
}

impl GridInput {
    /// The grid in data units and its world frame.
    pub fn load(&self) -> Result<(Grid, IndexFrame)> {
        let is_vti = self.input.extension().is_some_and(|e| e.eq_ignore_ascii_case("vti"));
        let (grid, origin, spacing) = if is_vti {
            let v = vti::read_vti(&self.input, self.array.as_deref())?;
            let s = v.spacing;
            if s.iter().any(|&d| !d.is_finite() || d <= 0.0) {
                return Err(Error::data(format!("{}: spacing {s:?} must be positive and finite", self.input.display())));
            }
            if (0..3).any(|i| ((s[i] - s[0]) / s[0]).abs() > 1e-6) {
                return Err(Error::data(format!("{}: spacing {s:?} is not isotropic; resample the grid to cubic voxels first", self.input.display())));
            }
            (v.grid, v.origin, s[0])
        } else {
            let dims = self.dims.ok_or_else(|| Error::arg("--dims X,Y,Z is required for raw input"))?;
            let dtype = self.dtype.ok_or_else(|| Error::arg("--dtype is required for raw input"))?;
            (raw::read_raw(&self.input, dims, dtype, self.order)?, [0.0; 3], 1.0)
        };
        let k = self.downsample;
        let grid = grid.downsample(k)?;
        // Block means sit at the centre of each block.
        let shift = 0.5 * (k as f64 - 1.0) * spacing;
        let frame = IndexFrame::for_grid(grid.dims, origin.map(|o| o + shift), spacing * k as f64)?;
        Ok((grid, frame))
    }
}

/// How values are normalised.
#[derive(Args, Clone)]
pub struct ValueArgs {
    /// Value range MIN,MAX (after --log10); default: the data's range.
    #[arg(long, value_parser = parse_range, allow_hyphen_values = true)]
    pub range: Option<[f64; 2]>,
    /// Normalise log10 of the values.
    #[arg(long)]
    pub log10: bool,
}

impl ValueArgs {
    pub fn spec(&self) -> Result<RangeSpec> {
        RangeSpec::of(self.range, self.log10)
    }
}

/// Which backend evaluates the mixture: every encoding and decoding command.
#[derive(Args, Clone, Copy)]
pub struct BackendArgs {
    /// auto: a hardware GPU when there is one, else the CPU (never a software
    /// adapter; falls back to the CPU if the GPU fails); cpu; gpu: the GPU
    /// or an error (GSENC_ADAPTER=llvmpipe selects Mesa's software adapter).
    /// GSENC_BACKEND overrides.
    #[arg(long, default_value = "auto", value_parser = one_of(&BackendKind::ALL, BackendKind::name))]
    pub backend: BackendKind,
    /// Which hardware GPU (the index `gsenc devices` lists).
    #[arg(long)]
    pub gpu_index: Option<usize>,
}

impl BackendArgs {
    pub fn choice(&self) -> BackendChoice {
        BackendChoice { kind: self.backend, gpu_index: self.gpu_index, brick: None }
    }
}

/// The budget and the optimisation: what every encoding command shares.
#[derive(Args)]
pub struct TrainingArgs {
    /// Number of Gaussians; with --target-psnr, the most it may choose
    /// (default: one per 32 voxels that hold data).
    #[arg(long, required_unless_present = "target_psnr")]
    pub budget: Option<usize>,
    /// Choose the number of Gaussians that reaches this voxel PSNR (dB) as
    /// stored: probed, predicted, then corrected (METHOD.md "A quality
    /// instead of a budget"). In a series the budget changes only at a step
    /// that misses the target.
    #[arg(long, allow_hyphen_values = true)]
    pub target_psnr: Option<f64>,
    /// full (3000 x 16384; 4000 iterations for particles), matched (1500 x 3072),
    /// short (500 x 8192), tuned (matched at 5x its learning rate, with
    /// points at voxel centres and where the model is wrong, every voxel
    /// weighed alike, flatter primitives allowed: more than full's quality
    /// at matched's cost; gsenc's, not the paper's), or
    /// tuned-full (full's iterations and points, trained as tuned: 1.2x
    /// full's cost, the most quality; gsenc's).
    #[arg(long, default_value = "matched", value_parser = one_of(&Schedule::ALL, Schedule::name))]
    pub schedule: Schedule,
    /// Override the schedule's iterations.
    #[arg(long)]
    pub iters: Option<usize>,
    /// Override the schedule's points per iteration.
    #[arg(long)]
    pub points: Option<usize>,
    /// Seed of the seeding draws.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Seed of the stratified point sampler.
    #[arg(long, default_value_t = 1)]
    pub sample_seed: u64,
    /// Skip the relocation passes.
    #[arg(long)]
    pub no_relocation: bool,
    /// stored (default): store where the data are non-zero with the model,
    /// so that it decodes to 0 there (METHOD.md "Support"; a few hundred
    /// bytes to a few KB); none: the paper's model exactly.
    #[arg(long, default_value = "stored", value_parser = one_of(&SUPPORT, support_name), action = clap::ArgAction::Set)]
    pub support: bool,
    /// Worker threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
    #[command(flatten)]
    pub device: BackendArgs,
}

impl TrainingArgs {
    /// The base configuration; the pipeline derives the schedule's length
    /// from the input's form (and a warm start's from its regime).
    pub fn config(&self) -> Result<EncodeConfig> {
        let mut cfg = EncodeConfig::new(self.budget.unwrap_or(0), self.schedule);
        cfg.target = self.target_psnr.map(TargetPsnr::new).transpose()?;
        cfg.iterations = self.iters;
        cfg.points = self.points;
        cfg.seed_init = self.seed;
        cfg.seed_sample = self.sample_seed;
        cfg.relocation = !self.no_relocation;
        Ok(cfg)
    }
}

/// Where the reference grid of particles or cells lies.
#[derive(Args, Clone)]
pub struct PlacementArgs {
    /// Reference grid dims X,Y,Z (or one number for a cube).
    #[arg(long, value_parser = parse_dims, required_unless_present = "fit_dims", conflicts_with = "fit_dims")]
    pub dims: Option<[usize; 3]>,
    /// Instead of --dims: this many voxels along the bounds' longest axis, and
    /// as many as fit along the others (cubic voxels).
    #[arg(long)]
    pub fit_dims: Option<usize>,
    /// World bounds XMIN,YMIN,ZMIN,XMAX,YMAX,ZMAX (default: the data's box).
    /// Items whose centres lie outside seed nothing; their support is clipped.
    #[arg(long, value_parser = parse_bounds, allow_hyphen_values = true)]
    pub bounds: Option<Bounds>,
}

impl PlacementArgs {
    /// The placement, with --fit-dims resolved against the given or the data's bounds.
    pub fn resolve(&self, data_bounds: impl FnOnce() -> Bounds) -> Result<Placement> {
        Placement::resolve(self.dims, self.fit_dims, self.bounds, data_bounds)
    }
}

/// Raw per-item array files: little-endian, C order, one row per item.
#[derive(Args, Clone)]
pub struct ItemFiles {
    /// Element type of every array file: f32 or f64 (also u8, u16).
    #[arg(long, default_value = "f32", value_parser = named(raw::DType::from_name))]
    pub dtype: raw::DType,
    /// Items per row, for files holding several steps (one row per step).
    #[arg(long)]
    pub count: Option<usize>,
    /// Which row to read (0-based; needs --count).
    #[arg(long, default_value_t = 0)]
    pub row: usize,
}

impl ItemFiles {
    fn rows(&self) -> raw::Rows {
        raw::Rows { count: self.count, row: self.row }
    }

    /// The first array of an input, read whole, and how many items it holds
    /// (every row): the bound on each other array's read ([`Self::read`]).
    fn read_first(&self, path: &Path, comps: usize) -> Result<(Vec<f64>, usize)> {
        raw::read_items_counted(path, self.dtype, comps, self.rows())
    }

    /// Another array of the input whose first array holds `held` items.
    fn read(&self, path: &Path, comps: usize, held: usize) -> Result<Vec<f64>> {
        raw::read_items_beside(path, self.dtype, comps, self.rows(), held)
    }
}

fn triples(v: Vec<f64>) -> Vec<[f64; 3]> {
    v.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect()
}

fn to_f32(v: Vec<f64>) -> Vec<f32> {
    v.into_iter().map(|x| x as f32).collect()
}

#[derive(Args, Clone)]
pub struct ParticleInput {
    /// Positions, N x 3.
    #[arg(long)]
    pub positions: PathBuf,
    /// SPH smoothing lengths hh, N (the kernel's support radius is 2 hh).
    #[arg(long)]
    pub smoothing_length: PathBuf,
    /// Masses, N (default: equal masses).
    #[arg(long)]
    pub mass: Option<PathBuf>,
    /// Field values, N.
    #[arg(long)]
    pub values: PathBuf,
    #[command(flatten)]
    pub files: ItemFiles,
    #[command(flatten)]
    pub placement: PlacementArgs,
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
        let (positions, held) = f.read_first(&self.positions, 3)?;
        let positions = triples(positions);
        let smoothing_length = f.read(&self.smoothing_length, 1, held)?;
        let values = to_f32(f.read(&self.values, 1, held)?);
        let mass = match &self.mass {
            Some(p) => to_f32(f.read(p, 1, held)?),
            None => vec![1.0; positions.len()],
        };
        let arrays = ParticleArrays { positions, smoothing_length, mass, values };
        // Checked before anything is made of them (their bounds, for --fit-dims).
        arrays.particles().validate()?;
        Ok(arrays)
    }
}

#[derive(Args, Clone)]
pub struct CellInput {
    /// Cell centres, N x 3.
    #[arg(long)]
    pub centers: PathBuf,
    /// Cell edge lengths, N x 3.
    #[arg(long, required_unless_present = "volumes", conflicts_with = "volumes")]
    pub sizes: Option<PathBuf>,
    /// Cell volumes, N (instead of --sizes).
    #[arg(long)]
    pub volumes: Option<PathBuf>,
    /// Field values, N.
    #[arg(long)]
    pub values: PathBuf,
    #[command(flatten)]
    pub files: ItemFiles,
    #[command(flatten)]
    pub placement: PlacementArgs,
}

/// Cell arrays read from files, owned (a [`Cells`] borrows them).
pub struct CellArrays {
    centres: Vec<[f64; 3]>,
    size: SizeArray,
    values: Vec<f32>,
}

/// The cells' sizes, as given: `--sizes` or `--volumes`.
enum SizeArray {
    Edges(Vec<[f64; 3]>),
    Volumes(Vec<f64>),
}

impl CellArrays {
    pub fn cells(&self) -> Cells<'_> {
        let size = match &self.size {
            SizeArray::Edges(e) => CellSize::Edges(e),
            SizeArray::Volumes(v) => CellSize::Volumes(v),
        };
        Cells { centres: &self.centres, size, values: &self.values }
    }
}

impl CellInput {
    pub fn load(&self) -> Result<CellArrays> {
        let f = &self.files;
        let (centres, held) = f.read_first(&self.centers, 3)?;
        let centres = triples(centres);
        let values = to_f32(f.read(&self.values, 1, held)?);
        let size = match (&self.sizes, &self.volumes) {
            (Some(p), _) => SizeArray::Edges(triples(f.read(p, 3, held)?)),
            (None, Some(p)) => SizeArray::Volumes(f.read(p, 1, held)?),
            (None, None) => return Err(Error::arg("give --sizes or --volumes")),
        };
        let arrays = CellArrays { centres, size, values };
        // Checked before anything is made of them (their bounds, for --fit-dims).
        arrays.cells().validate()?;
        Ok(arrays)
    }
}

#[derive(Args, Clone, Copy)]
pub struct OutputFlags {
    /// Print one JSON object instead of text.
    #[arg(long)]
    pub json: bool,
    /// No progress bar.
    #[arg(long, short)]
    pub quiet: bool,
}

/// Where a decoded or deposited grid goes.
#[derive(Args)]
pub struct GridOutput {
    /// Write normalised values in [0, 1] (what the encoder is fitted to)
    /// instead of data units.
    #[arg(long)]
    pub normalized: bool,
    /// Output: .vti (VTK ImageData) or anything else for raw float32, x
    /// fastest (`-`: raw to standard output; the results then go to standard
    /// error).
    #[arg(short, long)]
    pub output: PathBuf,
    #[arg(long)]
    pub threads: Option<usize>,
    #[command(flatten)]
    pub out: OutputFlags,
}

/// Comma-separated numbers, exactly `N` of them.
fn numbers<T: std::str::FromStr, const N: usize>(s: &str, what: &str, form: &str) -> std::result::Result<[T; N], String> {
    let v: Vec<T> = s.split(',').map(|x| x.trim().parse::<T>().map_err(|_| format!("bad {what} '{s}'"))).collect::<std::result::Result<_, _>>()?;
    v.try_into().map_err(|_| format!("{what} must be {form}, got '{s}'"))
}

pub fn parse_box(s: &str) -> std::result::Result<[usize; 6], String> {
    numbers(s, "box", "X0,Y0,Z0,X1,Y1,Z1")
}

pub fn parse_dims(s: &str) -> std::result::Result<[usize; 3], String> {
    let dims = match numbers::<usize, 1>(s, "dims", "X,Y,Z") {
        Ok([x]) => [x; 3],
        Err(_) => numbers::<usize, 3>(s, "dims", "X,Y,Z (positive)")?,
    };
    match dims.contains(&0) {
        false => Ok(dims),
        true => Err(format!("dims must be X,Y,Z (positive), got '{s}'")),
    }
}

fn parse_bounds(s: &str) -> std::result::Result<Bounds, String> {
    let [a, b, c, d, e, f] = numbers::<f64, 6>(s, "bounds", "XMIN,YMIN,ZMIN,XMAX,YMAX,ZMAX")?;
    Ok(Bounds { min: [a, b, c], max: [d, e, f] })
}

fn parse_range(s: &str) -> std::result::Result<[f64; 2], String> {
    numbers(s, "range", "MIN,MAX")
}
