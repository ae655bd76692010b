//! The library's errors as Python exceptions, with its messages:
//! `ValueError` for bad arguments and data, `OSError` for files,
//! `gsenc.ModelError` (a `ValueError`) for bad or newer model files,
//! `KeyboardInterrupt` for an encode stopped by Ctrl-C, `RuntimeError`
//! for the rest (HDF5, the GPU).

use pyo3::exceptions::{PyKeyboardInterrupt, PyOSError, PyRuntimeError, PyValueError};
use pyo3::PyErr;

pyo3::create_exception!(gsenc, ModelError, PyValueError, "A model file (or store entry, or step index) that is corrupted, foreign or written by a newer gsenc.");

/// `gsenc::Error` into its Python exception.
pub fn to_py(e: gsenc::Error) -> PyErr {
    use gsenc::Error as E;
    let message = e.to_string();
    match e {
        E::InvalidArgument(_) | E::InvalidData(_) => PyValueError::new_err(message),
        E::Format(_) | E::Version(_) => ModelError::new_err(message),
        // With an errno, Python raises its subclass (FileNotFoundError, ...).
        E::Io { source, .. } => match source.raw_os_error() {
            Some(errno) => PyOSError::new_err((errno, message)),
            None => PyOSError::new_err(message),
        },
        E::Cancelled(_) => PyKeyboardInterrupt::new_err(message),
        E::Hdf5 { .. } | E::Mpi(_) | E::Device(_) => PyRuntimeError::new_err(message),
    }
}

/// `Result` of the library into `PyResult`.
pub trait IntoPy<T> {
    fn py_err(self) -> pyo3::PyResult<T>;
}

impl<T> IntoPy<T> for gsenc::Result<T> {
    fn py_err(self) -> pyo3::PyResult<T> {
        self.map_err(to_py)
    }
}
