//! What a decode reads: one model, the models of a domain's pieces, or a
//! step index with the models it names, as one global field. The command
//! line's `decode` and the Python package's `Model.decode` both decode
//! through [`GlobalField::decode_streaming`], so they give the same values.

use crate::backend::Backend;
use crate::domain::pieces::{blend, blend_points, merge, merge_onto};
use crate::error::{Error, Result};
use crate::field::IndexBox;
use crate::format::StepIndex;
use crate::model::Model;

/// One global field and where it came from.
pub struct GlobalField {
    /// The step index, when the field is a step's (its pieces are then
    /// blended across their halos).
    pub index: Option<StepIndex>,
    /// The models, in rank order for a step.
    pieces: Vec<Model>,
    /// Every piece's primitives in one model on the global lattice; `None`
    /// for one model, which is its own merge (see [`GlobalField::merged`]).
    merged: Option<Model>,
}

impl GlobalField {
    /// The field of one model.
    pub fn of_model(model: Model) -> GlobalField {
        GlobalField { index: None, merged: None, pieces: vec![model] }
    }

    /// The additive field of the models of a domain's pieces.
    pub fn of_pieces(pieces: Vec<Model>) -> Result<GlobalField> {
        let merged = Some(merge(&pieces)?);
        Ok(GlobalField { index: None, pieces, merged })
    }

    /// The field of a step index and the models it names (rank order,
    /// checked against it by [`crate::io::read_step`]), on the index's
    /// lattice (which may reach past the pieces).
    pub fn of_step(index: StepIndex, pieces: Vec<Model>) -> Result<GlobalField> {
        let merged = Some(merge_onto(&pieces, &index.frame())?);
        Ok(GlobalField { index: Some(index), pieces, merged })
    }

    /// The models, in rank order for a step (never empty).
    pub fn pieces(&self) -> &[Model] {
        &self.pieces
    }

    /// Every piece's primitives in one model on the global lattice (the
    /// model itself when there is one).
    pub fn merged(&self) -> &Model {
        self.merged.as_ref().unwrap_or(&self.pieces[0])
    }

    /// The region of piece `i` on the global lattice.
    pub fn piece_box(&self, i: usize) -> Result<IndexBox> {
        let piece = self.pieces.get(i).ok_or_else(|| Error::arg(format!("piece {i}: the field has {} pieces", self.pieces.len())))?;
        self.merged().meta.frame.box_of(&piece.meta.frame)
    }

    /// Decodes `region` of a lattice of `dims` over the global box in slabs
    /// of whole z layers (at most `slab_voxels` voxels each), handing each
    /// slab (x fastest, normalised values) to `sink` in order. A step's
    /// pieces are each decoded on their own box and blended across their
    /// halos, unless `additive` (every piece's primitives decoded together).
    pub fn decode_streaming(
        &self,
        backend: &mut dyn Backend,
        dims: [usize; 3],
        region: IndexBox,
        additive: bool,
        slab_voxels: usize,
        sink: &mut dyn FnMut(&[f32]) -> Result<()>,
    ) -> Result<()> {
        match self.index.as_ref().filter(|_| !additive) {
            Some(index) => {
                region.check_within(dims)?;
                let (global, boxes) = index.layout();
                let layers = (slab_voxels / (region.dims()[0] * region.dims()[1]).max(1)).max(1);
                let mut z = region.lo[2];
                while z < region.hi[2] {
                    let slab = IndexBox { lo: [region.lo[0], region.lo[1], z], hi: [region.hi[0], region.hi[1], (z + layers).min(region.hi[2])] };
                    // A blend holds two f64 sums and the f32 values a voxel.
                    crate::model::check_slab(slab.dims().iter().product(), 20)?;
                    sink(&blend(&global, &self.pieces, &boxes, index.halo, dims, slab, backend)?.values)?;
                    z = slab.hi[2];
                }
                Ok(())
            }
            None => self.merged().decode_streaming(backend, dims, region, slab_voxels, sink),
        }
    }

    /// The field (normalised) at world points, each finite: a step's pieces
    /// blended as its decode blends them, unless `additive`.
    pub fn evaluate(&self, backend: &mut dyn Backend, points: &[[f64; 3]], additive: bool) -> Result<Vec<f32>> {
        match self.index.as_ref().filter(|_| !additive) {
            Some(index) => {
                let (global, boxes) = index.layout();
                blend_points(&global, &self.pieces, &boxes, index.halo, points, backend)
            }
            None => self.merged().evaluate(backend, points),
        }
    }

    /// [`GlobalField::decode_streaming`] into one array (x fastest), the
    /// values normalised ([`crate::field::ValueRange::denormalize_all`]
    /// maps them to data units).
    pub fn decode(&self, backend: &mut dyn Backend, dims: [usize; 3], region: IndexBox, additive: bool) -> Result<Vec<f32>> {
        region.check_within(dims)?;
        // Before the product below, which wraps beyond 64 bits.
        self.merged().lattice_dims(Some(dims))?;
        let mut out = crate::model::decode_buffer(region.dims().iter().product())?;
        self.decode_streaming(backend, dims, region, additive, crate::model::DEFAULT_SLAB_VOXELS, &mut |slab| {
            out.extend_from_slice(slab);
            Ok(())
        })?;
        Ok(out)
    }
}
