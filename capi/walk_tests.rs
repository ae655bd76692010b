//! Seeded random walks over the whole C API, as a careless or unlucky host
//! might call it: encoders made from perturbed configs (unknown enum
//! values, zero and huge budgets, dims, queue sizes and thread counts,
//! folders that do not exist, a struct too small), pushes of grids,
//! particles and cells with NaN, infinities, zero extents, unknown dtypes,
//! negative smoothing lengths and connectivity past the points, steps out
//! of order, handles destroyed, destroyed twice, of the other kind or
//! foreign, models read back from their bytes whole, cut short or with a
//! byte changed, decodes and evaluations at odd sizes and at NaN points,
//! resumes, waits, polls and cancels in any order.
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
//! The walks found two faults: a lattice of [1, 2^32 - 1, 1] accepted at
//! create whose first deposit aborted the process (a failed 34 GB
//! allocation; the deposit now checks what it needs first), and a failure
//! whose message named its field and step twice.
//!
//! `GSENC_CAPI_WALKS` sets the number of walks (default 150 of 60 calls,
//! about 6 s on two cores) and `GSENC_CAPI_WALK_SEED` the first seed
//! (default 1): the same seeds make the same calls (what a call answers may
//! still depend on timing: a full queue). A failure names its seed and the
//! calls that led to it; `GSENC_CAPI_WALK_TRACE=1` prints every call with
//! its answer.

use crate::config::*;
use crate::encoder::{gsenc_encoder, gsenc_encoder_create, gsenc_encoder_create_mpi, gsenc_encoder_destroy};
use crate::handles::{is_live, Kind};
use crate::inputs::*;
use crate::jobs::*;
use crate::model::*;
use crate::resume::{gsenc_encoder_resume, gsenc_encoder_resume_stored};
use crate::status::{gsenc_status, gsenc_status_string, last_error_text};
use crate::{GSENC_DTYPE_FLOAT32, GSENC_DTYPE_FLOAT64};
use std::collections::BTreeMap;
use std::ffi::{CStr, CString};
use std::path::PathBuf;
use std::ptr::{null, null_mut};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Calls in one walk.
const CALLS: usize = 60;
/// Walks in a run, unless `GSENC_CAPI_WALKS` says.
const WALKS: u64 = 150;

/// splitmix64: the walk's only source of choices.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }
    /// 0..n.
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n as u64) as usize
    }
    /// True with probability `p`.
    fn chance(&mut self, p: f64) -> bool {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64 <= p
    }
    fn unit(&mut self) -> f64 {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }
    fn pick<T: Copy>(&mut self, all: &[T]) -> T {
        all[self.below(all.len())]
    }
}

/// A value as a careless caller might hand it over: mostly ordinary,
/// sometimes not a number, infinite, huge or negative.
fn odd_f64(rng: &mut Rng, ordinary: f64) -> f64 {
    match rng.below(40) {
        0 => f64::NAN,
        1 => f64::INFINITY,
        2 => -ordinary,
        3 => 0.0,
        4 => 1e300,
        _ => ordinary,
    }
}

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

/// A short CPU encode of a few Gaussians, with the fixed range a resume
/// needs or the range of the first step's data.
fn base_config(fixed_range: bool) -> gsenc_config {
    // SAFETY: a plain C struct, all zeros a valid value; then initialised.
    let mut c: gsenc_config = unsafe { std::mem::zeroed() };
    c.struct_size = std::mem::size_of::<gsenc_config>();
    assert_eq!(unsafe { gsenc_config_init(&mut c) }, gsenc_status::Ok);
    (c.budget, c.schedule, c.iterations, c.points, c.backend) = (6, GSENC_SCHEDULE_SHORT, 8, 48, GSENC_BACKEND_CPU);
    c.dims = [6, 5, 4];
    (c.has_bounds, c.bounds_min, c.bounds_max) = (1, [0.0; 3], [1.0; 3]);
    c.threads = 1;
    if fixed_range {
        (c.fixed_range, c.value_min, c.value_max) = (1, -1.0, 3.0);
    }
    c
}

