//! Continuing a series after a restart: the encoder takes up a field from
//! the model stored last, as if the run had not stopped.
//!
//! A simulation restarted from a checkpoint creates its encoder again, and
//! each field's first step would be encoded cold (seeded from its data,
//! the full schedule) and on a value range and lattice of its own. Resuming
//! hands the encoder the model of the field's last stored step instead (a
//! model file read with `gsenc_model_read`, or the bytes of
//! `gsenc_encoder_model_bytes` a code kept in its checkpoint, read with
//! `gsenc_model_read_buffer`); the library's side is
//! `gsenc::series::queue::BackgroundEncoder::resume` and, over MPI,
//! `gsenc::domain::mpi::Decomposition::resume`.

use crate::config::OutputFormat;
use crate::encoder::{with_encoder, gsenc_encoder};
use crate::ffi::c_str;
use crate::model::{gsenc_model, with_model};
use crate::status::{fail, gsenc_status, guard, Failure};
use gsenc::model::Model;
use std::os::raw::c_char;

/// Continues the series of `model`'s field from `model`, the step stored
/// last before the run stopped (a restart from a checkpoint): the field's
/// next push must come after that step and is warm-started from it, on its
/// lattice and value range, as the unbroken run would have (bit for bit
/// when the model was stored with `GSENC_PAYLOAD_F32`; with another payload
/// it starts from the stored, rounded parameters). Call it before the
/// field's first push, with the encoder configured as the run that stored
/// the model (its schedule, warm start, seeds and range settings);
/// `gsenc_encoder_last_step` and `gsenc_encoder_model_bytes` give the model
/// until a step is encoded. The model is copied: the caller may destroy
/// it at once. Refused with `GSENC_STATUS_INVALID_ARGUMENT`, the encoder
/// unchanged: a field pushed or resumed already, another rank's model, a
/// value range other than a fixed `value_min`/`value_max` or `transform`
/// configured; `GSENC_STATUS_INVALID_DATA`: a model with no Gaussians.
///
/// For an encoder of `gsenc_encoder_create_mpi` this call is
/// **collective**: every rank passes its own piece's model of the same
/// field and step (`FIELD_STEP_rRANK.gsm`, or its bytes), on the ranks,
/// `dims`, `bounds` and `halo` of the run that stored them. The ranks
/// gather each other's pieces, and the field's first push rebuilds from
/// them the lattice and pieces the series had, so that its models and step
/// indexes continue the unbroken run's; pieces that are not of one lattice
/// are that push's `GSENC_STATUS_MPI` on every rank. A rank whose `model`
/// is refused (NULL included) fails with its own error and the others
/// with `GSENC_STATUS_MPI`, none resumed.
///
/// # Safety
/// `encoder` and `model` may be any values: only live handles are used.
#[no_mangle]
pub unsafe extern "C" fn gsenc_encoder_resume(encoder: *mut gsenc_encoder, model: *const gsenc_model) -> gsenc_status {
    guard(|| {
        let what = "gsenc_encoder_resume";
        let model: Result<Model, Failure> = with_model(model, what, |m| Ok(m.clone()));
        with_encoder(encoder, what, |enc| enc.resume(model))
    })
}

/// `gsenc_encoder_resume` from the encoder's own output: the model of
/// `field`'s step `step` that a run with the same `output_dir` and
/// `output_format` stored, read from `output_dir/FIELD_STEP.gsm` (rank r's
/// `FIELD_STEP_rR.gsm`) or from the HDF5 store (`/<field>/<step>/rank_<r>`),
/// so that a restarted code needs only the step it restarts from. The
/// steps it then pushes go into the same folder or store. A step the output
/// does not hold is its read's error (`GSENC_STATUS_IO` for a missing
/// file, `GSENC_STATUS_INVALID_ARGUMENT` for a missing store entry); an
/// encoder with no output is `GSENC_STATUS_CALL_ORDER`. Collective for an
/// encoder of `gsenc_encoder_create_mpi`, as `gsenc_encoder_resume`: each
/// rank reads its own model file, or rank 0 reads every rank's from the
/// store it alone has open and sends each its own. `field` is read during
/// the call only.
///
/// # Safety
/// `encoder` may be any value (only a live encoder handle is used);
/// `field` is NULL or a NUL-terminated string.
#[no_mangle]
pub unsafe extern "C" fn gsenc_encoder_resume_stored(encoder: *mut gsenc_encoder, field: *const c_char, step: u64) -> gsenc_status {
    guard(|| {
        let what = "gsenc_encoder_resume_stored";
        // SAFETY: NUL-terminated string or NULL (that rank's failure).
        let field = unsafe { c_str(field, &format!("{what}: field")) };
        with_encoder(encoder, what, |enc| {
            let read = enc.read_stored(field, step);
            enc.resume(read)
        })
    })
}

