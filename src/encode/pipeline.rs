//! The one encode pipeline. Every caller takes this path: `gsenc encode`
//! through [`encode`], the series encoder (and so `gsenc encode-series`, the
//! background queue, the C API and MPI) through [`encode_prepared`].
//!
//! 1. **Prepare** the input ([`crate::input::prepare()`]): the index frame,
//!    the value range, the samples and the reference grid.
//! 2. **Resolve the configuration** ([`config_for`]): the schedule's length
//!    follows the input's form (the `full` schedule runs longer for
//!    particles), a warm start follows its regime.
//! 3. **Encode**: seeded from the samples, or warm-started from a previous
//!    model's parameters ([`crate::encode::refine`]).
//! 4. **Build the model**: its metadata, and its support (where the
//!    reference holds data; METHOD.md "Support") unless the request asks
//!    for the paper's model.
//! 5. **Score the model as it will be stored**: for the packed payload,
//!    first measure the precision it needs ([`crate::encode::precision`]);
//!    then the payload's round trip, decoded on the reference lattice with
//!    the support, against the reference.
//!
//! With a target PSNR instead of a budget, [`crate::encode::target`]
//! chooses the budget: each of its tries takes steps 3 to 5.
//!
//! No I/O: the caller writes the model ([`crate::io`]).

use crate::backend::Backend;
use crate::encode::fixed::encode_budget;
pub use crate::encode::fixed::{config_for, Encoded, Labels, Request, Start, AUTO_VALIDATION_POINTS};
use crate::encode::refine::Progress;
pub use crate::encode::stored::{decode_as_stored, Stored};
use crate::encode::target::encode_to_target;
use crate::error::Result;
use crate::input::{prepare, Input, Prepared, RangeSpec};

/// Prepares `input` and encodes it: the whole pipeline for one field of one step.
pub fn encode(
    input: &Input,
    range: &RangeSpec,
    request: &Request,
    backend: &mut dyn Backend,
    progress: &mut dyn FnMut(&Progress),
) -> Result<(Prepared, Encoded)> {
    let prepared = prepare(input, range)?;
    let encoded = encode_prepared(&prepared, request, backend, progress)?;
    Ok((prepared, encoded))
}

/// Encodes a prepared input, scores the model as stored and builds it:
/// with the configuration's budget, or the budget that reaches its target
/// PSNR ([`crate::encode::target`]).
pub fn encode_prepared(
    prepared: &Prepared,
    request: &Request,
    backend: &mut dyn Backend,
    progress: &mut dyn FnMut(&Progress),
) -> Result<Encoded> {
    match request.config.target {
        Some(t) => encode_to_target(prepared, request, t, backend, progress),
        None => encode_budget(prepared, request, backend, progress),
    }
}
