//! In-situ previews: a picture of every step beside its model, drawn by the
//! background queue's worker on the encoder's threads (never the caller's),
//! as `FIELD_STEP.png` (`FIELD_STEP_rRANK.png` off rank 0).

use super::image::{model_figure, write_png};
use crate::backend::cpu::CpuBackend;
use crate::backend::Backend;
use crate::error::Result;
use crate::format::model_file_name;
use crate::model::Model;
use crate::render::View;
use crate::series::queue::ModelSink;
use std::path::{Path, PathBuf};

/// A sink that stores each model through `inner`, then writes its preview
/// into `dir`. A preview that cannot be drawn or written is logged
/// (`tracing` warning) and never costs the model.
pub struct Previewed {
    pub inner: Box<dyn ModelSink>,
    pub view: View,
    pub dir: PathBuf,
    backend: CpuBackend,
}

impl Previewed {
    pub fn new(inner: Box<dyn ModelSink>, view: View, dir: PathBuf) -> Previewed {
        Previewed { inner, view, dir, backend: CpuBackend::new() }
    }

    fn draw(&mut self, model: &Model) -> Result<PathBuf> {
        write_preview(&self.dir, model, &mut self.backend, &self.view)
    }
}

/// Where the preview of `model` goes in `dir`: its model file's name with
/// `.png`.
pub fn preview_path(dir: &Path, model: &Model) -> PathBuf {
    dir.join(model_file_name(&model.meta.field, model.meta.step, model.meta.rank)).with_extension("png")
}

/// Draws `model` as `view` says into `dir` (see [`preview_path`]).
pub fn write_preview(dir: &Path, model: &Model, backend: &mut dyn Backend, view: &View) -> Result<PathBuf> {
    let path = preview_path(dir, model);
    write_png(&path, &model_figure(model, backend, view)?)?;
    Ok(path)
}

impl ModelSink for Previewed {
    fn store(&mut self, model: &Model) -> Result<Option<String>> {
        let stored = self.inner.store(model)?;
        match self.draw(model) {
            Ok(path) => tracing::debug!(path = %path.display(), "preview written"),
            Err(e) => tracing::warn!(field = %model.meta.field, step = model.meta.step, error = %e, "preview not written"),
        }
        Ok(stored)
    }
}
