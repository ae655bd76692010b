//! Reading a model file and evaluating it: decode onto a lattice into a
//! caller's buffer, or at arbitrary world points. A model handle is
//! read-only: any number of threads may decode and evaluate it at once.

use crate::ffi::{c_str, check_sized, extents};
use crate::handles::Kind;
use crate::status::{fail, gsenc_status, guard, Failure};
use gsenc::backend::cpu::CpuBackend;
use gsenc::backend::select::BackendChoice;
use gsenc::field::IndexBox;
use gsenc::model::{Model, WarmTaken, DEFAULT_SLAB_VOXELS};
use gsenc::threads::with_threads;
use std::os::raw::c_char;

/// Opaque model; read with `gsenc_model_read`, free with `gsenc_model_destroy`.
pub struct gsenc_model {
    model: Model,
}

/// What a model covers. Set `struct_size` to `sizeof(gsenc_model_info)`.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
#[allow(non_camel_case_types)]
pub struct gsenc_model_info {
    pub struct_size: usize,
    /// Number of Gaussians.
    pub count: u64,
    /// Reference lattice dims, and its box: lower corner and cell edge.
    pub dims: [u64; 3],
    pub origin: [f64; 3],
    pub spacing: f64,
    pub step: u64,
    /// Simulation time; NaN when unknown.
    pub time: f64,
    pub rank: u32,
    /// Optimisation iterations the step ran.
    pub iterations: u32,
    /// Non-zero when the step started from the field's previous model.
    pub warm_started: i32,
    /// Voxel PSNR (dB) of the stored model against its reference at encode
    /// time; NaN when not measured.
    pub encode_psnr: f64,
    /// Non-zero when the encode ran on the CPU although a GPU was chosen
    /// (`auto` fell back after a device error; `gsenc info` says why).
    pub fell_back: i32,
    /// `GSENC_WARM_TAKEN_*`: the start an `auto` warm step took (NONE for
    /// every other encode).
    pub warm_taken: i32,
    /// Gaussians the `auto` warm start's repair moved.
    pub warm_moved: u32,
}

/// `gsenc_model_info.warm_taken`.
pub const GSENC_WARM_TAKEN_NONE: i32 = 0;
/// The previous step's model as it was.
pub const GSENC_WARM_TAKEN_KEPT: i32 = 1;
/// The previous model, `warm_moved` Gaussians re-seeded where it missed.
pub const GSENC_WARM_TAKEN_REPAIRED: i32 = 2;
/// A fresh seeding from the step's own data.
pub const GSENC_WARM_TAKEN_FRESH: i32 = 3;

/// Runs `f` on the live model `model`, which is not freed meanwhile (other
/// calls may read it too).
pub(crate) fn with_model<R>(model: *const gsenc_model, what: &str, f: impl FnOnce(&Model) -> Result<R, Failure>) -> Result<R, Failure> {
    crate::handles::hold(model, Kind::Model, what, false, || {
        // SAFETY: a live handle from gsenc_model_read, held.
        f(unsafe { &(*model).model })
    })
}

/// Reads the model file at `path` into `*out` (NULL on failure). The
/// caller owns the new handle and frees it with `gsenc_model_destroy`.
/// Thread-safe.
///
/// # Safety
/// `path` is NULL or a NUL-terminated string; `out` is NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn gsenc_model_read(path: *const c_char, out: *mut *mut gsenc_model) -> gsenc_status {
    guard(|| {
        if out.is_null() {
            return fail(gsenc_status::NullPointer, "gsenc_model_read: out is NULL");
        }
        // SAFETY: non-null pointer to the caller's handle slot.
        unsafe { *out = std::ptr::null_mut() };
        // SAFETY: NUL-terminated string or NULL (refused).
        let path = unsafe { c_str(path, "gsenc_model_read: path") }?;
        let model = gsenc::io::read_model_file(std::path::Path::new(&path))?.model;
        // SAFETY: as above.
        unsafe { *out = new_handle(model) };
        Ok(())
    })
}

