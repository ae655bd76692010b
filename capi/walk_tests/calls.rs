//! The calls of a walk, one function each: what it passes (drawn by the
//! walk's [`Rng`]) and what it requires of the answer beyond what
//! [`World::answered`] requires of every call.

use super::inputs::{base_config, config, dtype, odd_f64, typed, values};
use super::{Rng, World};
use crate::encoder::{gsenc_encoder_create, gsenc_encoder_create_mpi, gsenc_encoder_destroy};
use crate::inputs::*;
use crate::jobs::*;
use crate::model::*;
use crate::resume::{gsenc_encoder_resume, gsenc_encoder_resume_stored};
use crate::status::gsenc_status;
use std::ffi::{CStr, CString};
use std::ptr::{null, null_mut};

/// One call of the walk.
pub(super) unsafe fn call(rng: &mut Rng, world: &mut World, strings: &mut Vec<CString>) {
    let mut foreign = 0u64;
    let foreign: *mut u64 = &mut foreign;
    // SAFETY: as the walk's (mod.rs).
    unsafe {
        match rng.below(28) {
            0 | 1 => create(rng, world, strings),
            2..=4 | 19 | 20 => push_grid(rng, world, foreign),
            5 => push_particles(rng, world, foreign),
            6 => push_cells(rng, world, foreign),
            7 | 8 => wait(rng, world, foreign),
            9 => poll(rng, world, foreign),
            10 => queue_call(rng, world, foreign),
            11 | 21 | 22 => model_bytes(rng, world, foreign),
            12 => write_model(rng, world, foreign),
            13 => read_bytes(rng, world),
            // Without a file written, mostly a destroy instead.
            14 if !world.files.is_empty() || rng.chance(0.3) => read_file(rng, world),
            15 | 23 | 24 => decode(rng, world, foreign),
            16 | 25 => evaluate(rng, world, foreign),
            17 => info(rng, world, foreign),
            18 | 26 => resume(rng, world, foreign),
            _ => destroy(rng, world, foreign),
        }
    }
}

/// A push's answer: the step is the field's when it was queued; a foreign
/// encoder handle must have been refused.
fn pushed(world: &mut World, status: gsenc_status, call: String, (name, step): (&'static str, u64), alien: bool) {
    if world.answered(status, call) {
        world.pushed.push((name, step));
    }
    world.require(!alien || status == gsenc_status::InvalidArgument, "a foreign encoder handle was not refused");
}

/// An encoder from a perturbed config, now and then over MPI.
unsafe fn create(rng: &mut Rng, world: &mut World, strings: &mut Vec<CString>) {
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

/// A grid, contiguous or with ghost values at the rows' ends.
unsafe fn push_grid(rng: &mut Rng, world: &mut World, foreign: *mut u64) {
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
    pushed(world, status, format!("push_grid('{name}', {step}, dims {dims:?}, dtype {dt}, pad {pad})"), (name, step), alien);
}

/// SPH particles, interleaved or in separate x, y, z arrays.
unsafe fn push_particles(rng: &mut Rng, world: &mut World, foreign: *mut u64) {
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
    pushed(world, status, format!("push_particles('{name}', {step}, {count}, dtype {dt})"), (name, step), alien);
}

/// AMR boxes or hexahedra.
unsafe fn push_cells(rng: &mut Rng, world: &mut World, foreign: *mut u64) {
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
    pushed(world, status, format!("push_cells('{name}', {step}, {count}, layout {}, dtype {dt})", c.layout), (name, step), alien);
}

/// `gsenc_wait` for one field or all.
unsafe fn wait(rng: &mut Rng, world: &mut World, foreign: *mut u64) {
    let (enc, _) = world.encoder(rng, foreign);
    let (field, name) = world.field(rng);
    let all = rng.chance(0.5);
    let status = unsafe { gsenc_wait(enc, if all { null() } else { field.as_ptr() }) };
    world.answered(status, format!("wait({})", if all { "all" } else { name }));
}

/// `gsenc_poll` of a pushed step, mostly.
unsafe fn poll(rng: &mut Rng, world: &mut World, foreign: *mut u64) {
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

/// `gsenc_encoder_cancel`, `gsenc_encoder_reserve` or
/// `gsenc_encoder_last_step`.
unsafe fn queue_call(rng: &mut Rng, world: &mut World, foreign: *mut u64) {
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

/// A field's model as bytes, sized then filled, and read back.
unsafe fn model_bytes(rng: &mut Rng, world: &mut World, foreign: *mut u64) {
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

/// A field's model written to a file, and read back.
unsafe fn write_model(rng: &mut Rng, world: &mut World, foreign: *mut u64) {
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

/// Model bytes read back whole, cut short, with a bit changed, or no
/// model's.
unsafe fn read_bytes(rng: &mut Rng, world: &mut World) {
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

/// A model file read again, or a missing one.
unsafe fn read_file(rng: &mut Rng, world: &mut World) {
    let path = match world.files.len() {
        0 => CString::new("/nonexistent-gsenc-walk/m.gsm").unwrap(),
        n => world.files[rng.below(n)].clone(),
    };
    let mut m = null_mut();
    if world.answered(unsafe { gsenc_model_read(path.as_ptr(), &mut m) }, format!("model_read({path:?})")) {
        world.models.add(m);
    }
}

/// `gsenc_model_decode` at odd dims and buffer lengths.
unsafe fn decode(rng: &mut Rng, world: &mut World, foreign: *mut u64) {
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

/// `gsenc_model_evaluate` at world points, some not finite.
unsafe fn evaluate(rng: &mut Rng, world: &mut World, foreign: *mut u64) {
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

/// `gsenc_model_info_get` and `gsenc_model_field`.
unsafe fn info(rng: &mut Rng, world: &mut World, foreign: *mut u64) {
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

/// A resume from a model, or from the encoder's own output.
unsafe fn resume(rng: &mut Rng, world: &mut World, foreign: *mut u64) {
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

/// A destroy: an encoder (drained) or a model, maybe destroyed already,
/// maybe NULL or foreign (both ignored).
unsafe fn destroy(rng: &mut Rng, world: &mut World, foreign: *mut u64) {
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
