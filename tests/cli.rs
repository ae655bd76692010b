//! The command-line tool end to end: encode, eval, info, decode, and its errors.

mod common;
use common::*;
use gsenc::backend::cpu::CpuBackend;
use gsenc::io::vti;
use std::path::{Path, PathBuf};
use std::process::Command;

fn tmpdir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("gsenc-cli-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn gsenc(args: &[&str]) -> (i32, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_gsenc")).args(args).output().unwrap();
    (out.status.code().unwrap_or(-1), String::from_utf8_lossy(&out.stdout).into(), String::from_utf8_lossy(&out.stderr).into())
}

fn json(s: &str) -> serde_json::Value {
    serde_json::from_str(s.trim()).unwrap_or_else(|e| panic!("not JSON ({e}): {s}"))
}

/// A 20x16x12 float32 field scaled to [2, 12] (so that normalisation matters).
fn write_input(dir: &Path) -> (PathBuf, Vec<f32>) {
    let g = blobs([20, 16, 12], 5, 4);
    let vals: Vec<f32> = g.values.iter().map(|v| 2.0 + 10.0 * v).collect();
    let p = dir.join("field.f32");
    std::fs::write(&p, gsenc::io::raw::to_f32_bytes(&vals)).unwrap();
    (p, vals)
}

