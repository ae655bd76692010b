//! The input forms and what the encoder is fitted to. Grids, SPH particles
//! ([`particles`]) and hexahedral cells ([`cells`]) become samples
//! ([`samples`]) and a reference grid, the deposit of particles and cells
//! ([`deposit`]); [`prepare()`] does this for any form; [`data`] holds a step
//! copied out of a caller's memory.

pub mod cells;
pub mod data;
pub mod deposit;
mod items;
pub mod particles;
pub mod prepare;
pub mod samples;

pub use data::StepData;
pub use prepare::{prepare, Form, Input, Placement, Prepared, RangeSpec};

use crate::field::Grid;
use samples::SampleSet;

/// What the encoder is fitted to: the reference grid (normalised to `[0, 1]`)
/// and the samples that seed it, both in the reference grid's index frame.
/// A grid's own voxels serve as its samples: `Target { reference: &g, samples: &g }`.
pub struct Target<'a> {
    pub reference: &'a Grid,
    pub samples: &'a dyn SampleSet,
}

/// The first `i < n` for which `bad(i)`, sought on rayon's pool, or on the
/// calling thread alone where `serial` (a push, on the caller's side of the
/// background queue, must not wake a pool: the host's, or the global one
/// the encoder's threads compete with).
pub(crate) fn first_bad(n: usize, serial: bool, bad: impl Fn(usize) -> bool + Sync + Send) -> Option<usize> {
    use rayon::prelude::*;
    if serial {
        (0..n).position(bad)
    } else {
        (0..n).into_par_iter().position_first(bad)
    }
}
