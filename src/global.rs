//! One global field from models of pieces of a domain (the per-rank models
//! of a domain-decomposed run).
//!
//! Pieces share one global index frame: the same voxel size and a lattice
//! whose origins differ by whole voxels, each piece covering its own part of
//! the domain plus a halo. The mixture is additive, so the global model is
//! every piece's primitives together, their centres moved into the global
//! frame; decoding it computes `sum n / max(sum rho, eps)` over all of
//! them, which blends the pieces across their boundaries where their halos
//! overlap. No I/O here.

use crate::error::{Error, Result};
use crate::field::IndexFrame;
use crate::kernel::layout::MU;
use crate::model::Model;

/// How far (in voxels) a piece's origin may sit from the global lattice.
const LATTICE_TOLERANCE: f64 = 1e-6;

/// The global model of `pieces`: one frame covering all of them, every
/// primitive of every piece. Pieces must be of the same field and step,
/// share the value range and the voxel size, and sit on one lattice.
pub fn merge(pieces: &[Model]) -> Result<Model> {
    let first = pieces.first().ok_or_else(|| Error::arg("no models to merge"))?;
    let gamma = first.meta.frame.gamma;
    for (i, p) in pieces.iter().enumerate() {
        let m = &p.meta;
        if m.field != first.meta.field || m.step != first.meta.step {
            return Err(Error::arg(format!(
                "piece {i} is field '{}' step {}, piece 0 is field '{}' step {}: merge pieces of one step",
                m.field, m.step, first.meta.field, first.meta.step
            )));
        }
        if m.range != first.meta.range {
            return Err(Error::arg(format!(
                "piece {i} has value range {:?}, piece 0 {:?}: the pieces of a field must share one range",
                m.range, first.meta.range
            )));
        }
        if ((m.frame.gamma - gamma) / gamma).abs() > 1e-9 {
            return Err(Error::arg(format!(
                "piece {i} has {} voxels per unit, piece 0 {gamma}: the pieces must share one voxel size",
                m.frame.gamma
            )));
        }
    }
    let bmin: [f64; 3] = std::array::from_fn(|a| pieces.iter().map(|p| p.meta.frame.bmin[a]).fold(f64::INFINITY, f64::min));
    let mut dims = [0usize; 3];
    let mut offsets = Vec::with_capacity(pieces.len());
    for (i, p) in pieces.iter().enumerate() {
        let f = &p.meta.frame;
        let mut offset = [0usize; 3];
        for a in 0..3 {
            let voxels = (f.bmin[a] - bmin[a]) * gamma;
            if (voxels - voxels.round()).abs() > LATTICE_TOLERANCE {
                return Err(Error::arg(format!(
                    "piece {i} starts {voxels} voxels from the others along axis {a}: the pieces must sit on one lattice"
                )));
            }
            offset[a] = voxels.round() as usize;
            dims[a] = dims[a].max(offset[a] + f.dims[a]);
        }
        offsets.push(offset);
    }
    let mut meta = first.meta.clone();
    meta.frame = IndexFrame { dims, bmin, gamma };
    meta.rank = 0;
    meta.encode_psnr = None;
    let mut params = Vec::with_capacity(pieces.iter().map(|p| p.params.len()).sum());
    for (p, offset) in pieces.iter().zip(&offsets) {
        params.extend(p.params.iter().map(|q| {
            let mut q = *q;
            for a in 0..3 {
                q[MU + a] += offset[a] as f32;
            }
            q
        }));
    }
    Ok(Model { meta, params })
}

/// The box of `piece` in the index frame of `global` (its lattice there),
/// to decode one piece's region alone.
pub fn piece_box(global: &IndexFrame, piece: &IndexFrame) -> Result<crate::model::IndexBox> {
    let mut lo = [0usize; 3];
    let mut hi = [0usize; 3];
    for a in 0..3 {
        let voxels = (piece.bmin[a] - global.bmin[a]) * global.gamma;
        if voxels < -LATTICE_TOLERANCE || (voxels - voxels.round()).abs() > LATTICE_TOLERANCE {
            return Err(Error::arg("the piece is not on the global lattice"));
        }
        lo[a] = voxels.round() as usize;
        hi[a] = lo[a] + piece.dims[a];
        if hi[a] > global.dims[a] {
            return Err(Error::arg("the piece reaches outside the global frame"));
        }
    }
    Ok(crate::model::IndexBox { lo, hi })
}
