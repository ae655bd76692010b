//! The three input forms as they lie in a caller's memory (grids with
//! strides, particles as tuples or separate arrays, cells as boxes or
//! hexahedra), and the pushes that copy one field of a step out of them
//! into the encoder's queue.

use crate::encoder::{gsenc_encoder, with_encoder, Copied};
use crate::ffi::{c_str, check_reach, copy_grid, extents, item_count, read_scalars, read_sized, read_tuples, DType};
use crate::status::{fail, gsenc_status, guard, Failure};
use gsenc::domain::halo::Kind as DataKind;
use gsenc::field::{Grid, IndexFrame};
use gsenc::input::StepData;
use std::os::raw::{c_char, c_void};

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
/// Tuple strides default to 3 and component strides to 1 (0 selects them);
/// strides are checked as `gsenc_particles`' are.
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
/// extents skip ghost layers without a copy; a negative stride walks its
/// axis backwards from `data` (a reversed view, `data` at value
/// `(0, 0, 0)`). A zero stride among non-zero ones (but on an axis of one
/// cell, where none is used: a 2D slab's z), or strides that reach an
/// element more than `PTRDIFF_MAX` bytes from `data`, are
/// `GSENC_STATUS_INVALID_ARGUMENT`.
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
/// vector field). Strides are in elements; 0 selects the default. A
/// stride that reaches past what any array can hold (an element more than
/// `PTRDIFF_MAX` bytes from the start) is `GSENC_STATUS_INVALID_ARGUMENT`.
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

/// Hands over one field of step `step` (simulation time `time`; NaN when
/// unknown) on a regular grid. The values and `field` are copied before
/// the call returns: the caller keeps ownership and may reuse its buffers
/// at once. The step is queued for the background encode (see
/// `gsenc_config.when_full` for a full queue: `GSENC_STATUS_BUSY` or
/// `GSENC_STATUS_SKIPPED`); `gsenc_wait` and `gsenc_poll` follow it.
/// Calls on one encoder from several threads run one at a time; different
/// encoders are independent.
///
/// # Safety
/// `encoder` may be any value (only a live encoder handle is used);
/// `field` is NULL or a NUL-terminated string; `grid` is NULL or an
/// initialised `gsenc_grid` whose `data` holds every element its `extents`
/// and strides name. gsenc cannot see an array's length: a shorter array
/// is read past its end.
#[no_mangle]
pub unsafe extern "C" fn gsenc_push_grid(
    encoder: *mut gsenc_encoder,
    field: *const c_char,
    step: u64,
    time: f64,
    grid: *const gsenc_grid,
) -> gsenc_status {
    // SAFETY (both): `field` and `grid` per this function's contract.
    unsafe { push_step(encoder, "gsenc_push_grid", field, step, time, DataKind::Grid, |enc| grid_data(enc, grid)) }
}

/// One push of one field of one step: the encoder and the field's name
/// checked, `make` (the checked copy of the caller's data) run, and what it
/// made pushed, or its failure reported (`push_made`, which for an MPI
/// encoder lets the other ranks' pushes fail too instead of waiting).
///
/// # Safety
/// `field` is NULL or a NUL-terminated string.
unsafe fn push_step(
    encoder: *mut gsenc_encoder,
    what: &str,
    field: *const c_char,
    step: u64,
    time: f64,
    kind: DataKind,
    make: impl FnOnce(&gsenc_encoder) -> Result<Copied, Failure>,
) -> gsenc_status {
    guard(|| {
        with_encoder(encoder, what, |enc| {
            // SAFETY: a NUL-terminated string or NULL (refused).
            let field = unsafe { c_str(field, &format!("{what}: field")) };
            let name = field.as_ref().map_or(String::new(), Clone::clone);
            let made = field.and_then(|_| make(enc));
            enc.push_made(&name, step, time, kind, made)
        })
    })
}