/// Reads a model from the `size` bytes at `data` (what a model file holds,
/// as `gsenc_encoder_model_bytes` gives them) into `*out` (NULL on
/// failure). The bytes are read during the call only. The caller owns the
/// new handle and frees it with `gsenc_model_destroy`. Thread-safe.
///
/// # Safety
/// `data` is NULL or holds `size` readable bytes; `out` is NULL or
/// writable.
#[no_mangle]
pub unsafe extern "C" fn gsenc_model_read_buffer(data: *const u8, size: usize, out: *mut *mut gsenc_model) -> gsenc_status {
    guard(|| {
        if out.is_null() || data.is_null() {
            return fail(gsenc_status::NullPointer, "gsenc_model_read_buffer: data or out is NULL");
        }
        // SAFETY: non-null pointer to the caller's handle slot.
        unsafe { *out = std::ptr::null_mut() };
        if size > isize::MAX as usize {
            return fail(gsenc_status::InvalidArgument, format!("gsenc_model_read_buffer: size {size} is more bytes than a buffer can hold"));
        }
        // SAFETY: the caller's `size` readable bytes at `data`.
        let bytes = unsafe { std::slice::from_raw_parts(data, size) };
        let model = gsenc::format::read_model(bytes)?;
        // SAFETY: as above.
        unsafe { *out = new_handle(model) };
        Ok(())
    })
}

/// A registered handle owning `model`.
fn new_handle(model: Model) -> *mut gsenc_model {
    let raw = Box::into_raw(Box::new(gsenc_model { model }));
    crate::handles::register(raw, Kind::Model);
    raw
}

/// Frees a model. NULL, and a handle destroyed already, are ignored;
/// other calls with it afterwards fail with `GSENC_STATUS_INVALID_ARGUMENT`.
/// Calls on it in flight on other threads are waited for first.
///
/// # Safety
/// `model` may be any value: only a live model handle is freed.
#[no_mangle]
pub unsafe extern "C" fn gsenc_model_destroy(model: *mut gsenc_model) {
    crate::handles::release(model, Kind::Model, || {
        let _ = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            // SAFETY: made by Box::into_raw in gsenc_model_read, live until
            // now (released, so never freed twice, and no call holds it).
            drop(unsafe { Box::from_raw(model) });
        }));
    });
}

/// The model's field name: copied into `buf` (at most `len` bytes, always
/// NUL-terminated when `len > 0`), its full length without the NUL in
/// `*length`, so that a call with a NULL `buf` sizes the buffer.
/// Thread-safe, also on one model.
///
/// # Safety
/// `model` may be any value (only a live model handle is used); `buf` is
/// NULL or holds `len` writable bytes; `length` is NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn gsenc_model_field(model: *const gsenc_model, buf: *mut c_char, len: usize, length: *mut usize) -> gsenc_status {
    guard(|| {
        with_model(model, "gsenc_model_field", |m| {
            if length.is_null() {
                return fail(gsenc_status::NullPointer, "gsenc_model_field: length is NULL");
            }
            // SAFETY: `buf` is NULL or the caller's `len` bytes; `length` non-null.
            unsafe { *length = crate::status::copy_c_string(&m.meta.field, buf, len) };
            Ok(())
        })
    })
}

/// Fills `*info` (whose `struct_size` must be set). Thread-safe, also on
/// one model.
///
/// # Safety
/// `model` may be any value (only a live model handle is used); `info`
/// is NULL or a writable `gsenc_model_info` whose `struct_size` is set.
#[no_mangle]
pub unsafe extern "C" fn gsenc_model_info_get(model: *const gsenc_model, info: *mut gsenc_model_info) -> gsenc_status {
    guard(|| {
        with_model(model, "gsenc_model_info_get", |m| {
            // SAFETY: NULL or the caller's gsenc_model_info, to be filled.
            unsafe { check_sized(info.cast_const(), "gsenc_model_info_get: info") }?;
            let want = std::mem::size_of::<gsenc_model_info>();
            let f = &m.meta.frame;
            let value = gsenc_model_info {
                struct_size: want,
                count: m.len() as u64,
                dims: f.dims.map(|d| d as u64),
                origin: f.bmin,
                spacing: 1.0 / f.gamma,
                step: m.meta.step,
                time: m.meta.time.unwrap_or(f64::NAN),
                rank: m.meta.rank,
                iterations: m.meta.iterations,
                warm_started: m.meta.schedule.starts_with("warm-") as i32,
                encode_psnr: m.meta.encode_psnr.unwrap_or(f64::NAN),
                fell_back: m.meta.fell_back.is_some() as i32,
                warm_taken: m.meta.warm.map_or(GSENC_WARM_TAKEN_NONE, |w| match w.taken {
                    WarmTaken::Kept => GSENC_WARM_TAKEN_KEPT,
                    WarmTaken::Repaired => GSENC_WARM_TAKEN_REPAIRED,
                    WarmTaken::Fresh => GSENC_WARM_TAKEN_FRESH,
                }),
                warm_moved: m.meta.warm.map_or(0, |w| w.moved),
            };
            // SAFETY: as above.
            unsafe { info.write(value) };
            Ok(())
        })
    })
}

