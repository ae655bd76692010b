//! Following the background queue: wait for pushed steps, poll one,
//! cancel, and the last model of a field (its step and PSNR, or written to
//! a file).

use crate::encoder::{gsenc_encoder, with_encoder};
use crate::ffi::{c_str, check_sized};
use crate::status::{fail, gsenc_status, guard, Failure};
use gsenc::format::write_model_as;
use gsenc::io::write_atomic;
use gsenc::series::queue::JobState;
use std::os::raw::c_char;

/// Blocks until every pushed step of `field` (NULL: of every field) is
/// encoded and written. Returns the first failure not reported before
/// (its message names the field and step; later steps were still encoded),
/// else `GSENC_STATUS_OK`. Models bound for an HDF5 store are written here,
/// on the caller's thread. Collective for an MPI encoder writing an HDF5
/// store (rank 0 writes every rank's models; a rank's failed write is its
/// step's failure). Calls on one encoder run one at a time.
///
/// # Safety
/// `encoder` may be any value (only a live encoder handle is used);
/// `field` is NULL or a NUL-terminated string.
#[no_mangle]
pub unsafe extern "C" fn gsenc_wait(encoder: *mut gsenc_encoder, field: *const c_char) -> gsenc_status {
    guard(|| {
        with_encoder(encoder, "gsenc_wait", |enc| {
            // SAFETY: NULL or a NUL-terminated string.
            let field = if field.is_null() { Ok(None) } else { unsafe { c_str(field, "gsenc_wait: field") }.map(Some) };
            let field = field.and_then(|f| {
                if let Some(name) = &f {
                    gsenc::format::check_field_name(name)?;
                }
                Ok(f)
            });
            let waited = field.as_ref().map_or(Ok(()), |f| enc.queue.wait(f.as_deref()));
            // Collective for an MPI encoder writing a store: on a bad field too.
            enc.flush(true);
            let field = field?;
            waited?;
            // A store write that failed in the flush is a failure of this wait too.
            enc.queue.wait(field.as_deref())?;
            Ok(())
        })
    })
}

/// Job states (`gsenc_job.state`).
pub const GSENC_JOB_QUEUED: i32 = 0;
pub const GSENC_JOB_RUNNING: i32 = 1;
/// Encoded, and written when an output is configured (for an MPI encoder
/// writing an HDF5 store: written at its next collective call).
pub const GSENC_JOB_DONE: i32 = 2;
pub const GSENC_JOB_FAILED: i32 = 3;
/// Dropped by the `GSENC_QUEUE_SKIP` policy.
pub const GSENC_JOB_SKIPPED: i32 = 4;
/// Dropped by `gsenc_encoder_cancel`.
pub const GSENC_JOB_CANCELLED: i32 = 5;

/// Where one pushed step is. Set `struct_size` to `sizeof(gsenc_job)`.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
#[allow(non_camel_case_types)]
pub struct gsenc_job {
    pub struct_size: usize,
    /// `GSENC_JOB_*`.
    pub state: i32,
    /// While running: the optimisation iteration reached, of `iterations`
    /// (both 0 while depositing and seeding).
    pub iteration: u32,
    pub iterations: u32,
    /// When failed: the failure's status (its message is then the calling
    /// thread's `gsenc_last_error`); else `GSENC_STATUS_OK`.
    pub error: i32,
    /// When done: the voxel PSNR (dB) of the model as stored; else NaN.
    pub psnr: f64,
}

/// Fills `*job` with the state of `field`'s step `step`, without waiting.
/// `GSENC_STATUS_CALL_ORDER` when that step was never pushed, or when its
/// state is no longer kept: an encoder keeps the states of the last 4,096
/// steps (of all its fields) to finish, and every failure `gsenc_wait` has
/// not reported, so that its memory does not grow with the length of the
/// run. Models bound for an HDF5 store are written here. Calls on one
/// encoder run one at a time.
///
/// # Safety
/// As for `gsenc_wait` (`field` NULL is refused here); `job` is NULL or a
/// writable `gsenc_job` whose `struct_size` is set.
#[no_mangle]
pub unsafe extern "C" fn gsenc_poll(encoder: *mut gsenc_encoder, field: *const c_char, step: u64, job: *mut gsenc_job) -> gsenc_status {
    guard(|| {
        with_encoder(encoder, "gsenc_poll", |enc| {
            // SAFETY: a NUL-terminated string or NULL (refused).
            let field = unsafe { c_str(field, "gsenc_poll: field") }?;
            // SAFETY: NULL or the caller's gsenc_job.
            unsafe { check_sized(job.cast_const(), "gsenc_poll: job") }?;
            enc.flush(false);
            let Some(state) = enc.queue.poll(&field, step) else {
                if enc.queue.dropped(&field, step) {
                    let kept = enc.queue.config().kept_states;
                    return fail(
                        gsenc_status::CallOrder,
                        format!("field '{field}' step {step}: no state kept (the encoder keeps the states of its last {kept} finished steps; or it was never pushed)"),
                    );
                }
                return fail(gsenc_status::CallOrder, format!("field '{field}' step {step} was never pushed"));
            };
            let mut out = gsenc_job {
                struct_size: std::mem::size_of::<gsenc_job>(),
                state: GSENC_JOB_QUEUED,
                iteration: 0,
                iterations: 0,
                error: gsenc_status::Ok as i32,
                psnr: f64::NAN,
            };
            let mut message = None;
            match state {
                JobState::Queued => {}
                JobState::Running { iteration, iterations } => {
                    out.state = GSENC_JOB_RUNNING;
                    out.iteration = iteration as u32;
                    out.iterations = iterations as u32;
                }
                JobState::Written { psnr, .. } | JobState::Encoded { psnr } => {
                    out.state = GSENC_JOB_DONE;
                    out.psnr = psnr;
                }
                JobState::Failed(e) => {
                    out.state = GSENC_JOB_FAILED;
                    let f = Failure::from(e.in_context(&format!("field '{field}' step {step}")));
                    out.error = f.0 as i32;
                    message = Some(f.1);
                }
                JobState::Skipped => out.state = GSENC_JOB_SKIPPED,
                JobState::Cancelled => out.state = GSENC_JOB_CANCELLED,
            }
            // SAFETY: as above.
            unsafe { job.write(out) };
            if let Some(m) = message {
                crate::status::set_last_error(m);
            }
            Ok(())
        })
    })
}

