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
pub fn model_file_name(field: &str, step: u64, rank: u32) -> String {
    match rank {
        0 => format!("{field}_{step:06}.gsm"),
        r => format!("{field}_{step:06}_r{r}.gsm"),
    }
}

/// A background queue's sink that writes each model as
/// `FIELD_STEP.gsm` (`FIELD_STEP_rRANK.gsm` off rank 0) into a folder, on
/// the worker, through a temporary file and a rename.
pub struct ModelFolder {
    pub dir: std::path::PathBuf,
    pub payload: crate::format::Payload,
}

impl crate::queue::ModelSink for ModelFolder {
    fn store(&mut self, model: &crate::model::Model) -> crate::Result<Option<String>> {
        let path = self.dir.join(model_file_name(&model.meta.field, model.meta.step, model.meta.rank));
        write_atomic(&path, &crate::format::write_model_as(model, self.payload)?)?;
        Ok(Some(path.display().to_string()))
    }
}

/// Reads a model file, naming the file in format errors.
pub fn read_model_file(path: &std::path::Path) -> crate::Result<crate::format::ModelFile> {
    use crate::Error;
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    crate::format::read_model_file(&bytes).map_err(|e| match e {
        Error::Format(m) => Error::Format(format!("{}: {m}", path.display())),
        Error::Version(m) => Error::Version(format!("{}: {m}", path.display())),
        other => other,
    })
}

/// Reads a step index and every rank's model it names (rank order),
/// checking that each is the piece the index says.
pub fn read_step(index_path: &std::path::Path) -> crate::Result<(crate::global::StepIndex, Vec<crate::model::Model>)> {
    use crate::Error;
    let text = std::fs::read_to_string(index_path).map_err(|e| Error::io(index_path, e))?;
    let index = crate::global::StepIndex::from_json(&text).map_err(|e| e.in_context(&index_path.display().to_string()))?;
    let dir = index_path.parent().unwrap_or(std::path::Path::new("."));
    let mut models = Vec::with_capacity(index.pieces.len());
    for p in &index.pieces {
        let path = dir.join(&p.model);
        if !path.exists() {
            return Err(Error::data(format!(
                "rank {}'s model {} is missing (its encode has not finished, or failed)",
                p.rank,
                path.display()
            )));
        }
        models.push(read_model_file(&path)?.model);
    }
    index.check_pieces(&models)?;
    Ok((index, models))
}

/// The step index rank 0 writes beside the per-rank models of a step
/// (`crate::global::StepIndex`).
pub fn step_index_file_name(field: &str, step: u64) -> String {
    format!("{field}_{step:06}.gsi")
}

/// Checks a field name: it names an HDF5 group of a store and a part of
/// model file names.
pub fn check_field_name(field: &str) -> crate::Result<()> {
    if field.is_empty() || field == "." || field == ".." || field.contains('/') || field.contains('\\') || field.contains('\0') {
        return Err(crate::Error::arg(format!("field name '{field}' cannot name a file or group (empty, '.', '/', '\\' or NUL)")));
    }
    Ok(())
}
