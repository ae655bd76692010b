//! Seeded random runs of the tool, as a careless user might type them:
//! each command with its options drawn from what is valid and what is not
//! (missing, foreign, cut and damaged files, dims of zero, of the wrong
//! count or past 2^32, unknown names, huge or non-numeric counts, outputs
//! in folders that do not exist, onto folders, or over a file already
//! there). Nothing is expected of a run but what the tool promises of
//! every run: it never panics or dies of a signal, it exits 0 or with one
//! of its codes (README "Exit codes"; 2 for what clap refuses), a failure
//! says why on the standard error, no temporary file is left behind, and
//! a failed run leaves a file that was there byte for byte as it was.
//!
//! `GSENC_TOOL_WALKS` sets the number of runs (default 120, about 20 s on
//! two cores), `GSENC_TOOL_WALK_SEED` the first seed (default 1); a
//! failure names its seed and its command line.

#[path = "../../tests/common/mod.rs"]
mod common;
mod tool;
use common::{tmpdir, Draws as Rng};
use std::path::Path;
use tool::{gsenc, write_input, write_particles};

/// Runs, unless `GSENC_TOOL_WALKS` says.
const RUNS: u64 = 120;

/// Mostly `usual`, sometimes one of `odd`.
fn value(rng: &mut Rng, usual: &str, odd: &[&str]) -> String {
    match rng.chance(0.8) || odd.is_empty() {
        true => usual.to_string(),
        false => odd[rng.below(odd.len())].to_string(),
    }
}

/// The files a run may name, made once.
struct Inputs {
    field: String,
    model: String,
    model_8bit: String,
    cut: String,
    damaged: String,
    empty: String,
    particles: [String; 4],
}

fn inputs(dir: &Path) -> Inputs {
    let s = |p: &Path| p.to_str().unwrap().to_string();
    let (field, _) = write_input(dir);
    let particles = write_particles(dir).map(|p| s(&p));
    let model = dir.join("m.gsm");
    let (code, _, err) = gsenc(&[
        "encode", "grid", "--input", &s(&field), "--dims", "20,16,12", "--dtype", "f32", "--budget", "12", "--schedule", "short",
        "--iters", "10", "--points", "256", "--backend", "cpu", "-o", &s(&model), "--quiet",
    ]);
    assert_eq!(code, 0, "{err}");
    let model_8bit = dir.join("m8.gsm");
    let (code, _, err) = gsenc(&["convert", &s(&model), "--payload", "8bit", "-o", &s(&model_8bit)]);
    assert_eq!(code, 0, "{err}");
    let bytes = std::fs::read(&model).unwrap();
    let (cut, damaged, empty) = (dir.join("cut.gsm"), dir.join("damaged.gsm"), dir.join("empty.gsm"));
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
    let mut d = bytes.clone();
    let at = d.len() / 3;
    d[at] ^= 0x10;
    std::fs::write(&damaged, d).unwrap();
    std::fs::write(&empty, b"").unwrap();
    Inputs { field: s(&field), model: s(&model), model_8bit: s(&model_8bit), cut: s(&cut), damaged: s(&damaged), empty: s(&empty), particles }
}

