//! The encoder handle: push a step's fields (copied, then queued), and the
//! calls that follow the background queue: wait, poll, cancel, the last
//! model of a field.
//!
//! Pushed arrays are copied before the push returns, so the caller may
//! reuse its buffers at once; a worker thread of the encoder encodes them
//! (`queue::BackgroundEncoder`). An encoder is used by one thread at a
//! time; different encoders are independent.

use super::config::{gsenc_config, OutputFormat, Settings};
use super::handles::Kind;
use super::status::{fail, gsenc_status, guard, Failure};
use super::{c_str, DType};
use crate::field::{Grid, IndexFrame};
use crate::format::write_model_as;
use crate::io::{write_atomic, ModelFolder};
use crate::model::Model;
use crate::queue::{BackgroundEncoder, CallerStores, Job, JobState, ModelSink, Pushed, QueueConfig, StepData};
use crate::reference::Placement;
use std::os::raw::{c_char, c_void};

/// Opaque encoder; create with `gsenc_encoder_create`, free with
/// `gsenc_encoder_destroy`.
pub struct gsenc_encoder {
    settings: Settings,
    queue: BackgroundEncoder,
    /// The HDF5 store models go to, written on the caller's thread at the
    /// synchronising calls (`gsenc_wait`, `gsenc_poll`, destroy).
    #[cfg(feature = "hdf5")]
    store: Option<crate::io::store::Store>,
    /// Set by `gsenc_encoder_create_mpi`: pushes are collective, each rank
    /// encodes its piece of the domain.
    #[cfg(feature = "mpi")]
    ranks: Option<crate::mpi::Decomposition>,
}

/// Keeps models in memory only (no output configured).
struct KeepInMemory;

impl ModelSink for KeepInMemory {
    fn store(&mut self, _: &Model) -> crate::Result<Option<String>> {
        Ok(Some(String::new()))
    }
}

/// Cell layouts (`gsenc_cells.layout`).
pub const GSENC_CELLS_BOXES: i32 = 0;
pub const GSENC_CELLS_HEXAHEDRA: i32 = 1;

/// Hexahedral cells as they lie in memory, with one value each, in one of
/// two layouts:
/// - `GSENC_CELLS_BOXES` (AMR codes): axis-aligned boxes, `centres` and
///   `edges` (edge lengths along x, y, z) as tuples like particle positions;
/// - `GSENC_CELLS_HEXAHEDRA` (unstructured meshes): `points` (`point_count`
///   tuples) and `connectivity`, eight 0-based point indices per cell in VTK
///   order (0-1-2-3 one face, 4-5-6-7 the opposite, `i + 4` above `i`);
///   gsenc computes each cell's centre and volume.
///
/// Tuple strides default to 3 and component strides to 1 (0 selects them).
#[repr(C)]
#[derive(Clone, Copy, Debug)]
#[allow(non_camel_case_types)]
pub struct gsenc_cells {
    /// `sizeof(gsenc_cells)`.
    pub struct_size: usize,
    /// `GSENC_DTYPE_*` of every floating-point array.
    pub dtype: i32,
    /// `GSENC_CELLS_BOXES` or `GSENC_CELLS_HEXAHEDRA`.
    pub layout: i32,
    /// Number of cells.
    pub count: u64,
    pub centres: *const c_void,
    pub centre_stride: i64,
    pub centre_component_stride: i64,
    pub edges: *const c_void,
    pub edge_stride: i64,
    pub edge_component_stride: i64,
    pub points: *const c_void,
    pub point_count: u64,
    pub point_stride: i64,
    pub point_component_stride: i64,
    pub connectivity: *const i64,
    pub values: *const c_void,
    pub value_stride: i64,
}

/// A regular grid as it lies in the caller's memory: value `(i, j, k)` is
/// element `i * strides[0] + j * strides[1] + k * strides[2]` of `data`.
/// Strides are in elements; all zero means contiguous with i fastest
/// (C `[nz][ny][nx]`, Fortran `(nx, ny, nz)`). Strides larger than the
/// extents skip ghost layers without a copy.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
#[allow(non_camel_case_types)]
pub struct gsenc_grid {
    /// `sizeof(gsenc_grid)`.
    pub struct_size: usize,
    /// `GSENC_DTYPE_FLOAT32` or `GSENC_DTYPE_FLOAT64`.
    pub dtype: i32,
    pub data: *const c_void,
    /// Cells along x, y, z.
    pub extents: [u64; 3],
    pub strides: [i64; 3],
    /// World position of the lower corner of cell (0, 0, 0), and the edge of
    /// every (cubic) cell. Values are cell-centred.
    pub origin: [f64; 3],
    pub spacing: f64,
}

