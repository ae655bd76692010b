//! Files and the file system, above the core (which works on memory only):
//! raw arrays ([`raw`]), VTK ImageData ([`vti`]), crash-safe writes
//! ([`atomic`]), model files and folders of them ([`models`]), the HDF5
//! store of a time series and its decoded series ([`store`], [`series`],
//! feature `hdf5`), and PNG charts ([`plot`]). Used by the command-line
//! tool, the C API and the MPI layer; never by the encoder.

pub mod atomic;
pub mod models;
pub mod plot;
pub mod raw;
#[cfg(feature = "hdf5")]
pub mod series;
#[cfg(feature = "hdf5")]
pub mod store;
pub mod vti;

pub use atomic::{write_atomic, AtomicFile};
pub use models::{read_field, read_model_file, read_step, ModelFolder};