/// One command line.
fn command(rng: &mut Rng, inp: &Inputs, out: &Path) -> Vec<String> {
    let o = |name: &str| out.join(name).to_str().unwrap().to_string();
    let output = |rng: &mut Rng, ext: &str| -> String {
        match rng.below(10) {
            0 => format!("/nonexistent-gsenc-walk/x.{ext}"),
            1 => out.to_str().unwrap().to_string(),
            2 => o(&format!("x.{}", ["txt", "gsm", "vti", "raw"][rng.below(4)])),
            _ => o(&format!("x.{ext}")),
        }
    };
    let model = |rng: &mut Rng| -> String {
        let all = [&inp.model, &inp.model_8bit, &inp.cut, &inp.damaged, &inp.empty, &inp.field];
        match rng.chance(0.7) {
            true => inp.model.clone(),
            false => match rng.below(7) {
                6 => "/nonexistent-gsenc-walk/m.gsm".into(),
                i => all[i].clone(),
            },
        }
    };
    let mut a: Vec<String> = Vec::new();
    let push = |a: &mut Vec<String>, items: &[&str]| a.extend(items.iter().map(|s| s.to_string()));
    match rng.below(7) {
        0 | 1 => {
            push(&mut a, &["encode", "grid", "--input"]);
            let input = value(rng, &inp.field, &[&inp.empty, &inp.model, "/nonexistent-gsenc-walk/f.f32"]);
            a.push(input);
            let dims = value(rng, "20,16,12", &["0,16,12", "20,16", "20,16,12,1", "4294967296,1,1", "1,4294967295,1", "a,b,c", "10,16,12", "-1,2,3"]);
            let dtype = value(rng, "f32", &["u8", "u16", "f64", "x"]);
            let budget = value(rng, "10", &["0", "1", "1000000", "99999999999999999999", "-3", "ten"]);
            push(&mut a, &["--dims", &dims, "--dtype", &dtype, "--budget", &budget, "--backend", "cpu"]);
            let schedule = value(rng, "short", &["matched", "tuned", "bogus"]);
            let iters = value(rng, "8", &["0", "1", "10000001", "x"]);
            let points = value(rng, "256", &["0", "1", "4294967296"]);
            push(&mut a, &["--schedule", &schedule, "--iters", &iters, "--points", &points]);
            for (option, values) in [
                ("--range", &["0,1", "1,0", "nan,1", "0", "2,12"][..]),
                ("--payload", &["f32", "8bit", "8bit-u16", "packed", "zip"][..]),
                ("--threads", &["1", "0", "100000"][..]),
                ("--downsample", &["2", "0", "64"][..]),
                ("--order", &["zfast", "yfast"][..]),
                ("--field", &["rho", "", "a/b"][..]),
                ("--step", &["3", "-1", "x"][..]),
                ("--time", &["0.5", "nan", "inf"][..]),
                ("--support", &["none", "stored", "some"][..]),
                ("--seed", &["7", "-7"][..]),
            ] {
                if rng.chance(0.12) {
                    let v = values[rng.below(values.len())];
                    push(&mut a, &[option, v]);
                }
            }
            if rng.chance(0.1) {
                a.push("--log10".into());
            }
            if rng.chance(0.05) {
                push(&mut a, &["--target-psnr", ["30", "0", "nan", "1000"][rng.below(4)]]);
            }
            let to = output(rng, "gsm");
            push(&mut a, &["-o", &to, "--quiet"]);
        }
        2 => {
            let m = model(rng);
            push(&mut a, &["decode", &m, "--backend", "cpu"]);
            if rng.chance(0.5) {
                let dims = value(rng, "8,6,4", &["0,1,1", "1,2", "4294967296,4,1", "100000,100000,100000", "x"]);
                push(&mut a, &["--dims", &dims]);
            }
            if rng.chance(0.2) {
                let b = value(rng, "0,0,0,4,4,4", &["4,4,4,0,0,0", "0,0,0,100,100,100", "-5,0,0,1,1,1", "0,0,0"]);
                push(&mut a, &["--box", &b]);
            }
            if rng.chance(0.2) {
                a.push("--normalized".into());
            }
            let ext = ["vti", "raw"][rng.below(2)];
            let to = output(rng, ext);
            push(&mut a, &["-o", &to]);
        }
        3 => {
            let m = model(rng);
            push(&mut a, &["info", &m]);
            if rng.chance(0.5) {
                a.push("--json".into());
            }
        }
        4 => {
            let m = model(rng);
            let input = value(rng, &inp.field, &[&inp.empty, "/nonexistent-gsenc-walk/f.f32"]);
            let dims = value(rng, "20,16,12", &["0,16,12", "10,16,12", "20,16,12,2"]);
            let dtype = value(rng, "f32", &["u8", "f64", "x"]);
            push(&mut a, &["eval", &m, "--input", &input, "--dims", &dims, "--dtype", &dtype, "--backend", "cpu"]);
        }
        5 => {
            let m = model(rng);
            let payload = value(rng, "packed", &["f32", "8bit", "8bit-u16", "zip"]);
            let to = output(rng, "gsm");
            push(&mut a, &["convert", &m, "--payload", &payload, "-o", &to]);
        }
        _ => {
            let kind = value(rng, "encode", &["deposit"]);
            push(&mut a, &[&kind, "particles"]);
            let [pos, h, mass, val] = &inp.particles;
            let positions = value(rng, pos, &[&inp.empty, val, "/nonexistent-gsenc-walk/p.f32"]);
            let smoothing = value(rng, h, &[pos]);
            push(&mut a, &["--positions", &positions, "--smoothing-length", &smoothing, "--values", val]);
            if rng.chance(0.3) {
                push(&mut a, &["--mass", mass]);
            }
            if rng.chance(0.5) {
                let dims = value(rng, "16,12,8", &["0,1,1", "1,4294967295,1", "16,12", "1,1,1"]);
                push(&mut a, &["--dims", &dims]);
            } else {
                let n = value(rng, "16", &["0", "1", "100000"]);
                push(&mut a, &["--fit-dims", &n]);
            }
            if rng.chance(0.5) {
                let count = value(rng, "600", &["0", "601", "1200", "x"]);
                let row = value(rng, "1", &["0", "2", "9"]);
                push(&mut a, &["--count", &count, "--row", &row]);
            }
            if rng.chance(0.15) {
                let b = value(rng, "0,0,0,3,2,1", &["3,2,1,0,0,0", "0,0,0,0,0,0", "nan,0,0,1,1,1"]);
                push(&mut a, &["--bounds", &b]);
            }
            if kind == "encode" {
                let budget = value(rng, "10", &["0", "1000000"]);
                push(&mut a, &["--budget", &budget, "--schedule", "short", "--iters", "8", "--points", "256", "--backend", "cpu", "--quiet"]);
            }
            let ext = if kind == "encode" { "gsm" } else { ["vti", "raw"][rng.below(2)] };
            let to = output(rng, ext);
            push(&mut a, &["-o", &to]);
        }
    }
    a
}