/// SPH particles as they lie in memory. Component `c` of particle `p`'s
/// position is element `p * position_stride + c * position_component_stride`
/// of `positions` (defaults 3 and 1: interleaved xyz; give 1 and `count` for
/// separate x, y, z arrays); a scalar array's element `p` is
/// `p * stride` (default 1, or the tuple size to pick one component of a
/// vector field). Strides are in elements; 0 selects the default.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
#[allow(non_camel_case_types)]
pub struct gsenc_particles {
    /// `sizeof(gsenc_particles)`.
    pub struct_size: usize,
    /// `GSENC_DTYPE_FLOAT32` or `GSENC_DTYPE_FLOAT64`, for every array.
    pub dtype: i32,
    pub count: u64,
    pub positions: *const c_void,
    pub position_stride: i64,
    pub position_component_stride: i64,
    /// SPH smoothing length `hh` (support radius `2 hh`).
    pub smoothing_length: *const c_void,
    pub smoothing_length_stride: i64,
    /// Masses; NULL for equal masses.
    pub mass: *const c_void,
    pub mass_stride: i64,
    /// The field's values.
    pub values: *const c_void,
    pub value_stride: i64,
}

/// `n` tuples of three from a caller's array (strides in elements, 0 = default).
///
/// # Safety
/// `ptr` holds every element the count and strides name.
unsafe fn read_tuples(dtype: DType, ptr: *const c_void, n: usize, stride: i64, component: i64) -> Vec<[f64; 3]> {
    let (ts, cs) = (if stride == 0 { 3 } else { stride }, if component == 0 { 1 } else { component });
    // SAFETY: per the contract.
    (0..n as i64).map(|i| std::array::from_fn(|c| unsafe { dtype.read(ptr, (i * ts + c as i64 * cs) as isize) })).collect()
}

/// `n` scalars from a caller's array (stride in elements, 0 = 1).
///
/// # Safety
/// `ptr` holds every element the count and stride name.
unsafe fn read_scalars(dtype: DType, ptr: *const c_void, n: usize, stride: i64) -> Vec<f64> {
    let s = if stride == 0 { 1 } else { stride };
    // SAFETY: per the contract.
    (0..n as i64).map(|i| unsafe { dtype.read(ptr, (i * s) as isize) }).collect()
}

/// The values of a strided grid, x fastest, as float32, into `values`
/// (a recycled buffer: no page faults for a fresh allocation). Rows with unit
/// stride are copied as slices (a 128^3 float push is a few memcpy-speed
/// milliseconds, the solver's only wait); other layouts element by element.
///
/// # Safety
/// `ptr` holds every element that `dims` and `strides` name.
unsafe fn copy_grid(dtype: DType, ptr: *const c_void, dims: [usize; 3], strides: [i64; 3], mut values: Vec<f32>) -> Vec<f32> {
    values.clear();
    values.reserve(dims.iter().product());
    // Slices need aligned data; a misaligned caller buffer takes the slow path.
    let unit = match dtype {
        DType::F32 if ptr.cast::<f32>().is_aligned() => strides[0] == 1,
        DType::F64 if ptr.cast::<f64>().is_aligned() => strides[0] == 1,
        _ => false,
    };
    for k in 0..dims[2] as i64 {
        for j in 0..dims[1] as i64 {
            let row = j * strides[1] + k * strides[2];
            // SAFETY (all three arms): per the contract, the row's elements exist.
            match (dtype, unit) {
                (DType::F32, true) => values.extend_from_slice(unsafe {
                    std::slice::from_raw_parts(ptr.cast::<f32>().offset(row as isize), dims[0])
                }),
                (DType::F64, true) => values.extend(
                    unsafe { std::slice::from_raw_parts(ptr.cast::<f64>().offset(row as isize), dims[0]) }.iter().map(|&v| v as f32),
                ),
                _ => values.extend((0..dims[0] as i64).map(|i| unsafe { dtype.read(ptr, (row + i * strides[0]) as isize) } as f32)),
            }
        }
    }
    values
}

