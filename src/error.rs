//! One error type for the whole library; every variant carries a message a
//! user can act on. The C API maps variants to stable status codes.

use std::fmt;

/// What went wrong, with enough context to act on it.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// An argument is out of its valid range (budget, dims, iterations, ...).
    #[error("invalid argument: {0}")]
    InvalidArgument(String),
    /// Input data is unusable: wrong size, NaN or infinite values, empty.
    #[error("invalid data: {0}")]
    InvalidData(String),
    /// A model or input file is not in a format gsenc reads.
    #[error("bad format: {0}")]
    Format(String),
    /// A model file written by a newer, incompatible gsenc.
    #[error("unsupported version: {0}")]
    Version(String),
    /// A file could not be read or written.
    #[error("i/o error on {path}: {source}")]
    Io {
        path: String,
        #[source]
        source: std::io::Error,
    },
    /// The HDF5 library refused an operation on a store.
    #[error("HDF5 error on {path}: {message}")]
    Hdf5 { path: String, message: String },
}

impl Error {
    pub fn arg(msg: impl fmt::Display) -> Self {
        Error::InvalidArgument(msg.to_string())
    }
    pub fn data(msg: impl fmt::Display) -> Self {
        Error::InvalidData(msg.to_string())
    }
    pub fn format(msg: impl fmt::Display) -> Self {
        Error::Format(msg.to_string())
    }
    pub fn io(path: impl AsRef<std::path::Path>, source: std::io::Error) -> Self {
        Error::Io { path: path.as_ref().display().to_string(), source }
    }
}

pub type Result<T, E = Error> = std::result::Result<T, E>;
