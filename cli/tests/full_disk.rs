//! The tool on a full disk: every write it makes fails with its error and
//! keeps what was there before.

#[path = "../../tests/common/mod.rs"]
mod common;
use common::disk::{says_full, SmallDisk};
use std::path::{Path, PathBuf};
#[cfg(feature = "hdf5")]
use std::process::Command;

// A full disk (`common::disk`: a small tmpfs, or a file size limit where
// none can be mounted): every write the tool makes fails with its error
// (exit 5) and leaves what was there before as it was, with no temporary
// file behind.

/// The tool with `args`, writing on `disk`: (exit code, stderr).
fn gsenc_on(disk: &SmallDisk, args: &[&str]) -> (i32, String) {
    let out = disk.command(env!("CARGO_BIN_EXE_gsenc")).args(args).env("XDG_RUNTIME_DIR", std::env::temp_dir()).output().unwrap();
    (out.status.code().unwrap_or(-1), String::from_utf8_lossy(&out.stderr).into_owned())
}

/// A 32^3 float32 field, off the small disk.
fn write_input32(dir: &Path) -> PathBuf {
    let n = 32;
    let v: Vec<u8> = (0..n * n * n)
        .flat_map(|i| {
            let x = [i % n, (i / n) % n, i / (n * n)].map(|c| (c as f32 + 0.5) / n as f32);
            let r2 = (x[0] - 0.4).powi(2) + (x[1] - 0.5).powi(2) + (x[2] - 0.6).powi(2);
            ((-r2 / 0.02).exp() + 0.3 * (9.0 * x[0]).sin() * (7.0 * x[1]).cos()).to_le_bytes()
        })
        .collect();
    let p = dir.join("in.raw");
    std::fs::write(&p, v).unwrap();
    p
}

fn encode32_args<'a>(input: &'a str, budget: &'a str, out: &'a str) -> Vec<&'a str> {
    let common = ["encode", "grid", "--input", input, "--dims", "32,32,32", "--dtype", "f32", "--iters", "30", "--points", "512", "--backend", "cpu", "-q"];
    [&common[..], &["--budget", budget, "-o", out]].concat()
}

#[test]
fn a_full_disk_fails_model_and_decode_writes_and_keeps_the_earlier_file() {
    // A model of 40 Gaussians (2 KB) and a decode of 8^3 fit; one of 3,000
    // (144 KB) or a decode of 32^3 (128 KiB) does not.
    let disk = SmallDisk::new("full-disk-files", 64);
    let input = write_input32(disk.dir.parent().unwrap());
    let input = input.to_str().unwrap();
    let model = disk.path("m.gsm");
    let m = model.to_str().unwrap();
    let (code, err) = gsenc_on(&disk, &encode32_args(input, "40", m));
    assert_eq!(code, 0, "a small model fits: {err}");
    let small = std::fs::read(&model).unwrap();

    // A model that does not fit: the error, the earlier model as it was.
    let (code, err) = gsenc_on(&disk, &encode32_args(input, "3000", m));
    assert_eq!(code, 5, "{err}");
    assert!(says_full(&err) && err.contains("m.gsm"), "{err}");
    assert_eq!(std::fs::read(&model).unwrap(), small, "the earlier model changed");
    assert_eq!(disk.names(), ["m.gsm"], "a temporary file was left behind");

    // A decode that does not fit, over an earlier decode that did.
    let raw = disk.path("d.raw");
    let (code, err) = gsenc_on(&disk, &["decode", m, "--dims", "8,8,8", "--backend", "cpu", "-q", "-o", raw.to_str().unwrap()]);
    assert_eq!(code, 0, "{err}");
    let decoded = std::fs::read(&raw).unwrap();
    assert_eq!(decoded.len(), 8 * 8 * 8 * 4);
    // In one slab, and in slabs of one layer, so that the disk fills while
    // later slabs still decode (the writer's error stops the decode).
    for slab in ["16777216", "1024"] {
        let (code, err) = gsenc_on(&disk, &["decode", m, "--dims", "32,32,32", "--slab-voxels", slab, "--backend", "cpu", "-q", "-o", raw.to_str().unwrap()]);
        assert_eq!(code, 5, "{err}");
        assert!(says_full(&err) && err.contains("d.raw"), "{err}");
        assert_eq!(std::fs::read(&raw).unwrap(), decoded, "the earlier decode changed");
        assert_eq!(disk.names(), ["d.raw", "m.gsm"], "a temporary file was left behind");
    }
}

#[cfg(feature = "hdf5")]
#[test]
fn a_full_disk_fails_a_store_append_and_keeps_the_earlier_steps() {
    // A store of one small model (about 130 KB: its groups are sized for
    // many steps) fits; a model of 6,000 Gaussians (290 KB) more does not.
    let disk = SmallDisk::new("full-disk-store", 256);
    let off = disk.dir.parent().unwrap().to_path_buf();
    let input = write_input32(&off);
    let input = input.to_str().unwrap();
    let (small, big) = (off.join("small.gsm"), off.join("big.gsm"));
    for (path, budget, step) in [(&small, "40", "0"), (&big, "6000", "1")] {
        let args = [&encode32_args(input, budget, path.to_str().unwrap())[..], &["--step", step]].concat();
        let out = Command::new(env!("CARGO_BIN_EXE_gsenc")).args(args).output().unwrap();
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    }
    let store = disk.path("s.h5");
    let s = store.to_str().unwrap();
    let (code, err) = gsenc_on(&disk, &["store", "add", s, small.to_str().unwrap()]);
    assert_eq!(code, 0, "a store of a small model fits: {err}");

    // Appending a model that does not fit fails with the disk's error...
    let (code, err) = gsenc_on(&disk, &["store", "add", s, big.to_str().unwrap()]);
    assert_eq!(code, 5, "{err}");
    assert!(says_full(&err) && err.contains("s.h5") && err.contains("big.gsm not added; 0 of 1 added"), "{err}");

    // ...and the step stored before reads back as it was written, the only
    // entry the store lists.
    let out = Command::new(env!("CARGO_BIN_EXE_gsenc")).args(["info", "--json", s]).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let info: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let names: Vec<&str> = info["entries"].as_array().unwrap().iter().map(|e| e["entry"].as_str().unwrap()).collect();
    assert_eq!(names, ["/scalar/0/rank_0"], "{info}");
    let got = off.join("got.gsm");
    let out = Command::new(env!("CARGO_BIN_EXE_gsenc")).args(["store", "extract", s]).arg(small_key(&small)).arg("-o").arg(&got).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let read = |p: &Path| gsenc::format::read_model(&std::fs::read(p).unwrap()).unwrap();
    assert_eq!(read(&got), read(&small));
    assert_eq!(disk.names(), ["s.h5"], "a temporary file was left behind");

    // A new store that nothing could be added to is not left behind, under
    // its name or another.
    let (code, err) = gsenc_on(&disk, &["store", "add", disk.path("t.h5").to_str().unwrap(), big.to_str().unwrap()]);
    assert_eq!(code, 5, "{err}");
    assert!(says_full(&err) && err.contains("t.h5"), "{err}");
    assert_eq!(disk.names(), ["s.h5"], "a temporary file was left behind");
}

/// The store entry (`field/step/rank`) of a model file.
#[cfg(feature = "hdf5")]
fn small_key(path: &Path) -> String {
    let m = gsenc::format::read_model(&std::fs::read(path).unwrap()).unwrap();
    gsenc::io::store::EntryKey::of(&m.meta).path().trim_start_matches('/').replace("/rank_", "/")
}