fn item_count(count: u64, what: &str) -> Result<usize, Failure> {
    usize::try_from(count)
        .ok()
        .filter(|&n| n > 0 && n <= 1 << 40)
        .ok_or_else(|| Failure(gsenc_status::InvalidArgument, format!("{what} count {count} must be 1..2^40")))
}

/// Creates an encoder from `*config` (read, not kept) into `*out`.
/// On failure `*out` is NULL. Thread-safe.
#[no_mangle]
pub unsafe extern "C" fn gsenc_encoder_create(config: *const gsenc_config, out: *mut *mut gsenc_encoder) -> gsenc_status {
    // SAFETY: per this function's contract.
    guard(|| unsafe { create_into(config, out, "gsenc_encoder_create", gsenc_encoder::new) })
}

/// Creates an encoder by `make` from `*config` into `*out` (NULL on
/// failure) and registers its handle.
///
/// # Safety
/// `config` is NULL or a caller's config of at least its `struct_size`
/// bytes; `out` is NULL or the caller's handle slot.
unsafe fn create_into(
    config: *const gsenc_config,
    out: *mut *mut gsenc_encoder,
    what: &str,
    make: impl FnOnce(Settings) -> Result<gsenc_encoder, Failure>,
) -> Result<(), Failure> {
    if out.is_null() {
        return fail(gsenc_status::NullPointer, format!("{what}: out is NULL"));
    }
    // SAFETY: non-null pointer to the caller's handle slot.
    unsafe { *out = std::ptr::null_mut() };
    // SAFETY: the caller passes a config of at least its struct_size bytes.
    let settings = unsafe { Settings::from_c(config) }?;
    let raw = Box::into_raw(Box::new(make(settings)?));
    super::handles::register(raw, Kind::Encoder);
    // SAFETY: as above.
    unsafe { *out = raw };
    Ok(())
}

/// Creates one rank's encoder of a domain-decomposed run, over the
/// communicator whose Fortran handle is `comm` (`MPI_Comm_c2f(comm)` in C;
/// `integer :: comm` in Fortran), so that this header needs no `mpi.h`.
/// **Collective** over `comm`, as are every push and
/// `gsenc_encoder_destroy` of the encoder it makes; `gsenc_wait`,
/// `gsenc_poll` and the other calls are local. MPI must be initialised at
/// `MPI_THREAD_FUNNELED` or above, and collective calls must come from the
/// thread that initialised it (the encoder's own threads never call MPI).
/// The communicator is duplicated here and the duplicate freed at destroy;
/// the caller's is never freed.
///
/// Each rank pushes its own part of the domain; at a field's first step the
/// ranks agree one global lattice (a grid's spacing, or `dims` over
/// `bounds` or the union of every rank's particles or cells), each rank's
/// piece of it (its data's box grown by `config.halo` voxels) and the value
/// range, fixed for the series. Every push then sends each rank the data its
/// piece needs, and the rank encodes `config.budget` Gaussians over it.
/// Models go to `output_dir` as `FIELD_STEP.gsm` (rank 0) and
/// `FIELD_STEP_rRANK.gsm`, with rank 0's step index `FIELD_STEP.gsi`;
/// `gsenc decode FIELD_STEP.gsi` gives the global field. Ranks pushing
/// different fields, steps or forms get `GSENC_STATUS_MPI` together.
/// `GSENC_STATUS_MPI` too when this gsenc was built without MPI.
#[no_mangle]
pub unsafe extern "C" fn gsenc_encoder_create_mpi(config: *const gsenc_config, comm: i32, out: *mut *mut gsenc_encoder) -> gsenc_status {
    // SAFETY: per this function's contract.
    guard(|| unsafe { create_into(config, out, "gsenc_encoder_create_mpi", |settings| create_mpi(settings, comm)) })
}

#[cfg(feature = "mpi")]
fn create_mpi(mut settings: Settings, comm: i32) -> Result<gsenc_encoder, Failure> {
    use crate::mpi::{Decomposition, DecompositionConfig};
    if settings.output.is_some() && settings.output_format == OutputFormat::Hdf5 {
        return fail(
            gsenc_status::InvalidArgument,
            "an MPI encoder writes a folder of per-rank model files and step indexes; HDF5 output is for serial encoders",
        );
    }
    let cfg = DecompositionConfig { dims: settings.dims, bounds: settings.bounds, halo: settings.halo, range: settings.series.range };
    let ranks = Decomposition::from_fortran(comm, cfg)?;
    settings.rank = ranks.rank() as u32;
    let mut enc = gsenc_encoder::new(settings)?;
    enc.ranks = Some(ranks);
    Ok(enc)
}