/// Decodes the model onto `dims` cells covering its box (NULL `dims`: its
/// reference dims) into `out`, which holds `out_len` floats, x fastest,
/// in data units; with its support, where it stores one (its outside where
/// the data were empty). The caller owns `out`. Runs on a hardware GPU when
/// there is one, else on the CPU (`GSENC_BACKEND=cpu|gpu` chooses), there
/// on a pool of one thread per CPU the process may use, started by the
/// first decode or evaluation (`RAYON_NUM_THREADS` sets its size; the
/// encoders never use it; a process forked after it started starts its
/// own). Thread-safe, also on one model.
///
/// # Safety
/// `model` may be any value (only a live model handle is used); `dims`
/// is NULL or three readable `uint64_t`; `out` is NULL or holds `out_len`
/// writable floats (`out_len` is checked against `dims`; that `out` holds
/// them, gsenc cannot see).
#[no_mangle]
pub unsafe extern "C" fn gsenc_model_decode(model: *const gsenc_model, dims: *const u64, out: *mut f32, out_len: u64) -> gsenc_status {
    guard(|| {
        with_model(model, "gsenc_model_decode", |m| {
            let dims = if dims.is_null() {
                m.meta.frame.dims
            } else {
                // SAFETY: three u64 at `dims`.
                extents(unsafe { [*dims, *dims.add(1), *dims.add(2)] })?
            };
            let n: usize = dims.iter().product();
            if out.is_null() {
                return fail(gsenc_status::NullPointer, "gsenc_model_decode: out is NULL");
            }
            if out_len != n as u64 {
                return fail(gsenc_status::InvalidArgument, format!("gsenc_model_decode: out holds {out_len} floats, {dims:?} needs {n}"));
            }
            // SAFETY: the caller's buffer holds out_len floats.
            let out = unsafe { std::slice::from_raw_parts_mut(out, n) };
            let mut at = 0;
            let range = m.meta.range;
            let mut backend = BackendChoice::default().open()?;
            with_threads(None, || {
                m.decode_streaming(backend.as_mut(), dims, IndexBox::whole(dims), DEFAULT_SLAB_VOXELS, &mut |slab| {
                    range.output_into(false, slab, &mut out[at..at + slab.len()]);
                    at += slab.len();
                    Ok(())
                })
            })??;
            Ok(())
        })
    })
}

