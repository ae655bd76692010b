//! Routing one rank's data to the pieces of a decomposed domain: which
//! particles, cells or grid voxels each piece's reference grid needs, its
//! halo included.
//!
//! Every piece is a box of the global lattice (its rank's own region grown by
//! a halo of voxels). A rank sends each of its items to every piece the
//! item's deposit can reach, and each grid voxel to every piece that holds
//! it; a piece that receives them all deposits exactly the global reference
//! restricted to its box, so neighbouring pieces fit the same values where
//! they overlap and the summed mixture blends across the cut.
//!
//! Pure computation on flat `f64` records; the MPI layer (`crate::domain::mpi`)
//! moves them between ranks.

use crate::error::{Error, Result};
use crate::field::{Bounds, Grid, IndexBox, IndexFrame};
use crate::input::cells::{CellSize, Cells};
use crate::input::{Placement, StepData};

/// Where the items of `piece` (a box of the lattice of `global`) are
/// deposited: exactly the piece's lattice, which goes on past each face
/// that is not the global lattice's, so that the piece's deposit is the
/// global one on its voxels (`Placement::continues`).
pub fn placement_of(global: &IndexFrame, piece: &IndexBox) -> Placement {
    let frame = global.sub_frame(piece);
    let continues = std::array::from_fn(|a| [piece.lo[a] > 0, piece.hi[a] < global.dims[a]]);
    Placement { continues, ..Placement::new(frame.dims, Some(frame.world_box())) }
}

/// The box of a grid whose voxel centres are `frame`'s in the lattice of
/// `global`, or an error when it has another spacing, is off that lattice
/// or reaches outside it.
pub fn grid_box(global: &IndexFrame, frame: &IndexFrame) -> Result<IndexBox> {
    if ((frame.gamma - global.gamma) / global.gamma).abs() > 1e-9 {
        return Err(Error::arg(format!("the grid's spacing {} is not the other ranks' {}", 1.0 / frame.gamma, 1.0 / global.gamma)));
    }
    global.box_of(frame)
        .map_err(|e| e.in_context("this rank's grid, in the domain the ranks agreed at the field's first step (their grids must sit on one lattice)"))
}

/// The overlap of two boxes, if any.
pub fn intersect(a: &IndexBox, b: &IndexBox) -> Option<IndexBox> {
    let lo = std::array::from_fn(|i| a.lo[i].max(b.lo[i]));
    let hi = std::array::from_fn(|i| a.hi[i].min(b.hi[i]));
    (0..3).all(|i| lo[i] < hi[i]).then_some(IndexBox { lo, hi })
}

/// The kind of records a step's data travels as (the same on every rank).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    /// Blocks `lo[3] hi[3] values...` of a grid.
    Grid = 1,
    /// `x y z smoothing_length mass value` per particle.
    Particles = 2,
    /// `x y z edge_x edge_y edge_z value` per box cell.
    CellBoxes = 3,
    /// `x y z volume value` per cell given by its volume.
    CellVolumes = 4,
}

impl Kind {
    pub fn of(data: &StepData) -> Kind {
        match data {
            StepData::Grid { .. } => Kind::Grid,
            StepData::Particles { .. } => Kind::Particles,
            StepData::Cells { volumes, .. } if volumes.is_empty() => Kind::CellBoxes,
            StepData::Cells { .. } => Kind::CellVolumes,
        }
    }

    fn record_len(self) -> usize {
        match self {
            Kind::Grid => 0,
            Kind::Particles => 6,
            Kind::CellBoxes => 7,
            Kind::CellVolumes => 5,
        }
    }
}

/// The world box of a rank's own data: particle positions, cell extents, or
/// the grid's cells.
pub fn data_bounds(data: &StepData) -> Bounds {
    match data {
        StepData::Grid { frame, .. } => frame.world_box(),
        StepData::Particles { positions, smoothing_length, mass, values, .. } => {
            crate::input::particles::Particles { positions, smoothing_length, mass, values }.bounds()
        }
        StepData::Cells { centres, edges, volumes, values, .. } => {
            let size = if volumes.is_empty() { CellSize::Edges(edges) } else { CellSize::Volumes(volumes) };
            Cells { centres, size, values }.bounds()
        }
    }
}

/// The values of a rank's own data (for the agreed range).
pub fn data_values(data: &StepData) -> &[f32] {
    match data {
        StepData::Grid { grid, .. } => &grid.values,
        StepData::Particles { values, .. } | StepData::Cells { values, .. } => values,
    }
}