#[cfg(not(feature = "mpi"))]
fn create_mpi(_: Settings, _: i32) -> Result<gsenc_encoder, Failure> {
    fail(gsenc_status::Mpi, "this gsenc was built without MPI (cargo feature mpi; CMake -DGSENC_CARGO_FEATURES=mpi)")
}

/// Drains the queue (every pushed step is encoded and written; call
/// `gsenc_encoder_cancel` first to drop them instead), then frees the
/// encoder and everything it holds. Failures of the drained jobs are not
/// reported: call `gsenc_wait` first to see them. NULL, and a handle
/// destroyed already, are ignored; other calls with it afterwards fail with
/// `GSENC_STATUS_INVALID_ARGUMENT`. Not concurrently with other calls on it.
/// Collective for an encoder of `gsenc_encoder_create_mpi` (it frees the
/// duplicated communicator).
#[no_mangle]
pub unsafe extern "C" fn gsenc_encoder_destroy(encoder: *mut gsenc_encoder) {
    if !encoder.is_null() && super::handles::release(encoder, Kind::Encoder) {
        let _ = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            // SAFETY: made by Box::into_raw in gsenc_encoder_create, and live
            // until now (released above, so never freed twice).
            let mut enc = unsafe { Box::from_raw(encoder) };
            let _ = enc.queue.wait(None);
            enc.flush();
            drop(enc); // the queue's drop joins its idle worker
        }));
    }
}

fn encoder_mut<'a>(encoder: *mut gsenc_encoder, what: &str) -> Result<&'a mut gsenc_encoder, Failure> {
    super::handles::check(encoder, Kind::Encoder, what)?;
    // SAFETY: a live handle from gsenc_encoder_create, used by one thread.
    Ok(unsafe { &mut *encoder })
}

/// Checks that a caller's struct, which starts with `size_t struct_size`,
/// holds at least this version's fields. Reads the size only.
///
/// # Safety
/// `p` is NULL or points to such a struct.
pub(crate) unsafe fn check_sized<T>(p: *const T, what: &str) -> Result<(), Failure> {
    if p.is_null() {
        return fail(gsenc_status::NullPointer, format!("{what} is NULL"));
    }
    // SAFETY: per the contract, the first field is a usize.
    let size = unsafe { p.cast::<usize>().read_unaligned() };
    let want = std::mem::size_of::<T>();
    if size < want {
        return fail(gsenc_status::StructSize, format!("{what}: struct_size is {size}, this gsenc needs {want}"));
    }
    Ok(())
}

/// A copy of a caller's struct after [`check_sized`].
///
/// # Safety
/// As for [`check_sized`], and the struct is initialised.
pub(crate) unsafe fn read_sized<T: Copy>(p: *const T, what: &str) -> Result<T, Failure> {
    // SAFETY: per the contract; then it holds at least size_of::<T>() bytes.
    unsafe {
        check_sized(p, what)?;
        Ok(p.read_unaligned())
    }
}

fn time_of(time: f64) -> Option<f64> {
    time.is_finite().then_some(time)
}

impl gsenc_encoder {
    fn new(settings: Settings) -> Result<gsenc_encoder, Failure> {
        let sink: Box<dyn ModelSink> = match (&settings.output, settings.output_format) {
            (None, _) => Box::new(KeepInMemory),
            (Some(dir), OutputFormat::Folder) => Box::new(ModelFolder { dir: dir.clone(), payload: settings.payload }),
            (Some(_), OutputFormat::Hdf5) => Box::new(CallerStores),
        };
        #[cfg(feature = "hdf5")]
        let store = match (&settings.output, settings.output_format) {
            (Some(path), OutputFormat::Hdf5) => Some(crate::io::store::Store::open_append(path)?),
            _ => None,
        };
        #[cfg(not(feature = "hdf5"))]
        if settings.output.is_some() && settings.output_format == OutputFormat::Hdf5 {
            return fail(
                gsenc_status::InvalidArgument,
                "this gsenc was built without HDF5 (cargo feature hdf5); write a folder of model files",
            );
        }
        let queue = BackgroundEncoder::new(
            QueueConfig {
                series: settings.series.clone(),
                max_bytes: settings.queue_bytes,
                when_full: settings.when_full,
                threads: settings.threads,
                payload: settings.payload,
                rank: settings.rank,
            },
            sink,
        )?;
        Ok(gsenc_encoder {
            settings,
            queue,
            #[cfg(feature = "hdf5")]
            store,
            #[cfg(feature = "mpi")]
            ranks: None,
        })
    }