/// Readies the encoder for grid pushes of up to `values` values (the
/// product of a grid's extents): one buffer for the copy is allocated and
/// its memory touched now, so that the first `gsenc_push_grid` copies into
/// it, as later pushes copy into buffers recycled from finished steps,
/// instead of paying for a new buffer's page faults (the first push of a
/// 128^3 field took 7.4 ms on a 16-core machine, later ones about 4 ms).
/// Optional; call it once after creating the encoder, with the largest
/// grid this rank will push. 0, or a size a buffer kept already covers,
/// does nothing; a size this process's memory cannot take now is refused
/// (`GSENC_STATUS_INVALID_ARGUMENT`, nothing allocated). Calls on one
/// encoder run one at a time.
///
/// # Safety
/// `encoder` may be any value (only a live encoder handle is used).
#[no_mangle]
pub unsafe extern "C" fn gsenc_encoder_reserve(encoder: *mut gsenc_encoder, values: u64) -> gsenc_status {
    guard(|| {
        with_encoder(encoder, "gsenc_encoder_reserve", |enc| {
            let Ok(len) = usize::try_from(values) else {
                return fail(gsenc_status::InvalidArgument, format!("gsenc_encoder_reserve: {values} values do not fit in memory"));
            };
            Ok(enc.queue.reserve(len)?)
        })
    })
}

/// The checked copy of a caller's grid.
///
/// # Safety
/// `grid` is NULL or the caller's gsenc_grid, whose array holds every element its extents and strides name.
unsafe fn grid_data(enc: &gsenc_encoder, grid: *const gsenc_grid) -> Result<Copied, Failure> {
    // SAFETY: NULL or the caller's gsenc_grid.
    let g = unsafe { read_sized(grid, "gsenc_push_grid: grid") }?;
    let dtype = DType::from_c(g.dtype)?;
    if g.data.is_null() {
        return fail(gsenc_status::NullPointer, "gsenc_push_grid: data is NULL");
    }
    let dims = extents(g.extents)?;
    if !(g.spacing.is_finite() && g.spacing > 0.0) || g.origin.iter().any(|o| !o.is_finite()) {
        return fail(gsenc_status::InvalidArgument, format!("origin {:?} and spacing {} must be finite, spacing positive", g.origin, g.spacing));
    }
    let strides = if g.strides == [0; 3] {
        [1, dims[0] as i64, (dims[0] * dims[1]) as i64]
    } else {
        g.strides
    };
    // Negative strides walk an axis backwards from `data` (a reversed view).
    // A zero stride would read one value along its whole axis: refused, but
    // on an axis of one cell (a 2D slab's z), where no stride is ever used.
    if (0..3).any(|a| strides[a] == 0 && dims[a] > 1) {
        return fail(gsenc_status::InvalidArgument, format!("strides {:?} must be non-zero along every axis of more than one cell (or all zero: contiguous)", g.strides));
    }
    check_reach("gsenc_push_grid: data", dtype, &[(dims[0], strides[0]), (dims[1], strides[1]), (dims[2], strides[2])])?;
    let voxels = dims.iter().product::<usize>();
    // A recycled buffer takes no memory; a new one must fit (asking the
    // system takes 0.2 ms, which the usual push, into a recycled buffer,
    // is spared).
    let buffer = match enc.queue.recycled_buffer(voxels) {
        Some(b) => b,
        None => {
            gsenc::memory::check_fits("gsenc_push_grid: the field's copy", 4 * voxels as u64)?;
            gsenc::memory::with_pages(voxels)
        }
    };
    // SAFETY: the caller's array holds every element its extents and strides name.
    let (values, finite) = unsafe { copy_grid(dtype, g.data, dims, strides, buffer) };
    if !finite {
        // Which value, in the words of the queue's own check.
        gsenc::field::check_finite_serial(&values)?;
    }
    let frame = IndexFrame { dims, bmin: g.origin, gamma: 1.0 / g.spacing };
    Ok(Copied { data: StepData::Grid { grid: Grid::new(dims, values)?, frame }, finite: true })
}