/// How far (world units) item `j`'s deposit reaches from its centre: the
/// SPH support `2 hh`, or the cell stamp's `cbrt(volume)`, plus one voxel
/// for the stamp's rounding and the nearest-voxel fallback.
fn reach(data: &StepData, j: usize, gamma: f64) -> f64 {
    let voxel = 1.0 / gamma;
    match data {
        StepData::Grid { .. } => 0.0,
        StepData::Particles { smoothing_length, .. } => 2.0 * smoothing_length[j] + voxel,
        StepData::Cells { edges, volumes, .. } => {
            let vol = if volumes.is_empty() { edges[j][0] * edges[j][1] * edges[j][2] } else { volumes[j] };
            vol.cbrt() + voxel
        }
    }
}

/// What one rank sends each piece, counted before anything is allocated,
/// so that the exchange's memory can be checked first
/// ([`exchange_bytes`]): `lens()[p]` values of records for piece `p`.
pub struct Routing {
    lens: Vec<usize>,
    /// A grid's box in the global lattice (`None` for items).
    grid: Option<IndexBox>,
}

impl Routing {
    /// Values for each piece, in piece order.
    pub fn lens(&self) -> &[usize] {
        &self.lens
    }

    /// Values for all pieces.
    pub fn total(&self) -> usize {
        self.lens.iter().sum()
    }
}

/// Counts what a rank's data sends each piece (`pieces`: boxes of the
/// lattice of `global`). Items go to every piece they reach; grid voxels to
/// every piece that holds them. An error for a grid off the lattice.
pub fn plan(data: &StepData, global: &IndexFrame, pieces: &[IndexBox]) -> Result<Routing> {
    let grid = match data {
        StepData::Grid { frame, .. } => Some(grid_box(global, frame)?),
        _ => None,
    };
    let mut lens = vec![0; pieces.len()];
    route(data, global, pieces, grid.as_ref(), &mut |p, n, _| lens[p] += n);
    Ok(Routing { lens, grid })
}

/// The records [`plan`] counted, in one buffer, piece after piece
/// (`routing.lens()` long each).
pub fn fill(data: &StepData, global: &IndexFrame, pieces: &[IndexBox], routing: &Routing) -> Vec<f64> {
    let mut out = vec![f64::NAN; routing.total()];
    let mut at: Vec<usize> = routing.lens.iter().scan(0, |start, &n| Some(std::mem::replace(start, *start + n))).collect();
    route(data, global, pieces, routing.grid.as_ref(), &mut |p, n, write| {
        write(&mut out[at[p]..at[p] + n]);
        at[p] += n;
    });
    out
}

/// Where each record of a rank's data goes: `emit(piece, n, write)` for
/// each run of `n` values, which `write` writes into a slice of `n`.
/// `grid` is the box of a grid's data (from [`grid_box`]).
fn route(data: &StepData, global: &IndexFrame, pieces: &[IndexBox], grid: Option<&IndexBox>, emit: &mut dyn FnMut(usize, usize, &dyn Fn(&mut [f64]))) {
    let (centres, width) = match data {
        StepData::Grid { grid: values, .. } => {
            let Some(mine) = grid else { return };
            for (p, piece) in pieces.iter().enumerate() {
                let Some(common) = intersect(mine, piece) else { continue };
                emit(p, 6, &|out| out.iter_mut().zip(common.lo.iter().chain(&common.hi)).for_each(|(o, &v)| *o = v as f64));
                let n = common.hi[0] - common.lo[0];
                for k in common.lo[2]..common.hi[2] {
                    for j in common.lo[1]..common.hi[1] {
                        let row = values.index(common.lo[0] - mine.lo[0], j - mine.lo[1], k - mine.lo[2]);
                        emit(p, n, &|out| out.iter_mut().zip(&values.values[row..row + n]).for_each(|(o, &v)| *o = v as f64));
                    }
                }
            }
            return;
        }
        StepData::Particles { positions: centres, .. } | StepData::Cells { centres, .. } => (centres, Kind::of(data).record_len()),
    };
    let boxes: Vec<Bounds> = pieces.iter().map(|b| global.sub_frame(b).world_box()).collect();
    for (j, c) in centres.iter().enumerate() {
        let r = reach(data, j, global.gamma);
        for (p, b) in boxes.iter().enumerate() {
            if (0..3).all(|a| c[a] + r >= b.min[a] && c[a] - r <= b.max[a]) {
                emit(p, width, &|out| record(data, j, out));
            }
        }
    }
}