/// A config as a careless caller might fill it: mostly a short CPU encode
/// of a few Gaussians, each setting sometimes out of its range.
fn config(rng: &mut Rng, world: &World, strings: &mut Vec<CString>) -> gsenc_config {
    let mut c = base_config(rng.chance(0.5));
    let changes = if rng.chance(0.5) { 0 } else { 1 + rng.below(2) };
    for _ in 0..changes {
        match rng.below(22) {
            0 => c.budget = rng.pick(&[0, 1, 40, 1 << 40, u64::MAX]),
            1 => c.schedule = rng.pick(&[GSENC_SCHEDULE_MATCHED, GSENC_SCHEDULE_TUNED, -1, 77]),
            2 => c.warm_start = rng.pick(&[GSENC_WARM_OFF, GSENC_WARM_COARSE, GSENC_WARM_DENSE, GSENC_WARM_AUTO, 9]),
            3 => c.iterations = rng.pick(&[0, 1, 3, u32::MAX]),
            4 => c.points = rng.pick(&[0, 1, 7, u32::MAX]),
            5 => c.transform = rng.pick(&[GSENC_TRANSFORM_LINEAR, GSENC_TRANSFORM_LOG10, 5]),
            6 => {
                c.fixed_range = rng.pick(&[0, 1, 2]);
                (c.value_min, c.value_max) = (odd_f64(rng, 0.0), odd_f64(rng, 1.0));
            }
            7 => c.dims = [rng.pick(&[0, 1, 3, 8]), rng.pick(&[1, 4, u32::MAX]), rng.pick(&[1, 5])],
            8 => {
                c.has_bounds = rng.pick(&[0, 1, 3]);
                c.bounds_min = [odd_f64(rng, 0.0), 0.0, -1.0];
                c.bounds_max = [odd_f64(rng, 1.0), 0.0, 1.0];
            }
            9 => c.payload = rng.pick(&[GSENC_PAYLOAD_F32, GSENC_PAYLOAD_8BIT, GSENC_PAYLOAD_8BIT_U16, GSENC_PAYLOAD_PACKED, 12]),
            10 => c.threads = rng.pick(&[0, 2, 100_000]),
            11 => (c.seed_init, c.seed_sample) = (rng.next(), rng.next()),
            12 => c.rank = rng.pick(&[1, u32::MAX]),
            13 => c.support = rng.pick(&[GSENC_SUPPORT_STORED, GSENC_SUPPORT_NONE, 3]),
            14 => {
                let dir = match rng.below(3) {
                    0 => world.dir.join("out").to_str().unwrap().to_owned(),
                    1 => "/nonexistent-gsenc-walk/out".to_owned(),
                    _ => String::new(),
                };
                strings.push(CString::new(dir).unwrap());
                c.output_dir = strings.last().unwrap().as_ptr();
                c.output_format = rng.pick(&[GSENC_OUTPUT_FOLDER, GSENC_OUTPUT_FOLDER, GSENC_OUTPUT_HDF5, 4]);
            }
            15 => c.warm_iterations = rng.pick(&[0, 2, u32::MAX]),
            16 => (c.when_full, c.queue_bytes) = (rng.pick(&[GSENC_QUEUE_BLOCK, GSENC_QUEUE_SKIP, GSENC_QUEUE_BUSY, 8]), rng.pick(&[0, 1, 400, 1 << 20])),
            17 => c.halo = rng.pick(&[1, u32::MAX]),
            18 => (c.backend, c.gpu_index) = (rng.pick(&[GSENC_BACKEND_AUTO, GSENC_BACKEND_CPU, 9]), rng.pick(&[-1, 0, 7])),
            19 => {
                c.preview = rng.pick(&[GSENC_PREVIEW_NONE, GSENC_PREVIEW_SLICE, GSENC_PREVIEW_VOLUME, 6]);
                (c.preview_axis, c.preview_at) = (rng.pick(&[0, 2, 3, -1]), odd_f64(rng, 0.5));
                (c.preview_width, c.preview_height) = (rng.pick(&[0, 8, u32::MAX]), rng.pick(&[8, 1]));
                (c.preview_azimuth, c.preview_elevation) = (odd_f64(rng, 30.0), odd_f64(rng, 20.0));
            }
            20 => c.target_psnr = odd_f64(rng, 30.0),
            _ => {
                strings.push(CString::new(rng.pick(&["0", "0-1", "x", "99999", ""])).unwrap());
                c.encoder_cpus = strings.last().unwrap().as_ptr();
                c.encoder_priority = rng.pick(&[GSENC_PRIORITY_NORMAL, GSENC_PRIORITY_LOW, GSENC_PRIORITY_IDLE, 5]);
            }
        }
    }
    if rng.chance(0.04) {
        c.struct_size = rng.pick(&[0, 8, 64]);
    }
    c
}

