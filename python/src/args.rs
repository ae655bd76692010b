//! Values the native functions convert themselves: those taken out of a
//! dict (the encode options, a deposit's placement) and a decode's `box`.
//! pyo3 notes the argument whose conversion failed ("while processing
//! 'dims'" under the traceback), but not a dict's value, and it would call
//! `box` by its Rust name `r#box`; `named` puts the name before the
//! message itself.

use pyo3::conversion::FromPyObjectOwned;
use pyo3::prelude::*;

/// `value` as a `T`, or the conversion's exception, of its own type
/// (`TypeError`, `OverflowError` for a negative or huge integer,
/// `ValueError` for a sequence of the wrong length), with its message
/// prefixed by `name` ("budget: can't convert negative int to unsigned").
pub fn named<'py, T: FromPyObjectOwned<'py>>(value: &Bound<'py, PyAny>, name: &str) -> PyResult<T> {
    value.extract::<T>().map_err(|e| {
        let e: PyErr = e.into();
        let py = value.py();
        PyErr::from_type(e.get_type(py), format!("{name}: {}", e.value(py)))
    })
}