/// Drops every queued step and stops the running one at its next
/// iteration; returns when the worker is idle. Their states become
/// `GSENC_JOB_CANCELLED`; each field's next step warm-starts from its last
/// encoded one. The encoder stays usable. Calls on one encoder run one at a time.
/// Local on an MPI encoder: rank 0 wrote a cancelled step's index at its
/// push, and it names models that never come (`gsenc store verify` reports
/// it; the step's global field cannot be decoded).
///
/// # Safety
/// `encoder` may be any value (only a live encoder handle is used).
#[no_mangle]
pub unsafe extern "C" fn gsenc_encoder_cancel(encoder: *mut gsenc_encoder) -> gsenc_status {
    guard(|| {
        with_encoder(encoder, "gsenc_encoder_cancel", |enc| {
            enc.queue.cancel()?;
            enc.flush(false);
            Ok(())
        })
    })
}

/// Writes the last encoded model of `field` to `path` (through a temporary
/// file beside the file `path` names and a rename: a symbolic link stays a
/// link; a device or a pipe is written in place), with the configured
/// payload. That is the last step encoded also when its store failed (a
/// full disk): this call can write it elsewhere. Does not wait for
/// queued steps (call `gsenc_wait` first for the newest). Strings are read
/// during the call only. Calls on one encoder run one at a time.
///
/// # Safety
/// `encoder` may be any value (only a live encoder handle is used);
/// `field` and `path` are NULL or NUL-terminated strings.
#[no_mangle]
pub unsafe extern "C" fn gsenc_encoder_write_model(encoder: *mut gsenc_encoder, field: *const c_char, path: *const c_char) -> gsenc_status {
    guard(|| {
        with_encoder(encoder, "gsenc_encoder_write_model", |enc| {
            // SAFETY: NUL-terminated strings or NULL (refused).
            let (field, path) = unsafe { (c_str(field, "gsenc_encoder_write_model: field")?, c_str(path, "gsenc_encoder_write_model: path")?) };
            let Some((model, _)) = enc.queue.last(&field) else {
                return fail(gsenc_status::CallOrder, format!("field '{field}' has no encoded step yet"));
            };
            write_atomic(&path, &write_model_as(&model, enc.settings.series.payload)?)?;
            Ok(())
        })
    })
}

/// The bytes `gsenc_encoder_write_model` would write for the last encoded
/// model of `field`, into `buffer` (`capacity` bytes), for callers that
/// store models themselves (an ADIOS2 operator, a staging service).
/// `*size` is set to the bytes the model takes in any case: call with a
/// NULL `buffer` to learn it; a `capacity` below it is
/// `GSENC_STATUS_INVALID_ARGUMENT` with nothing written. Does not wait for
/// queued steps: one that finishes between the call that sizes the buffer
/// and the call that fills it changes the model, whose new size the second
/// call then gives (call `gsenc_wait` first, or size again). Calls on one
/// encoder run one at a time.
///
/// # Safety
/// As for `gsenc_wait`; `buffer` is NULL or holds `capacity` writable
/// bytes; `size` is NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn gsenc_encoder_model_bytes(
    encoder: *mut gsenc_encoder,
    field: *const c_char,
    buffer: *mut u8,
    capacity: usize,
    size: *mut usize,
) -> gsenc_status {
    guard(|| {
        with_encoder(encoder, "gsenc_encoder_model_bytes", |enc| {
            // SAFETY: NUL-terminated string or NULL (refused).
            let field = unsafe { c_str(field, "gsenc_encoder_model_bytes: field") }?;
            if size.is_null() {
                return fail(gsenc_status::NullPointer, "gsenc_encoder_model_bytes: size is NULL");
            }
            let Some((model, _)) = enc.queue.last(&field) else {
                return fail(gsenc_status::CallOrder, format!("field '{field}' has no encoded step yet"));
            };
            let bytes = write_model_as(&model, enc.settings.series.payload)?;
            // SAFETY: non-null out pointer.
            unsafe { *size = bytes.len() };
            if buffer.is_null() {
                return Ok(());
            }
            if capacity < bytes.len() {
                return fail(gsenc_status::InvalidArgument, format!("gsenc_encoder_model_bytes: a buffer of {capacity} bytes, the model takes {}", bytes.len()));
            }
            // SAFETY: the caller's `capacity` writable bytes at `buffer`, at
            // least `bytes.len()`; a fresh Vec does not overlap them.
            unsafe { std::ptr::copy_nonoverlapping(bytes.as_ptr(), buffer, bytes.len()) };
            Ok(())
        })
    })
}