/// Item `j`'s record (the layout of its [`Kind`]) into `out`.
fn record(data: &StepData, j: usize, out: &mut [f64]) {
    match data {
        StepData::Grid { .. } => {}
        StepData::Particles { positions, smoothing_length, mass, values, .. } => {
            out.copy_from_slice(&[positions[j][0], positions[j][1], positions[j][2], smoothing_length[j], mass[j] as f64, values[j] as f64]);
        }
        StepData::Cells { centres, edges, volumes, values, .. } => {
            out[..3].copy_from_slice(&centres[j]);
            match volumes.is_empty() {
                true => out[3..6].copy_from_slice(&edges[j]),
                false => out[3] = volumes[j],
            }
            out[out.len() - 1] = values[j] as f64;
        }
    }
}

/// The most a rank holds at once exchanging and joining its piece: what it
/// sends (`sent` values) and receives (`received` values), both as `f64`,
/// then what it received and the joined step data, of which the larger.
pub fn exchange_bytes(kind: Kind, sent: usize, received: usize, piece: &IndexBox) -> u64 {
    8 * received as u64 + joined_bytes(kind, received, piece).max(8 * sent as u64)
}

/// The [`StepData::bytes`] of what [`join`] makes of `received` values of
/// records for `piece`.
pub fn joined_bytes(kind: Kind, received: usize, piece: &IndexBox) -> u64 {
    let items = (kind != Kind::Grid).then(|| (received / kind.record_len()) as u64);
    match kind {
        Kind::Grid => piece.dims().iter().map(|&n| n as u64).product::<u64>() * 4,
        // Centres, the value, and the rest of the record.
        Kind::Particles => items.unwrap_or(0) * (24 + 4 + 8 + 4),
        Kind::CellBoxes => items.unwrap_or(0) * (24 + 4 + 24),
        Kind::CellVolumes => items.unwrap_or(0) * (24 + 4 + 8),
    }
}

/// Joins the records every rank sent to `piece` into its step data, placed
/// exactly on the piece's lattice. A grid piece must be covered whole.
pub fn join(kind: Kind, received: &[&[f64]], global: &IndexFrame, piece: &IndexBox) -> Result<StepData> {
    let frame = global.sub_frame(piece);
    if kind == Kind::Grid {
        let dims = frame.dims;
        let mut values = vec![f32::NAN; dims.iter().product()];
        for buf in received {
            let mut rest = *buf;
            while !rest.is_empty() {
                let bad = || Error::arg("a grid block from another rank is malformed (internal error)");
                if rest.len() < 6 {
                    return Err(bad());
                }
                let b = IndexBox { lo: std::array::from_fn(|a| rest[a] as usize), hi: std::array::from_fn(|a| rest[3 + a] as usize) };
                let n: usize = b.dims().iter().product();
                if intersect(&b, piece) != Some(b) || rest.len() < 6 + n {
                    return Err(bad());
                }
                let mut src = rest[6..6 + n].iter();
                for k in b.lo[2]..b.hi[2] {
                    for j in b.lo[1]..b.hi[1] {
                        for i in b.lo[0]..b.hi[0] {
                            let at = (i - piece.lo[0]) + dims[0] * ((j - piece.lo[1]) + dims[1] * (k - piece.lo[2]));
                            values[at] = *src.next().expect("block length checked") as f32;
                        }
                    }
                }
                rest = &rest[6 + n..];
            }
        }
        let uncovered = values.iter().filter(|v| v.is_nan()).count();
        if uncovered > 0 {
            return Err(Error::data(format!(
                "{uncovered} voxels of this rank's piece (voxels {:?}..{:?} of the domain) are on no rank's grid: the ranks' grids must tile the domain",
                piece.lo, piece.hi
            )));
        }
        return Ok(StepData::Grid { grid: Grid::new(dims, values)?, frame });
    }
    let width = kind.record_len();
    let records = received.iter().flat_map(|b| b.chunks_exact(width));
    let placement = placement_of(global, piece);
    let centres = records.clone().map(|r| [r[0], r[1], r[2]]).collect();
    let values = records.clone().map(|r| r[width - 1] as f32).collect();
    Ok(match kind {
        Kind::Particles => StepData::Particles {
            positions: centres,
            smoothing_length: records.clone().map(|r| r[3]).collect(),
            mass: records.map(|r| r[4] as f32).collect(),
            values,
            placement,
        },
        Kind::CellBoxes => StepData::Cells { centres, edges: records.map(|r| [r[3], r[4], r[5]]).collect(), volumes: Vec::new(), values, placement },
        Kind::CellVolumes => StepData::Cells { centres, edges: Vec::new(), volumes: records.map(|r| r[3]).collect(), values, placement },
        Kind::Grid => unreachable!("handled above"),
    })
}
