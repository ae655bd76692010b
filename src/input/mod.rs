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