impl gsenc_encoder {
    /// This rank's model of `field`'s step `step` in the encoder's output
    /// (`gsenc_encoder_resume_stored`). Collective for an MPI encoder
    /// writing a store, even where this rank has no `field`.
    fn read_stored(&mut self, field: Result<String, Failure>, step: u64) -> Result<Model, Failure> {
        let rank = self.settings.series.rank;
        let Some(out) = self.settings.output.clone() else {
            // Nothing collective without an output: a bad field is this
            // call's error first.
            field?;
            return fail(gsenc_status::CallOrder, "gsenc_encoder_resume_stored: this encoder writes no output to resume from; pass the model to gsenc_encoder_resume");
        };
        match self.settings.output_format {
            OutputFormat::Folder => {
                let path = out.join(gsenc::format::model_file_name(&field?, step, rank));
                Ok(gsenc::io::read_model_file(&path)?.model)
            }
            OutputFormat::Hdf5 => self.read_from_store(field, step),
        }
    }

    /// This rank's model of a step in the HDF5 store: read here, or over
    /// MPI by rank 0, which alone has the store open, for every rank.
    #[cfg(feature = "hdf5")]
    fn read_from_store(&mut self, field: Result<String, Failure>, step: u64) -> Result<Model, Failure> {
        use gsenc::io::store::EntryKey;
        let store = self.store.as_ref();
        let read = |f: &str, rank: u32| match store {
            Some(s) => Ok(s.read(&EntryKey { field: f.to_owned(), step, rank })?.0),
            None => Err(gsenc::Error::arg("this rank has no store open")),
        };
        #[cfg(feature = "mpi")]
        if let Some(ranks) = self.ranks.as_mut() {
            let mut each = |r: u32| match &field {
                Ok(f) => read(f, r),
                Err(why) => Err(gsenc::Error::arg(format!("rank 0 was given no field name ({})", why.1))),
            };
            let mine = ranks.models_from_root(&mut each);
            field?;
            return Ok(mine?);
        }
        Ok(read(&field?, self.settings.series.rank)?)
    }