#[test]
fn encode_eval_info_decode_round_trip() {
    let dir = tmpdir("roundtrip");
    let (input, vals) = write_input(&dir);
    let model = dir.join("m.gsm");
    let (inp, m) = (input.to_str().unwrap(), model.to_str().unwrap());
    let (code, out, err) = gsenc(&[
        "encode", "grid", "--input", inp, "--dims", "20,16,12", "--dtype", "f32", "--budget", "300", "--schedule", "short",
        "--iters", "120", "--points", "2048", "--field", "temp", "--step", "4", "-o", m, "--json",
    ]);
    assert_eq!(code, 0, "{err}");
    let e = json(&out);
    for key in ["primitives", "bytes", "voxel_psnr", "sampled_psnr", "seconds", "total_seconds"] {
        assert!(e.get(key).is_some(), "missing {key} in {out}");
    }
    assert_eq!(e["primitives"], 300);
    assert_eq!(e["bytes"].as_u64().unwrap(), std::fs::metadata(&model).unwrap().len());
    let vpsnr = e["voxel_psnr"].as_f64().unwrap();
    assert!(vpsnr > 25.0, "{vpsnr}");
    assert!(e["seconds"].as_f64().unwrap() <= e["total_seconds"].as_f64().unwrap());

    let (code, out, err) = gsenc(&["eval", m, "--input", inp, "--dims", "20,16,12", "--dtype", "f32", "--json"]);
    assert_eq!(code, 0, "{err}");
    assert!((json(&out)["voxel_psnr"].as_f64().unwrap() - vpsnr).abs() < 1e-9);

    let (code, out, _) = gsenc(&["info", m, "--json"]);
    assert_eq!(code, 0);
    let i = json(&out);
    assert_eq!(i["field"], "temp");
    assert_eq!(i["step"], 4);
    assert_eq!(i["primitives"], 300);
    assert_eq!(i["dims"], serde_json::json!([20, 16, 12]));
    assert_eq!(i["value_min"].as_f64().unwrap(), *vals.iter().min_by(|a, b| a.total_cmp(b)).unwrap() as f64);

    // A .vti decode parses back and equals the library's decode in data units.
    let out_vti = dir.join("d.vti");
    let (code, _, err) = gsenc(&["decode", m, "-o", out_vti.to_str().unwrap(), "--quiet"]);
    assert_eq!(code, 0, "{err}");
    let parsed = vti::read_vti(&out_vti, None).unwrap();
    let lib_model = gsenc::format::read_model(&std::fs::read(&model).unwrap()).unwrap();
    let lib = lib_model.decode(&mut CpuBackend::new(), None).unwrap();
    assert_eq!(parsed.grid.dims, [20, 16, 12]);
    assert_eq!(parsed.origin, [0.0; 3]);
    assert_eq!(parsed.spacing, [1.0; 3]);
    for (a, b) in parsed.grid.values.iter().zip(&lib.values) {
        assert_eq!(*a, lib_model.meta.range.denormalize(*b) as f32);
    }
    // The decoded field is close to the input in data units.
    let rms = (parsed.grid.values.iter().zip(&vals).map(|(a, b)| ((a - b) as f64).powi(2)).sum::<f64>() / vals.len() as f64).sqrt();
    assert!(rms < 0.5, "rms {rms}");

    // Any resolution: a 2x raw decode has 8x the voxels; a .vti input encodes too.
    let out_raw = dir.join("d2.raw");
    let (code, _, _) = gsenc(&["decode", m, "--dims", "40,32,24", "-o", out_raw.to_str().unwrap()]);
    assert_eq!(code, 0);
    assert_eq!(std::fs::metadata(&out_raw).unwrap().len(), 40 * 32 * 24 * 4);
    let m2 = dir.join("m2.gsm");
    let (code, out, err) = gsenc(&["encode", "grid", "--input", out_vti.to_str().unwrap(), "--budget", "200", "--iters", "40", "--points", "1024", "-o", m2.to_str().unwrap(), "--json"]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(json(&out)["primitives"], 200);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn bad_inputs_fail_with_codes_and_messages() {
    let dir = tmpdir("errors");
    let (input, mut vals) = write_input(&dir);
    let inp = input.to_str().unwrap();
    let m = dir.join("m.gsm");
    let ms = m.to_str().unwrap();
    let enc = |extra: &[&str], dims: &str, file: &str| {
        let mut a = vec!["encode", "grid", "--input", file, "--dims", dims, "--dtype", "f32", "--iters", "5", "--points", "256", "-o", ms, "--quiet"];
        a.extend_from_slice(extra);
        gsenc(&a)
    };
    let (code, _, err) = enc(&["--budget", "10"], "20,16,13", inp);
    assert_eq!(code, 3);
    assert!(err.contains("bytes"), "{err}");
    let (code, _, err) = enc(&["--budget", "0"], "20,16,12", inp);
    assert_eq!(code, 2);
    assert!(err.contains("at least 1"), "{err}");
    let (code, _, err) = enc(&["--budget", "4000"], "20,16,12", inp);
    assert_eq!(code, 2);
    assert!(err.contains("exceeds the 3840 voxels"), "{err}");
    vals[123] = f32::NAN;
    let nan = dir.join("nan.f32");
    std::fs::write(&nan, gsenc::io::raw::to_f32_bytes(&vals)).unwrap();
    let (code, _, err) = enc(&["--budget", "10"], "20,16,12", nan.to_str().unwrap());
    assert_eq!(code, 3);
    assert!(err.contains("index 123") && err.contains("not finite"), "{err}");
    assert!(!m.exists(), "a failed encode must not leave a model behind");

    // A good model, then damaged copies.
    let (code, _, err) = enc(&["--budget", "10"], "20,16,12", inp);
    assert_eq!(code, 0, "{err}");
    let bytes = std::fs::read(&m).unwrap();
    let cut = dir.join("cut.gsm");
    std::fs::write(&cut, &bytes[..bytes.len() - 7]).unwrap();
    let (code, _, err) = gsenc(&["info", cut.to_str().unwrap()]);
    assert_eq!(code, 4);
    assert!(err.contains("truncated"), "{err}");
    let (code, _, err) = gsenc(&["info", inp]);
    assert_eq!(code, 4);
    assert!(err.contains("not a gsenc model"), "{err}");
    let (code, _, err) = gsenc(&["decode", ms, "--dims", "0,4,4", "-o", dir.join("x.raw").to_str().unwrap()]);
    assert_ne!(code, 0);
    assert!(err.contains("dims"), "{err}");
    let (code, _, err) = gsenc(&["decode", ms, "-o", dir.join("no/such/dir/x.raw").to_str().unwrap()]);
    assert_eq!(code, 5, "{err}");
    std::fs::remove_dir_all(&dir).unwrap();
}
