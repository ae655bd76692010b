//! The encoder handle: push a step's fields, encode them (each warm-started
//! from its own previous step where configured), write the models.
//!
//! Pushed arrays are copied before the push returns, so the caller may
//! reuse its buffers at once. An encoder is used by one thread at a time;
//! different encoders are independent.

use super::config::{gsenc_config, Settings};
use super::handles::Kind;
use super::status::{fail, gsenc_status, guard, Failure};
use super::{c_str, DType};
use crate::backend::cpu::CpuBackend;
use crate::backend::{Backend, Lattice};
use crate::cells::{CellSize, Cells};
use crate::encoder::with_threads;
use crate::field::{Grid, IndexFrame};
use crate::format::write_model_as;
use crate::io::write_atomic;
use crate::metrics::voxel_psnr;
use crate::model::Model;
use crate::particles::Particles;
use crate::reference::Placement;
use crate::series::{SeriesEncoder, StepInput};
use std::collections::BTreeMap;
use std::os::raw::{c_char, c_void};

/// Opaque encoder; create with `gsenc_encoder_create`, free with
/// `gsenc_encoder_destroy`.
pub struct gsenc_encoder {
    settings: Settings,
    series: SeriesEncoder,
    pending: Vec<Pending>,
    /// The last model of each field and the PSNR of what was stored.
    last: BTreeMap<String, (Model, f64)>,
}

/// A pushed field waiting for `gsenc_encode`.
struct Pending {
    field: String,
    step: u64,
    time: Option<f64>,
    data: PendingData,
}

enum PendingData {
    Grid { grid: Grid, frame: IndexFrame },
    Particles { positions: Vec<[f64; 3]>, smoothing_length: Vec<f64>, mass: Vec<f32>, values: Vec<f32> },
    /// Cells as centres with edge lengths, or with volumes (from hexahedra).
    Cells { centres: Vec<[f64; 3]>, edges: Vec<[f64; 3]>, volumes: Vec<f64>, values: Vec<f32> },
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
    guard(|| {
        if out.is_null() {
            return fail(gsenc_status::NullPointer, "gsenc_encoder_create: out is NULL");
        }
        // SAFETY: non-null pointer to the caller's handle slot.
        unsafe { *out = std::ptr::null_mut() };
        // SAFETY: the caller passes a config of at least its struct_size bytes.
        let settings = unsafe { Settings::from_c(config) }?;
        let series = SeriesEncoder::new(settings.series.clone())?;
        let enc = Box::new(gsenc_encoder { settings, series, pending: Vec::new(), last: BTreeMap::new() });
        // SAFETY: as above.
        let raw = Box::into_raw(enc);
        super::handles::register(raw, Kind::Encoder);
        unsafe { *out = raw };
        Ok(())
    })
}

/// Frees an encoder and everything it holds. NULL, and a handle destroyed
/// already, are ignored; other calls with it afterwards fail with
/// `GSENC_STATUS_INVALID_ARGUMENT`. Not concurrently with other calls on it.
#[no_mangle]
pub unsafe extern "C" fn gsenc_encoder_destroy(encoder: *mut gsenc_encoder) {
    if !encoder.is_null() && super::handles::release(encoder, Kind::Encoder) {
        let _ = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            // SAFETY: made by Box::into_raw in gsenc_encoder_create, and live
            // until now (released above, so never freed twice).
            drop(unsafe { Box::from_raw(encoder) });
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
    fn push(&mut self, field: String, step: u64, time: f64, data: PendingData) -> Result<(), Failure> {
        crate::io::check_field_name(&field)?;
        // Refused now, not at encode, so the caller sees which push was bad.
        match &data {
            PendingData::Grid { grid, .. } => crate::field::check_finite(&grid.values)?,
            PendingData::Particles { positions, smoothing_length, mass, values } => {
                crate::field::check_finite(values)?;
                crate::field::check_finite(mass)?;
                if positions.iter().flatten().chain(smoothing_length).any(|v| !v.is_finite()) {
                    return fail(gsenc_status::InvalidData, "a particle position or smoothing length is not finite");
                }
            }
            PendingData::Cells { centres, edges, volumes, values } => {
                crate::field::check_finite(values)?;
                if centres.iter().chain(edges).flatten().chain(volumes).any(|v| !v.is_finite()) {
                    return fail(gsenc_status::InvalidData, "a cell centre, edge length or volume is not finite");
                }
            }
        }
        if self.pending.iter().any(|p| p.field == field) {
            return fail(gsenc_status::CallOrder, format!("field '{field}' was already pushed for this step; call gsenc_encode first"));
        }
        self.pending.push(Pending { field, step, time: time_of(time), data });
        Ok(())
    }
}

/// Hands over one field of step `step` (simulation time `time`; NaN when
/// unknown) on a regular grid. The values and `field` are copied before
/// the call returns: the caller keeps ownership and may reuse its buffers
/// at once. Encode with `gsenc_encode`.
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
        let mut values = Vec::with_capacity(dims.iter().product());
        for k in 0..dims[2] {
            for j in 0..dims[1] {
                for i in 0..dims[0] {
                    let at = i as i64 * strides[0] + j as i64 * strides[1] + k as i64 * strides[2];
                    // SAFETY: the caller's array holds every element its extents and strides name.
                    values.push(unsafe { dtype.read(g.data, at as isize) } as f32);
                }
            }
        }
        let frame = IndexFrame { dims, bmin: g.origin, gamma: 1.0 / g.spacing };
        enc.push(field, step, time, PendingData::Grid { grid: Grid::new(dims, values)?, frame })
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
        enc.push(field, step, time, PendingData::Particles { positions, smoothing_length, mass, values })
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
                PendingData::Cells { centres, edges, volumes: Vec::new(), values }
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
                PendingData::Cells { centres, edges: Vec::new(), volumes, values }
            }
            l => return fail(gsenc_status::InvalidArgument, format!("unknown cell layout {l}")),
        };
        enc.push(field, step, time, data)
    })
}

