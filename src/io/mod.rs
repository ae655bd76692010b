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

/// The file name of a model in a folder of a series: `FIELD_STEP.gsm`,
/// with `_rRANK` on ranks other than 0.
pub fn model_file_name(meta: &crate::model::ModelMeta) -> String {
    match meta.rank {
        0 => format!("{}_{:06}.gsm", meta.field, meta.step),
        r => format!("{}_{:06}_r{r}.gsm", meta.field, meta.step),
    }
}

/// Checks a field name: it names an HDF5 group of a store and a part of
/// model file names.
pub fn check_field_name(field: &str) -> crate::Result<()> {
    if field.is_empty() || field == "." || field == ".." || field.contains('/') || field.contains('\\') || field.contains('\0') {
        return Err(crate::Error::arg(format!("field name '{field}' cannot name a file or group (empty, '.', '/', '\\' or NUL)")));
    }
    Ok(())
}