#[test]
fn random_runs_of_the_tool_keep_its_promises() {
    let runs: u64 = std::env::var("GSENC_TOOL_WALKS").ok().and_then(|s| s.parse().ok()).unwrap_or(RUNS);
    let first: u64 = std::env::var("GSENC_TOOL_WALK_SEED").ok().and_then(|s| s.parse().ok()).unwrap_or(1);
    let dir = tmpdir("tool-walk");
    let inp = inputs(&dir);
    let out = dir.join("out");
    std::fs::create_dir_all(&out).unwrap();
    // A file already there, which a failed run must leave as it was.
    let there = out.join("x.gsm");
    let mut codes = std::collections::BTreeMap::new();
    for seed in first..first + runs {
        std::fs::copy(&inp.model, &there).unwrap();
        let before = std::fs::read(&there).unwrap();
        let mut rng = Rng::new(seed);
        let args = command(&mut rng, &inp, &out);
        let refs: Vec<&str> = args.iter().map(String::as_str).collect();
        let (code, _, err) = gsenc(&refs);
        let line = format!("run {seed}: gsenc {}", args.join(" "));
        *codes.entry(code).or_insert(0) += 1;
        assert!([0, 2, 3, 4, 5, 6, 7].contains(&code), "{line}\nexit code {code}: {err}");
        if code != 0 {
            assert!(!err.trim().is_empty(), "{line}\nexit code {code} without a word on the standard error");
            let kept = std::fs::read(&there).ok();
            assert!(kept.as_ref() == Some(&before), "{line}\nfailed (exit {code}: {err}) and changed or removed the file that was there");
        }
        let left: Vec<String> = std::fs::read_dir(&out).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).filter(|n| n.contains(".tmp")).collect();
        assert!(left.is_empty(), "{line}\nleft temporary files behind: {left:?}");
        for e in std::fs::read_dir(&out).unwrap() {
            let p = e.unwrap().path();
            if p != there {
                let _ = std::fs::remove_file(&p).or_else(|_| std::fs::remove_dir_all(&p));
            }
        }
    }
    eprintln!("{runs} runs; exit codes: {codes:?}");
    // The runs reached what they are for: some succeeded, some failed.
    assert!(runs < RUNS || (codes.get(&0).is_some_and(|&n| n > runs as usize / 10) && codes.len() > 2), "exit codes {codes:?}");
    let _ = std::fs::remove_dir_all(&dir);
}
