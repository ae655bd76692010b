//! Model files on disk: written into a folder by the background queue's
//! sink, read back naming the file in errors, the models of a step index,
//! and the global field a decode reads.

use crate::error::{Error, Result};
use crate::format::{model_file_name, read_model_file as parse_model_file, write_model_as, ModelFile, Payload, StepIndex, MAGIC};
use crate::io::atomic::write_atomic;
use crate::domain::global::GlobalField;
use crate::model::Model;
use crate::series::queue::ModelSink;
use std::io::Read;
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

/// The bytes of a model file, read past its first 8 only when they are the
/// magic: what is not a model (`/dev/zero`, a stream of another format) is
/// refused after 8 bytes instead of read to its end, which may never come.
/// Past the magic, content beyond half the memory available (the model
/// parsed from it takes as much again) is refused by name, so that a pipe
/// that never ends after a model's first bytes cannot fill memory.
/// [`read_model_file`] (the tool's, Python's and `gsenc_model_read`'s reader of
/// a path) reads through it.
fn read_model_bytes(path: &Path) -> Result<Vec<u8>> {
    read_model_bytes_within(path, super::budget::whole_read_budget(1)?)
}

fn read_model_bytes_within(path: &Path, budget: u64) -> Result<Vec<u8>> {
    let mut file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let mut bytes = Vec::new();
    (&mut file).take(MAGIC.len() as u64).read_to_end(&mut bytes).map_err(|e| Error::io(path, e))?;
    if bytes[..] == MAGIC[..] {
        let rest = super::file_len(&file).map(|n| n.saturating_sub(MAGIC.len() as u64));
        bytes.extend(super::budget::read_within(path, &file, rest, budget, |e| Error::io(path, e))?);
    }
    Ok(bytes)
}

/// Reads a model file, naming the file in format errors.
pub fn read_model_file(path: &Path) -> Result<ModelFile> {
    let bytes = read_model_bytes(path)?;
    parse_model_file(&bytes).map_err(|e| match e {
        Error::Format(m) => Error::Format(format!("{}: {m}", path.display())),
        Error::Version(m) => Error::Version(format!("{}: {m}", path.display())),
        other => other,
    })
}

/// Reads a step index file (`.gsi`), naming the file in its errors.
pub fn read_step_index(index_path: &Path) -> Result<StepIndex> {
    let bytes = super::read_whole(index_path)?;
    let text = String::from_utf8(bytes).map_err(|_| Error::format(format!("{}: not a step index (not UTF-8 text)", index_path.display())))?;
    StepIndex::from_json(&text).map_err(|e| e.in_context(&index_path.display().to_string()))
}

