//! Seeded random walks over the whole C API, as a careless or unlucky host
//! might call it: encoders made from perturbed configs (unknown enum
//! values, zero and huge budgets, dims, queue sizes and thread counts,
//! folders that do not exist, a struct too small), pushes of grids,
//! particles and cells with NaN, infinities, zero extents, unknown dtypes,
//! negative smoothing lengths and connectivity past the points, steps out
//! of order, handles destroyed, destroyed twice, of the other kind or
//! foreign, models read back from their bytes whole, cut short or with a
//! byte changed, decodes and evaluations at odd sizes and at NaN points,
//! resumes, waits, polls and cancels in any order. Now and then an encoder
//! asks for the GPU backend: without a hardware GPU that is a device error
//! at create, unless `GSENC_ADAPTER=llvmpipe` is set for the run, which
//! puts those encoders on Mesa's software adapter (11,600 walks clean so).
//!
//! Nothing is expected of a call but what the header promises of every
//! call: no panic reaches the caller (`GSENC_STATUS_INTERNAL` fails the
//! walk), a failure leaves a message, a named status, and what the library
//! answered is sound: the bytes it gives for a model read back as a model
//! of that field, a model it wrote reads back, a decode and an evaluation
//! at finite points give finite values, a poll a known state, a foreign or
//! wrong-kind handle `GSENC_STATUS_INVALID_ARGUMENT`. A walk that stops
//! moving for two minutes (a call that never returns) aborts the run,
//! naming its seed.
//!
//! The walks found three faults: a lattice of [1, 2^32 - 1, 1] accepted
//! at create whose first deposit aborted the process (a failed 34 GB
//! allocation; the deposit now checks what it needs first), a failure
//! whose message named its field and step twice, and one that called a
//! handle "a encoder". This file holds the walk and what it requires of
//! every answer; `inputs.rs` what it hands over; `calls.rs` one function a
//! call, with what it requires of that call's answer.
//!
//! `GSENC_CAPI_WALKS` sets the number of walks (default 150 of 60 calls,
//! about 6 s on two cores) and `GSENC_CAPI_WALK_SEED` the first seed
//! (default 1): the same seeds make the same calls (what a call answers may
//! still depend on timing: a full queue). A failure names its seed and the
//! calls that led to it; `GSENC_CAPI_WALK_TRACE=1` prints every call with
//! its answer.

mod calls;
mod inputs;

use crate::common::Draws as Rng;
use crate::encoder::{gsenc_encoder, gsenc_encoder_destroy};
use crate::handles::{is_live, Kind};
use crate::model::{gsenc_model, gsenc_model_destroy};
use crate::status::{gsenc_status, gsenc_status_string, last_error_text};
use std::collections::BTreeMap;
use std::ffi::{CStr, CString};
use std::path::PathBuf;
use std::ptr::null_mut;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Calls in one walk.
const CALLS: usize = 60;
/// Walks in a run, unless `GSENC_CAPI_WALKS` says.
const WALKS: u64 = 150;

/// What the walk made and still knows of.
struct World {
    dir: PathBuf,
    encoders: Made<gsenc_encoder>,
    models: Made<gsenc_model>,
    /// Model files the library wrote, to read again.
    files: Vec<CString>,
    /// Model bytes the library gave, to read again whole or damaged.
    bytes: Vec<Vec<u8>>,
    /// The next step to push (most pushes follow it, whatever the field).
    next_step: u64,
    /// The steps pushed (field, step), for polls.
    pushed: Vec<(&'static str, u64)>,
    /// The calls so far, for a failure's message.
    log: Vec<String>,
    seed: u64,
    /// Per call, how often it succeeded.
    oks: BTreeMap<String, usize>,
    /// Print every call and its answer (`GSENC_CAPI_WALK_TRACE`).
    trace: bool,
}

const FIELDS: [&str; 4] = ["rho", "T", "", "a/b"];

/// The handles of one kind a walk made: every one (a destroyed one stays,
/// to be passed again) and those it has not destroyed. The walk keeps its
/// own account: other tests of this crate make handles beside it, and one
/// of theirs may sit at the address of one the walk destroyed.
struct Made<T> {
    all: Vec<*mut T>,
    live: Vec<*mut T>,
}

impl<T> Made<T> {
    fn new() -> Self {
        Made { all: Vec::new(), live: Vec::new() }
    }

