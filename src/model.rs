//! A model: its primitives and everything needed to decode them.

use crate::backend::{Backend, Lattice};
use crate::error::{Error, Result};
use crate::field::{Grid, IndexFrame, ValueRange};
use crate::kernel::Primitive;

/// Decoding metadata stored with every model.
#[derive(Clone, Debug, PartialEq)]
pub struct ModelMeta {
    /// Index frame of the reference grid: dims, world origin of its box, voxels per world unit.
    pub frame: IndexFrame,
    /// Normalisation of the field (per field and time series).
    pub range: ValueRange,
    pub field: String,
    pub step: u64,
    /// Schedule name and the iterations and points actually used.
    pub schedule: String,
    pub iterations: u32,
    pub points: u32,
    pub seed_init: u64,
    pub seed_sample: u64,
}

#[derive(Clone, Debug, PartialEq)]
pub struct Model {
    pub meta: ModelMeta,
    pub params: Vec<Primitive>,
}

impl Model {
    pub fn len(&self) -> usize {
        self.params.len()
    }

    pub fn is_empty(&self) -> bool {
        self.params.is_empty()
    }

    /// Decodes `V_eval` (normalised, in `[0, 1]`) on a lattice of `dims`
    /// covering the model's box; the reference dims when `None`.
    pub fn decode(&self, backend: &mut dyn Backend, dims: Option<[usize; 3]>) -> Result<Grid> {
        let ref_dims = self.meta.frame.dims;
        let out_dims = dims.unwrap_or(ref_dims);
        if out_dims.iter().any(|&d| d == 0) {
            return Err(Error::arg(format!("decode dims must be positive, got {out_dims:?}")));
        }
        let n = out_dims.iter().try_fold(1usize, |a, &d| a.checked_mul(d));
        let n = n.filter(|&n| n <= (1usize << 34)).ok_or_else(|| Error::arg(format!("decode dims {out_dims:?} are too large")))?;
        let lattice = Lattice::resampled(ref_dims, out_dims);
        let mut out = Vec::new();
        out.try_reserve_exact(n).map_err(|_| Error::arg(format!("cannot allocate {n} voxels")))?;
        out.resize(n, 0.0);
        backend.decode_lattice(&self.params, &lattice, &mut out);
        Grid::new(out_dims, out)
    }
}
