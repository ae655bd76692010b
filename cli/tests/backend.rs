//! The tool's backends end to end: every SIMD build of the CPU backend,
//! and the choice of backend (`--backend`, `gsenc devices`, the GPU on any
//! adapter there is).

#[path = "../../tests/common/mod.rs"]
mod common;
mod tool;
use common::*;
use std::process::Command;
use tool::{gsenc, json, write_input};

/// The chunk loops, the regularisers with Adam and the decode's rows are
/// compiled for AVX-512, AVX2 and the baseline and chosen at run time
/// (`GSENC_SIMD` caps the level, `math/simd.rs`); all three execute the
/// same float operations in the same order, so the models and the decoded
/// values are identical.
/// The output's `simd` names the build that ran: the cap, or what the CPU
/// has below it (on a CPU without AVX-512 or AVX2 the test compares fewer
/// builds, and says which it compared). A cap that names no build is a
/// usage error, not a silent run of another build.
#[test]
fn every_simd_build_of_the_cpu_backend_gives_the_same_model() {
    let dir = tmpdir("simd");
    let (input, _) = write_input(&dir);
    let encode = |level: &str| {
        let m = dir.join(format!("{level}.gsm"));
        let out = Command::new(env!("CARGO_BIN_EXE_gsenc"))
            .args(["encode", "grid", "--input", input.to_str().unwrap(), "--dims", "20,16,12", "--dtype", "f32", "--budget", "200"])
            .args(["--schedule", "short", "--iters", "80", "--points", "1500", "--backend", "cpu", "--quiet", "--json", "-o", m.to_str().unwrap()])
            .env("GSENC_SIMD", level)
            .output()
            .unwrap();
        (out, m)
    };
    let model = |level: &str| {
        let (out, m) = encode(level);
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        let ran = serde_json::from_slice::<serde_json::Value>(&out.stdout).unwrap()["simd"].as_str().unwrap().to_string();
        (std::fs::read(m).unwrap(), ran)
    };
    let (best, top) = model("avx512");
    assert_eq!(gsenc::format::read_model(&best).unwrap().params.len(), 200);
    let (avx2, ran_avx2) = model("avx2");
    let (baseline, ran_baseline) = model("baseline");
    assert_eq!(ran_baseline, "baseline", "GSENC_SIMD=baseline ran another build");
    let order = ["baseline", "avx2", "avx512"];
    let rank = |s: &str| order.iter().position(|&o| o == s).unwrap_or_else(|| panic!("unknown build {s}"));
    assert_eq!(ran_avx2, order[rank(&top).min(1)], "GSENC_SIMD=avx2 on a CPU whose best build is {top}");
    eprintln!("compared the builds {top}, {ran_avx2} and baseline");
    assert!(avx2 == best, "the {ran_avx2} build's model differs from the {top} build's");
    assert!(baseline == best, "the baseline build's model differs from the {top} build's");
    // The decode's rows are vectors of each build too: the same values,
    // on a lattice whose sides are no multiple of its bricks.
    let decode = |level: &str| {
        let raw = dir.join(format!("{level}.raw"));
        let out = Command::new(env!("CARGO_BIN_EXE_gsenc"))
            .args(["decode", dir.join("avx512.gsm").to_str().unwrap(), "--dims", "37,29,19", "--backend", "cpu", "--quiet", "-o", raw.to_str().unwrap()])
            .env("GSENC_SIMD", level)
            .output()
            .unwrap();
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        std::fs::read(raw).unwrap()
    };
    let decoded = decode("avx512");
    assert_eq!(decoded.len(), 4 * 37 * 29 * 19);
    assert!(decoded.chunks(4).any(|v| f32::from_le_bytes(v.try_into().unwrap()) > 0.0));
    assert!(decode("avx2") == decoded, "the {ran_avx2} build's decode differs from the {top} build's");
    assert!(decode("baseline") == decoded, "the baseline build's decode differs from the {top} build's");
    let (out, _) = encode("avx-2");
    assert_eq!(out.status.code(), Some(2), "a GSENC_SIMD that names no build");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.ends_with("gsenc: invalid argument: GSENC_SIMD: unknown build 'avx-2' (avx512, avx2, baseline)\n"), "{err}");
}

