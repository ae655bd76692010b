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
    /// MPI is missing, not initialised, at too low a thread level, or the
    /// ranks' calls disagree (a collective call made differently on them).
    #[error("MPI: {0}")]
    Mpi(String),
    /// The encode was cancelled (`queue::BackgroundEncoder::cancel`).
    #[error("cancelled: {0}")]
    Cancelled(String),
    /// The GPU backend cannot run: no adapter, a lost device, or a model or
    /// batch beyond the device's limits or memory.
    #[error("GPU: {0}")]
    Device(String),
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

    /// The same kind of error with `context` ("field 'rho' step 4") before
    /// its message, for errors reported away from where they happened; a
    /// message that begins with that context already keeps it once.
    pub fn in_context(&self, context: &str) -> Error {
        let with = |m: &str| match m.strip_prefix(context).is_some_and(|rest| rest.starts_with(": ")) {
            true => m.to_string(),
            false => format!("{context}: {m}"),
        };
        match self {
            Error::InvalidArgument(m) => Error::InvalidArgument(with(m)),
            Error::InvalidData(m) => Error::InvalidData(with(m)),
            Error::Format(m) => Error::Format(with(m)),
            Error::Version(m) => Error::Version(with(m)),
            Error::Io { path, source } => {
                Error::Io { path: with(path), source: std::io::Error::new(source.kind(), source.to_string()) }
            }
            Error::Hdf5 { path, message } => Error::Hdf5 { path: with(path), message: message.clone() },
            Error::Mpi(m) => Error::Mpi(with(m)),
            Error::Cancelled(m) => Error::Cancelled(with(m)),
            Error::Device(m) => Error::Device(with(m)),
        }
    }
}

pub type Result<T, E = Error> = std::result::Result<T, E>;

/// The value among `all` that `name` calls `s`, or an invalid-argument error
/// naming `what` and listing the names: how every named setting (schedule,
/// warm start, payload) is parsed.
pub(crate) fn by_name<T: Copy>(all: &[T], name: fn(T) -> &'static str, s: &str, what: &str) -> Result<T> {
    all.iter().copied().find(|&v| name(v) == s).ok_or_else(|| {
        let names: Vec<&str> = all.iter().map(|&v| name(v)).collect();
        Error::arg(format!("unknown {what} '{s}' ({})", names.join(", ")))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_context_is_said_once() {
        let at = "field 'rho' step 6";
        let e = Error::arg("grid of [1, 1, 3] voxels").in_context(at);
        assert_eq!(e.to_string(), "invalid argument: field 'rho' step 6: grid of [1, 1, 3] voxels");
        // Given again, or already in the message as the queue's wait finds
        // it in the series encoder's: once.
        assert_eq!(e.in_context(at).to_string(), e.to_string());
        // Another context, or the same words not as a context, go before.
        assert_eq!(e.in_context("field 'rho' step 7").to_string(), "invalid argument: field 'rho' step 7: field 'rho' step 6: grid of [1, 1, 3] voxels");
        assert_eq!(Error::data("field 'rho' step 60: x").in_context(at).to_string(), "invalid data: field 'rho' step 6: field 'rho' step 60: x");
        let io = Error::io("rho.gsm", std::io::Error::other("disk full")).in_context(at);
        assert_eq!(io.in_context(at).to_string(), "i/o error on field 'rho' step 6: rho.gsm: disk full");
    }
}