    #[cfg(not(feature = "hdf5"))]
    fn read_from_store(&mut self, _: Result<String, Failure>, _: u64) -> Result<Model, Failure> {
        fail(gsenc_status::InvalidArgument, "this gsenc was built without HDF5 (cargo feature hdf5)")
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::{gsenc_config, gsenc_config_init, GSENC_BACKEND_CPU, GSENC_SCHEDULE_SHORT};
    use crate::encoder::{gsenc_encoder_create, gsenc_encoder_destroy};
    use crate::inputs::{f32_grid, gsenc_push_grid};
    use crate::jobs::{gsenc_encoder_last_step, gsenc_encoder_model_bytes, gsenc_wait};
    use crate::model::{gsenc_model_destroy, gsenc_model_read_buffer};
    use crate::status::last_error_text as last_error;
    use std::ffi::CString;

    fn encoder() -> *mut gsenc_encoder {
        encoder_into(None)
    }

    /// An encoder writing model files into `dir`, or keeping them.
    fn encoder_into(dir: Option<&CString>) -> *mut gsenc_encoder {
        // SAFETY: the test's own config, string and handle slot.
        unsafe {
            let mut cfg: gsenc_config = std::mem::zeroed();
            cfg.struct_size = std::mem::size_of::<gsenc_config>();
            assert_eq!(gsenc_config_init(&mut cfg), gsenc_status::Ok);
            (cfg.budget, cfg.schedule, cfg.iterations, cfg.points, cfg.backend) = (12, GSENC_SCHEDULE_SHORT, 20, 128, GSENC_BACKEND_CPU);
            cfg.output_dir = dir.map_or(std::ptr::null(), |d| d.as_ptr());
            let mut enc = std::ptr::null_mut();
            assert_eq!(gsenc_encoder_create(&cfg, &mut enc), gsenc_status::Ok);
            enc
        }
    }

    /// `field`'s step `step` of the test's series, pushed.
    unsafe fn push(enc: *mut gsenc_encoder, field: &CString, step: u64) {
        let v = values(step);
        let grid = f32_grid(&v, [6, 5, 4], 0.1);
        // SAFETY: a live encoder, the test's string and grid.
        let status = unsafe { gsenc_push_grid(enc, field.as_ptr(), step, step as f64, &grid) };
        assert_eq!(status, gsenc_status::Ok, "{}", last_error());
    }

    /// The step's grid: a bump that moves with the step.
    fn values(step: u64) -> Vec<f32> {
        (0..6 * 5 * 4).map(|i| (((i % 6) as f32 - 1.0 - step as f32 * 0.5).powi(2) * -0.3).exp()).collect()
    }

    /// The bytes of `field`'s last model, as a code keeps them in its checkpoint.
    unsafe fn checkpoint(enc: *mut gsenc_encoder, field: &CString) -> Vec<u8> {
        let mut size = 0;
        // SAFETY: a live encoder, the test's strings and out pointers.
        unsafe {
            assert_eq!(gsenc_encoder_model_bytes(enc, field.as_ptr(), std::ptr::null_mut(), 0, &mut size), gsenc_status::Ok);
            let mut bytes = vec![0u8; size];
            assert_eq!(gsenc_encoder_model_bytes(enc, field.as_ptr(), bytes.as_mut_ptr(), size, &mut size), gsenc_status::Ok);
            bytes
        }
    }

    /// A run stopped after step 1 and resumed from the bytes it kept gives
    /// the unbroken run's step 2; what cannot be resumed is refused.
    #[test]
    fn a_restart_continues_from_the_checkpointed_model() {
        let field = CString::new("rho").unwrap();
        // SAFETY: the test's own handles, grids and buffers.
        unsafe {
            let push = |enc, step| push(enc, &field, step);
            let unbroken = encoder();
            push(unbroken, 1);
            assert_eq!(gsenc_wait(unbroken, std::ptr::null()), gsenc_status::Ok);
            let kept = checkpoint(unbroken, &field);
            push(unbroken, 2);
            assert_eq!(gsenc_wait(unbroken, std::ptr::null()), gsenc_status::Ok);
            let want = checkpoint(unbroken, &field);
            gsenc_encoder_destroy(unbroken);

            let mut model = std::ptr::null_mut();
            assert_eq!(gsenc_model_read_buffer(kept.as_ptr(), kept.len(), &mut model), gsenc_status::Ok);
            let restarted = encoder();
            assert_eq!(gsenc_encoder_resume(restarted, std::ptr::null()), gsenc_status::NullPointer);
            assert_eq!(gsenc_encoder_resume(restarted, model), gsenc_status::Ok, "{}", last_error());
            gsenc_model_destroy(model);
            let (mut step, mut psnr) = (0u64, 0f64);
            assert_eq!(gsenc_encoder_last_step(restarted, field.as_ptr(), &mut step, &mut psnr), gsenc_status::Ok);
            assert_eq!(step, 1);
            assert_eq!(checkpoint(restarted, &field), kept, "the resumed model is the field's last");
            push(restarted, 2);
            assert_eq!(gsenc_wait(restarted, std::ptr::null()), gsenc_status::Ok);
            assert_eq!(checkpoint(restarted, &field), want, "the restarted run's step 2 differs from the unbroken run's");

            // A field with steps already: refused, the encoder unchanged.
            assert_eq!(gsenc_model_read_buffer(kept.as_ptr(), kept.len(), &mut model), gsenc_status::Ok);
            assert_eq!(gsenc_encoder_resume(restarted, model), gsenc_status::InvalidArgument);
            assert!(last_error().contains("has begun on this encoder already (its last step 2)"), "{}", last_error());
            push(restarted, 3);
            assert_eq!(gsenc_wait(restarted, std::ptr::null()), gsenc_status::Ok);
            gsenc_encoder_destroy(restarted);
            // A destroyed encoder.
            assert_eq!(gsenc_encoder_resume(restarted, model), gsenc_status::InvalidArgument);
            gsenc_model_destroy(model);
        }
    }

    /// A restarted encoder resumes from its own folder: the step the stopped
    /// run wrote there, then its next steps as the unbroken run's; no
    /// output, a step not there, a NULL field: refused.
    #[test]
    fn a_restart_resumes_from_its_own_folder() {
        let dir = crate::common::tmpdir("capi-resume-stored");
        let out = CString::new(dir.to_str().unwrap()).unwrap();
        let field = CString::new("rho").unwrap();
        // SAFETY: the test's own handles, strings and grids.
        unsafe {
            let unbroken = encoder();
            for step in 1..=2 {
                push(unbroken, &field, step);
            }
            assert_eq!(gsenc_wait(unbroken, std::ptr::null()), gsenc_status::Ok);
            let want = checkpoint(unbroken, &field);
            assert_eq!(gsenc_encoder_resume_stored(unbroken, field.as_ptr(), 1), gsenc_status::CallOrder);
            assert!(last_error().contains("writes no output"), "{}", last_error());
            gsenc_encoder_destroy(unbroken);

            let stopped = encoder_into(Some(&out));
            push(stopped, &field, 1);
            gsenc_encoder_destroy(stopped);
            let restarted = encoder_into(Some(&out));
            assert_eq!(gsenc_encoder_resume_stored(restarted, std::ptr::null(), 1), gsenc_status::NullPointer);
            assert_eq!(gsenc_encoder_resume_stored(restarted, field.as_ptr(), 7), gsenc_status::Io);
            assert!(last_error().contains("rho_000007.gsm"), "{}", last_error());
            assert_eq!(gsenc_encoder_resume_stored(restarted, field.as_ptr(), 1), gsenc_status::Ok, "{}", last_error());
            push(restarted, &field, 2);
            assert_eq!(gsenc_wait(restarted, std::ptr::null()), gsenc_status::Ok);
            gsenc_encoder_destroy(restarted);
            assert_eq!(std::fs::read(dir.join("rho_000002.gsm")).unwrap(), want, "the restarted run's step 2 differs from the unbroken run's");
        }
    }
}
