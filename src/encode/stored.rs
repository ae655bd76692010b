//! A model as a reader of its file will see it: the payload's round trip,
//! decoded on the reference lattice, with its support's outside fitted to
//! that decode. The pipeline scores every encode this way, and the packed
//! payload's precision search ([`crate::encode::precision`]) checks its
//! choice with it.

use crate::backend::{Backend, Lattice};
use crate::error::Result;
use crate::field::Grid;
use crate::format::Payload;
use crate::model::{Model, Support};

/// A model's decode as stored, and the support it is stored with.
pub struct Stored {
    /// On the reference lattice, x fastest.
    pub decoded: Vec<f32>,
    /// The model's support with its outside fitted to this payload's
    /// parameters ([`Support::fit_outside`]); `None` when it has none.
    pub support: Option<Support>,
}

/// `model` as a reader of it stored with `payload` sees it, decoded on its
/// reference lattice; its support's outside is fitted against `reference`
/// on the Gaussians' own decode before the support is applied (one decode:
/// what [`Model::decode_lattice`] does, with the fit between its two
/// steps). Fails on parameters the payload cannot store.
pub fn decode_as_stored(payload: Payload, model: &Model, reference: &Grid, backend: &mut dyn Backend) -> Result<Stored> {
    let params = payload.round_trip(model)?;
    let lattice = Lattice::reference(model.meta.frame.dims);
    let mut decoded = vec![0f32; lattice.len()];
    backend.decode_lattice(&params, &lattice, &mut decoded)?;
    let support = match &model.support {
        Some(s) => {
            let fitted = s.clone().with_outside(s.fit_outside(&decoded, reference))?;
            fitted.apply(&lattice, &mut decoded);
            Some(fitted)
        }
        None => None,
    };
    Ok(Stored { decoded, support })
}