/// Values of a smooth field at `n` points, some not numbers or infinite.
fn values(rng: &mut Rng, n: usize) -> Vec<f64> {
    // Now and then constant, huge or below float32's normal range.
    let usual = 1.0 + rng.unit();
    let ordinary = rng.pick(&[usual, usual, usual, 0.0, 1e30, 1e-40]);
    let (scale, offset) = (odd_f64(rng, ordinary), if rng.chance(0.2) { -0.5 } else { 0.1 });
    let spoil = rng.chance(0.15);
    (0..n)
        .map(|i| match spoil && rng.chance(0.1) {
            true => rng.pick(&[f64::NAN, f64::INFINITY, 1e39]),
            false => offset + scale * (0.3 * i as f64).sin().abs(),
        })
        .collect()
}

/// `values` in the dtype the walk chose (`float32`, `float64`, or an
/// unknown one read as `float32`), as bytes that stay where they are.
fn typed(values: &[f64], dtype: i32) -> Vec<u64> {
    let bytes: Vec<u8> = match dtype {
        GSENC_DTYPE_FLOAT64 => values.iter().flat_map(|v| v.to_ne_bytes()).collect(),
        _ => values.iter().flat_map(|&v| (v as f32).to_ne_bytes()).collect(),
    };
    // 8-byte aligned storage.
    bytes.chunks(8).map(|c| {
        let mut w = [0u8; 8];
        w[..c.len()].copy_from_slice(c);
        u64::from_ne_bytes(w)
    }).collect()
}

fn dtype(rng: &mut Rng) -> i32 {
    if rng.chance(0.05) { 9 } else { rng.pick(&[GSENC_DTYPE_FLOAT32, GSENC_DTYPE_FLOAT64]) }
}