/// Hands over one field of step `step` as SPH particles (see
/// `gsenc_particles`), deposited on the configured `dims` and bounds. The
/// arrays and `field` are copied before the call returns. `count` is at
/// least 1, but on an MPI encoder, whose ranks may hold none (the arrays
/// may then be NULL) at every step but a field's first.
/// Calls on one encoder from several threads run one at a time; different
/// encoders are independent.
///
/// # Safety
/// As for `gsenc_push_grid`, with `particles` NULL or an initialised
/// `gsenc_particles` whose arrays each hold every element `count` and
/// their strides name (`mass` may be NULL).
#[no_mangle]
pub unsafe extern "C" fn gsenc_push_particles(
    encoder: *mut gsenc_encoder,
    field: *const c_char,
    step: u64,
    time: f64,
    particles: *const gsenc_particles,
) -> gsenc_status {
    // SAFETY (both): `field` and `particles` per this function's contract.
    unsafe { push_step(encoder, "gsenc_push_particles", field, step, time, DataKind::Particles, |enc| particle_data(enc, particles).map(Copied::unchecked)) }
}

/// The checked copy of a caller's particles.
///
/// # Safety
/// `particles` is NULL or the caller's gsenc_particles, whose arrays hold every element that `count` and the strides name.
unsafe fn particle_data(enc: &gsenc_encoder, particles: *const gsenc_particles) -> Result<StepData, Failure> {
    // SAFETY: NULL or the caller's gsenc_particles.
    let p = unsafe { read_sized(particles, "gsenc_push_particles: particles") }?;
    let dtype = DType::from_c(p.dtype)?;
    let n = item_count(p.count, "particle", enc.is_mpi())?;
    // Positions, smoothing lengths (f64), masses and values (f32).
    gsenc::memory::check_fits("gsenc_push_particles: the particles' copy", 40 * n as u64)?;
    for (ptr, name) in [(p.positions, "positions"), (p.smoothing_length, "smoothing_length"), (p.values, "values")] {
        // None to read: an empty C++ vector's data() is NULL.
        if ptr.is_null() && n > 0 {
            return fail(gsenc_status::NullPointer, format!("gsenc_push_particles: {name} is NULL"));
        }
    }
    // SAFETY (every read below): the caller's arrays hold every element
    // that `count` and the strides name.
    let positions = unsafe { read_tuples("gsenc_push_particles: positions", dtype, p.positions, n, p.position_stride, p.position_component_stride) }?;
    let smoothing_length = unsafe { read_scalars("gsenc_push_particles: smoothing_length", dtype, p.smoothing_length, n, p.smoothing_length_stride) }?;
    let values = unsafe { read_scalars("gsenc_push_particles: values", dtype, p.values, n, p.value_stride) }?.into_iter().map(|v| v as f32).collect();
    let mass = if p.mass.is_null() || n == 0 {
        vec![1.0; n]
    } else {
        unsafe { read_scalars("gsenc_push_particles: mass", dtype, p.mass, n, p.mass_stride) }?.into_iter().map(|v| v as f32).collect()
    };
    let placement = enc.placement();
    Ok(StepData::Particles { positions, smoothing_length, mass, values, placement })
}

/// Hands over one field of step `step` on hexahedral cells (see
/// `gsenc_cells`), deposited on the configured `dims` and bounds
/// (volume-weighted). The arrays and `field` are copied before the call
/// returns. `count` is at least 1, but on an MPI encoder, as for
/// `gsenc_push_particles`.
/// Calls on one encoder from several threads run one at a time; different
/// encoders are independent.
///
/// # Safety
/// As for `gsenc_push_grid`, with `cells` NULL or an initialised
/// `gsenc_cells` whose arrays of its layout each hold every element
/// `count` (`point_count` for `points`) and their strides name, and
/// `connectivity` `8 * count` indices.
#[no_mangle]
pub unsafe extern "C" fn gsenc_push_cells(
    encoder: *mut gsenc_encoder,
    field: *const c_char,
    step: u64,
    time: f64,
    cells: *const gsenc_cells,
) -> gsenc_status {
    // Read once (its size checked first): its layout is the form the
    // ranks' push names even when the copy fails. SAFETY: NULL or the
    // caller's gsenc_cells.
    let c = unsafe { read_sized(cells, "gsenc_push_cells: cells") };
    let kind = match &c {
        Ok(c) if c.layout == GSENC_CELLS_HEXAHEDRA => DataKind::CellVolumes,
        _ => DataKind::CellBoxes,
    };
    // SAFETY (both): `field` and the arrays of `cells` per this function's contract.
    unsafe { push_step(encoder, "gsenc_push_cells", field, step, time, kind, |enc| cell_data(enc, &c?).map(Copied::unchecked)) }
}