/// The last encoded step of `field` and the voxel PSNR (dB) of its model as
/// stored, against the reference it was fitted to. Does not wait for queued
/// steps. Calls on one encoder run one at a time.
///
/// # Safety
/// As for `gsenc_wait`; `step` and `psnr` are NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn gsenc_encoder_last_step(
    encoder: *mut gsenc_encoder,
    field: *const c_char,
    step: *mut u64,
    psnr: *mut f64,
) -> gsenc_status {
    guard(|| {
        with_encoder(encoder, "gsenc_encoder_last_step", |enc| {
            // SAFETY: NUL-terminated string or NULL (refused).
            let field = unsafe { c_str(field, "gsenc_encoder_last_step: field") }?;
            if step.is_null() || psnr.is_null() {
                return fail(gsenc_status::NullPointer, "gsenc_encoder_last_step: step or psnr is NULL");
            }
            let Some((model, p)) = enc.queue.last(&field) else {
                return fail(gsenc_status::CallOrder, format!("field '{field}' has no encoded step yet"));
            };
            // SAFETY: non-null out pointers.
            unsafe {
                *step = model.meta.step;
                *psnr = p;
            }
            Ok(())
        })
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::{gsenc_config, gsenc_config_init, GSENC_BACKEND_CPU, GSENC_SCHEDULE_SHORT};
    use crate::encoder::{create_tweaked, gsenc_encoder_destroy};
    use crate::inputs::{f32_grid, gsenc_push_grid};
    use crate::status::last_error_text as last_error;
    use std::ffi::CString;

    /// A poll of a step whose state the encoder no longer keeps says so,
    /// apart from a step beyond every one pushed.
    #[test]
    fn a_poll_of_a_dropped_state_says_so() {
        // SAFETY: the test's own config, grid, strings and handle.
        unsafe {
            let mut cfg: gsenc_config = std::mem::zeroed();
            cfg.struct_size = std::mem::size_of::<gsenc_config>();
            assert_eq!(gsenc_config_init(&mut cfg), gsenc_status::Ok);
            (cfg.budget, cfg.schedule, cfg.iterations, cfg.points, cfg.backend) = (8, GSENC_SCHEDULE_SHORT, 10, 64, GSENC_BACKEND_CPU);
            let mut enc = std::ptr::null_mut();
            assert_eq!(create_tweaked(&cfg, &mut enc, |s| s.kept_states = 2), gsenc_status::Ok);
            let field = CString::new("rho").unwrap();
            let values: Vec<f32> = (0..120).map(|i| (i % 7) as f32 / 7.0).collect();
            let grid = f32_grid(&values, [6, 5, 4], 0.1);
            for step in [0, 2, 4, 6] {
                assert_eq!(gsenc_push_grid(enc, field.as_ptr(), step, step as f64, &grid), gsenc_status::Ok);
            }
            assert_eq!(gsenc_wait(enc, std::ptr::null()), gsenc_status::Ok);
            let mut job: gsenc_job = std::mem::zeroed();
            job.struct_size = std::mem::size_of::<gsenc_job>();
            for step in [4, 6] {
                assert_eq!(gsenc_poll(enc, field.as_ptr(), step, &mut job), gsenc_status::Ok, "step {step}");
                assert_eq!(job.state, GSENC_JOB_DONE, "step {step}");
            }
            for step in [0, 1, 2] {
                assert_eq!(gsenc_poll(enc, field.as_ptr(), step, &mut job), gsenc_status::CallOrder, "step {step}");
                let e = last_error();
                assert!(e.contains(&format!("step {step}: no state kept")) && e.contains("last 2 finished steps"), "{e}");
            }
            assert_eq!(gsenc_poll(enc, field.as_ptr(), 7, &mut job), gsenc_status::CallOrder);
            assert!(last_error().contains("step 7 was never pushed"), "{}", last_error());
            gsenc_encoder_destroy(enc);
        }
    }
}
