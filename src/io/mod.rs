//! File formats and file system access, kept out of the encoder core: the
//! command-line tool and the C API use these; the core works on memory only.

pub mod atomic;
pub mod plot;
pub mod raw;
#[cfg(feature = "hdf5")]
pub mod series;
#[cfg(feature = "hdf5")]
pub mod store;
pub mod vti;

pub use atomic::{write_atomic, AtomicFile};