    fn push(&mut self, field: String, step: u64, time: f64, data: StepData) -> Result<(), Failure> {
        let queue_bytes = self.settings.queue_bytes;
        let full = || format!("field '{field}' step {step}: the queue is full (queue_bytes {queue_bytes})");
        let job = Job { field: field.clone(), step, time: time_of(time), data, range: None };
        match self.push_job(job)? {
            Pushed::Queued => Ok(()),
            Pushed::Skipped => fail(gsenc_status::Skipped, format!("{}; the step was skipped", full())),
            Pushed::Busy => fail(gsenc_status::Busy, format!("{}; nothing was queued, push it again later", full())),
        }
    }

    /// Queues a job: on this encoder alone, or across the ranks (then rank 0
    /// also writes the step's index beside the models).
    fn push_job(&mut self, job: Job) -> Result<Pushed, Failure> {
        #[cfg(feature = "mpi")]
        if let Some(ranks) = self.ranks.as_mut() {
            let (field, step) = (job.field.clone(), job.step);
            let done = ranks.push(&self.queue, job, &|rank| crate::io::model_file_name(&field, step, rank))?;
            if let (Some(index), Some(dir)) = (done.index, self.settings.output.as_ref()) {
                if done.pushed == Pushed::Queued {
                    write_atomic(dir.join(crate::io::step_index_file_name(&field, step)), index.to_json().as_bytes())?;
                }
            }
            return Ok(done.pushed);
        }
        Ok(self.queue.push(job)?)
    }

    /// Appends the models the worker left for the caller's thread (HDF5).
    fn flush(&mut self) {
        #[cfg(feature = "hdf5")]
        if let Some(store) = self.store.as_mut() {
            for m in self.queue.take_finished() {
                let r = store.append(&m, self.settings.payload).map(|()| {
                    format!("{}:{}", store.path().display(), crate::io::store::EntryKey::of(&m.meta).path())
                });
                self.queue.set_stored(&m.meta.field, m.meta.step, r);
            }
        }
    }

    fn placement(&self) -> Placement {
        Placement { dims: self.settings.dims, bounds: self.settings.bounds }
    }
}

/// Hands over one field of step `step` (simulation time `time`; NaN when
/// unknown) on a regular grid. The values and `field` are copied before
/// the call returns: the caller keeps ownership and may reuse its buffers
/// at once. The step is queued for the background encode (see
/// `gsenc_config.when_full` for a full queue: `GSENC_STATUS_BUSY` or
/// `GSENC_STATUS_SKIPPED`); `gsenc_wait` and `gsenc_poll` follow it.
/// Not thread-safe on one encoder (one thread at a time); different
/// encoders are independent.
#[no_mangle]
pub unsafe extern "C" fn gsenc_push_grid(
    encoder: *mut gsenc_encoder,
    field: *const c_char,
    step: u64,
    time: f64,
    grid: *const gsenc_grid,
) -> gsenc_status {
    guard(|| {
        let enc = encoder_mut(encoder, "gsenc_push_grid")?;
        // SAFETY: a NUL-terminated string or NULL (refused).
        let field = unsafe { c_str(field, "field") }?;
        // SAFETY: NULL or the caller's gsenc_grid.
        let g = unsafe { read_sized(grid, "gsenc_push_grid: grid") }?;
        let dtype = DType::from_c(g.dtype)?;
        if g.data.is_null() {
            return fail(gsenc_status::NullPointer, "gsenc_push_grid: data is NULL");
        }
        let dims = super::extents(g.extents)?;
        if !(g.spacing.is_finite() && g.spacing > 0.0) || g.origin.iter().any(|o| !o.is_finite()) {
            return fail(gsenc_status::InvalidArgument, format!("origin {:?} and spacing {} must be finite, spacing positive", g.origin, g.spacing));
        }
        let strides = if g.strides == [0; 3] {
            [1, dims[0] as i64, (dims[0] * dims[1]) as i64]
        } else {
            g.strides
        };
        if strides.iter().any(|&s| s <= 0) {
            return fail(gsenc_status::InvalidArgument, format!("strides {:?} must all be positive (or all zero)", g.strides));
        }
        // SAFETY: the caller's array holds every element its extents and strides name.
        let buffer = enc.queue.recycled_buffer(dims.iter().product());
        // SAFETY: as above.
        let values = unsafe { copy_grid(dtype, g.data, dims, strides, buffer) };
        let frame = IndexFrame { dims, bmin: g.origin, gamma: 1.0 / g.spacing };
        enc.push(field, step, time, StepData::Grid { grid: Grid::new(dims, values)?, frame })
    })
}