/// One call of the walk.
unsafe fn call(rng: &mut Rng, world: &mut World, strings: &mut Vec<CString>) {
    let mut foreign = 0u64;
    let foreign: *mut u64 = &mut foreign;
    match rng.below(27) {
        0 | 1 => {
            let cfg = config(rng, world, strings);
            let mut enc = null_mut();
            // Now and then over MPI, which this process has not started
            // (or this build lacks): refused.
            let mpi = rng.chance(0.05);
            let status = match mpi {
                true => unsafe { gsenc_encoder_create_mpi(&cfg, rng.pick(&[0, 1, -1]), &mut enc) },
                false => unsafe { gsenc_encoder_create(&cfg, &mut enc) },
            };
            let ok = world.answered(status, format!("create(budget {}, dims {:?}, iterations {}, threads {}, mpi {mpi})", cfg.budget, cfg.dims, cfg.iterations, cfg.threads));
            world.require(!mpi || !ok, "an MPI encoder without MPI");
            world.require(ok != enc.is_null(), "a handle without success, or success without one");
            if ok {
                world.encoders.add(enc);
            }
        }
        2..=4 | 19 | 20 => {
            let (enc, alien) = world.encoder(rng, foreign);
            let (field, name) = world.field(rng);
            let step = world.step(rng);
            let dims = [1 + rng.below(6), 1 + rng.below(5), if rng.chance(0.05) { 0 } else { 1 + rng.below(4) }];
            let n: usize = dims.iter().product();
            let pad = rng.chance(0.3) as usize;
            let dt = dtype(rng);
            // Padded rows: strides that skip a ghost value at each row's end.
            let row = dims[0] + pad;
            let vals = values(rng, row * dims[1] * dims[2].max(1));
            let data = typed(&vals, dt);
            let mut g = f32_grid(&vec![0.0; n], dims, odd_f64(rng, 0.1));
            (g.dtype, g.data) = (dt, data.as_ptr().cast());
            if pad == 1 {
                g.strides = [1, row as i64, (row * dims[1]) as i64];
            }
            if rng.chance(0.03) {
                // Rows past any array (with one row, only row 0 is named).
                g.strides = [1, i64::MAX, (row * dims[1]) as i64];
            }
            g.origin = [odd_f64(rng, 0.0), 0.0, 0.0];
            if rng.chance(0.04) {
                g.struct_size = 8;
            }
            let status = unsafe { gsenc_push_grid(enc, field.as_ptr(), step, odd_f64(rng, 0.5), &g) };
            if world.answered(status, format!("push_grid('{name}', {step}, dims {dims:?}, dtype {dt}, pad {pad})")) {
                world.pushed.push((name, step));
            }
            world.require(!alien || status == gsenc_status::InvalidArgument, "a foreign encoder handle was not refused");
        }
        5 => {
            let (enc, alien) = world.encoder(rng, foreign);
            let (field, name) = world.field(rng);
            let step = world.step(rng);
            let count = rng.pick(&[0, 1, 5, 30]);
            let dt = dtype(rng);
            let pos: Vec<f64> = (0..3 * count).map(|_| if rng.chance(0.03) { f64::NAN } else { rng.unit() * 1.4 - 0.2 }).collect();
            let h: Vec<f64> = (0..count).map(|_| odd_f64(rng, 0.2)).collect();
            let (pos_b, h_b, val_b) = (typed(&pos, dt), typed(&h, dt), typed(&values(rng, count), dt));
            let mass_b = typed(&(0..count).map(|_| odd_f64(rng, 1.0)).collect::<Vec<_>>(), dt);
            let mut p: gsenc_particles = unsafe { std::mem::zeroed() };
            p.struct_size = std::mem::size_of::<gsenc_particles>();
            (p.dtype, p.count) = (dt, count as u64);
            (p.positions, p.smoothing_length, p.values) = (pos_b.as_ptr().cast(), h_b.as_ptr().cast(), val_b.as_ptr().cast());
            if rng.chance(0.3) {
                p.mass = mass_b.as_ptr().cast();
            }
            if rng.chance(0.3) {
                (p.position_stride, p.position_component_stride) = (1, count as i64);
            }
            // A stride past any array (refused before anything is read;
            // with one particle it names only element 0).
            if rng.chance(0.03) {
                *[&mut p.value_stride, &mut p.smoothing_length_stride, &mut p.position_stride][rng.below(3)] = i64::MAX;
            }
            let status = unsafe { gsenc_push_particles(enc, field.as_ptr(), step, f64::NAN, &p) };
            if world.answered(status, format!("push_particles('{name}', {step}, {count}, dtype {dt})")) {
                world.pushed.push((name, step));
            }
            world.require(!alien || status == gsenc_status::InvalidArgument, "a foreign encoder handle was not refused");
        }
        6 => {
            let (enc, alien) = world.encoder(rng, foreign);
            let (field, name) = world.field(rng);
            let step = world.step(rng);
            let count = rng.pick(&[0, 1, 4, 12]);
            let dt = dtype(rng);
            let mut c: gsenc_cells = unsafe { std::mem::zeroed() };
            c.struct_size = std::mem::size_of::<gsenc_cells>();
            (c.dtype, c.count) = (dt, count as u64);
            let val_b = typed(&values(rng, count), dt);
            c.values = val_b.as_ptr().cast();
            let centres = typed(&(0..3 * count).map(|_| rng.unit()).collect::<Vec<_>>(), dt);
            let edges = typed(&(0..3 * count).map(|_| odd_f64(rng, 0.25)).collect::<Vec<_>>(), dt);
            let points = typed(&(0..24).map(|i| ((i / 3) >> (i % 3) & 1) as f64 * 0.5 + 0.2).collect::<Vec<_>>(), dt);
            // Eight corners of one hexahedron per cell; now and then an
            // index past the 8 points, or negative.
            let conn: Vec<i64> = (0..8 * count).map(|i| if rng.chance(0.02) { rng.pick(&[8, -1, i64::MAX]) } else { [0, 1, 3, 2, 4, 5, 7, 6][i % 8] }).collect();
            if rng.chance(0.5) {
                c.layout = GSENC_CELLS_BOXES;
                (c.centres, c.edges) = (centres.as_ptr().cast(), edges.as_ptr().cast());
            } else {
                c.layout = if rng.chance(0.05) { 7 } else { GSENC_CELLS_HEXAHEDRA };
                (c.points, c.point_count, c.connectivity) = (points.as_ptr().cast(), 8, conn.as_ptr());
            }
            if rng.chance(0.03) {
                *[&mut c.value_stride, &mut c.centre_stride, &mut c.point_stride][rng.below(3)] = i64::MAX;
            }
            let status = unsafe { gsenc_push_cells(enc, field.as_ptr(), step, 0.0, &c) };
            if world.answered(status, format!("push_cells('{name}', {step}, {count}, layout {}, dtype {dt})", c.layout)) {
                world.pushed.push((name, step));
            }
            world.require(!alien || status == gsenc_status::InvalidArgument, "a foreign encoder handle was not refused");
        }
        7 | 8 => {
            let (enc, _) = world.encoder(rng, foreign);
            let (field, name) = world.field(rng);
            let all = rng.chance(0.5);
            let status = unsafe { gsenc_wait(enc, if all { null() } else { field.as_ptr() }) };
            world.answered(status, format!("wait({})", if all { "all" } else { name }));
        }
        9 => {
            let (enc, _) = world.encoder(rng, foreign);
            let ((field, name), step) = match world.pushed.len() {
                n if n > 0 && rng.chance(0.8) => {
                    let (name, step) = world.pushed[rng.below(n)];
                    ((CString::new(name).unwrap(), name), step)
                }
                _ => (world.field(rng), rng.next() % (world.next_step + 2)),
            };
            let mut job: gsenc_job = unsafe { std::mem::zeroed() };
            job.struct_size = if rng.chance(0.05) { 4 } else { std::mem::size_of::<gsenc_job>() };
            let ok = world.answered(unsafe { gsenc_poll(enc, field.as_ptr(), step, &mut job) }, format!("poll('{name}', {step})"));
            world.require(!ok || (GSENC_JOB_QUEUED..=GSENC_JOB_CANCELLED).contains(&job.state), "a poll gave an unknown state");
        }
        10 => {
            let (enc, _) = world.encoder(rng, foreign);
            let call = rng.below(3);
            let status = match call {
                0 => unsafe { gsenc_encoder_cancel(enc) },
                1 => unsafe { gsenc_encoder_reserve(enc, rng.pick(&[0, 100, 1 << 16, 1 << 62, u64::MAX])) },
                _ => {
                    let (mut step, mut psnr) = (0u64, 0f64);
                    let (field, _) = world.field(rng);
                    unsafe { gsenc_encoder_last_step(enc, field.as_ptr(), &mut step, &mut psnr) }
                }
            };
            world.answered(status, ["cancel", "reserve", "last_step"][call].to_string());
        }
        11 | 21 | 22 => {
            let (enc, _) = world.encoder(rng, foreign);
            let (field, name) = world.field(rng);
            let mut size = 0usize;
            let ok = world.answered(unsafe { gsenc_encoder_model_bytes(enc, field.as_ptr(), null_mut(), 0, &mut size) }, format!("model_bytes('{name}') size"));
            if ok {
                let short = rng.chance(0.1);
                let mut buf = vec![0u8; size];
                let cap = if short { size.saturating_sub(1) } else { size };
                let status = unsafe { gsenc_encoder_model_bytes(enc, field.as_ptr(), buf.as_mut_ptr(), cap, &mut size) };
                let ok = world.answered(status, format!("model_bytes('{name}') into {cap}"));
                // A step that finished since the first call may have
                // changed the model: its size is the second call's.
                world.require(ok == (cap >= size), "a short buffer was not refused, or a whole one was");
                buf.truncate(size);
                if ok {
                    let mut m = null_mut();
                    let read = world.answered(unsafe { gsenc_model_read_buffer(buf.as_ptr(), buf.len(), &mut m) }, "read_buffer(its own bytes)".into());
                    world.require(read, "the bytes the library gave for a model do not read back");
                    let mut len = 0usize;
                    let mut text = [0 as std::ffi::c_char; 64];
                    world.answered(unsafe { gsenc_model_field(m, text.as_mut_ptr(), text.len(), &mut len) }, "field".into());
                    let got = unsafe { CStr::from_ptr(text.as_ptr()) }.to_string_lossy().into_owned();
                    world.require(got == name, &format!("the model of '{name}' says it is of '{got}'"));
                    world.models.add(m);
                    world.bytes.push(buf);
                }
            }
        }
        12 => {
            let (enc, _) = world.encoder(rng, foreign);
            let (field, name) = world.field(rng);
            let to = match rng.below(4) {
                0 => "/nonexistent-gsenc-walk/m.gsm".to_owned(),
                1 => world.dir.to_str().unwrap().to_owned(),
                _ => world.dir.join(format!("m{}.gsm", world.files.len())).to_str().unwrap().to_owned(),
            };
            let path = CString::new(to.clone()).unwrap();
            let ok = world.answered(unsafe { gsenc_encoder_write_model(enc, field.as_ptr(), path.as_ptr()) }, format!("write_model('{name}', {to})"));
            if ok {
                let mut m = null_mut();
                let read = world.answered(unsafe { gsenc_model_read(path.as_ptr(), &mut m) }, format!("model_read({to})"));
                world.require(read, "a model the library wrote does not read back");
                world.models.add(m);
                world.files.push(path);
            }
        }
        13 => {
            // Bytes of a model, whole, cut short, with a byte changed, or
            // none of a model's.
            let mut bytes = match world.bytes.len() {
                0 => (0..rng.below(200)).map(|_| rng.next() as u8).collect(),
                n => world.bytes[rng.below(n)].clone(),
            };
            let how = rng.below(4);
            match how {
                1 if !bytes.is_empty() => bytes.truncate(rng.below(bytes.len())),
                2 if !bytes.is_empty() => {
                    let at = rng.below(bytes.len());
                    bytes[at] ^= 1 << rng.below(8);
                }
                _ => {}
            }
            let mut m = null_mut();
            let ok = world.answered(unsafe { gsenc_model_read_buffer(bytes.as_ptr(), bytes.len(), &mut m) }, format!("read_buffer({} bytes, change {how})", bytes.len()));
            world.require(ok != m.is_null(), "a handle without success, or success without one");
            if ok {
                world.models.add(m);
            }
        }
        14 if !world.files.is_empty() || rng.chance(0.3) => {
            let path = match world.files.len() {
                0 => CString::new("/nonexistent-gsenc-walk/m.gsm").unwrap(),
                n => world.files[rng.below(n)].clone(),
            };
            let mut m = null_mut();
            if world.answered(unsafe { gsenc_model_read(path.as_ptr(), &mut m) }, format!("model_read({path:?})")) {
                world.models.add(m);
            }
        }
        15 | 23 | 24 => {
            let (m, alien) = world.model(rng, foreign);
            let dims: [u64; 3] = [rng.pick(&[0, 1, 3, 7]), rng.pick(&[1, 4, u64::MAX]), rng.pick(&[1, 5, 1 << 40])];
            // The model's own dims, for a NULL `dims`: its info says them.
            let mut info: gsenc_model_info = unsafe { std::mem::zeroed() };
            info.struct_size = std::mem::size_of::<gsenc_model_info>();
            let known = unsafe { gsenc_model_info_get(m, &mut info) } == gsenc_status::Ok;
            let whole = rng.chance(0.2);
            let asked: u128 = match whole {
                true => info.dims.iter().map(|&d| d as u128).product::<u128>() * known as u128,
                false => dims.iter().map(|&d| d as u128).product(),
            };
            // A buffer of what the dims ask, but never of more than 4,096
            // values (then the call must refuse it), and sometimes one more.
            let wrong = rng.chance(0.1);
            let len = asked.min(1 << 12) as usize + wrong as usize;
            let mut out = vec![f32::NAN; len];
            let status = unsafe { gsenc_model_decode(m, if whole { null() } else { dims.as_ptr() }, out.as_mut_ptr(), len as u64) };
            let ok = world.answered(status, format!("decode({}, out_len {len})", if whole { "its dims".to_string() } else { format!("{dims:?}") }));
            world.require(!alien || status == gsenc_status::InvalidArgument, "a foreign model handle was not refused");
            world.require(!ok || len as u128 == asked, "an out_len that is not the dims' was taken");
            world.require(!ok || out.iter().all(|v| v.is_finite()), "a decode gave a value that is not finite");
        }
        16 | 25 => {
            let (m, alien) = world.model(rng, foreign);
            let count = rng.pick(&[0, 1, 9]);
            let spoil = rng.chance(0.2);
            let pts: Vec<f64> = (0..3 * count).map(|_| if spoil && rng.chance(0.3) { rng.pick(&[f64::NAN, 1e308, f64::NEG_INFINITY]) } else { rng.unit() * 8.0 - 1.0 }).collect();
            let mut out = vec![f32::NAN; count];
            let status = unsafe { gsenc_model_evaluate(m, pts.as_ptr(), count as u64, out.as_mut_ptr()) };
            let ok = world.answered(status, format!("evaluate({count}, spoiled {spoil})"));
            world.require(!alien || status == gsenc_status::InvalidArgument, "a foreign model handle was not refused");
            let finite_points = pts.iter().all(|p| p.is_finite());
            world.require(!ok || !finite_points || out.iter().all(|v| v.is_finite()), "an evaluation at finite points gave a value that is not finite");
        }
        17 => {
            let (m, _) = world.model(rng, foreign);
            let mut info: gsenc_model_info = unsafe { std::mem::zeroed() };
            info.struct_size = if rng.chance(0.1) { 8 } else { std::mem::size_of::<gsenc_model_info>() };
            let ok = world.answered(unsafe { gsenc_model_info_get(m, &mut info) }, "info_get".into());
            world.require(!ok || info.count > 0, "a model of no Gaussians");
            let mut len = 0usize;
            let mut text = [0 as std::ffi::c_char; 4];
            let cap = rng.below(5);
            world.answered(unsafe { gsenc_model_field(m, if cap == 0 { null_mut() } else { text.as_mut_ptr() }, cap, &mut len) }, format!("field(buffer {cap})"));
        }
        18 => {
            let (enc, _) = world.encoder(rng, foreign);
            if rng.chance(0.5) {
                // Mostly into an encoder made for it, as a restarted run
                // makes one.
                let enc = match world.models.live.is_empty() || rng.chance(0.3) {
                    true => enc,
                    false => {
                        let cfg = base_config(true);
                        let mut fresh = null_mut();
                        let made = world.answered(unsafe { gsenc_encoder_create(&cfg, &mut fresh) }, "create(for a resume)".into());
                        world.require(made, "the base config was refused");
                        world.encoders.add(fresh);
                        fresh
                    }
                };
                let (m, _) = world.model(rng, foreign);
                world.answered(unsafe { gsenc_encoder_resume(enc, m) }, "resume".into());
            } else {
                let (field, name) = world.field(rng);
                let step = rng.next() % (world.next_step + 2);
                world.answered(unsafe { gsenc_encoder_resume_stored(enc, field.as_ptr(), step) }, format!("resume_stored('{name}', {step})"));
            }
        }
        _ => {
            // Destroys: an encoder (drained) or a model, maybe destroyed
            // already, maybe NULL or foreign (both ignored).
            if rng.chance(0.5) {
                let (enc, _) = world.encoder(rng, foreign);
                unsafe { gsenc_encoder_destroy(enc) };
                world.encoders.destroyed(enc);
                world.log.push("encoder_destroy".into());
            } else {
                let (m, _) = world.model(rng, foreign);
                unsafe { gsenc_model_destroy(m) };
                world.models.destroyed(m);
                world.log.push("model_destroy".into());
            }
        }
    }
}

