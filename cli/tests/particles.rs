//! The tool's particle and cell inputs end to end: encode, deposit and
//! eval of particles and of cells, and `encode-series` of a particle time
//! series (its warm starts, CSV, plot and store).

#[path = "../../tests/common/mod.rs"]
mod common;
mod tool;
use common::*;
use gsenc::io::vti;
use std::path::{Path, PathBuf};
use tool::{gsenc, json, write_input, write_f32, write_particles};

#[test]
fn particles_encode_deposit_and_eval_agree() {
    let dir = tmpdir("particles");
    let [pos, hh, mass, val] = write_particles(&dir);
    let s = |p: &PathBuf| p.to_str().unwrap().to_string();
    let inputs = [
        "--positions", &s(&pos), "--smoothing-length", &s(&hh), "--mass", &s(&mass), "--values", &s(&val),
        "--count", "600", "--row", "1", "--dims", "24,16,8", "--log10",
    ];
    let m = dir.join("p.gsm");
    let mut a = vec!["encode", "particles"];
    a.extend_from_slice(&inputs);
    a.extend_from_slice(&["--budget", "400", "--schedule", "short", "--iters", "100", "--points", "2048", "-o", m.to_str().unwrap(), "--json"]);
    let (code, out, err) = gsenc(&a);
    assert_eq!(code, 0, "{err}");
    let e = json(&out);
    // Every key of a grid encode, plus what the deposit did.
    let (gcode, gout, gerr) = gsenc(&[
        "encode", "grid", "--input", &s(&write_input(&dir).0), "--dims", "20,16,12", "--dtype", "f32", "--budget", "50",
        "--iters", "3", "--points", "256", "-o", dir.join("g.gsm").to_str().unwrap(), "--json",
    ]);
    assert_eq!(gcode, 0, "{gerr}");
    for key in json(&gout).as_object().unwrap().keys() {
        assert!(e.get(key).is_some(), "particle encode lacks grid key {key}: {out}");
    }
    for key in ["items", "samples", "outside", "deposit_seconds", "deposit_peak_bytes", "peak_rss_bytes"] {
        assert!(e.get(key).is_some(), "missing {key}: {out}");
    }
    assert_eq!(e["items"], 600);
    assert_eq!(e["outside"], 0);
    assert_eq!(e["dims"], serde_json::json!([24, 16, 8]));
    let psnr = e["voxel_psnr"].as_f64().unwrap();
    assert!(psnr > 25.0, "{psnr}");

    // The deposit in data units, as .vti, scores the model as the encode did.
    let dep = dir.join("dep.vti");
    let mut a = vec!["deposit", "particles"];
    a.extend_from_slice(&inputs);
    a.extend_from_slice(&["-o", dep.to_str().unwrap(), "--json"]);
    let (code, out, err) = gsenc(&a);
    assert_eq!(code, 0, "{err}");
    assert_eq!(json(&out)["voxels"], 24 * 16 * 8);
    let parsed = vti::read_vti(&dep, None).unwrap();
    let gamma = e["gamma"].as_f64().unwrap();
    assert!((parsed.spacing[0] - 1.0 / gamma).abs() < 1e-9);
    let (code, out, err) = gsenc(&["eval", m.to_str().unwrap(), "--input", dep.to_str().unwrap(), "--json"]);
    assert_eq!(code, 0, "{err}");
    let eval_psnr = json(&out)["voxel_psnr"].as_f64().unwrap();
    assert!((eval_psnr - psnr).abs() < 0.05, "eval {eval_psnr} vs encode {psnr}");

    // The value range is that of row 1 of the two-step files.
    let (code, out, _) = gsenc(&["info", m.to_str().unwrap(), "--json"]);
    assert_eq!(code, 0);
    let vmax = json(&out)["value_max"].as_f64().unwrap();
    let vals = gsenc::io::raw::read_items(&val, gsenc::io::raw::DType::F32, 1, gsenc::io::raw::Rows { count: Some(600), row: 1 }).unwrap();
    // (serde_json's default float parsing may be one ulp off)
    assert!((vmax - vals.iter().fold(f64::MIN, |a, &b| a.max(b.log10()))).abs() < 1e-12);

    // Errors: mismatched arrays, a row past the end, zero smoothing length.
    let short_hh = dir.join("hh_short.f32");
    write_f32(&short_hh, &[0.1; 599]);
    let (code, _, err) = gsenc(&[
        "deposit", "particles", "--positions", &s(&pos), "--smoothing-length", &s(&short_hh), "--values", &s(&val),
        "--count", "600", "--dims", "8", "-o", dir.join("x.raw").to_str().unwrap(),
    ]);
    assert_eq!(code, 3, "{err}");
    assert!(err.contains("not whole rows of 600"), "{err}");
    let (code, _, err) = gsenc(&[
        "deposit", "particles", "--positions", &s(&pos), "--smoothing-length", &s(&hh), "--values", &s(&val),
        "--count", "600", "--row", "2", "--dims", "8", "-o", dir.join("x.raw").to_str().unwrap(),
    ]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("row 2"), "{err}");
    // A device as the first array is refused unread; as another array, it is
    // read no further than the first array's items.
    #[cfg(unix)]
    for (positions, hh, code, says) in [("/dev/zero".to_owned(), s(&hh), 2, "is a device"), (s(&pos), "/dev/zero".to_owned(), 3, "more than 1200 items")] {
        let (c, _, err) = gsenc(&[
            "deposit", "particles", "--positions", &positions, "--smoothing-length", &hh, "--values", &s(&val),
            "--count", "600", "--dims", "8", "-o", dir.join("x.raw").to_str().unwrap(),
        ]);
        assert_eq!(c, code, "{err}");
        assert!(err.contains("/dev/zero") && err.contains(says), "{err}");
    }
    let zero_hh = dir.join("hh_zero.f32");
    write_f32(&zero_hh, &[0.0; 1200]);
    let (code, _, err) = gsenc(&[
        "encode", "particles", "--positions", &s(&pos), "--smoothing-length", &s(&zero_hh), "--values", &s(&val),
        "--count", "600", "--dims", "8", "--budget", "10", "-o", dir.join("z.gsm").to_str().unwrap(),
    ]);
    assert_eq!(code, 3, "{err}");
    assert!(err.contains("smoothing length 0"), "{err}");
    assert!(!dir.join("z.gsm").exists() && !dir.join("x.raw").exists());
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn cells_encode_and_deposit() {
    let dir = tmpdir("cells");
    // A 2-level AMR-like tiling of [0, 1]^3: 8 coarse cells, one of them split.
    let (mut c, mut e, mut v) = (vec![], vec![], vec![]);
    for k in 0..2 {
        for j in 0..2 {
            for i in 0..2 {
                let centre = [0.25 + 0.5 * i as f32, 0.25 + 0.5 * j as f32, 0.25 + 0.5 * k as f32];
                if (i, j, k) == (1, 1, 0) {
                    for s in 0..8 {
                        let o = [(s & 1) as f32, ((s >> 1) & 1) as f32, ((s >> 2) & 1) as f32];
                        c.extend([0, 1, 2].map(|a| centre[a] - 0.125 + 0.25 * o[a]));
                        e.extend([0.25f32; 3]);
                        v.push(10.0 + s as f32);
                    }
                } else {
                    c.extend(centre);
                    e.extend([0.5f32; 3]);
                    v.push(1.0 + (i + 2 * j + 4 * k) as f32);
                }
            }
        }
    }
    let files = ["c.f32", "e.f32", "v.f32"].map(|n| dir.join(n));
    for (p, x) in files.iter().zip([&c, &e, &v]) {
        write_f32(p, x);
    }
    let s = |p: &PathBuf| p.to_str().unwrap().to_string();
    let m = dir.join("c.gsm");
    let (code, out, err) = gsenc(&[
        "encode", "cells", "--centers", &s(&files[0]), "--sizes", &s(&files[1]), "--values", &s(&files[2]), "--dims", "16",
        "--budget", "12", "--iters", "60", "--points", "1024", "-o", m.to_str().unwrap(), "--json",
    ]);
    assert_eq!(code, 0, "{err}");
    let r = json(&out);
    assert_eq!(r["items"], 15);
    assert_eq!(r["empty_voxels"], 0);
    assert_eq!(r["gamma"].as_f64().unwrap(), 16.0);
    let dep = dir.join("dep.raw");
    let (code, _, err) = gsenc(&[
        "deposit", "cells", "--centers", &s(&files[0]), "--sizes", &s(&files[1]), "--values", &s(&files[2]), "--dims", "16",
        "-o", dep.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{err}");
    let d = gsenc::io::raw::read_raw(&dep, [16; 3], gsenc::io::raw::DType::F32, gsenc::io::raw::Order::XFastest).unwrap();
    // Voxel (0,0,0) lies only in the first coarse cell's stamp: its value, 1.
    assert!((d.values[0] - 1.0).abs() < 1e-5, "{}", d.values[0]);
    let (code, _, err) = gsenc(&["deposit", "cells", "--centers", &s(&files[0]), "--values", &s(&files[2]), "--dims", "16", "-o", dep.to_str().unwrap()]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("--sizes") || err.contains("--volumes"), "{err}");
    // Arrays that do not match are named as given, before their box is
    // fitted (an empty volume file panicked there).
    let empty = dir.join("empty.f32");
    std::fs::write(&empty, b"").unwrap();
    let (centres, volumes, values) = (s(&files[0]), s(&empty), s(&files[2]));
    for kind in ["encode", "deposit"] {
        let mut args = vec![kind, "cells", "--centers", &centres, "--volumes", &volumes, "--values", &values, "--fit-dims", "16", "-o", dep.to_str().unwrap()];
        if kind == "encode" {
            args.extend(["--budget", "4"]);
        }
        let (code, _, err) = gsenc(&args);
        assert_eq!(code, 3, "{kind}: {err}");
        assert!(err.contains("15 cell centres but 0 volumes"), "{kind}: {err}");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Writes a 3-step particle series (rows of 300 particles drifting in x):
/// positions, smoothing lengths and values as little-endian f32.
fn write_particle_series(dir: &Path, steps: usize) -> [PathBuf; 3] {
    let n = 300;
    let mut rng = gsenc::math::rng::Rng::new(9);
    let base: Vec<[f64; 3]> = (0..n).map(|_| [rng.range(0.2, 0.8), rng.range(0.2, 0.8), rng.range(0.2, 0.8)]).collect();
    let (mut pos, mut hh, mut val) = (Vec::new(), Vec::new(), Vec::new());
    for s in 0..steps {
        for (i, p) in base.iter().enumerate() {
            pos.extend([p[0] + 0.02 * s as f64, p[1], p[2]].map(|c| c as f32));
            hh.push(0.06f32);
            val.push(1.0 + (i % 7) as f32 + s as f32);
        }
    }
    let bytes = |v: &[f32]| v.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<u8>>();
    let paths = [dir.join("pos.f32"), dir.join("hh.f32"), dir.join("val.f32")];
    for (p, v) in paths.iter().zip([&pos, &hh, &val]) {
        std::fs::write(p, bytes(v)).unwrap();
    }
    paths
}

#[test]
fn encode_series_warm_starts_writes_models_csv_and_plot() {
    let dir = tmpdir("series");
    let [pos, hh, val] = write_particle_series(&dir, 3);
    let (out, csv, png) = (dir.join("models"), dir.join("psnr.csv"), dir.join("psnr.png"));
    let common = [
        "encode-series", "--positions", pos.to_str().unwrap(), "--smoothing-length", hh.to_str().unwrap(),
        "--values", val.to_str().unwrap(), "--count", "300", "--dims", "16", "--bounds", "0,0,0,1.2,1,1",
        "--budget", "60", "--schedule", "short", "--iters", "200", "--points", "512", "--validation-every", "100",
        "--validation-points", "2000", "--field", "rho", "--quiet",
    ];
    let mut args = common.to_vec();
    // A bad preview fails before any step is encoded.
    for (bad, says) in [("w=0.5", "AXIS=FRACTION"), ("volume:30,100", "elevation"), ("volume:x", "volume:AZIMUTH,ELEVATION")] {
        let mut args = common.to_vec();
        args.extend(["-o", out.to_str().unwrap(), "--preview", bad]);
        let (code, _, err) = gsenc(&args);
        assert_eq!(code, 2, "{bad}: {err}");
        assert!(err.contains(says), "{bad}: {err}");
        assert!(!out.exists(), "nothing written for a bad preview");
    }
    // So does an output that cannot be written: a plot or CSV in a folder
    // that is not there, a folder of models where a file is, or below one
    // (the plot was found out after every step was encoded and stored).
    let nowhere = dir.join("missing").join("p.png");
    let file = pos.to_str().unwrap();
    let below = format!("{file}/models");
    for (option, path) in [("--plot", nowhere.to_str().unwrap()), ("--csv", nowhere.to_str().unwrap()), ("-o", file), ("-o", &below)] {
        let mut args = common.to_vec();
        if option != "-o" {
            args.extend(["-o", out.to_str().unwrap()]);
        }
        args.extend([option, path]);
        let (code, _, err) = gsenc(&args);
        assert_eq!(code, 5, "{option} {path}: {err}");
        assert!(!err.contains("voxel PSNR") && !out.exists(), "{option} {path}: a step was encoded first: {err}");
    }
    args.extend(["--warm", "coarse", "-o", out.to_str().unwrap(), "--csv", csv.to_str().unwrap(), "--plot", png.to_str().unwrap(), "--json"]);
    args.extend(["--preview", "x=0.5", "--preview-size", "48,32"]);
    let (code, stdout, err) = gsenc(&args);
    assert_eq!(code, 0, "{err}");
    let lines: Vec<serde_json::Value> = stdout.lines().map(json).collect();
    assert_eq!(lines.len(), 4, "three steps and a summary: {stdout}");
    // Each step's picture lies beside its model, and its line says where.
    for s in 0..3 {
        let p = out.join(format!("rho_{s:06}.png"));
        assert_eq!(lines[s]["preview"], p.to_str().unwrap());
        let img = gsenc::io::image::read_png(&p).unwrap();
        assert!(img.width > 48 && img.height > 32, "{}x{}", img.width, img.height);
    }
    assert_eq!(lines[0]["start"], "independent");
    assert_eq!(lines[1]["start"], "coarse");
    assert_eq!(lines[2]["iterations"], 1000);
    assert_eq!(lines[2]["outside_items"], 0, "--bounds covers the drift");
    // Every step is a complete model on the first step's range and frame.
    let models: Vec<gsenc::model::Model> = (0..3)
        .map(|s| gsenc::format::read_model(&std::fs::read(out.join(format!("rho_{s:06}.gsm"))).unwrap()).unwrap())
        .collect();
    for (s, m) in models.iter().enumerate() {
        assert_eq!(m.meta.step, s as u64);
        assert_eq!(m.meta.range, models[0].meta.range, "one range per series");
        assert_eq!(m.meta.frame, models[0].meta.frame);
        assert_eq!(m.len(), 60);
        assert!((m.meta.encode_psnr.unwrap() - lines[s]["voxel_psnr"].as_f64().unwrap()).abs() < 1e-9);
    }
    assert_eq!(models[1].meta.schedule, "warm-coarse");
    // Later steps hold values beyond the first step's range: clamped and counted.
    assert_eq!(lines[0]["clamped_values"], 0);
    assert!(lines[2]["clamped_values"].as_u64().unwrap() > 0);
    // The CSV logs every step from iteration 0 to its end.
    let text = std::fs::read_to_string(&csv).unwrap();
    let rows: Vec<Vec<&str>> = text.lines().skip(1).map(|l| l.split(',').collect()).collect();
    let its = |step: &str| rows.iter().filter(|r| r[1] == step).map(|r| r[3].parse::<usize>().unwrap()).collect::<Vec<_>>();
    assert_eq!(its("0"), [0, 100, 200]);
    assert_eq!(its("2"), (0..=1000).step_by(100).collect::<Vec<_>>());
    let last = rows.iter().rfind(|r| r[1] == "2").unwrap();
    assert!((last[4].parse::<f64>().unwrap() - lines[2]["validation_psnr"].as_f64().unwrap()).abs() < 1e-3);
    assert_eq!(&std::fs::read(&png).unwrap()[..8], b"\x89PNG\r\n\x1a\n");
    // plot-series draws several CSVs; a foreign CSV is refused.
    let (code, _, err) = gsenc(&["plot-series", csv.to_str().unwrap(), csv.to_str().unwrap(), "-o", png.to_str().unwrap()]);
    assert_eq!(code, 0, "{err}");
    let (code, _, err) = gsenc(&["plot-series", pos.to_str().unwrap(), "-o", png.to_str().unwrap()]);
    assert_eq!(code, 4, "{err}");

    // Resumed from its stored step 1, the series' step 2 is the unbroken one's.
    let resumed = dir.join("resumed");
    let step1 = out.join("rho_000001.gsm");
    let mut args = common.to_vec();
    args.extend(["--steps", "2..3", "--warm", "coarse", "--resume-from", step1.to_str().unwrap(), "-o", resumed.to_str().unwrap()]);
    let (code, _, err) = gsenc(&args);
    assert_eq!(code, 0, "{err}");
    let again = gsenc::format::read_model(&std::fs::read(resumed.join("rho_000002.gsm")).unwrap()).unwrap();
    assert_eq!(again.params, models[2].params, "a resumed series must continue as the unbroken one");
    assert_eq!(again.meta.schedule, "warm-coarse");
    // Resuming from another field, or from a step not before the first to encode, is refused.
    let mut args = common.to_vec();
    args.extend(["--steps", "2..3", "--resume-from", step1.to_str().unwrap(), "-o", resumed.to_str().unwrap()]);
    let field_at = args.iter().position(|a| *a == "rho").unwrap();
    args[field_at] = "temp";
    let (code, _, err) = gsenc(&args);
    assert_eq!(code, 2);
    assert!(err.contains("holds field 'rho'"), "{err}");
    let mut args = common.to_vec();
    args.extend(["--steps", "1..3", "--resume-from", step1.to_str().unwrap(), "-o", resumed.to_str().unwrap()]);
    let (code, _, err) = gsenc(&args);
    assert_eq!(code, 2);
    assert!(err.contains("must come after"), "{err}");
    // So is a --range other than the series' (the model's).
    let mut args = common.to_vec();
    args.extend(["--steps", "2..3", "--range", "0,1e6", "--resume-from", step1.to_str().unwrap(), "-o", resumed.to_str().unwrap()]);
    let (code, _, err) = gsenc(&args);
    assert_eq!(code, 2);
    assert!(err.contains("keeps its range"), "{err}");

    // A step the input does not hold is a clear error, before any work.
    let mut args = common.to_vec();
    let other = dir.join("other");
    args.extend(["--steps", "1..5", "-o", other.to_str().unwrap()]);
    let (code, _, err) = gsenc(&args);
    assert_eq!(code, 2);
    assert!(err.contains("step 3 is missing"), "{err}");
    assert!(!other.exists());
    // So is a range far beyond it (which once asked for 2^63 bytes of steps).
    let mut args = common.to_vec();
    args.extend(["--steps", "1..18446744073709551615", "-o", other.to_str().unwrap()]);
    let (code, _, err) = gsenc(&args);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("step 3 is missing"), "{err}");
    assert!(!other.exists());
}

#[test]
fn encode_series_warm_starts_auto_by_default_and_says_what_it_took() {
    let dir = tmpdir("series-auto");
    let [pos, hh, val] = write_particle_series(&dir, 2);
    let out = dir.join("models");
    let (code, stdout, err) = gsenc(&[
        "encode-series", "--positions", pos.to_str().unwrap(), "--smoothing-length", hh.to_str().unwrap(),
        "--values", val.to_str().unwrap(), "--count", "300", "--dims", "16", "--bounds", "0,0,0,1.2,1,1",
        "--budget", "60", "--schedule", "short", "--iters", "200", "--points", "512", "--validation-every", "20",
        "--validation-points", "2000", "--field", "rho", "--quiet", "--json", "-o", out.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{err}");
    let lines: Vec<serde_json::Value> = stdout.lines().map(json).collect();
    assert_eq!(lines[0]["start"], "independent");
    assert!(lines[0]["taken"].is_null());
    assert_eq!(lines[1]["start"], "auto");
    let taken = lines[1]["taken"].as_str().unwrap();
    assert!(["kept", "repaired", "fresh"].contains(&taken), "{taken}");
    assert!(lines[1]["iterations"].as_u64().unwrap() <= 200, "the schedule's iterations are the cap");
    let model = out.join("rho_000001.gsm");
    let (code, stdout, err) = gsenc(&["info", "--json", model.to_str().unwrap()]);
    assert_eq!(code, 0, "{err}");
    let info = json(&stdout);
    assert_eq!(info["warm_start"], taken);
    assert_eq!(info["warm_moved"], lines[1]["moved"]);
    assert_eq!(info["schedule"], "warm-auto");
    assert_eq!(info["iterations"], lines[1]["iterations"]);
}

/// With the `hdf5` feature the series goes into one store, a complete model
/// per step, readable like any store entry.
#[cfg(feature = "hdf5")]
#[test]
fn encode_series_into_a_store() {
    let dir = tmpdir("series-store");
    let [pos, hh, val] = write_particle_series(&dir, 2);
    let store = dir.join("run.h5");
    let (code, _, err) = gsenc(&[
        "encode-series", "--positions", pos.to_str().unwrap(), "--smoothing-length", hh.to_str().unwrap(),
        "--values", val.to_str().unwrap(), "--count", "300", "--dims", "12", "--budget", "40", "--schedule", "short",
        "--iters", "100", "--points", "256", "--validation-points", "500", "--warm", "dense", "--as-grid",
        "--payload", "8bit", "--field", "rho", "--quiet", "-o", store.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{err}");
    let (code, stdout, err) = gsenc(&["info", "--json", store.to_str().unwrap()]);
    assert_eq!(code, 0, "{err}");
    let v = json(&stdout);
    let entries = v["entries"].as_array().unwrap();
    let names: Vec<&str> = entries.iter().map(|e| e["entry"].as_str().unwrap()).collect();
    assert_eq!(names, ["/rho/0/rank_0", "/rho/1/rank_0"]);
    for e in entries {
        assert_eq!(e["payload"], "8bit");
        assert_eq!(e["primitives"], 40);
        assert_eq!(e["value_min"], entries[0]["value_min"]);
        assert_eq!(e["value_max"], entries[0]["value_max"]);
    }
    assert_eq!(entries[1]["schedule"], "warm-dense");
    assert_eq!(entries[1]["iterations"], 1500);
    // Steps are never rewritten: a series whose steps the store holds is
    // refused before any is encoded, and the store is left as it was; so
    // is a file that is not a store.
    let before = std::fs::read(&store).unwrap();
    let foreign = dir.join("foreign.h5");
    std::fs::copy(&pos, &foreign).unwrap();
    // A new store's folder is not made: one that is not there is refused
    // before any step too (it was found at the first step's storing).
    let nowhere = dir.join("missing").join("run.h5");
    for (output, exit, says) in [(&store, 2, "holds /rho/1/rank_0 already"), (&foreign, 4, "not an HDF5 file"), (&nowhere, 5, "no folder")] {
        let (code, _, err) = gsenc(&[
            "encode-series", "--positions", pos.to_str().unwrap(), "--smoothing-length", hh.to_str().unwrap(),
            "--values", val.to_str().unwrap(), "--count", "300", "--dims", "12", "--budget", "40", "--schedule", "short",
            "--iters", "100", "--points", "256", "--steps", "1", "--field", "rho", "--quiet", "-o", output.to_str().unwrap(),
        ]);
        assert_eq!(code, exit, "{err}");
        assert!(err.contains(says) && !err.contains("voxel PSNR"), "{err}");
    }
    assert_eq!(std::fs::read(&store).unwrap(), before);
}