/// Hands over one field of step `step` as SPH particles (see
/// `gsenc_particles`), deposited on the configured `dims` and bounds. The
/// arrays and `field` are copied before the call returns.
/// Not thread-safe on one encoder (one thread at a time); different
/// encoders are independent.
#[no_mangle]
pub unsafe extern "C" fn gsenc_push_particles(
    encoder: *mut gsenc_encoder,
    field: *const c_char,
    step: u64,
    time: f64,
    particles: *const gsenc_particles,
) -> gsenc_status {
    guard(|| {
        let enc = encoder_mut(encoder, "gsenc_push_particles")?;
        // SAFETY: a NUL-terminated string or NULL (refused).
        let field = unsafe { c_str(field, "field") }?;
        // SAFETY: NULL or the caller's gsenc_particles.
        let p = unsafe { read_sized(particles, "gsenc_push_particles: particles") }?;
        let dtype = DType::from_c(p.dtype)?;
        let n = item_count(p.count, "particle")?;
        for (ptr, name) in [(p.positions, "positions"), (p.smoothing_length, "smoothing_length"), (p.values, "values")] {
            if ptr.is_null() {
                return fail(gsenc_status::NullPointer, format!("gsenc_push_particles: {name} is NULL"));
            }
        }
        // SAFETY (every read below): the caller's arrays hold every element
        // that `count` and the strides name.
        let positions = unsafe { read_tuples(dtype, p.positions, n, p.position_stride, p.position_component_stride) };
        let smoothing_length = unsafe { read_scalars(dtype, p.smoothing_length, n, p.smoothing_length_stride) };
        let values = unsafe { read_scalars(dtype, p.values, n, p.value_stride) }.into_iter().map(|v| v as f32).collect();
        let mass = if p.mass.is_null() {
            vec![1.0; n]
        } else {
            unsafe { read_scalars(dtype, p.mass, n, p.mass_stride) }.into_iter().map(|v| v as f32).collect()
        };
        let placement = enc.placement();
        enc.push(field, step, time, StepData::Particles { positions, smoothing_length, mass, values, placement })
    })
}

/// Hands over one field of step `step` on hexahedral cells (see
/// `gsenc_cells`), deposited on the configured `dims` and bounds
/// (volume-weighted). The arrays and `field` are copied before the call
/// returns.
/// Not thread-safe on one encoder (one thread at a time); different
/// encoders are independent.
#[no_mangle]
pub unsafe extern "C" fn gsenc_push_cells(
    encoder: *mut gsenc_encoder,
    field: *const c_char,
    step: u64,
    time: f64,
    cells: *const gsenc_cells,
) -> gsenc_status {
    guard(|| {
        let enc = encoder_mut(encoder, "gsenc_push_cells")?;
        // SAFETY: a NUL-terminated string or NULL (refused).
        let field = unsafe { c_str(field, "field") }?;
        // SAFETY: NULL or the caller's gsenc_cells.
        let c = unsafe { read_sized(cells, "gsenc_push_cells: cells") }?;
        let dtype = DType::from_c(c.dtype)?;
        let n = item_count(c.count, "cell")?;
        if c.values.is_null() {
            return fail(gsenc_status::NullPointer, "gsenc_push_cells: values is NULL");
        }
        // SAFETY (every read below): the caller's arrays hold every element
        // that the counts and strides name.
        let values: Vec<f32> = unsafe { read_scalars(dtype, c.values, n, c.value_stride) }.into_iter().map(|v| v as f32).collect();
        let data = match c.layout {
            GSENC_CELLS_BOXES => {
                if c.centres.is_null() || c.edges.is_null() {
                    return fail(gsenc_status::NullPointer, "gsenc_push_cells: centres or edges is NULL");
                }
                let centres = unsafe { read_tuples(dtype, c.centres, n, c.centre_stride, c.centre_component_stride) };
                let edges = unsafe { read_tuples(dtype, c.edges, n, c.edge_stride, c.edge_component_stride) };
                StepData::Cells { centres, edges, volumes: Vec::new(), values, placement: enc.placement() }
            }
            GSENC_CELLS_HEXAHEDRA => {
                if c.points.is_null() || c.connectivity.is_null() {
                    return fail(gsenc_status::NullPointer, "gsenc_push_cells: points or connectivity is NULL");
                }
                let np = item_count(c.point_count, "point")?;
                let points = unsafe { read_tuples(dtype, c.points, np, c.point_stride, c.point_component_stride) };
                // SAFETY: 8 indices per cell.
                let conn = unsafe { std::slice::from_raw_parts(c.connectivity, 8 * n) };
                if let Some(i) = conn.iter().position(|&k| k < 0 || k as u64 >= np as u64) {
                    return fail(
                        gsenc_status::InvalidArgument,
                        format!("connectivity entry {i} (cell {}) is {}, outside 0..{np}", i / 8, conn[i]),
                    );
                }
                let (centres, volumes) = conn
                    .chunks_exact(8)
                    .map(|k| crate::cells::hexahedron_centre_volume(&std::array::from_fn(|j| points[k[j] as usize])))
                    .unzip();
                StepData::Cells { centres, edges: Vec::new(), volumes, values, placement: enc.placement() }
            }
            l => return fail(gsenc_status::InvalidArgument, format!("unknown cell layout {l}")),
        };
        enc.push(field, step, time, data)
    })
}

