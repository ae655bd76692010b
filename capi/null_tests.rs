//! Every required pointer of every C entry point, NULL in turn with the
//! others valid: `GSENC_STATUS_NULL_POINTER` and a message that names the
//! function, never a crash; and the pointers the header lets be NULL
//! (an optional mass, every field's wait, a size query) accepted.

use crate::config::{gsenc_config, gsenc_config_init, GSENC_BACKEND_CPU, GSENC_SCHEDULE_SHORT};
use crate::encoder::{gsenc_encoder, gsenc_encoder_create, gsenc_encoder_destroy};
use crate::inputs::*;
use crate::jobs::*;
use crate::model::*;
use crate::resume::{gsenc_encoder_resume, gsenc_encoder_resume_stored};
use crate::status::{gsenc_status, last_error_text as last_error};
use crate::GSENC_DTYPE_FLOAT32;
use std::ffi::{c_void, CString};
use std::ptr::{null, null_mut};

/// `status` is `NULL_POINTER` and the thread's last error names `function`.
#[track_caller]
fn refused(status: gsenc_status, function: &str) {
    assert_eq!(status, gsenc_status::NullPointer, "{function}: {}", last_error());
    let e = last_error();
    assert!(e.contains(function) && e.contains("NULL"), "{function}: the message is '{e}'");
}

/// A valid config of a short CPU encode of 8 Gaussians.
fn config() -> gsenc_config {
    // SAFETY: a plain C struct, all zeros a valid value; then initialised.
    let mut cfg: gsenc_config = unsafe { std::mem::zeroed() };
    cfg.struct_size = std::mem::size_of::<gsenc_config>();
    // SAFETY: the test's own config.
    assert_eq!(unsafe { gsenc_config_init(&mut cfg) }, gsenc_status::Ok);
    (cfg.budget, cfg.schedule, cfg.iterations, cfg.points, cfg.backend) = (8, GSENC_SCHEDULE_SHORT, 10, 64, GSENC_BACKEND_CPU);
    cfg
}

