//! A model as a reader of its file will see it: the payload's round trip,
//! decoded on the reference lattice. The pipeline scores every encode this
//! way, and the packed payload's precision search ([`crate::encode::precision`])
//! checks its choice with it.

use crate::backend::{Backend, Lattice};
use crate::error::Result;
use crate::format::Payload;
use crate::model::Model;

/// `model` as a reader of it stored with `payload` sees it, decoded on its
/// reference lattice (support included). Fails on parameters the payload
/// cannot store.
pub fn decode_as_stored(payload: Payload, model: &Model, backend: &mut dyn Backend) -> Result<Vec<f32>> {
    let stored = Model { meta: model.meta.clone(), params: payload.round_trip(model)?, support: model.support.clone() };
    let dims = model.meta.frame.dims;
    let mut decoded = vec![0f32; dims.iter().product()];
    stored.decode_lattice(backend, &Lattice::reference(dims), &mut decoded)?;
    Ok(decoded)
}
