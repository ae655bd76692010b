//! Files and the file system, above the core (which works on memory only):
//! raw arrays ([`raw`]), VTK ImageData ([`vti`]), crash-safe writes
//! ([`atomic`]), model files and folders of them ([`models`]), the HDF5
//! store of a time series and its decoded series (`store`, `series`,
//! feature `hdf5`), and PNG charts ([`plot`]). Used by the command-line
//! tool, the C API and the MPI layer; never by the encoder.

pub mod atomic;
pub mod image;
pub mod models;
pub mod plot;
pub mod preview;
pub mod raw;
#[cfg(feature = "hdf5")]
pub mod series;
#[cfg(feature = "hdf5")]
pub mod store;
pub mod vti;

pub use atomic::{write_atomic, AtomicFile};

/// Whether `path` starts with HDF5's signature (an HDF5 store, as opposed
/// to a model file); false when it cannot be read. Builds without the
/// `hdf5` feature have it too, to say that a store needs that feature.
pub fn is_hdf5_file(path: &std::path::Path) -> bool {
    hdf5_signature(path).unwrap_or(false)
}

/// Whether `path` starts with HDF5's signature (gsenc stores have no user
/// block); an error only when the file cannot be opened or read, not when
/// it is shorter than the signature.
pub fn hdf5_signature(path: &std::path::Path) -> std::io::Result<bool> {
    use std::io::Read;
    let mut head = [0u8; 8];
    match std::fs::File::open(path)?.read_exact(&mut head) {
        Ok(()) => Ok(&head == b"\x89HDF\r\n\x1a\n"),
        Err(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => Ok(false),
        Err(e) => Err(e),
    }
}
pub use models::{read_field, read_model_file, read_step, ModelFolder};