/// `--backend`: a GPU that is not there is exit code 7 and no file; the
/// adapters `gsenc devices` lists; and, on any adapter (llvmpipe on CI), the
/// same encode through `--backend gpu` names its backend, times its kernels
/// (unless `GSENC_GPU_TIMING=0`, which changes nothing else; nor do
/// `GSENC_GPU_WAIT=sleep`, `GSENC_GPU_BATCH` and `GSENC_GPU_SPLIT`, whose
/// bad values are usage errors) and lands within 0.3 dB of the CPU's.
#[test]
fn backend_choice_end_to_end() {
    let dir = tmpdir("backend");
    let (input, _) = write_input(&dir);
    let inp = input.to_str().unwrap();
    let enc = |extra: &[&str], out: &str| {
        let mut args = vec!["encode", "grid", "--input", inp, "--dims", "20,16,12", "--dtype", "f32", "--budget", "200", "--schedule", "short"];
        args.extend(["--iters", "150", "--points", "2048", "-o", out, "--json", "-q"]);
        args.extend(extra);
        gsenc(&args)
    };
    let missing = dir.join("missing.gsm");
    let (code, _, err) = enc(&["--backend", "gpu", "--gpu-index", "99"], missing.to_str().unwrap());
    assert_eq!(code, 7, "{err}");
    assert!(err.contains("GPU"), "{err}");
    assert!(!missing.exists());
    let (code, _, err) = enc(&["--backend", "cuda"], missing.to_str().unwrap());
    assert_eq!(code, 2, "{err}");

    let (code, out, err) = gsenc(&["devices", "--json"]);
    assert_eq!(code, 0, "{err}");
    let d = json(&out);
    let adapters = d["adapters"].as_array().unwrap();
    let hardware = adapters.iter().filter(|a| !a["software"].as_bool().unwrap()).count();
    assert_eq!(d["hardware_gpus"].as_u64().unwrap() as usize, hardware);
    assert_eq!(d["auto"], if hardware > 0 { "gpu" } else { "cpu" });
    let Some(adapter) = adapters.first().and_then(|a| a["name"].as_str()) else {
        assert!(std::env::var("GSENC_REQUIRE_GPU").as_deref() != Ok("1"), "GSENC_REQUIRE_GPU=1 and wgpu sees no adapter");
        eprintln!("NOT RUN: the GPU half of this test (wgpu sees no adapter)");
        return;
    };
    let cpu = dir.join("cpu.gsm");
    let (code, out, err) = enc(&["--backend", "cpu"], cpu.to_str().unwrap());
    assert_eq!(code, 0, "{err}");
    let c = json(&out);
    assert_eq!(c["backend"], "cpu");
    assert!(c["kernel_seconds"].is_null());
    assert!(c["gpu_host_seconds"].is_null());
    let on_gpu = |out: &std::path::Path, env: &[(&str, &str)]| {
        let run = Command::new(env!("CARGO_BIN_EXE_gsenc"))
            .args(["encode", "grid", "--input", inp, "--dims", "20,16,12", "--dtype", "f32", "--budget", "200", "--schedule", "short"])
            .args(["--iters", "150", "--points", "2048", "-o", out.to_str().unwrap(), "--json", "-q", "--backend", "gpu"])
            .env("GSENC_ADAPTER", adapter)
            .envs(env.iter().copied())
            .output()
            .unwrap();
        assert_eq!(run.status.code(), Some(0), "{}", String::from_utf8_lossy(&run.stderr));
        json(&String::from_utf8_lossy(&run.stdout))
    };
    let gpu = dir.join("gpu.gsm");
    let g = on_gpu(&gpu, &[]);
    assert!(g["backend"].as_str().unwrap().starts_with("wgpu:"), "{g}");
    assert!(g["fell_back"].is_null());
    if let Some(k) = g["kernel_seconds"].as_object() {
        assert!(k["forward"]["passes"].as_u64().unwrap() >= 150, "{g}");
    }
    // The host's phases, whatever the adapter: each at least once a step.
    let h = &g["gpu_host_seconds"];
    for phase in ["arrange", "write", "record", "submit", "wait", "read"] {
        assert!(h[phase]["times"].as_u64().unwrap() >= 150 && h[phase]["seconds"].as_f64().unwrap() >= 0.0, "{phase}: {h}");
    }
    let untimed = dir.join("untimed.gsm");
    let u = on_gpu(&untimed, &[("GSENC_GPU_TIMING", "0")]);
    assert!(u["kernel_seconds"].as_object().is_none_or(|k| k.is_empty()), "{u}");
    assert!(std::fs::read(&untimed).unwrap() == std::fs::read(&gpu).unwrap(), "GSENC_GPU_TIMING=0 changed the model");
    let sleepy = dir.join("sleepy.gsm");
    on_gpu(&sleepy, &[("GSENC_GPU_WAIT", "sleep")]);
    assert!(std::fs::read(&sleepy).unwrap() == std::fs::read(&gpu).unwrap(), "GSENC_GPU_WAIT=sleep changed the model");
    // Another cut of the work into workgroups (pieces of 3 points, 2
    // backward slices, bin chunks of 64 primitives of the 200, reduction
    // teams of 4 threads, coarse lists in 3 chunks at the brick level):
    // the same model.
    let split = dir.join("split.gsm");
    let s = on_gpu(&split, &[("GSENC_GPU_SPLIT", "3,2,64,4,3")]);
    assert!(std::fs::read(&split).unwrap() == std::fs::read(&gpu).unwrap(), "GSENC_GPU_SPLIT changed the model");
    if let (Some(a), Some(b)) = (g["kernel_seconds"]["forward"]["passes"].as_u64(), s["kernel_seconds"]["forward"]["passes"].as_u64()) {
        assert_eq!(a, b, "{g} {s}");
    }
    // Three training steps to a submission: the same model, in fewer
    // submissions than steps.
    let batched = dir.join("batched.gsm");
    let b = on_gpu(&batched, &[("GSENC_GPU_BATCH", "3")]);
    assert!(std::fs::read(&batched).unwrap() == std::fs::read(&gpu).unwrap(), "GSENC_GPU_BATCH changed the model");
    let times = |j: &serde_json::Value, phase: &str| j["gpu_host_seconds"][phase]["times"].as_u64().unwrap();
    assert_eq!(times(&b, "record"), times(&g, "record"), "{b}");
    assert!(3 * times(&b, "submit") < 2 * times(&g, "submit"), "{b}");
    let bad_values = [("GSENC_GPU_BATCH", ["0", "5", "x", "2,2"].as_slice()), ("GSENC_GPU_SPLIT", &["0,8", "8", "8,8,8,8,8,8", "8,x", "8,8,8,6", "8,8,8,256", "8,8,8,8,0", "8,8,8,8,257"])];
    for (var, bad) in bad_values.iter().flat_map(|(var, values)| values.iter().map(move |v| (*var, *v))) {
        let run = Command::new(env!("CARGO_BIN_EXE_gsenc"))
            .args(["encode", "grid", "--input", inp, "--dims", "20,16,12", "--dtype", "f32", "--budget", "200", "--iters", "5"])
            .args(["-o", missing.to_str().unwrap(), "-q", "--backend", "gpu"])
            .env("GSENC_ADAPTER", adapter)
            .env(var, bad)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&run.stderr);
        assert_eq!(run.status.code(), Some(2), "{var}={bad}: {err}");
        assert!(err.contains(var), "{err}");
        assert!(!missing.exists());
    }
    // On a toy field this small a different summation order alone moves the
    // final PSNR by a dB or two (tests/gpu/encode.rs compares encodes on real
    // data); here, the GPU model must be sound and decode alike on both.
    assert!(g["voxel_psnr"].as_f64().unwrap() > 25.0, "{g}");
    let eval = |backend: &str| {
        let out = Command::new(env!("CARGO_BIN_EXE_gsenc"))
            .args(["eval", gpu.to_str().unwrap(), "--input", inp, "--dims", "20,16,12", "--dtype", "f32", "--json", "--backend", backend])
            .env("GSENC_ADAPTER", adapter)
            .output()
            .unwrap();
        assert_eq!(out.status.code(), Some(0), "{}", String::from_utf8_lossy(&out.stderr));
        json(&String::from_utf8_lossy(&out.stdout))["voxel_psnr"].as_f64().unwrap()
    };
    let (on_cpu, on_gpu) = (eval("cpu"), eval("gpu"));
    assert!((on_cpu - on_gpu).abs() < 1e-3, "decoded on the CPU {on_cpu} dB, on the GPU {on_gpu} dB");
    assert!((on_cpu - g["voxel_psnr"].as_f64().unwrap()).abs() < 1e-3, "{on_cpu} vs {g}");
}
