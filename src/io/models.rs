//! Model files on disk: written into a folder by the background queue's
//! sink, read back naming the file in errors, the models of a step index,
//! and the global field a decode reads.

use crate::error::{Error, Result};
use crate::format::{model_file_name, read_model_file as parse_model_file, write_model_as, ModelFile, Payload, StepIndex};
use crate::io::atomic::write_atomic;
use crate::domain::global::GlobalField;
use crate::model::Model;
use crate::series::queue::ModelSink;
use std::path::{Path, PathBuf};

/// A background queue's sink that writes each model as
/// `FIELD_STEP.gsm` (`FIELD_STEP_rRANK.gsm` off rank 0) into a folder, on
/// the worker, through a temporary file and a rename.
pub struct ModelFolder {
    pub dir: PathBuf,
    pub payload: Payload,
}

impl ModelSink for ModelFolder {
    fn store(&mut self, model: &Model) -> Result<Option<String>> {
        let path = self.dir.join(model_file_name(&model.meta.field, model.meta.step, model.meta.rank));
        write_atomic(&path, &write_model_as(model, self.payload)?)?;
        Ok(Some(path.display().to_string()))
    }
}

/// Reads a model file, naming the file in format errors.
pub fn read_model_file(path: &Path) -> Result<ModelFile> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    parse_model_file(&bytes).map_err(|e| match e {
        Error::Format(m) => Error::Format(format!("{}: {m}", path.display())),
        Error::Version(m) => Error::Version(format!("{}: {m}", path.display())),
        other => other,
    })
}

/// Reads a step index and every rank's model it names (rank order),
/// checking that each is the piece the index says.
pub fn read_step(index_path: &Path) -> Result<(StepIndex, Vec<Model>)> {
    let text = std::fs::read_to_string(index_path).map_err(|e| Error::io(index_path, e))?;
    let index = StepIndex::from_json(&text).map_err(|e| e.in_context(&index_path.display().to_string()))?;
    let dir = index_path.parent().unwrap_or(Path::new("."));
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


/// What `gsenc decode` and the Python package's `read` take: one step index
/// (`.gsi`: the step's pieces, blended), or the models of one field (one
/// model, or the pieces of a domain, merged).
pub fn read_field(paths: &[PathBuf]) -> Result<GlobalField> {
    match paths {
        [] => Err(Error::arg("no model to read")),
        [index] if index.extension().is_some_and(|e| e == "gsi") => {
            let (index, pieces) = read_step(index)?;
            GlobalField::of_step(index, pieces)
        }
        [one] => Ok(GlobalField::of_model(read_model_file(one)?.model)),
        models => GlobalField::of_pieces(models.iter().map(|p| read_model_file(p).map(|f| f.model)).collect::<Result<Vec<_>>>()?),
    }
}
