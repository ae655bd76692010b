//! `gsenc._gsenc`, the native half of the Python package `gsenc`: a thin
//! layer over the library's readers, its decode and its one encode
//! pipeline. `gsenc/__init__.py` adds what is easier said in Python
//! (progress bars, the structured dtype of primitives, keyword arguments);
//! `gsenc/_gsenc.pyi`
//! types it. Every call that decodes or encodes releases the GIL.

mod args;
mod arrays;
mod encode;
mod errors;
mod inputs;
mod model;
mod series;
#[cfg(feature = "hdf5")]
mod store;

use pyo3::prelude::*;

#[pymodule]
fn _gsenc(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", gsenc::VERSION)?;
    m.add("ModelError", m.py().get_type::<errors::ModelError>())?;
    m.add("HAS_HDF5", cfg!(feature = "hdf5"))?;
    m.add_class::<model::Model>()?;
    m.add_function(wrap_pyfunction!(model::read, m)?)?;
    m.add_function(wrap_pyfunction!(encode::encode_grid, m)?)?;
    m.add_function(wrap_pyfunction!(encode::encode_particles, m)?)?;
    m.add_function(wrap_pyfunction!(encode::encode_cells, m)?)?;
    m.add_class::<series::Series>()?;
    #[cfg(feature = "hdf5")]
    {
        m.add_class::<store::Store>()?;
        m.add_function(wrap_pyfunction!(store::open_store, m)?)?;
    }
    Ok(())
}
