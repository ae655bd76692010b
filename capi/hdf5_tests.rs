//! The C API writing an HDF5 store (cargo feature `hdf5`): models are
//! appended at the synchronising calls, on the caller's thread, and read
//! back equal to the encoder's own.

use crate::common;
use crate::config::{gsenc_config, gsenc_config_init, GSENC_OUTPUT_HDF5, GSENC_SCHEDULE_SHORT};
use crate::encoder::*;
use crate::jobs::*;
use crate::status::gsenc_status;
use common::blobs;
use gsenc::io::store::{EntryKey, Store};
use std::ffi::CString;

#[test]
fn the_c_api_appends_every_step_to_an_hdf5_store() {
    let _hdf5 = common::hdf5_serial();
    let dir = common::tmpdir("capi-h5");
    let path = dir.join("run.h5");
    let c_path = CString::new(path.to_str().unwrap()).unwrap();
    let field = CString::new("rho").unwrap();
    unsafe {
        let mut cfg: gsenc_config = std::mem::zeroed();
        cfg.struct_size = std::mem::size_of::<gsenc_config>();
        assert_eq!(gsenc_config_init(&mut cfg), gsenc_status::Ok);
        cfg.budget = 40;
        cfg.schedule = GSENC_SCHEDULE_SHORT;
        cfg.iterations = 40;
        cfg.warm_iterations = 20;
        cfg.points = 256;
        cfg.output_format = GSENC_OUTPUT_HDF5;
        cfg.output_dir = c_path.as_ptr();
        let mut enc = std::ptr::null_mut();
        assert_eq!(gsenc_encoder_create(&cfg, &mut enc), gsenc_status::Ok);
        let dims = [12usize, 10, 8];
        let mut psnr = [0.0; 3];
        for step in 0..3u64 {
            let g = blobs(dims, 90 + step, 3);
            let grid = crate::inputs::f32_grid(&g.values, dims, 0.1);
            assert_eq!(crate::inputs::gsenc_push_grid(enc, field.as_ptr(), step, 0.5 * step as f64, &grid), gsenc_status::Ok);
            assert_eq!(gsenc_wait(enc, field.as_ptr()), gsenc_status::Ok);
            let mut s = 0;
            assert_eq!(gsenc_encoder_last_step(enc, field.as_ptr(), &mut s, &mut psnr[step as usize]), gsenc_status::Ok);
            assert_eq!(s, step);
        }
        // Every step is in the store once the wait returned.
        {
            let store = Store::open_read(&path).unwrap();
            let keys: Vec<u64> = store.entries().unwrap().iter().map(|e| e.key.step).collect();
            assert_eq!(keys, [0, 1, 2]);
            let (m, _) = store.read(&EntryKey { field: "rho".into(), step: 2, rank: 0 }).unwrap();
            assert_eq!(m.meta.encode_psnr, Some(psnr[2]));
            assert_eq!(m.meta.schedule, "warm-auto", "the default warm start");
            assert!(m.meta.warm.is_some(), "an auto step's record survives the store");
            assert!(m.meta.iterations <= 20, "warm_iterations caps an auto step: {}", m.meta.iterations);
            let mut job: gsenc_job = std::mem::zeroed();
            job.struct_size = std::mem::size_of::<gsenc_job>();
            assert_eq!(gsenc_poll(enc, field.as_ptr(), 2, &mut job), gsenc_status::Ok);
            assert_eq!((job.state, job.psnr), (GSENC_JOB_DONE, psnr[2]));
        }
        gsenc_encoder_destroy(enc);
    }
}

/// A restarted encoder resumes from the store it writes: a step the
/// stopped run appended, then its next step as the unbroken run's, stored
/// again where the stopped run had stored it; a step the store does not
/// hold is refused, naming the entry.
#[test]
fn a_restart_resumes_from_its_own_store() {
    let _hdf5 = common::hdf5_serial();
    let dir = common::tmpdir("capi-h5-resume");
    let field = CString::new("rho").unwrap();
    let dims = [12usize, 10, 8];
    // SAFETY: the test's own config, handles, strings and grids.
    unsafe {
        let create = |path: &CString| {
            let mut cfg: gsenc_config = std::mem::zeroed();
            cfg.struct_size = std::mem::size_of::<gsenc_config>();
            assert_eq!(gsenc_config_init(&mut cfg), gsenc_status::Ok);
            (cfg.budget, cfg.schedule, cfg.iterations, cfg.warm_iterations, cfg.points) = (40, GSENC_SCHEDULE_SHORT, 40, 20, 256);
            cfg.output_format = GSENC_OUTPUT_HDF5;
            cfg.output_dir = path.as_ptr();
            let mut enc = std::ptr::null_mut();
            assert_eq!(gsenc_encoder_create(&cfg, &mut enc), gsenc_status::Ok);
            enc
        };
        let push = |enc, step: u64| {
            let g = blobs(dims, 90 + step, 3);
            let grid = crate::inputs::f32_grid(&g.values, dims, 0.1);
            assert_eq!(crate::inputs::gsenc_push_grid(enc, field.as_ptr(), step, 0.5 * step as f64, &grid), gsenc_status::Ok);
        };
        let (unbroken, stopped) = (dir.join("unbroken.h5"), dir.join("stopped.h5"));
        let (unbroken_c, stopped_c) = (CString::new(unbroken.to_str().unwrap()).unwrap(), CString::new(stopped.to_str().unwrap()).unwrap());
        let enc = create(&unbroken_c);
        (0..3).for_each(|step| push(enc, step));
        gsenc_encoder_destroy(enc);
        // The stopped run stored steps 0 to 2; the restart goes on from
        // step 1 (a checkpoint taken before it stopped) and stores step 2
        // again: the same model, which the store takes as a no-op.
        let enc = create(&stopped_c);
        (0..3).for_each(|step| push(enc, step));
        gsenc_encoder_destroy(enc);

        let enc = create(&stopped_c);
        assert_eq!(crate::resume::gsenc_encoder_resume_stored(enc, field.as_ptr(), 5), gsenc_status::InvalidArgument);
        assert!(crate::status::last_error_text().contains("holds no model /rho/5/rank_0"), "{}", crate::status::last_error_text());
        assert_eq!(crate::resume::gsenc_encoder_resume_stored(enc, field.as_ptr(), 1), gsenc_status::Ok, "{}", crate::status::last_error_text());
        push(enc, 2);
        assert_eq!(gsenc_wait(enc, std::ptr::null()), gsenc_status::Ok);
        gsenc_encoder_destroy(enc);
        let key = EntryKey { field: "rho".into(), step: 2, rank: 0 };
        let want = Store::open_read(&unbroken).unwrap().read(&key).unwrap().0;
        let store = Store::open_read(&stopped).unwrap();
        assert_eq!(store.entries().unwrap().iter().map(|e| e.key.step).collect::<Vec<_>>(), [0, 1, 2]);
        assert_eq!(store.read(&key).unwrap().0.params, want.params, "the restarted run's step 2 differs from the unbroken run's");
    }
}

