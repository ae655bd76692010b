//! The command-line tool end to end on grids: encode, eval, info, decode,
//! render and convert, and its errors (the backends in `backend.rs`,
//! particles, cells and series in `particles.rs`, a full disk in
//! `full_disk.rs`).

#[path = "../../tests/common/mod.rs"]
mod common;
mod tool;
use common::*;
use gsenc::backend::cpu::CpuBackend;
use gsenc::io::vti;
use std::path::{Path, PathBuf};
use std::process::Command;
use tool::{gsenc, json, write_input, write_f32, write_particles};

#[test]
fn encode_eval_info_decode_round_trip() {
    let dir = tmpdir("roundtrip");
    let (input, vals) = write_input(&dir);
    let model = dir.join("m.gsm");
    let (inp, m) = (input.to_str().unwrap(), model.to_str().unwrap());
    let (code, out, err) = gsenc(&[
        "encode", "grid", "--input", inp, "--dims", "20,16,12", "--dtype", "f32", "--budget", "300", "--schedule", "short",
        "--iters", "120", "--points", "2048", "--field", "temp", "--step", "4", "--backend", "cpu", "-o", m, "--json",
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
    // The loop's host phases lie inside the loop; a CPU encode only draws.
    let phase = |k: &str| e["loop_phases"][k].as_f64().unwrap_or_else(|| panic!("loop_phases.{k} in {out}"));
    assert!(phase("draw") > 0.0 && phase("draw") <= e["seconds"].as_f64().unwrap(), "{out}");
    assert_eq!((phase("submit"), phase("wait")), (0.0, 0.0), "{out}");

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
    // Written in slabs of any size (each written while the next decodes:
    // write_behind.rs), .vti and raw, the same bytes as in one slab.
    let whole_raw = dir.join("whole.raw");
    let (code, _, err) = gsenc(&["decode", m, "-o", whole_raw.to_str().unwrap(), "--quiet"]);
    assert_eq!(code, 0, "{err}");
    for slab in ["1", "320", "1000", "3839"] {
        for (name, whole) in [("s.vti", &out_vti), ("s.raw", &whole_raw)] {
            let p = dir.join(name);
            let (code, _, err) = gsenc(&["decode", m, "--slab-voxels", slab, "-o", p.to_str().unwrap(), "--quiet"]);
            assert_eq!(code, 0, "{err}");
            assert!(std::fs::read(&p).unwrap() == std::fs::read(whole).unwrap(), "{name} in slabs of {slab} voxels differs");
        }
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

/// A `.vti` input must have cubic voxels of a positive, finite edge: other
/// spacings are refused with their values, not encoded in a broken frame.
#[test]
fn vti_inputs_need_cubic_finite_voxels() {
    let dir = tmpdir("vti-spacing");
    let grid = gsenc::field::Grid::new([6, 5, 4], (0..120).map(|i| (i % 7) as f32).collect()).unwrap();
    let m = dir.join("m.gsm");
    let bad = "must be positive and finite";
    for (spacing, refused) in [
        ([0.5; 3], None),
        ([1.0, 1.0, 2.0], Some("is not isotropic")),
        ([0.0; 3], Some(bad)),
        ([-1.0; 3], Some(bad)),
        ([1.0, f64::INFINITY, 1.0], Some(bad)),
        ([f64::NAN; 3], Some(bad)),
    ] {
        let input = dir.join("in.vti");
        std::fs::write(&input, vti::write_vti_bytes(&grid, [0.0; 3], spacing, "f")).unwrap();
        let (code, _, err) = gsenc(&["encode", "grid", "--input", input.to_str().unwrap(), "--budget", "8", "--iters", "5", "--points", "64", "-o", m.to_str().unwrap(), "--quiet"]);
        match refused {
            None => assert_eq!(code, 0, "{spacing:?}: {err}"),
            Some(why) => {
                assert_eq!(code, 3, "{spacing:?}: {err}");
                assert!(err.contains(why), "{spacing:?}: {err}");
            }
        }
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `gsenc render`: a slice and a volume of a model beside its reference,
/// the PNG written and the image scores printed; bad views fail before
/// any decoding, with exit code 2 and the reason.
#[test]
fn render_draws_the_model_beside_its_reference_and_rejects_bad_views() {
    let dir = tmpdir("render");
    let (input, _) = write_input(&dir);
    let model = dir.join("m.gsm");
    let (inp, m) = (input.to_str().unwrap(), model.to_str().unwrap());
    let (code, _, err) = gsenc(&["encode", "grid", "--input", inp, "--dims", "20,16,12", "--dtype", "f32", "--budget", "300", "--schedule", "short", "--iters", "150", "-o", m, "--quiet"]);
    assert_eq!(code, 0, "{err}");
    let png = dir.join("view.png");
    let p = png.to_str().unwrap();
    let reference = ["--reference", inp, "--reference-dims", "20,16,12", "--dtype", "f32"];
    for view in [&["--slice", "y=0.4"][..], &["--volume", "--azimuth", "-60", "--elevation", "10"][..]] {
        let mut args = vec!["render", m, "-o", p, "--size", "64,48", "--json"];
        args.extend_from_slice(view);
        args.extend_from_slice(&reference);
        let (code, out, err) = gsenc(&args);
        assert_eq!(code, 0, "{view:?}: {err}");
        let r = json(&out);
        let (psnr, ssim) = (r["image_psnr"].as_f64().unwrap(), r["ssim"].as_f64().unwrap());
        assert!(psnr > 15.0 && ssim > 0.5 && ssim <= 1.0, "{view:?}: {out}");
        let img = gsenc::io::image::read_png(&png).unwrap();
        assert_eq!((img.width as u64, img.height as u64), (r["width"].as_u64().unwrap(), r["height"].as_u64().unwrap()));
        assert!(img.width > 2 * 64 && img.height > 48);
    }
    // Without a reference: one panel, no scores.
    let (code, out, err) = gsenc(&["render", m, "-o", p, "--json"]);
    assert_eq!(code, 0, "{err}");
    assert!(json(&out)["ssim"].is_null());
    let before = std::fs::read(&png).unwrap();
    for (bad, says) in [
        (&["--slice", "q=0.5"][..], "AXIS=FRACTION"),
        (&["--slice", "z=2"][..], "AXIS=FRACTION"),
        (&["--size", "4"][..], "image width 4"),
        (&["--volume", "--elevation", "120"][..], "elevation"),
        (&["--volume", "--opacity", "0"][..], "opacity"),
        (&["--colormap", "rainbow"][..], "viridis"),
        // A lattice beyond what a decode makes is refused before anything
        // is allocated (500 GB aborted the tool before), and one whose
        // voxel count wraps past 64 bits is too.
        (&["--dims", "5000,5000,5000"][..], "decode dims [5000, 5000, 5000] are too large"),
        (&["--dims", "4294967295,4294967295,4294967295"][..], "are too large"),
    ] {
        let mut args = vec!["render", m, "-o", p];
        args.extend_from_slice(bad);
        let (code, _, err) = gsenc(&args);
        assert_eq!(code, 2, "{bad:?}: {err}");
        assert!(err.contains(says), "{bad:?}: {err}");
    }
    // A failed render leaves the picture already written as it was.
    assert_eq!(std::fs::read(&png).unwrap(), before);
}

/// A random `n`^3 u8 grid in `dir`, and the tool run with `args` (where
/// `GRID` stands for the grid's path) under `ulimit -v` of `kib`: its exit
/// code, standard output and standard error.
#[cfg(target_os = "linux")]
fn encode_under_ulimit(dir: &Path, n: u32, kib: u64, args: &[&str]) -> (Option<i32>, String, String) {
    let grid = dir.join(format!("random{n}.u8"));
    if !grid.exists() {
        std::fs::write(&grid, (0..n * n * n).map(|i| (i.wrapping_mul(2654435761) >> 24) as u8).collect::<Vec<u8>>()).unwrap();
    }
    let args: Vec<String> = args.iter().map(|a| if *a == "GRID" { grid.display().to_string() } else { a.to_string() }).collect();
    let out = Command::new("sh")
        .arg("-c")
        .arg(format!("ulimit -v {kib} && exec \"$0\" \"$@\""))
        .arg(env!("CARGO_BIN_EXE_gsenc"))
        .args(&args)
        .output()
        .unwrap();
    (out.status.code(), String::from_utf8_lossy(&out.stdout).into_owned(), String::from_utf8_lossy(&out.stderr).into_owned())
}

/// A budget whose training state cannot fit in the memory the process may
/// take (here `ulimit -v` of 3 GB; 7M primitives take about 5.6 GB) is a
/// usage error before it is allocated: the allocation aborted the tool
/// before (exit 134), and in a simulation that links gsenc the whole run.
/// A budget that fits encodes under the same limit.
#[cfg(target_os = "linux")]
#[test]
fn a_budget_beyond_the_memory_available_is_refused() {
    let dir = tmpdir("memory");
    let model = dir.join("m.gsm");
    let m = model.to_str().unwrap();
    let limited = |budget: &str| {
        let args = ["encode", "grid", "--input", "GRID", "--dims", "192,192,192", "--dtype", "u8", "--budget", budget, "--iters", "2", "--backend", "cpu", "-o", m, "--quiet"];
        let (code, _, err) = encode_under_ulimit(&dir, 192, 3_000_000, &args);
        (code, err)
    };
    let (code, err) = limited("7000000");
    assert_eq!(code, Some(2), "{err}");
    assert!(err.contains("training a budget of 7000000 primitives") && err.contains("this process can take now"), "{err}");
    assert!(!model.exists());
    let (code, err) = limited("20000");
    assert_eq!(code, Some(0), "{err}");
    assert!(model.exists());
}

/// A target PSNR's search stays within the budgets whose training fits: on
/// a random grid that never reaches 80 dB the search goes to its cap
/// (2,000,000 asked), which under `ulimit -v` of 1.2 GB does not fit; the
/// search then caps itself at what fits and ends with a model (before, the
/// encode at the cap was refused and the whole command failed, exit 2).
#[cfg(target_os = "linux")]
#[test]
fn a_target_search_caps_itself_at_the_memory_available() {
    let dir = tmpdir("memory-target");
    let model = dir.join("m.gsm");
    let args = ["encode", "grid", "--input", "GRID", "--dims", "128,128,128", "--dtype", "u8", "--target-psnr", "80", "--budget", "2000000"];
    let args = [&args[..], &["--iters", "2", "--points", "64", "--backend", "cpu", "-o", model.to_str().unwrap(), "--json"]].concat();
    let (code, out, err) = encode_under_ulimit(&dir, 128, 1_200_000, &args);
    assert_eq!(code, Some(0), "{err}");
    let v = json(&out);
    let cap = v["target"]["cap"].as_u64().unwrap();
    assert!((16..2_000_000).contains(&cap), "cap {cap}");
    assert!(v["primitives"].as_u64().unwrap() <= cap, "{v}");
    assert_eq!(gsenc::format::read_model(&std::fs::read(&model).unwrap()).unwrap().params.len() as u64, v["primitives"].as_u64().unwrap());
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
    // A batch of 4e9 points (320 GB: it aborted the tool) is refused first.
    let (code, _, err) = gsenc(&["encode", "grid", "--input", inp, "--dims", "20,16,12", "--dtype", "f32", "--budget", "10", "--points", "4000000000", "-o", ms, "--quiet"]);
    assert_eq!(code, 2);
    assert!(err.contains("4000000000 points per iteration are more than the 16777216"), "{err}");
    // So are 2^32 + 1 iterations (which ran for days), before any work.
    let (code, _, err) = gsenc(&["encode", "grid", "--input", inp, "--dims", "20,16,12", "--dtype", "f32", "--budget", "10", "--iters", "4294967297", "-o", ms, "--quiet"]);
    assert_eq!(code, 2);
    assert!(err.contains("iterations 4294967297 are more than the 10000000"), "{err}");
    // A memory limit that is not a size is a usage error, as a bad
    // GSENC_BACKEND is, not a limit silently ignored; a size is taken.
    let limited = dir.join("limited.gsm");
    for (limit, code) in [("lots", 2), ("8GB", 2), ("64G", 0)] {
        let out = Command::new(env!("CARGO_BIN_EXE_gsenc"))
            .args(["encode", "grid", "--input", inp, "--dims", "20,16,12", "--dtype", "f32", "--budget", "10", "--iters", "5", "--points", "256", "--quiet"])
            .arg("-o")
            .arg(&limited)
            .env("GSENC_MEMORY_LIMIT", limit)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(code), "{limit}: {err}");
        if code == 2 {
            assert!(err.contains(&format!("GSENC_MEMORY_LIMIT: '{limit}' is not a size")), "{err}");
        }
        assert_eq!(limited.exists(), code == 0, "{limit}");
    }
    // A backend that does not exist, named where a job script sets it.
    let out = Command::new(env!("CARGO_BIN_EXE_gsenc"))
        .args(["encode", "grid", "--input", inp, "--dims", "20,16,12", "--dtype", "f32", "--budget", "10", "--quiet", "-o", ms])
        .env("GSENC_BACKEND", "cuda")
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.ends_with("gsenc: invalid argument: GSENC_BACKEND: unknown backend 'cuda' (auto, cpu, gpu)\n"), "{err}");
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

#[test]
fn target_psnr_chooses_the_budget_and_bad_targets_are_refused() {
    let dir = tmpdir("target");
    let (input, _) = write_input(&dir);
    let m = dir.join("m.gsm");
    let enc = |extra: &[&str]| {
        let mut a = vec!["encode", "grid", "--input", input.to_str().unwrap(), "--dims", "20,16,12", "--dtype", "f32", "--schedule", "short", "--iters", "300", "--points", "2048", "-o", m.to_str().unwrap(), "--json", "--quiet"];
        a.extend_from_slice(extra);
        gsenc(&a)
    };
    for (bad, says) in [("-3", "target PSNR"), ("0", "target PSNR"), ("nan", "target PSNR"), ("500", "at most 120"), ("x", "invalid value")] {
        let (code, _, err) = enc(&["--target-psnr", bad]);
        assert_eq!(code, 2, "--target-psnr {bad}: {err}");
        assert!(err.contains(says), "--target-psnr {bad}: {err}");
        assert!(!m.exists(), "nothing written for --target-psnr {bad}");
    }
    let (code, _, err) = enc(&[]);
    assert_eq!(code, 2);
    assert!(err.contains("--budget"), "neither a budget nor a target: {err}");

    let (code, out, err) = enc(&["--target-psnr", "30"]);
    assert_eq!(code, 0, "{err}");
    let e = json(&out);
    let t = &e["target"];
    let psnr = e["voxel_psnr"].as_f64().unwrap();
    let chosen = &t["tries"][t["chosen"].as_u64().unwrap() as usize];
    assert_eq!((chosen["budget"].clone(), chosen["psnr"].as_f64().unwrap()), (e["primitives"].clone(), psnr), "{out}");
    assert!(t["landed"].as_bool().unwrap() && (psnr - 30.0).abs() <= 1.0, "{out}");
    assert_eq!(t["probes"].as_array().unwrap().len(), 4, "{out}");
    // The cap: --budget with a target is the most it may choose.
    let (code, out, err) = enc(&["--target-psnr", "90", "--budget", "50"]);
    assert_eq!(code, 0, "{err}");
    let e = json(&out);
    assert!(e["primitives"].as_u64().unwrap() <= 50 && !e["target"]["landed"].as_bool().unwrap(), "{out}");
    // Without a target, no report.
    let (code, out, err) = enc(&["--budget", "40"]);
    assert_eq!(code, 0, "{err}");
    assert!(json(&out)["target"].is_null(), "{out}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Options that take numbers accept a leading minus (`--bounds -5,...`, not
/// only `--bounds=-5,...`); names of schedules, payloads and warm starts are
/// checked when the command line is parsed, before any file is read.
#[test]
fn negative_numbers_are_values_and_names_are_checked_first() {
    let dir = tmpdir("negative");
    let [pos, hh, mass, val] = write_particles(&dir);
    // The same particles moved into negative coordinates.
    let moved: Vec<f32> = gsenc::io::raw::read_items(&pos, gsenc::io::raw::DType::F32, 3, gsenc::io::raw::Rows { count: None, row: 0 })
        .unwrap()
        .iter()
        .map(|&x| x as f32 - 5.0)
        .collect();
    let neg = dir.join("neg.f32");
    write_f32(&neg, &moved);
    let s = |p: &PathBuf| p.to_str().unwrap().to_string();
    let m = dir.join("neg.gsm");
    let (code, out, err) = gsenc(&[
        "encode", "particles", "--positions", &s(&neg), "--smoothing-length", &s(&hh), "--mass", &s(&mass), "--values", &s(&val),
        "--count", "600", "--dims", "12,8,4", "--bounds", "-5,-5,-5,-2,-3,-4", "--range", "-1,120", "--time", "-0.5",
        "--budget", "30", "--iters", "5", "--points", "256", "-o", m.to_str().unwrap(), "--json",
    ]);
    assert_eq!(code, 0, "{err}");
    let e = json(&out);
    assert_eq!(e["bounds_min"], serde_json::json!([-5.0, -5.0, -5.0]));
    assert_eq!((e["value_min"].as_f64(), e["value_max"].as_f64()), (Some(-1.0), Some(120.0)));
    let (code, out, _) = gsenc(&["info", m.to_str().unwrap(), "--json"]);
    assert_eq!(code, 0);
    assert_eq!(json(&out)["time"], -0.5);

    // A misspelt name is refused by the parser (exit code 2), which lists the
    // names, before the missing input file is ever opened.
    let (missing, out) = (dir.join("missing.f32"), dir.join("out.gsm"));
    let (missing, out) = (missing.to_str().unwrap(), out.to_str().unwrap());
    let grid = ["encode", "grid", "--input", missing, "--dims", "4,4,4", "--budget", "8", "-o", out];
    for (extra, bad, names) in [
        (["--dtype", "f32", "--schedule", "fulll"], "fulll", "full, matched, short, tuned"),
        (["--dtype", "f32", "--payload", "8bits"], "8bits", "f32, 8bit, 8bit-u16, packed"),
        (["--schedule", "full", "--dtype", "f23"], "f23", "u8, u16, f32, f64"),
    ] {
        let mut a = grid.to_vec();
        a.extend_from_slice(&extra);
        let (code, _, err) = gsenc(&a);
        assert_eq!(code, 2, "{err}");
        assert!(err.contains(bad) && err.contains(names) && !err.contains("missing.f32"), "{err}");
    }
    let (code, _, err) = gsenc(&[
        "encode-series", "--positions", missing, "--smoothing-length", missing, "--values", missing, "--count", "600",
        "--dims", "8", "--budget", "8", "--warm", "dens", "-o", out,
    ]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("dens") && err.contains("off, coarse, dense") && !err.contains("missing.f32"), "{err}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `--support stored` (the default) stores where the data are, in a 1.2
/// file, and the decode is 0 elsewhere; `--support none` writes the
/// paper's 1.1 model.
#[test]
fn the_support_is_stored_by_default_and_none_leaves_it_out() {
    let dir = tmpdir("support");
    let (input, vals) = write_input(&dir);
    // The upper half in x is empty (0 in data units, the range's minimum).
    let vals: Vec<f32> = vals.iter().enumerate().map(|(i, &v)| if i % 20 >= 10 { 0.0 } else { v }).collect();
    std::fs::write(&input, gsenc::io::raw::to_f32_bytes(&vals)).unwrap();
    let inp = input.to_str().unwrap();
    let in_support = vals.iter().filter(|&&v| v / 12.0 > 0.005).count();
    for (support, version, voxels) in [("stored", "gsenc model 1.2", serde_json::json!(in_support)), ("none", "gsenc model 1.1", serde_json::Value::Null)] {
        let m = dir.join(format!("{support}.gsm"));
        let ms = m.to_str().unwrap();
        let (code, _, err) = gsenc(&[
            "encode", "grid", "--input", inp, "--dims", "20,16,12", "--dtype", "f32", "--budget", "120", "--iters", "60",
            "--points", "1024", "--support", support, "-o", ms, "--quiet",
        ]);
        assert_eq!(code, 0, "{err}");
        let (_, out, _) = gsenc(&["info", ms, "--json"]);
        let info = json(&out);
        assert_eq!((info["format"].as_str(), &info["support_voxels"]), (Some(version), &voxels), "{out}");
        let raw = dir.join(format!("{support}.raw"));
        let (code, _, err) = gsenc(&["decode", ms, "-o", raw.to_str().unwrap(), "--quiet"]);
        assert_eq!(code, 0, "{err}");
        let decoded = gsenc::io::raw::read_raw(&raw, [20, 16, 12], gsenc::io::raw::DType::F32, gsenc::io::raw::Order::XFastest).unwrap();
        let empty_max = (0..vals.len()).filter(|&i| vals[i] == 0.0).map(|i| decoded.values[i].abs()).fold(0f32, f32::max);
        if support == "stored" {
            assert_eq!(empty_max, 0.0);
        } else {
            assert!(empty_max > 0.0, "the paper's model has no tail in the empty half: no test");
        }
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn payloads_convert_info_and_sub_box_decode() {
    let dir = tmpdir("payloads");
    let (input, _) = write_input(&dir);
    let inp = input.to_str().unwrap();
    let p = |name: &str| dir.join(name).to_str().unwrap().to_string();
    let grid_args = ["--input", inp, "--dims", "20,16,12", "--dtype", "f32"];
    let encode = |payload: &str, out: &str| {
        let mut args = vec!["encode", "grid"];
        args.extend(grid_args);
        args.extend(["--budget", "300", "--iters", "100", "--points", "2048", "--time", "2.5", "--payload", payload, "-o", out, "--json", "--quiet"]);
        let (code, out, err) = gsenc(&args);
        assert_eq!(code, 0, "{err}");
        json(&out)
    };
    let eval = |model: &str| {
        let mut args = vec!["eval", model];
        args.extend(grid_args);
        args.push("--json");
        let (code, out, err) = gsenc(&args);
        assert_eq!(code, 0, "{err}");
        json(&out)["voxel_psnr"].as_f64().unwrap()
    };
    let info = |model: &str| {
        let (code, out, err) = gsenc(&["info", model, "--json"]);
        assert_eq!(code, 0, "{err}");
        json(&out)
    };

    // The same encode stored both ways: the 8-bit file is about 4x smaller,
    // and the PSNR it reports (and stores) is that of the file as read back.
    let (f32m, eightm) = (p("f32.gsm"), p("8.gsm"));
    let e32 = encode("f32", &f32m);
    let e8 = encode("8bit", &eightm);
    assert_eq!(e8["payload"], "8bit");
    assert!(e8["bytes"].as_u64().unwrap() * 3 < e32["bytes"].as_u64().unwrap(), "{e8} vs {e32}");
    let psnr8 = eval(&eightm);
    assert!((psnr8 - e8["voxel_psnr"].as_f64().unwrap()).abs() < 1e-9);
    assert!((eval(&f32m) - psnr8).abs() < 0.5, "8-bit costs little PSNR");
    let i8 = info(&eightm);
    assert_eq!((i8["payload"].as_str(), i8["format"].as_str()), (Some("8bit"), Some("gsenc model 1.2")));
    assert!(i8["fell_back"].is_null(), "an encode on the CPU it chose did not fall back");
    assert!((i8["encode_psnr"].as_f64().unwrap() - psnr8).abs() < 1e-9);
    assert_eq!(i8["time"].as_f64(), Some(2.5));

    // The packed payload: its precision measured by the encode, its loss
    // against the float32 model (the same parameters) at most 0.1 dB, and
    // smaller than the 8-bit one; a conversion packs at the default.
    let packedm = p("packed.gsm");
    let ep = encode("packed", &packedm);
    let psnr_packed = eval(&packedm);
    assert!((psnr_packed - ep["voxel_psnr"].as_f64().unwrap()).abs() < 1e-9);
    assert!((ep["float32_psnr"].as_f64().unwrap() - eval(&f32m)).abs() < 1e-9, "{ep}");
    assert!(eval(&f32m) - psnr_packed <= 0.1, "{ep}");
    let ip = info(&packedm);
    assert_eq!(ip["precision"], ep["precision"]);
    assert_eq!(ip["precision"].as_object().map(|o| o.len()), Some(5), "{ip}");
    assert!(ip["payload_bytes_per_primitive"].as_f64() < i8["payload_bytes_per_primitive"].as_f64(), "{ip} vs {i8}");
    assert!(info(&f32m)["precision"].is_null());
    let (code, _, err) = gsenc(&["convert", &f32m, "--payload", "packed", "-o", &p("conv.gsm")]);
    assert_eq!(code, 0, "{err}");
    let d = gsenc::format::packed::Precision::DEFAULT;
    let default = serde_json::json!({"centre": d.centre, "scale": d.scale, "rotation": d.rotation, "value": d.value, "weight": d.weight});
    assert_eq!(info(&p("conv.gsm"))["precision"], default);
    // A packed model written packed again is the same file, at its own precision.
    let (code, _, err) = gsenc(&["convert", &packedm, "--payload", "packed", "-o", &p("again.gsm")]);
    assert_eq!(code, 0, "{err}");
    assert!(std::fs::read(&packedm).unwrap() == std::fs::read(p("again.gsm")).unwrap(), "a packed model repacked changed");

    // convert: f32 -> 8bit-u16 -> f32; the PSNR of a lossy conversion is no
    // longer known, and going back to f32 loses nothing more.
    let (u16m, back) = (p("u16.gsm"), p("back.gsm"));
    let (code, out, err) = gsenc(&["convert", &f32m, "--payload", "8bit-u16", "-o", &u16m, "--json"]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(json(&out)["to"], "8bit-u16");
    assert!(info(&u16m)["encode_psnr"].is_null());
    let (code, _, err) = gsenc(&["convert", &u16m, "--payload", "f32", "-o", &back]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(eval(&back), eval(&u16m));
    assert_eq!(info(&back)["payload"], "f32");
    let (code, _, err) = gsenc(&["convert", &f32m, "--payload", "8bit", "-o", &f32m]);
    assert_eq!(code, 2, "{err}");
    let (code, _, err) = gsenc(&["convert", &f32m, "--payload", "4bit", "-o", &p("x.gsm")]);
    assert!(code == 2 && err.contains("8bit-u16"), "{err}");

    // A sub-box decode, at twice the resolution, is that part of the whole
    // decode, and its .vti places it in the world.
    let whole = p("whole.raw");
    let (code, _, err) = gsenc(&["decode", &eightm, "--dims", "40,32,24", "-o", &whole, "--quiet"]);
    assert_eq!(code, 0, "{err}");
    let whole: Vec<f32> = std::fs::read(&whole).unwrap().chunks_exact(4).map(|b| f32::from_le_bytes(b.try_into().unwrap())).collect();
    let part = p("part.vti");
    let (code, out, err) = gsenc(&["decode", &eightm, "--dims", "40,32,24", "--box", "5,6,7,25,30,19", "-o", &part, "--json", "--quiet"]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(json(&out)["voxels"], 20 * 24 * 12);
    let v = vti::read_vti(std::path::Path::new(&part), None).unwrap();
    assert_eq!(v.grid.dims, [20, 24, 12]);
    assert_eq!(v.spacing, [0.5; 3]);
    assert_eq!(v.origin, [5.0 * 0.5 - 0.25, 6.0 * 0.5 - 0.25, 7.0 * 0.5 - 0.25]);
    let mut i = 0;
    for z in 7..19 {
        for y in 6..30 {
            for x in 5..25 {
                let w = whole[(z * 32 + y) * 40 + x];
                assert!((v.grid.values[i] - w).abs() <= 1e-5 * w.abs().max(1.0), "({x},{y},{z}): {} vs {w}", v.grid.values[i]);
                i += 1;
            }
        }
    }
    let (code, _, err) = gsenc(&["decode", &eightm, "--box", "0,0,0,21,16,12", "-o", &p("bad.raw")]);
    assert!(code == 2 && err.contains("sub-box"), "{err}");
    assert!(!dir.join("bad.raw").exists());
    assert!(std::fs::read_dir(&dir).unwrap().all(|e| !e.unwrap().file_name().to_string_lossy().contains(".tmp-")));
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A build without the `hdf5` feature keeps the store commands, which say
/// how to get them instead of failing obscurely.
#[cfg(not(feature = "hdf5"))]
#[test]
fn store_commands_without_hdf5_say_how_to_get_them() {
    let dir = tmpdir("nohdf5");
    let store = dir.join("s.h5");
    let (s, m) = (store.to_str().unwrap(), dir.join("m.gsm"));
    for args in [
        vec!["store", "add", s, m.to_str().unwrap()],
        vec!["store", "extract", s, "rho/1/0", "-o", "x.gsm"],
        vec!["decode-series", s, "-o", "x.h5"],
    ] {
        let (code, _, err) = gsenc(&args);
        assert_eq!(code, 2, "{args:?}: {err}");
        assert!(err.contains("--features hdf5"), "{args:?}: {err}");
    }
    assert!(!store.exists());
}

#[test]
fn decode_of_several_pieces_writes_one_global_field() {
    use gsenc::field::{IndexFrame, Transform, ValueRange};
    use gsenc::model::{Model, ModelMeta};
    let dir = tmpdir("pieces");
    let range = ValueRange::new(2.0, 12.0, Transform::Linear).unwrap();
    // Two pieces of one lattice (voxel 0.5), the second 10 voxels along x.
    let piece = |x0: f64, seed: u64| {
        let g = blobs([14, 8, 6], seed, 2);
        let mut cfg = gsenc::encode::EncodeConfig::new(30, gsenc::encode::Schedule::Short);
        cfg.iterations = Some(30);
        let target = gsenc::input::Target { reference: &g, samples: &g };
        let out = gsenc::encode::encode(&target, &cfg, None, &mut CpuBackend::new(), &mut |_| {}).unwrap();
        let mut meta = ModelMeta::new(IndexFrame { dims: g.dims, bmin: [x0, 0.0, 0.0], gamma: 2.0 }, range);
        meta.field = "rho".into();
        Model { meta, params: out.params, support: None }
    };
    let (a, b) = (piece(0.0, 1), piece(5.0, 2));
    let (pa, pb) = (dir.join("rho_r0.gsm"), dir.join("rho_r1.gsm"));
    std::fs::write(&pa, gsenc::format::write_model(&a).unwrap()).unwrap();
    std::fs::write(&pb, gsenc::format::write_model(&b).unwrap()).unwrap();
    let (sa, sb) = (pa.to_str().unwrap(), pb.to_str().unwrap());
    let out = dir.join("global.raw");
    let (code, _, err) = gsenc(&["decode", sa, sb, "-o", out.to_str().unwrap()]);
    assert_eq!(code, 0, "{err}");
    // The global field is the library's merged decode, in data units.
    let merged = gsenc::domain::pieces::merge(&[a.clone(), b.clone()]).unwrap();
    assert_eq!(merged.meta.frame.dims, [24, 8, 6]);
    let want = merged.decode(&mut CpuBackend::new(), None).unwrap();
    let got = std::fs::read(&out).unwrap().chunks_exact(4).map(|b| f32::from_le_bytes(b.try_into().unwrap())).collect::<Vec<f32>>();
    assert_eq!(got.len(), want.values.len());
    for (g, w) in got.iter().zip(&want.values) {
        assert!((g - range.denormalize(*w) as f32).abs() < 1e-4, "{g} vs {w}");
    }
    // One piece's region alone: its cells of the global field.
    let (code, _, err) = gsenc(&["decode", sa, sb, "--piece", "1", "-o", out.to_str().unwrap()]);
    assert_eq!(code, 0, "{err}");
    let part = std::fs::read(&out).unwrap().chunks_exact(4).map(|b| f32::from_le_bytes(b.try_into().unwrap())).collect::<Vec<f32>>();
    assert_eq!(part.len(), 14 * 8 * 6);
    assert_eq!(part[0], got[10], "piece 1 starts 10 voxels along x");
    // Pieces that do not fit together, and a piece that is not there.
    let (code, _, err) = gsenc(&["decode", sa, sb, "--piece", "2", "-o", out.to_str().unwrap()]);
    assert_eq!(code, 2, "{err}");
    let mut c = b.clone();
    c.meta.frame.bmin[0] = 5.25; // half a voxel off the lattice
    let pc = dir.join("rho_off.gsm");
    std::fs::write(&pc, gsenc::format::write_model(&c).unwrap()).unwrap();
    let (code, _, err) = gsenc(&["decode", sa, pc.to_str().unwrap(), "-o", out.to_str().unwrap()]);
    assert_eq!(code, 2);
    assert!(err.contains("lattice"), "{err}");
}

#[test]
fn standard_output_and_links_as_outputs() {
    let dir = tmpdir("stdout");
    let (input, _) = write_input(&dir);
    let inp = input.to_str().unwrap();
    let encode = ["encode", "grid", "--input", inp, "--dims", "20,16,12", "--dtype", "f32", "--budget", "60", "--iters", "30", "--points", "512", "--backend", "cpu", "--json", "-q", "-o"];
    let model = dir.join("m.gsm");
    let (code, _, err) = gsenc(&[&encode[..], &[model.to_str().unwrap()]].concat());
    assert_eq!(code, 0, "{err}");
    let file_bytes = std::fs::read(&model).unwrap();

    // `-o -`: the model alone on standard output, the results on standard error.
    let out = Command::new(env!("CARGO_BIN_EXE_gsenc")).args([&encode[..], &["-"]].concat()).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert_eq!(out.stdout, file_bytes, "the same model through standard output");
    assert_eq!(json(&String::from_utf8_lossy(&out.stderr))["bytes"].as_u64().unwrap() as usize, file_bytes.len());
    assert!(!dir.join("-").exists());

    // A decode to standard output is the raw file's bytes, and nothing else.
    let raw = dir.join("d.raw");
    let (code, _, err) = gsenc(&["decode", model.to_str().unwrap(), "--backend", "cpu", "-q", "-o", raw.to_str().unwrap()]);
    assert_eq!(code, 0, "{err}");
    for to in ["-", "/dev/stdout"] {
        let out = Command::new(env!("CARGO_BIN_EXE_gsenc")).args(["decode", model.to_str().unwrap(), "--backend", "cpu", "-q", "--json", "-o", to]).output().unwrap();
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        assert_eq!(out.stdout, std::fs::read(&raw).unwrap(), "decode -o {to}");
        assert_eq!(json(&String::from_utf8_lossy(&out.stderr))["voxels"], 20 * 16 * 12);
    }

    // Written through a symbolic link, the link stays and its file is replaced.
    #[cfg(unix)]
    {
        std::fs::create_dir(dir.join("kept")).unwrap();
        std::fs::write(dir.join("kept/m.gsm"), b"old").unwrap();
        std::os::unix::fs::symlink("kept/m.gsm", dir.join("link.gsm")).unwrap();
        let (code, _, err) = gsenc(&[&encode[..], &[dir.join("link.gsm").to_str().unwrap()]].concat());
        assert_eq!(code, 0, "{err}");
        assert!(std::fs::symlink_metadata(dir.join("link.gsm")).unwrap().file_type().is_symlink());
        assert_eq!(std::fs::read(dir.join("kept/m.gsm")).unwrap(), file_bytes);
    }
    // A folder as the output is an i/o error (5), and stays a folder.
    let (code, _, err) = gsenc(&[&encode[..], &[dir.join("kept").to_str().unwrap()]].concat());
    assert_eq!(code, 5, "{err}");
    assert!(err.contains("folder"), "{err}");
    assert!(dir.join("kept").is_dir());
}