    fn add(&mut self, p: *mut T) {
        self.all.push(p);
        self.live.push(p);
    }

    /// `p` was passed to this kind's destroy.
    fn destroyed(&mut self, p: *mut T) {
        self.live.retain(|&q| q != p);
    }
}

/// A handle of `made`'s kind to pass: mostly a live one, sometimes one
/// destroyed already, NULL, a live one of `others` (the other kind) or a
/// foreign pointer. Also says whether the library must refuse it as not of
/// this kind (a destroyed handle's address may have been reused by a new
/// one, so only a live one of the other kind and the foreign pointer are
/// sure to be refused). A destroyed one whose address is live again, as
/// another's handle, is not passed (NULL instead): it is not the walk's.
fn pick_handle<T, U>(rng: &mut Rng, made: &Made<T>, others: &Made<U>, foreign: *mut u64) -> (*mut T, bool) {
    match rng.below(40) {
        0 => (null_mut(), false),
        1 => (foreign.cast(), true),
        2 if !others.live.is_empty() => (others.live[rng.below(others.live.len())].cast(), true),
        3 | 4 if !made.all.is_empty() => {
            let p = made.all[rng.below(made.all.len())];
            let taken = [Kind::Encoder, Kind::Model].into_iter().any(|k| is_live(p.cast_const(), k));
            (if taken && !made.live.contains(&p) { null_mut() } else { p }, false)
        }
        _ if !made.live.is_empty() => (made.live[rng.below(made.live.len())], false),
        _ => (null_mut(), false),
    }
}

impl World {
    /// Checks what every call promises: no panic, a failure's message and
    /// a named status. Returns `status == Ok`.
    #[track_caller]
    fn answered(&mut self, status: gsenc_status, call: String) -> bool {
        self.log.push(format!("{call} -> {status:?}"));
        if self.trace {
            eprintln!("walk {}: {call} -> {status:?}: {}", self.seed, last_error_text());
        }
        let name = unsafe { CStr::from_ptr(gsenc_status_string(status as i32)) }.to_string_lossy().into_owned();
        let message = last_error_text();
        self.require(status != gsenc_status::Internal, &format!("a panic reached the caller: {message}"));
        self.require(name != "GSENC_STATUS_UNKNOWN", "a status without a name");
        if status != gsenc_status::Ok {
            self.require(!message.is_empty(), "a failure without a message");
            let parts: Vec<&str> = message.split(": ").collect();
            self.require(parts.windows(2).all(|w| w[0] != w[1]), &format!("a message says a part of it twice: {message}"));
            self.require(!message.contains(" a encoder"), &format!("a message says 'a encoder': {message}"));
        } else {
            let name = call.split('(').next().unwrap_or_default().to_owned();
            *self.oks.entry(name).or_default() += 1;
        }
        status == gsenc_status::Ok
    }

    #[track_caller]
    fn require(&self, ok: bool, what: &str) {
        if !ok {
            let last: Vec<&String> = self.log.iter().rev().take(12).collect();
            panic!("walk seed {}: {what}\nthe last calls, newest first:\n  {}", self.seed, last.iter().map(|s| s.as_str()).collect::<Vec<_>>().join("\n  "));
        }
    }

    /// An encoder handle to pass, and whether the library must refuse it
    /// as not an encoder ([`pick_handle`]).
    fn encoder(&self, rng: &mut Rng, foreign: *mut u64) -> (*mut gsenc_encoder, bool) {
        pick_handle(rng, &self.encoders, &self.models, foreign)
    }

    /// A model handle to pass, as [`Self::encoder`].
    fn model(&self, rng: &mut Rng, foreign: *mut u64) -> (*mut gsenc_model, bool) {
        pick_handle(rng, &self.models, &self.encoders, foreign)
    }

    fn field(&self, rng: &mut Rng) -> (CString, &'static str) {
        let name = if rng.chance(0.8) { FIELDS[rng.below(2)] } else { rng.pick(&FIELDS) };
        (CString::new(name).unwrap(), name)
    }