/// Blocks until every pushed step of `field` (NULL: of every field) is
/// encoded and written. Returns the first failure not reported before
/// (its message names the field and step; later steps were still encoded),
/// else `GSENC_STATUS_OK`. Models bound for an HDF5 store are written here,
/// on the caller's thread. Not thread-safe on one encoder.
#[no_mangle]
pub unsafe extern "C" fn gsenc_wait(encoder: *mut gsenc_encoder, field: *const c_char) -> gsenc_status {
    guard(|| {
        let enc = encoder_mut(encoder, "gsenc_wait")?;
        // SAFETY: NULL or a NUL-terminated string.
        let field = if field.is_null() { None } else { Some(unsafe { c_str(field, "field") }?) };
        if let Some(f) = &field {
            crate::io::check_field_name(f)?;
        }
        let waited = enc.queue.wait(field.as_deref());
        enc.flush();
        waited?;
        // A store write that failed in the flush is a failure of this wait too.
        enc.queue.wait(field.as_deref())?;
        Ok(())
    })
}

/// Job states (`gsenc_job.state`).
pub const GSENC_JOB_QUEUED: i32 = 0;
pub const GSENC_JOB_RUNNING: i32 = 1;
/// Encoded, and written when an output is configured.
pub const GSENC_JOB_DONE: i32 = 2;
pub const GSENC_JOB_FAILED: i32 = 3;
/// Dropped by the `GSENC_QUEUE_SKIP` policy.
pub const GSENC_JOB_SKIPPED: i32 = 4;
/// Dropped by `gsenc_encoder_cancel`.
pub const GSENC_JOB_CANCELLED: i32 = 5;

/// Where one pushed step is. Set `struct_size` to `sizeof(gsenc_job)`.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
#[allow(non_camel_case_types)]
pub struct gsenc_job {
    pub struct_size: usize,
    /// `GSENC_JOB_*`.
    pub state: i32,
    /// While running: the optimisation iteration reached, of `iterations`
    /// (both 0 while depositing and seeding).
    pub iteration: u32,
    pub iterations: u32,
    /// When failed: the failure's status (its message is then the calling
    /// thread's `gsenc_last_error`); else `GSENC_STATUS_OK`.
    pub error: i32,
    /// When done: the voxel PSNR (dB) of the model as stored; else NaN.
    pub psnr: f64,
}