/// The process `an_hdf5_store_is_held_from_create_to_destroy` starts (a
/// run of this test binary; without `GSENC_LOCK_PROBE` it does nothing):
/// opens the store that variable names for append, prints `PROBE: held`
/// or `PROBE: refused: <why>`, and keeps the store until its standard
/// input closes.
#[test]
#[ignore = "a helper process of an_hdf5_store_is_held_from_create_to_destroy"]
fn store_lock_probe() {
    use std::io::Read;
    let Some(path) = std::env::var_os("GSENC_LOCK_PROBE") else { return };
    let held = Store::open_append(&path);
    match &held {
        Ok(_) => println!("PROBE: held"),
        Err(e) => println!("PROBE: refused: {e}"),
    }
    let _ = std::io::stdin().read_to_end(&mut Vec::new());
    drop(held);
}

/// A probe process on `path`, and what it said once it tried.
fn probe(path: &std::path::Path) -> (std::process::Child, String) {
    use std::io::BufRead;
    use std::process::{Command, Stdio};
    let mut child = Command::new(std::env::current_exe().unwrap())
        .args(["--ignored", "--exact", "hdf5_tests::store_lock_probe", "--nocapture", "--test-threads=1"])
        .env("GSENC_LOCK_PROBE", path)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    // Its output read to the end (a pipe closed early would fail its
    // harness's last lines); the harness prints the test's name on the
    // same line first.
    let out = std::io::BufReader::new(child.stdout.take().unwrap());
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        for l in out.lines().map_while(Result::ok) {
            if let Some(at) = l.find("PROBE: ") {
                let _ = tx.send(l[at..].to_string());
            }
        }
    });
    (child, rx.recv_timeout(std::time::Duration::from_secs(120)).expect("the probe said nothing"))
}

/// An encoder writing an HDF5 store holds it, under HDF5's file lock,
/// from create to destroy: another process cannot open it for writing
/// meanwhile, can after destroy, and a create on a store another process
/// holds fails with `GSENC_STATUS_IO` and the lock's message.
#[test]
fn an_hdf5_store_is_held_from_create_to_destroy() {
    let _hdf5 = common::hdf5_serial();
    let dir = common::tmpdir("capi-h5-lock");
    let path = dir.join("run.h5");
    let c_path = CString::new(path.to_str().unwrap()).unwrap();
    let done = |mut child: std::process::Child| {
        drop(child.stdin.take());
        assert!(child.wait().unwrap().success());
    };
    unsafe {
        let mut cfg: gsenc_config = std::mem::zeroed();
        cfg.struct_size = std::mem::size_of::<gsenc_config>();
        assert_eq!(gsenc_config_init(&mut cfg), gsenc_status::Ok);
        (cfg.budget, cfg.output_format, cfg.output_dir) = (10, GSENC_OUTPUT_HDF5, c_path.as_ptr());
        let mut enc = std::ptr::null_mut();
        assert_eq!(gsenc_encoder_create(&cfg, &mut enc), gsenc_status::Ok);
        let (child, said) = probe(&path);
        assert!(said.starts_with("PROBE: refused") && said.contains("lock"), "{said}");
        done(child);
        gsenc_encoder_destroy(enc);
        let (child, said) = probe(&path);
        assert_eq!(said, "PROBE: held");
        let mut other = std::ptr::null_mut();
        assert_eq!(gsenc_encoder_create(&cfg, &mut other), gsenc_status::Io);
        assert!(other.is_null() && crate::status::last_error_text().contains("lock"), "{}", crate::status::last_error_text());
        done(child);
        assert_eq!(gsenc_encoder_create(&cfg, &mut other), gsenc_status::Ok);
        gsenc_encoder_destroy(other);
    }
}
