//! numpy arrays in and out. Inputs of any of the dtypes below and any
//! strides are read in place, in one pass, straight into the library's
//! float32 (values) or float64 (positions) arrays: no intermediate copy,
//! contiguous or not.

use numpy::ndarray::{ArrayView, Dimension};
use numpy::{PyArray1, PyArray3, PyReadonlyArray, PyUntypedArray, PyUntypedArrayMethods};
use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;
use crate::errors::IntoPy;

/// The dtypes an input array may have.
pub const DTYPES: &str = "uint8, int8, uint16, int16, uint32, int32, uint64, int64, float32 or float64";

/// `$body` with `$view` bound to an `ArrayView<T, D>` of `$obj`, for
/// whichever supported element type `T` it holds; else a clear error.
macro_rules! with_view {
    ($obj:expr, $dim:ty, $what:expr, |$view:ident| $body:expr) => {
        with_view!(@types $obj, $dim, $what, $view, $body; u8, i8, u16, i16, u32, i32, u64, i64, f32, f64)
    };
    (@types $obj:expr, $dim:ty, $what:expr, $view:ident, $body:expr; $($t:ty),*) => {{
        let obj = $obj;
        'found: {
            $(
                if let Ok(a) = obj.extract::<PyReadonlyArray<'_, $t, $dim>>() {
                    let $view = a.as_array();
                    break 'found Ok($body);
                }
            )*
            Err(not_an_array(obj, $what))
        }
    }};
}

fn not_an_array(obj: &Bound<'_, PyAny>, what: &str) -> PyErr {
    match obj.cast::<PyUntypedArray>() {
        Ok(a) => PyValueError::new_err(format!(
            "{what}: a {}-dimensional array of {} (gsenc takes {DTYPES} arrays of the right shape)",
            a.ndim(),
            a.dtype()
        )),
        Err(_) => PyTypeError::new_err(format!("{what}: a numpy array is needed, got {}", obj.get_type().name().map(|n| n.to_string()).unwrap_or_default())),
    }
}

/// Element `T` as float32 / float64.
pub trait Element: Copy {
    fn f32(self) -> f32;
    fn f64(self) -> f64;
}

macro_rules! element {
    ($($t:ty),*) => {$(
        impl Element for $t {
            fn f32(self) -> f32 { self as f32 }
            fn f64(self) -> f64 { self as f64 }
        }
    )*};
}
element!(u8, i8, u16, i16, u32, i32, u64, i64, f32, f64);

/// The elements of `view` in C (logical) order as float32; a copy this
/// process cannot take now is a ValueError (`gsenc::memory`), not an abort
/// of the interpreter.
pub fn to_f32<T: Element, D: Dimension>(view: ArrayView<'_, T, D>, what: &str) -> PyResult<Vec<f32>> {
    fits(view.len(), 4, what)?;
    Ok(view.iter().map(|v| v.f32()).collect())
}

/// The elements of `view` in C (logical) order as float64 (as [`to_f32`]).
pub fn to_f64<T: Element, D: Dimension>(view: ArrayView<'_, T, D>, what: &str) -> PyResult<Vec<f64>> {
    fits(view.len(), 8, what)?;
    Ok(view.iter().map(|v| v.f64()).collect())
}

fn fits(n: usize, size: u64, what: &str) -> PyResult<()> {
    gsenc::memory::check_fits(&format!("{what}: the array's copy"), (n as u64).saturating_mul(size)).py_err()
}

/// A 3D array `[z][y][x]` of any supported dtype: its dims (x, y, z) and values, x fastest.
pub fn grid_values(obj: &Bound<'_, PyAny>, what: &str) -> PyResult<([usize; 3], Vec<f32>)> {
    with_view!(obj, numpy::Ix3, what, |view| {
        let s = view.shape();
        let dims = [s[2], s[1], s[0]];
        to_f32(view, what).map(|v| (dims, v))
    })?
}

/// A 1D array of `n` values (any supported dtype) as float32, or `None`.
pub fn values(obj: &Bound<'_, PyAny>, what: &str) -> PyResult<Vec<f32>> {
    with_view!(obj, numpy::Ix1, what, |view| to_f32(view, what))?
}

/// A 1D array as float64.
pub fn values_f64(obj: &Bound<'_, PyAny>, what: &str) -> PyResult<Vec<f64>> {
    with_view!(obj, numpy::Ix1, what, |view| to_f64(view, what))?
}

/// An `(n, 3)` array as triples of float64.
pub fn triples(obj: &Bound<'_, PyAny>, what: &str) -> PyResult<Vec<[f64; 3]>> {
    let flat: PyResult<(usize, Vec<f64>)> = with_view!(obj, numpy::Ix2, what, |view| {
        let cols = view.shape()[1];
        to_f64(view, what).map(|v| (cols, v))
    })?;
    let (cols, flat) = flat?;
    if cols != 3 {
        return Err(PyValueError::new_err(format!("{what}: an (n, 3) array is needed, got {cols} columns")));
    }
    Ok(flat.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect())
}

/// A decoded region (x fastest, dims x, y, z) as a float32 array `[z][y][x]`.
pub fn grid_array<'py>(py: Python<'py>, dims: [usize; 3], values: Vec<f32>) -> PyResult<Bound<'py, PyArray3<f32>>> {
    let a = numpy::ndarray::Array3::from_shape_vec((dims[2], dims[1], dims[0]), values).map_err(|e| PyValueError::new_err(e.to_string()))?;
    Ok(numpy::IntoPyArray::into_pyarray(a, py))
}

/// A float32 vector as a 1D array.
pub fn vector<'py>(py: Python<'py>, values: Vec<f32>) -> Bound<'py, PyArray1<f32>> {
    PyArray1::from_vec(py, values)
}