/// Evaluates the model at `count` world points (`points`: x, y, z per
/// point, interleaved) into `out` (`count` floats, data units, with the
/// model's support), both owned by the caller. A point's value is the same
/// bits whatever other points the call holds, in whatever order, and on
/// any thread count. On the CPU: a few points do not pay for opening a
/// GPU. Runs in runs of 65,536 points, so that it holds about a megabyte
/// besides the caller's arrays however many points there are, on the pool
/// `gsenc_model_decode` runs on. Thread-safe, also on one model.
///
/// # Safety
/// `model` may be any value (only a live model handle is used); `points`
/// is NULL or holds `3 * count` readable doubles, and `out` is NULL or
/// holds `count` writable floats; the two do not overlap.
#[no_mangle]
pub unsafe extern "C" fn gsenc_model_evaluate(model: *const gsenc_model, points: *const f64, count: u64, out: *mut f32) -> gsenc_status {
    guard(|| {
        with_model(model, "gsenc_model_evaluate", |m| {
            if points.is_null() || out.is_null() {
                return fail(gsenc_status::NullPointer, "gsenc_model_evaluate: points or out is NULL");
            }
            // No array of the caller's holds more than isize::MAX bytes.
            let n = usize::try_from(count).ok().filter(|&n| n.checked_mul(24).is_some_and(|b| b <= isize::MAX as usize));
            let Some(n) = n else {
                return fail(gsenc_status::InvalidArgument, format!("gsenc_model_evaluate: count {count} is more points than an array can hold"));
            };
            // SAFETY: the caller's arrays hold 3 count doubles (read in place
            // as count [f64; 3], of the same layout) and count floats.
            let (pts, out) = unsafe { (std::slice::from_raw_parts(points.cast::<[f64; 3]>(), n), std::slice::from_raw_parts_mut(out, n)) };
            // Into the caller's array, in runs: nothing sized by count is
            // copied. A point that is not finite is InvalidData, by index.
            with_threads(None, || {
                m.evaluate_into(&mut CpuBackend::new(), pts, out)?;
                m.meta.range.denormalize_all(out);
                Ok::<_, gsenc::Error>(())
            })??;
            Ok(())
        })
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use gsenc::field::{IndexFrame, Transform, ValueRange};
    use gsenc::model::{ModelMeta, WarmRecord};

    /// `gsenc_model_info_get` of a model whose every field is set by hand:
    /// each number as the model holds it, a time and a PSNR it lacks as
    /// NaN, and each warm-start record as its own constant.
    #[test]
    fn info_reports_every_field_of_the_model() {
        let frame = IndexFrame { dims: [6, 5, 4], bmin: [-1.0, 2.0, 0.5], gamma: 4.0 };
        let mut meta = ModelMeta::new(frame, ValueRange::new(0.0, 1.0, Transform::Linear).unwrap());
        (meta.step, meta.schedule, meta.iterations, meta.rank) = (12, "warm-matched".into(), 345, 7);
        (meta.time, meta.encode_psnr, meta.fell_back) = (Some(2.5), Some(41.25), Some("the GPU was lost".into()));
        let params = vec![gsenc::math::kernel::isotropic([1.0, 1.0, 1.0], 1.0, 0.5, 0.5); 3];
        let info_of = |meta: &ModelMeta| {
            let handle = new_handle(Model { meta: meta.clone(), params: params.clone(), support: None });
            // SAFETY: a zeroed plain struct of numbers.
            let mut info: gsenc_model_info = unsafe { std::mem::zeroed() };
            info.struct_size = std::mem::size_of::<gsenc_model_info>();
            // SAFETY: a live handle and a writable info of this version.
            let status = unsafe { gsenc_model_info_get(handle, &mut info) };
            // SAFETY: the handle made above, freed once.
            unsafe { gsenc_model_destroy(handle) };
            assert_eq!(status, gsenc_status::Ok);
            info
        };
        let info = info_of(&meta);
        assert_eq!((info.count, info.dims, info.origin, info.spacing), (3, [6, 5, 4], [-1.0, 2.0, 0.5], 0.25));
        assert_eq!((info.step, info.time, info.rank, info.iterations, info.encode_psnr), (12, 2.5, 7, 345, 41.25));
        assert_eq!((info.warm_started, info.fell_back, info.warm_taken, info.warm_moved), (1, 1, GSENC_WARM_TAKEN_NONE, 0));
        for (taken, code, moved) in [(WarmTaken::Kept, GSENC_WARM_TAKEN_KEPT, 0), (WarmTaken::Repaired, GSENC_WARM_TAKEN_REPAIRED, 17), (WarmTaken::Fresh, GSENC_WARM_TAKEN_FRESH, 3)] {
            meta.warm = Some(WarmRecord { taken, moved });
            let info = info_of(&meta);
            assert_eq!((info.warm_taken, info.warm_moved), (code, moved), "{taken:?}");
        }
        (meta.time, meta.encode_psnr, meta.fell_back, meta.schedule) = (None, None, None, "matched".into());
        let info = info_of(&meta);
        assert!(info.time.is_nan() && info.encode_psnr.is_nan(), "time {}, PSNR {}", info.time, info.encode_psnr);
        assert_eq!((info.warm_started, info.fell_back), (0, 0));
    }
}
