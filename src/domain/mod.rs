//! Pieces of a decomposed domain: the per-rank models of one step on one
//! global lattice. [`halo`] routes each rank's data to every piece it reaches
//! (pure, tested without MPI); [`pieces`] turns the models of a step into one
//! global field (the halo blend, or the additive merge); [`global`] is what a
//! decode reads (a model, pieces, or a step); `mpi` (feature
//! `mpi`) is the only code that calls MPI: per-rank encoders over the
//! simulation's communicator, above the background queue, and [`to_root`]
//! (its exchange: feature `mpi`) brings every rank's models to rank 0 for one store;
//! [`resume`] rebuilds a field's lattice and pieces from the models each
//! rank stored last, for a run restarted from a checkpoint.

pub mod global;
pub mod halo;
#[cfg(feature = "mpi")]
pub mod mpi;
pub mod pieces;
pub mod resume;
pub mod to_root;
