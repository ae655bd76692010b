//! Handles used from several threads at once: an encoder's calls run one
//! at a time, a destroy waits for the calls in flight, and a model is not
//! freed under a decode. Each order is checked by what the later call saw:
//! without the handles' locks the poll below sees the step still running,
//! and the destroy returns while the decode has not yet written its
//! values.

use crate::common;
use crate::config::{gsenc_config, gsenc_config_init, GSENC_SCHEDULE_SHORT};
use crate::encoder::*;
use crate::inputs::{f32_grid, gsenc_push_grid};
use crate::jobs::*;
use crate::model::*;
use crate::status::gsenc_status;
use common::blobs;
use std::ffi::CString;
use std::sync::Barrier;
use std::time::{Duration, Instant};

const DIMS: [usize; 3] = [14, 12, 10];

/// A raw pointer that may cross threads (the C caller's view of a handle).
struct Handle<T>(*mut T);
impl<T> Clone for Handle<T> {
    fn clone(&self) -> Self {
        *self
    }
}
impl<T> Copy for Handle<T> {}
impl<T> Handle<T> {
    /// The pointer (a method, so that a closure captures the whole handle).
    fn get(self) -> *mut T {
        self.0
    }
}
// SAFETY: handles are meant to be passed between the caller's threads.
unsafe impl<T> Send for Handle<T> {}
unsafe impl<T> Sync for Handle<T> {}

fn encoder(budget: u64, iterations: u32) -> Handle<gsenc_encoder> {
    unsafe {
        let mut cfg: gsenc_config = std::mem::zeroed();
        cfg.struct_size = std::mem::size_of::<gsenc_config>();
        assert_eq!(gsenc_config_init(&mut cfg), gsenc_status::Ok);
        cfg.budget = budget;
        cfg.schedule = GSENC_SCHEDULE_SHORT;
        cfg.iterations = iterations;
        cfg.warm_iterations = iterations / 2;
        cfg.points = 256;
        cfg.backend = crate::config::GSENC_BACKEND_CPU;
        let mut enc = std::ptr::null_mut();
        assert_eq!(gsenc_encoder_create(&cfg, &mut enc), gsenc_status::Ok);
        Handle(enc)
    }
}

fn push(enc: Handle<gsenc_encoder>, field: &str, step: u64) -> gsenc_status {
    let g = blobs(DIMS, 40 + step + 7 * field.len() as u64, 3);
    let field = CString::new(field).unwrap();
    let grid = f32_grid(&g.values, DIMS, 0.1);
    unsafe { gsenc_push_grid(enc.get(), field.as_ptr(), step, step as f64, &grid) }
}

fn model_bytes(enc: Handle<gsenc_encoder>, field: &str) -> Vec<u8> {
    let field = CString::new(field).unwrap();
    unsafe {
        let mut size = 0;
        assert_eq!(gsenc_encoder_model_bytes(enc.get(), field.as_ptr(), std::ptr::null_mut(), 0, &mut size), gsenc_status::Ok);
        let mut bytes = vec![0u8; size];
        assert_eq!(gsenc_encoder_model_bytes(enc.get(), field.as_ptr(), bytes.as_mut_ptr(), size, &mut size), gsenc_status::Ok);
        bytes
    }
}

const FIELDS: [&str; 4] = ["rho", "temp", "pressure", "vx"];

#[test]
fn pushes_from_several_threads_give_the_models_of_pushes_from_one() {
    // One thread: every field's steps in turn.
    let serial = encoder(30, 30);
    for step in 0..2 {
        for f in FIELDS {
            assert_eq!(push(serial, f, step), gsenc_status::Ok);
        }
    }
    assert_eq!(unsafe { gsenc_wait(serial.get(), std::ptr::null()) }, gsenc_status::Ok);
    // A thread a field, all at once (as from an OpenMP loop over fields),
    // each also waiting for its own field and reading its model.
    let shared = encoder(30, 30);
    let start = Barrier::new(FIELDS.len());
    let models: Vec<Vec<u8>> = std::thread::scope(|s| {
        let threads: Vec<_> = FIELDS
            .iter()
            .map(|&f| {
                let start = &start;
                s.spawn(move || {
                    start.wait();
                    let name = CString::new(f).unwrap();
                    for step in 0..2 {
                        assert_eq!(push(shared, f, step), gsenc_status::Ok);
                        assert_eq!(unsafe { gsenc_wait(shared.get(), name.as_ptr()) }, gsenc_status::Ok);
                    }
                    model_bytes(shared, f)
                })
            })
            .collect();
        threads.into_iter().map(|t| t.join().unwrap()).collect()
    });
    for (f, m) in FIELDS.iter().zip(&models) {
        assert_eq!(*m, model_bytes(serial, f), "field {f}");
    }
    unsafe {
        gsenc_encoder_destroy(serial.get());
        gsenc_encoder_destroy(shared.get());
    }
}