#[test]
fn random_walks_over_the_c_api_keep_every_promise() {
    let walks: u64 = std::env::var("GSENC_CAPI_WALKS").ok().and_then(|s| s.parse().ok()).unwrap_or(WALKS);
    let first: u64 = std::env::var("GSENC_CAPI_WALK_SEED").ok().and_then(|s| s.parse().ok()).unwrap_or(1);
    let root = std::env::temp_dir().join(format!("gsenc-walk-{}", std::process::id()));
    // The watchdog: a call that never returns stops the run, naming its walk.
    let moved = Arc::new(AtomicU64::new(0));
    let seed_now = Arc::new(AtomicU64::new(first));
    let start = Instant::now();
    {
        let (moved, seed_now) = (moved.clone(), seed_now.clone());
        std::thread::spawn(move || loop {
            std::thread::sleep(Duration::from_secs(5));
            let last = moved.load(Ordering::Relaxed);
            if start.elapsed().as_secs() > last + 120 {
                eprintln!("walk seed {}: no call returned for two minutes", seed_now.load(Ordering::Relaxed));
                std::process::abort();
            }
        });
    }
    let mut oks: BTreeMap<String, usize> = BTreeMap::new();
    let trace = std::env::var_os("GSENC_CAPI_WALK_TRACE").is_some();
    for seed in first..first + walks {
        seed_now.store(seed, Ordering::Relaxed);
        let dir = root.join(seed.to_string());
        std::fs::create_dir_all(&dir).unwrap();
        let mut world = World { dir, encoders: Made::new(), models: Made::new(), files: Vec::new(), bytes: Vec::new(), next_step: 0, pushed: Vec::new(), log: Vec::new(), seed, oks: BTreeMap::new(), trace };
        let mut rng = Rng(seed.wrapping_mul(0x2545_f491_4f6c_dd1d));
        let mut strings = Vec::new();
        for _ in 0..CALLS {
            // SAFETY: every pointer the walk passes is NULL, a handle the
            // library gave (live or destroyed), a live handle of the other
            // kind, the address of a local, or an array the walk sized for
            // what the call reads.
            unsafe { call(&mut rng, &mut world, &mut strings) };
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
    let _ = std::fs::remove_dir_all(&root);
    // The walks reached what they are for: each call that makes or reads
    // a model succeeded somewhere (else they test only refusals). Asked of
    // the default walks or more; fewer may not reach every call.
    eprintln!("{walks} walks of {CALLS} calls in {:.1} s; successes: {oks:?}", start.elapsed().as_secs_f64());
    for call in ["create", "push_grid", "push_particles", "push_cells", "wait", "poll", "model_bytes", "read_buffer", "write_model", "model_read", "decode", "evaluate", "info_get", "resume"] {
        assert!(walks < WALKS || oks.get(call).is_some_and(|&n| n > 0), "no walk made a successful {call}: {oks:?}");
    }
}