#[test]
fn every_required_pointer_null_is_refused_by_name() {
    let dir = std::env::temp_dir().join(format!("gsenc-null-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let cfg = config();
    let field = CString::new("rho").unwrap();
    let path = CString::new(dir.join("rho.gsm").to_str().unwrap()).unwrap();
    let values: Vec<f32> = (0..120).map(|i| (i % 7) as f32 / 7.0).collect();
    let grid = f32_grid(&values, [6, 5, 4], 0.1);
    // SAFETY: every pointer below is NULL or the test's own live value.
    unsafe {
        refused(gsenc_config_init(null_mut()), "gsenc_config_init");
        let mut enc: *mut gsenc_encoder = null_mut();
        refused(gsenc_encoder_create(null(), &mut enc), "gsenc_encoder_create");
        refused(gsenc_encoder_create(&cfg, null_mut()), "gsenc_encoder_create");
        assert_eq!(gsenc_encoder_create(&cfg, &mut enc), gsenc_status::Ok);
        let f = field.as_ptr();

        // Pushes: the handle, the field name, the description, its arrays.
        refused(gsenc_push_grid(null_mut(), f, 0, 0.0, &grid), "gsenc_push_grid");
        refused(gsenc_push_grid(enc, null(), 0, 0.0, &grid), "gsenc_push_grid");
        refused(gsenc_push_grid(enc, f, 0, 0.0, null()), "gsenc_push_grid");
        refused(gsenc_push_grid(enc, f, 0, 0.0, &gsenc_grid { data: null(), ..grid }), "gsenc_push_grid");
        refused(gsenc_encoder_reserve(null_mut(), 64), "gsenc_encoder_reserve");
        let pos: Vec<f32> = (0..30).map(|i| ((i * 7) % 11) as f32 / 11.0).collect();
        let h = [0.2f32; 10];
        let val: Vec<f32> = (0..10).map(|i| 1.0 + i as f32).collect();
        let mut parts: gsenc_particles = std::mem::zeroed();
        parts.struct_size = std::mem::size_of::<gsenc_particles>();
        (parts.dtype, parts.count) = (GSENC_DTYPE_FLOAT32, 10);
        (parts.positions, parts.smoothing_length, parts.values) = (pos.as_ptr().cast(), h.as_ptr().cast(), val.as_ptr().cast());
        let pf = CString::new("tracer").unwrap();
        refused(gsenc_push_particles(null_mut(), pf.as_ptr(), 0, 0.0, &parts), "gsenc_push_particles");
        refused(gsenc_push_particles(enc, pf.as_ptr(), 0, 0.0, null()), "gsenc_push_particles");
        for which in 0..3 {
            let mut p = parts;
            *[&mut p.positions, &mut p.smoothing_length, &mut p.values][which] = null::<c_void>();
            refused(gsenc_push_particles(enc, pf.as_ptr(), 0, 0.0, &p), "gsenc_push_particles");
        }
        let cf = CString::new("cells").unwrap();
        let (centres, edges) = ([0.5f64; 6], [0.25f64; 6]);
        let mut boxes: gsenc_cells = std::mem::zeroed();
        boxes.struct_size = std::mem::size_of::<gsenc_cells>();
        (boxes.dtype, boxes.layout, boxes.count) = (GSENC_DTYPE_FLOAT32, GSENC_CELLS_BOXES, 2);
        (boxes.centres, boxes.edges, boxes.values) = (centres.as_ptr().cast(), edges.as_ptr().cast(), val.as_ptr().cast());
        refused(gsenc_push_cells(null_mut(), cf.as_ptr(), 0, 0.0, &boxes), "gsenc_push_cells");
        refused(gsenc_push_cells(enc, cf.as_ptr(), 0, 0.0, null()), "gsenc_push_cells");
        for which in 0..3 {
            let mut c = boxes;
            *[&mut c.centres, &mut c.edges, &mut c.values][which] = null::<c_void>();
            refused(gsenc_push_cells(enc, cf.as_ptr(), 0, 0.0, &c), "gsenc_push_cells");
        }
        let (points, connectivity) = ([0.0f64; 24], [0i64, 1, 2, 3, 4, 5, 6, 7]);
        let mut hex = boxes;
        (hex.layout, hex.count, hex.centres, hex.edges) = (GSENC_CELLS_HEXAHEDRA, 1, null(), null());
        (hex.points, hex.point_count, hex.connectivity) = (points.as_ptr().cast(), 8, connectivity.as_ptr());
        refused(gsenc_push_cells(enc, cf.as_ptr(), 0, 0.0, &gsenc_cells { points: null(), ..hex }), "gsenc_push_cells");
        refused(gsenc_push_cells(enc, cf.as_ptr(), 0, 0.0, &gsenc_cells { connectivity: null(), ..hex }), "gsenc_push_cells");

        // Nothing refused above was queued: the field's first step is 0.
        assert_eq!(gsenc_push_grid(enc, f, 0, 0.0, &grid), gsenc_status::Ok);
        parts.mass = null(); // optional: equal masses
        assert_eq!(gsenc_push_particles(enc, pf.as_ptr(), 0, 0.0, &parts), gsenc_status::Ok);
        refused(gsenc_wait(null_mut(), f), "gsenc_wait");
        assert_eq!(gsenc_wait(enc, null()), gsenc_status::Ok, "{}", last_error()); // every field

        // Jobs and models of the encoder.
        let mut job: gsenc_job = std::mem::zeroed();
        job.struct_size = std::mem::size_of::<gsenc_job>();
        refused(gsenc_poll(null_mut(), f, 0, &mut job), "gsenc_poll");
        refused(gsenc_poll(enc, null(), 0, &mut job), "gsenc_poll");
        refused(gsenc_poll(enc, f, 0, null_mut()), "gsenc_poll");
        refused(gsenc_encoder_write_model(null_mut(), f, path.as_ptr()), "gsenc_encoder_write_model");
        refused(gsenc_encoder_write_model(enc, null(), path.as_ptr()), "gsenc_encoder_write_model");
        refused(gsenc_encoder_write_model(enc, f, null()), "gsenc_encoder_write_model");
        let mut size = 0usize;
        refused(gsenc_encoder_model_bytes(null_mut(), f, null_mut(), 0, &mut size), "gsenc_encoder_model_bytes");
        refused(gsenc_encoder_model_bytes(enc, null(), null_mut(), 0, &mut size), "gsenc_encoder_model_bytes");
        refused(gsenc_encoder_model_bytes(enc, f, null_mut(), 0, null_mut()), "gsenc_encoder_model_bytes");
        assert_eq!(gsenc_encoder_model_bytes(enc, f, null_mut(), 0, &mut size), gsenc_status::Ok); // a size query
        let mut bytes = vec![0u8; size];
        assert_eq!(gsenc_encoder_model_bytes(enc, f, bytes.as_mut_ptr(), size, &mut size), gsenc_status::Ok);
        let (mut step, mut psnr) = (0u64, 0f64);
        refused(gsenc_encoder_last_step(null_mut(), f, &mut step, &mut psnr), "gsenc_encoder_last_step");
        refused(gsenc_encoder_last_step(enc, null(), &mut step, &mut psnr), "gsenc_encoder_last_step");
        refused(gsenc_encoder_last_step(enc, f, null_mut(), &mut psnr), "gsenc_encoder_last_step");
        refused(gsenc_encoder_last_step(enc, f, &mut step, null_mut()), "gsenc_encoder_last_step");
        assert_eq!(gsenc_encoder_write_model(enc, f, path.as_ptr()), gsenc_status::Ok);

        // Models.
        let mut model: *mut gsenc_model = null_mut();
        refused(gsenc_model_read(null(), &mut model), "gsenc_model_read");
        refused(gsenc_model_read(path.as_ptr(), null_mut()), "gsenc_model_read");
        refused(gsenc_model_read_buffer(null(), size, &mut model), "gsenc_model_read_buffer");
        refused(gsenc_model_read_buffer(bytes.as_ptr(), size, null_mut()), "gsenc_model_read_buffer");
        assert_eq!(gsenc_model_read_buffer(bytes.as_ptr(), size, &mut model), gsenc_status::Ok);
        let mut length = 0usize;
        refused(gsenc_model_field(null(), null_mut(), 0, &mut length), "gsenc_model_field");
        refused(gsenc_model_field(model, null_mut(), 0, null_mut()), "gsenc_model_field");
        let mut info: gsenc_model_info = std::mem::zeroed();
        info.struct_size = std::mem::size_of::<gsenc_model_info>();
        refused(gsenc_model_info_get(null(), &mut info), "gsenc_model_info_get");
        refused(gsenc_model_info_get(model, null_mut()), "gsenc_model_info_get");
        let mut out = vec![0f32; 120];
        refused(gsenc_model_decode(null(), null(), out.as_mut_ptr(), 120), "gsenc_model_decode");
        refused(gsenc_model_decode(model, null(), null_mut(), 120), "gsenc_model_decode");
        assert_eq!(gsenc_model_decode(model, null(), out.as_mut_ptr(), 120), gsenc_status::Ok); // its own dims
        let at = [0.1f64, 0.2, 0.1];
        refused(gsenc_model_evaluate(null(), at.as_ptr(), 1, out.as_mut_ptr()), "gsenc_model_evaluate");
        refused(gsenc_model_evaluate(model, null(), 1, out.as_mut_ptr()), "gsenc_model_evaluate");
        refused(gsenc_model_evaluate(model, at.as_ptr(), 1, null_mut()), "gsenc_model_evaluate");

        // Resume, on an encoder that has not begun the field.
        let mut again: *mut gsenc_encoder = null_mut();
        assert_eq!(gsenc_encoder_create(&cfg, &mut again), gsenc_status::Ok);
        refused(gsenc_encoder_resume(null_mut(), model), "gsenc_encoder_resume");
        refused(gsenc_encoder_resume(again, null()), "gsenc_encoder_resume");
        refused(gsenc_encoder_resume_stored(null_mut(), f, 0), "gsenc_encoder_resume_stored");
        refused(gsenc_encoder_resume_stored(again, null(), 0), "gsenc_encoder_resume_stored");
        assert_eq!(gsenc_encoder_resume(again, model), gsenc_status::Ok, "{}", last_error());
        refused(gsenc_encoder_cancel(null_mut()), "gsenc_encoder_cancel");

        gsenc_model_destroy(model);
        gsenc_encoder_destroy(again);
        gsenc_encoder_destroy(enc);
        gsenc_model_destroy(null_mut()); // ignored
        gsenc_encoder_destroy(null_mut()); // ignored
    }
    std::fs::remove_dir_all(&dir).unwrap();
}
