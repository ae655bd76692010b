//! Fields on lattices: grids of values, their normalisation to `[0, 1]`, and
//! where a lattice sits in the world (the index frame, world boxes, boxes of
//! lattice indices).

mod frame;
mod grid;
mod prefetch;
mod range;

pub use frame::{ulps_apart, Bounds, IndexBox, IndexFrame};
pub(crate) use frame::LATTICE_TOLERANCE;
pub use grid::Grid;
pub use prefetch::prefetch;
pub use range::{all_finite, check_finite, check_finite_serial, Normalized, Transform, ValueRange};