    fn step(&mut self, rng: &mut Rng) -> u64 {
        if rng.chance(0.85) {
            self.next_step += 1;
            self.next_step
        } else {
            rng.next() % 4
        }
    }
}

/// Sets its flag when dropped, as a walk ends or fails.
struct SetOnDrop(Arc<AtomicBool>);

impl Drop for SetOnDrop {
    fn drop(&mut self) {
        self.0.store(true, Ordering::Relaxed);
    }
}

#[test]
fn random_walks_over_the_c_api_keep_every_promise() {
    let walks: u64 = std::env::var("GSENC_CAPI_WALKS").ok().and_then(|s| s.parse().ok()).unwrap_or(WALKS);
    let first: u64 = std::env::var("GSENC_CAPI_WALK_SEED").ok().and_then(|s| s.parse().ok()).unwrap_or(1);
    let root = std::env::temp_dir().join(format!("gsenc-walk-{}", std::process::id()));
    // The watchdog: a call that never returns stops the run, naming its
    // walk. It ends with the walks, a failed one too (the crate's other
    // tests run on in the same process, for as long as they take).
    let moved = Arc::new(AtomicU64::new(0));
    let seed_now = Arc::new(AtomicU64::new(first));
    let done = Arc::new(AtomicBool::new(false));
    let start = Instant::now();
    let watchdog = {
        let (moved, seed_now, done) = (moved.clone(), seed_now.clone(), done.clone());
        std::thread::spawn(move || {
            while !done.load(Ordering::Relaxed) {
                std::thread::sleep(Duration::from_millis(200));
                let last = moved.load(Ordering::Relaxed);
                if !done.load(Ordering::Relaxed) && start.elapsed().as_secs() > last + 120 {
                    eprintln!("walk seed {}: no call returned for two minutes", seed_now.load(Ordering::Relaxed));
                    std::process::abort();
                }
            }
        })
    };
    let ends_the_watchdog = SetOnDrop(done.clone());
    let mut oks: BTreeMap<String, usize> = BTreeMap::new();
    let trace = std::env::var_os("GSENC_CAPI_WALK_TRACE").is_some();
    for seed in first..first + walks {
        seed_now.store(seed, Ordering::Relaxed);
        let dir = root.join(seed.to_string());
        std::fs::create_dir_all(&dir).unwrap();
        let mut world = World { dir, encoders: Made::new(), models: Made::new(), files: Vec::new(), bytes: Vec::new(), next_step: 0, pushed: Vec::new(), log: Vec::new(), seed, oks: BTreeMap::new(), trace };
        let mut rng = Rng::new(seed);
        let mut strings = Vec::new();
        for _ in 0..CALLS {
            // SAFETY: every pointer the walk passes is NULL, a handle the
            // library gave (live or destroyed), a live handle of the other
            // kind, the address of a local, or an array the walk sized for
            // what the call reads.
            unsafe { calls::call(&mut rng, &mut world, &mut strings) };
            moved.store(start.elapsed().as_secs(), Ordering::Relaxed);
        }
        // SAFETY: handles the library gave; destroyed ones are ignored.
        unsafe {
            world.encoders.live.iter().for_each(|&e| gsenc_encoder_destroy(e));
            world.models.live.iter().for_each(|&m| gsenc_model_destroy(m));
        }
        moved.store(start.elapsed().as_secs(), Ordering::Relaxed);
        for (call, n) in world.oks {
            *oks.entry(call).or_default() += n;
        }
    }
    drop(ends_the_watchdog);
    watchdog.join().unwrap();
    let _ = std::fs::remove_dir_all(&root);
    // The walks reached what they are for: each call that makes or reads
    // a model succeeded somewhere (else they test only refusals). Asked of
    // the default walks or more; fewer may not reach every call.
    eprintln!("{walks} walks of {CALLS} calls in {:.1} s; successes: {oks:?}", start.elapsed().as_secs_f64());
    for call in ["create", "push_grid", "push_particles", "push_cells", "wait", "poll", "model_bytes", "read_buffer", "write_model", "model_read", "decode", "evaluate", "info_get", "resume"] {
        assert!(walks < WALKS || oks.get(call).is_some_and(|&n| n > 0), "no walk made a successful {call}: {oks:?}");
    }
}