/// The checked copy of a caller's cells.
///
/// # Safety
/// `c`'s arrays hold every element that the counts and strides name.
unsafe fn cell_data(enc: &gsenc_encoder, c: &gsenc_cells) -> Result<StepData, Failure> {
    let dtype = DType::from_c(c.dtype)?;
    let n = item_count(c.count, "cell", enc.is_mpi())?;
    // Centres and edges (or volumes) in f64, values in f32; a mesh's
    // points are counted below.
    gsenc::memory::check_fits("gsenc_push_cells: the cells' copy", 52 * n as u64)?;
    // None to read: an empty C++ vector's data() is NULL.
    if c.values.is_null() && n > 0 {
        return fail(gsenc_status::NullPointer, "gsenc_push_cells: values is NULL");
    }
    // SAFETY (every read below): the caller's arrays hold every element
    // that the counts and strides name.
    let values: Vec<f32> = unsafe { read_scalars("gsenc_push_cells: values", dtype, c.values, n, c.value_stride) }?.into_iter().map(|v| v as f32).collect();
    let data = match c.layout {
        GSENC_CELLS_BOXES => {
            if (c.centres.is_null() || c.edges.is_null()) && n > 0 {
                return fail(gsenc_status::NullPointer, "gsenc_push_cells: centres or edges is NULL");
            }
            let centres = unsafe { read_tuples("gsenc_push_cells: centres", dtype, c.centres, n, c.centre_stride, c.centre_component_stride) }?;
            let edges = unsafe { read_tuples("gsenc_push_cells: edges", dtype, c.edges, n, c.edge_stride, c.edge_component_stride) }?;
            StepData::Cells { centres, edges, volumes: Vec::new(), values, placement: enc.placement() }
        }
        GSENC_CELLS_HEXAHEDRA => {
            if (c.points.is_null() || c.connectivity.is_null()) && n > 0 {
                return fail(gsenc_status::NullPointer, "gsenc_push_cells: points or connectivity is NULL");
            }
            let np = item_count(c.point_count, "point", n == 0)?;
            gsenc::memory::check_fits("gsenc_push_cells: the mesh points' copy", 24 * np as u64)?;
            let points = unsafe { read_tuples("gsenc_push_cells: points", dtype, c.points, np, c.point_stride, c.point_component_stride) }?;
            // SAFETY: 8 indices per cell (none: no read of a pointer that may be NULL).
            let conn = if n == 0 { &[][..] } else { unsafe { std::slice::from_raw_parts(c.connectivity, 8 * n) } };
            if let Some(i) = conn.iter().position(|&k| k < 0 || k as u64 >= np as u64) {
                return fail(
                    gsenc_status::InvalidArgument,
                    format!("connectivity entry {i} (cell {}) is {}, outside 0..{np}", i / 8, conn[i]),
                );
            }
            let (centres, volumes) = conn
                .chunks_exact(8)
                .map(|k| gsenc::input::cells::hexahedron_centre_volume(&std::array::from_fn(|j| points[k[j] as usize])))
                .unzip();
            StepData::Cells { centres, edges: Vec::new(), volumes, values, placement: enc.placement() }
        }
        l => return fail(gsenc_status::InvalidArgument, format!("unknown cell layout {l}")),
    };
    Ok(data)
}

/// A contiguous float32 grid of `dims` over `values`, for the crate's tests.
#[cfg(test)]
pub(crate) fn f32_grid(values: &[f32], dims: [usize; 3], spacing: f64) -> gsenc_grid {
    assert_eq!(values.len(), dims.iter().product::<usize>());
    // SAFETY: a plain C struct, all zeros a valid value (NULL, 0).
    let mut grid: gsenc_grid = unsafe { std::mem::zeroed() };
    grid.struct_size = std::mem::size_of::<gsenc_grid>();
    grid.dtype = crate::GSENC_DTYPE_FLOAT32;
    grid.data = values.as_ptr().cast();
    grid.extents = dims.map(|d| d as u64);
    grid.spacing = spacing;
    grid
}