/// Encodes every field pushed since the last call, each warm-started from
/// its own previous step where configured, and writes the models to the
/// configured `output_dir`. Blocks until done. A field that fails leaves
/// its series as it was; the fields after it are still encoded, and the
/// first failure is returned. Runs on a pool of `config.threads` threads
/// of its own (0: rayon's global pool, every core).
/// Not thread-safe on one encoder (one thread at a time); different
/// encoders are independent.
#[no_mangle]
pub unsafe extern "C" fn gsenc_encode(encoder: *mut gsenc_encoder) -> gsenc_status {
    guard(|| {
        let enc = encoder_mut(encoder, "gsenc_encode")?;
        if enc.pending.is_empty() {
            return fail(gsenc_status::CallOrder, "gsenc_encode: nothing was pushed since the last encode");
        }
        let mut first_failure = None;
        for p in std::mem::take(&mut enc.pending) {
            if let Err(f) = enc.encode_one(p) {
                first_failure.get_or_insert(f);
            }
        }
        first_failure.map_or(Ok(()), Err)
    })
}

impl gsenc_encoder {
    fn encode_one(&mut self, p: Pending) -> Result<(), Failure> {
        let s = &self.settings;
        let placement = Placement { dims: s.dims, bounds: s.bounds };
        let (series, payload) = (&mut self.series, s.payload);
        let (model, psnr) = with_threads(s.threads, || -> crate::Result<(Model, f64)> {
            let mut cpu = CpuBackend::new();
            let particles;
            let cells;
            let input = match &p.data {
                PendingData::Grid { grid, frame } => StepInput::Grid { values: grid, frame: *frame },
                PendingData::Particles { positions, smoothing_length, mass, values } => {
                    particles = Particles { positions, smoothing_length, mass, values };
                    StepInput::Particles { particles: &particles, placement }
                }
                PendingData::Cells { centres, edges, volumes, values } => {
                    let size = if volumes.is_empty() { CellSize::Edges(edges) } else { CellSize::Volumes(volumes) };
                    cells = Cells { centres, size, values };
                    StepInput::Cells { cells: &cells, placement }
                }
            };
            let mut r = series.encode_step(&p.field, p.step, p.time, input, &mut cpu, &mut |_| {})?;
            let stored = payload.round_trip(&r.model.params)?;
            let mut decoded = vec![0f32; r.reference.len()];
            cpu.decode_lattice(&stored, &Lattice::reference(r.reference.dims), &mut decoded);
            let psnr = voxel_psnr(&decoded, &r.reference.values);
            r.model.meta.encode_psnr = Some(psnr);
            Ok((r.model, psnr))
        })??;
        let mut model = model;
        model.meta.rank = s.rank;
        if let Some(dir) = &s.output_dir {
            write_atomic(dir.join(model_file_name(&model)), &write_model_as(&model, s.payload)?)?;
        }
        self.last.insert(p.field, (model, psnr));
        Ok(())
    }
}

/// `FIELD_STEP.gsm`, with `_rRANK` on ranks other than 0.
fn model_file_name(m: &Model) -> String {
    match m.meta.rank {
        0 => format!("{}_{:06}.gsm", m.meta.field, m.meta.step),
        r => format!("{}_{:06}_r{r}.gsm", m.meta.field, m.meta.step),
    }
}

/// Writes the last model of `field` to `path` (through a temporary file and
/// a rename), with the configured payload. Strings are read during the
/// call only. Not thread-safe on one encoder (one thread at a time); different
/// encoders are independent.
#[no_mangle]
pub unsafe extern "C" fn gsenc_encoder_write_model(encoder: *mut gsenc_encoder, field: *const c_char, path: *const c_char) -> gsenc_status {
    guard(|| {
        let enc = encoder_mut(encoder, "gsenc_encoder_write_model")?;
        // SAFETY: NUL-terminated strings or NULL (refused).
        let (field, path) = unsafe { (c_str(field, "field")?, c_str(path, "path")?) };
        let Some((model, _)) = enc.last.get(&field) else {
            return fail(gsenc_status::CallOrder, format!("field '{field}' has not been encoded"));
        };
        write_atomic(&path, &write_model_as(model, enc.settings.payload)?)?;
        Ok(())
    })
}

/// The last encoded step of `field` and the voxel PSNR (dB) of its model as
/// stored, against the reference it was fitted to. Not thread-safe on one encoder (one thread at a time); different
/// encoders are independent.
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
        let Some((model, p)) = enc.last.get(&field) else {
            return fail(gsenc_status::CallOrder, format!("field '{field}' has not been encoded"));
        };
        // SAFETY: non-null out pointers.
        unsafe {
            *step = model.meta.step;
            *psnr = *p;
        }
        Ok(())
    })
}