/// Fills `*job` with the state of `field`'s step `step`, without waiting.
/// `GSENC_STATUS_CALL_ORDER` when that step was never pushed. Models bound
/// for an HDF5 store are written here. Not thread-safe on one encoder.
#[no_mangle]
pub unsafe extern "C" fn gsenc_poll(encoder: *mut gsenc_encoder, field: *const c_char, step: u64, job: *mut gsenc_job) -> gsenc_status {
    guard(|| {
        let enc = encoder_mut(encoder, "gsenc_poll")?;
        // SAFETY: a NUL-terminated string or NULL (refused).
        let field = unsafe { c_str(field, "field") }?;
        // SAFETY: NULL or the caller's gsenc_job.
        unsafe { check_sized(job.cast_const(), "gsenc_poll: job") }?;
        enc.flush();
        let Some(state) = enc.queue.poll(&field, step) else {
            return fail(gsenc_status::CallOrder, format!("field '{field}' step {step} was never pushed"));
        };
        let mut out = gsenc_job {
            struct_size: std::mem::size_of::<gsenc_job>(),
            state: GSENC_JOB_QUEUED,
            iteration: 0,
            iterations: 0,
            error: gsenc_status::Ok as i32,
            psnr: f64::NAN,
        };
        let mut message = None;
        match state {
            JobState::Queued => {}
            JobState::Running { iteration, iterations } => {
                out.state = GSENC_JOB_RUNNING;
                out.iteration = iteration as u32;
                out.iterations = iterations as u32;
            }
            JobState::Written { psnr, .. } | JobState::Encoded { psnr } => {
                out.state = GSENC_JOB_DONE;
                out.psnr = psnr;
            }
            JobState::Failed(e) => {
                out.state = GSENC_JOB_FAILED;
                let f = Failure::from(e.in_context(&format!("field '{field}' step {step}")));
                out.error = f.0 as i32;
                message = Some(f.1);
            }
            JobState::Skipped => out.state = GSENC_JOB_SKIPPED,
            JobState::Cancelled => out.state = GSENC_JOB_CANCELLED,
        }
        // SAFETY: as above.
        unsafe { job.write(out) };
        if let Some(m) = message {
            super::status::set_last_error(m);
        }
        Ok(())
    })
}

/// Drops every queued step and stops the running one at its next
/// iteration; returns when the worker is idle. Their states become
/// `GSENC_JOB_CANCELLED`; each field's next step warm-starts from its last
/// encoded one. The encoder stays usable. Not thread-safe on one encoder.
#[no_mangle]
pub unsafe extern "C" fn gsenc_encoder_cancel(encoder: *mut gsenc_encoder) -> gsenc_status {
    guard(|| {
        let enc = encoder_mut(encoder, "gsenc_encoder_cancel")?;
        enc.queue.cancel();
        enc.flush();
        Ok(())
    })
}

/// Writes the last encoded model of `field` to `path` (through a temporary
/// file and a rename), with the configured payload. Does not wait for
/// queued steps (call `gsenc_wait` first for the newest). Strings are read
/// during the call only. Not thread-safe on one encoder.
#[no_mangle]
pub unsafe extern "C" fn gsenc_encoder_write_model(encoder: *mut gsenc_encoder, field: *const c_char, path: *const c_char) -> gsenc_status {
    guard(|| {
        let enc = encoder_mut(encoder, "gsenc_encoder_write_model")?;
        // SAFETY: NUL-terminated strings or NULL (refused).
        let (field, path) = unsafe { (c_str(field, "field")?, c_str(path, "path")?) };
        let Some((model, _)) = enc.queue.last(&field) else {
            return fail(gsenc_status::CallOrder, format!("field '{field}' has no encoded step yet"));
        };
        write_atomic(&path, &write_model_as(&model, enc.settings.payload)?)?;
        Ok(())
    })
}

/// The last encoded step of `field` and the voxel PSNR (dB) of its model as
/// stored, against the reference it was fitted to. Does not wait for queued
/// steps. Not thread-safe on one encoder.
#[no_mangle]
pub unsafe extern "C" fn gsenc_encoder_last_step(
    encoder: *mut gsenc_encoder,
    field: *const c_char,
    step: *mut u64,
    psnr: *mut f64,
) -> gsenc_status {
    guard(|| {
        let enc = encoder_mut(encoder, "gsenc_encoder_last_step")?;
        // SAFETY: NUL-terminated string or NULL (refused).
        let field = unsafe { c_str(field, "field") }?;
        if step.is_null() || psnr.is_null() {
            return fail(gsenc_status::NullPointer, "gsenc_encoder_last_step: step or psnr is NULL");
        }
        let Some((model, p)) = enc.queue.last(&field) else {
            return fail(gsenc_status::CallOrder, format!("field '{field}' has no encoded step yet"));
        };
        // SAFETY: non-null out pointers.
        unsafe {
            *step = model.meta.step;
            *psnr = p;
        }
        Ok(())
    })
}