/// Runs `long` on another thread and, once it holds `handle` (or after
/// `give_up` ms), `then` here; returns what each returned.
fn beside<T, A: Send, B>(handle: Handle<T>, give_up: u64, long: impl FnOnce() -> A + Send, then: impl FnOnce() -> B) -> (A, B) {
    std::thread::scope(|s| {
        let t = s.spawn(long);
        // Without the handles' locks nothing is ever held: then `then`
        // starts after `give_up`, inside the long call (which takes longer).
        let give_up = Instant::now() + Duration::from_millis(give_up);
        while !crate::handles::held(handle.get()) && Instant::now() < give_up {
            std::thread::sleep(Duration::from_micros(200));
        }
        let b = then();
        (t.join().unwrap(), b)
    })
}

#[test]
fn a_poll_beside_a_wait_runs_after_it() {
    // An encode of a few seconds here (more than `beside` gives up after).
    let enc = encoder(800, 6000);
    assert_eq!(push(enc, "rho", 0), gsenc_status::Ok);
    let field = CString::new("rho").unwrap();
    let (waited, (polled, state)) = beside(
        enc,
        1500,
        || unsafe { gsenc_wait(enc.get(), field.as_ptr()) },
        || unsafe {
            let mut job: gsenc_job = std::mem::zeroed();
            job.struct_size = std::mem::size_of::<gsenc_job>();
            let st = gsenc_poll(enc.get(), field.as_ptr(), 0, &mut job);
            (st, job.state)
        },
    );
    assert_eq!(waited, gsenc_status::Ok);
    assert_eq!(polled, gsenc_status::Ok);
    // The poll waited for the wait, so it saw the step done.
    assert_eq!(state, GSENC_JOB_DONE, "the poll ran beside the wait");
    unsafe { gsenc_encoder_destroy(enc.get()) };
}

#[test]
fn a_destroy_beside_a_wait_waits_for_it_and_later_calls_fail() {
    let enc = encoder(400, 3000);
    assert_eq!(push(enc, "rho", 0), gsenc_status::Ok);
    let field = CString::new("rho").unwrap();
    let (waited, ()) = beside(enc, 1500, || unsafe { gsenc_wait(enc.get(), field.as_ptr()) }, || unsafe { gsenc_encoder_destroy(enc.get()) });
    assert_eq!(waited, gsenc_status::Ok);
    assert_eq!(unsafe { gsenc_wait(enc.get(), field.as_ptr()) }, gsenc_status::InvalidArgument);
    assert_eq!(push(enc, "rho", 1), gsenc_status::InvalidArgument);
}

#[test]
fn a_model_is_not_freed_under_a_decode() {
    // A model whose decode onto a fine lattice takes a while (here about
    // a second).
    let enc = encoder(400, 60);
    assert_eq!(push(enc, "rho", 0), gsenc_status::Ok);
    assert_eq!(unsafe { gsenc_wait(enc.get(), std::ptr::null()) }, gsenc_status::Ok);
    let bytes = model_bytes(enc, "rho");
    unsafe { gsenc_encoder_destroy(enc.get()) };
    let mut raw = std::ptr::null_mut();
    assert_eq!(unsafe { gsenc_model_read_buffer(bytes.as_ptr(), bytes.len(), &mut raw) }, gsenc_status::Ok);
    let model = Handle(raw);
    let dims = [224u64, 192, 160];
    let n = dims.iter().product::<u64>() as usize;
    let mut out = vec![f32::NAN; n];
    let out_at = Handle(out.as_mut_ptr());
    let (decoded, unwritten) = beside(
        model,
        200,
        || unsafe { gsenc_model_decode(model.get(), dims.as_ptr(), out_at.get(), n as u64) },
        || unsafe {
            gsenc_model_destroy(model.get());
            // The decode held the model until it had written every value,
            // so none is left unwritten once the destroy returns.
            (0..n).filter(|&i| std::ptr::read_volatile(out_at.get().add(i)).is_nan()).count()
        },
    );
    if decoded == gsenc_status::InvalidArgument {
        // The decode had not reached the model in 200 ms (a loaded
        // machine): it found the model destroyed and wrote nothing.
        assert_eq!(unwritten, n);
    } else {
        assert_eq!(decoded, gsenc_status::Ok);
        assert_eq!(unwritten, 0, "the destroy returned while the decode had {unwritten} of {n} values to write");
        assert!(out.iter().all(|v| v.is_finite()));
    }
    let mut info: gsenc_model_info = unsafe { std::mem::zeroed() };
    info.struct_size = std::mem::size_of::<gsenc_model_info>();
    assert_eq!(unsafe { gsenc_model_info_get(model.get(), &mut info) }, gsenc_status::InvalidArgument);
}