/// Reads a step index and every rank's model it names (rank order),
/// checking that each is the piece the index says.
pub fn read_step(index_path: &Path) -> Result<(StepIndex, Vec<Model>)> {
    let index = read_step_index(index_path)?;
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::field::{IndexBox, IndexFrame, Transform, ValueRange};
    use crate::format::write_model;
    use crate::model::ModelMeta;

    /// A model reads whole; what does not open with the magic is refused
    /// after its first 8 bytes, so a stream without an end (`/dev/zero`)
    /// gives an answer instead of filling memory, and what does is read no
    /// further than the memory budget past them.
    #[test]
    fn model_files_are_read_only_past_their_magic() {
        let dir = std::env::temp_dir().join(format!("gsenc-model-bytes-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let frame = IndexFrame::from_bounds([4; 3], [0.0; 3], [1.0; 3]).unwrap();
        let meta = ModelMeta::new(frame, ValueRange::new(0.0, 1.0, Transform::Linear).unwrap());
        let model = Model { meta, params: vec![crate::math::kernel::isotropic([1.0; 3], 1.0, 0.5, 0.5)], support: None };
        let bytes = write_model(&model).unwrap();
        std::fs::write(dir.join("m.gsm"), &bytes).unwrap();
        assert_eq!(read_model_bytes(&dir.join("m.gsm")).unwrap(), bytes);
        assert_eq!(read_model_file(&dir.join("m.gsm")).unwrap().model.params, model.params);
        std::fs::write(dir.join("short.gsm"), b"GSEN").unwrap();
        assert_eq!(read_model_bytes(&dir.join("short.gsm")).unwrap(), b"GSEN");
        #[cfg(unix)]
        {
            assert_eq!(read_model_bytes(Path::new("/dev/zero")).unwrap(), vec![0; 8]);
            let e = read_model_file(Path::new("/dev/zero")).unwrap_err();
            assert!(matches!(&e, Error::Format(m) if m.contains("/dev/zero") && m.contains("magic")), "{e}");
            // The magic, then a pipe without end: refused at the budget.
            let fifo = dir.join("endless.fifo");
            assert!(std::process::Command::new("mkfifo").arg(&fifo).status().expect("mkfifo runs").success());
            let writer = std::thread::spawn({
                let fifo = fifo.clone();
                move || {
                    let mut f = std::fs::File::create(fifo).unwrap();
                    std::io::Write::write_all(&mut f, MAGIC).unwrap();
                    std::io::copy(&mut std::io::repeat(0), &mut f).unwrap_err()
                }
            });
            let e = read_model_bytes_within(&fifo, 1 << 20).unwrap_err();
            assert!(matches!(&e, Error::Io { path, source } if path.contains("endless.fifo") && source.kind() == std::io::ErrorKind::OutOfMemory), "{e}");
            assert_eq!(writer.join().unwrap().kind(), std::io::ErrorKind::BrokenPipe);
        }
        // A model within the budget reads; one byte over it does not.
        let rest = (bytes.len() - MAGIC.len()) as u64;
        assert_eq!(read_model_bytes_within(&dir.join("m.gsm"), rest).unwrap(), bytes);
        assert!(read_model_bytes_within(&dir.join("m.gsm"), rest - 1).is_err());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// A step's models are checked against its index: a model of another
    /// voxel size, transform or value range than the index says is refused
    /// by name, as a model of another box (moved, or ending elsewhere) or of
    /// another rank is, and the models the index names read.
    #[test]
    fn a_step_reads_only_the_models_its_index_names() {
        let dir = std::env::temp_dir().join(format!("gsenc-read-step-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let global = IndexFrame { dims: [8, 4, 4], bmin: [0.0; 3], gamma: 4.0 };
        let boxes = [IndexBox { lo: [0; 3], hi: [5, 4, 4] }, IndexBox { lo: [3, 0, 0], hi: [8, 4, 4] }];
        let range = ValueRange::new(0.0, 2.0, Transform::Linear).unwrap();
        let names = vec![model_file_name("rho", 3, 0), model_file_name("rho", 3, 1)];
        let index = StepIndex::new("rho", 3, None, &range, &global, &boxes, 1, names.clone());
        std::fs::write(dir.join("rho_000003.gsi"), index.to_json()).unwrap();
        // The model of `rank`, written where the index names `file`'s.
        let piece = |rank: usize, file: usize, frame: IndexFrame, range: ValueRange| {
            let mut meta = ModelMeta::new(frame, range);
            (meta.field, meta.step, meta.rank) = ("rho".into(), 3, rank as u32);
            let model = Model { meta, params: vec![crate::math::kernel::isotropic([1.0; 3], 1.0, 0.5, 0.5)], support: None };
            std::fs::write(dir.join(&names[file]), write_model(&model).unwrap()).unwrap();
        };
        for (rank, b) in boxes.iter().enumerate() {
            piece(rank, rank, global.sub_frame(b), range);
        }
        let (read, models) = read_step(&dir.join("rho_000003.gsi")).unwrap();
        assert_eq!((read, models.len()), (index.clone(), 2));
        assert_eq!(models[1].meta.frame, global.sub_frame(&boxes[1]));
        let finer = IndexFrame { gamma: 8.0, ..global.sub_frame(&boxes[1]) };
        let logged = ValueRange { transform: Transform::Log10, ..range };
        let shifted = global.sub_frame(&IndexBox { lo: [2, 0, 0], hi: [7, 4, 4] });
        let shorter = global.sub_frame(&IndexBox { lo: [3, 0, 0], hi: [7, 4, 4] });
        let wider = ValueRange::new(0.0, 2.5, Transform::Linear).unwrap();
        let own = global.sub_frame(&boxes[1]);
        for (rank, frame, range, says) in [
            (1, finer, range, "8.0 voxels a world unit"),
            (1, own, logged, "transform log10"),
            (1, shifted, range, "covers voxels [2, 0, 0]"),
            (1, shorter, range, "covers voxels [3, 0, 0]..[7, 4, 4]"),
            (1, own, wider, "another value range"),
            (0, own, range, "rank 0, the index names field 'rho' step 3 rank 1"),
        ] {
            piece(rank, 1, frame, range);
            let e = read_step(&dir.join("rho_000003.gsi")).map(|_| ()).unwrap_err();
            assert!(matches!(&e, Error::InvalidData(m) if m.contains("rank 1") && m.contains(says)), "{says}: {e}");
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
