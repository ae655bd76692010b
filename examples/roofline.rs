//! The roofline of the CPU backend on one core (`benches/roofline.sh`):
//! what the core's vector multiply-add and `exp` throughput allow, and what
//! the backend's lane code reaches from cache. Prints one JSON object.
//! `cargo run --release --example roofline [-- SECONDS]`
use gsenc::backend::cpu::CpuBackend;
use gsenc::math::kernel::exp_neg_half;
use std::hint::black_box;
use std::time::Instant;

const CHAINS: usize = 12;
const LANES: usize = 8;

/// Independent multiply-add chains, 8 lanes each: the core's float
/// throughput (one flat array, so that it stays in vector registers).
#[inline(always)]
fn fma_chains(reps: usize) -> f32 {
    let mut acc = [1.0f32; CHAINS * LANES];
    let (a, b) = (black_box(0.999_9f32), black_box(1e-5f32));
    for _ in 0..reps {
        for x in acc.iter_mut() {
            *x = x.mul_add(a, b);
        }
    }
    acc.iter().sum()
}

/// `exp_neg_half` over an array that stays in L1, vectorised as the lane code is.
#[inline(always)]
fn exps(d2: &[f32], out: &mut [f32], reps: usize) -> f32 {
    for _ in 0..reps {
        for (o, &x) in out.iter_mut().zip(d2) {
            *o = exp_neg_half(x);
        }
        black_box(&mut *out);
    }
    out.iter().sum()
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512vl,avx2,fma")]
unsafe fn fma_chains_simd(reps: usize) -> f32 {
    fma_chains(reps)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512vl,avx2,fma")]
unsafe fn exps_simd(d2: &[f32], out: &mut [f32], reps: usize) -> f32 {
    exps(d2, out, reps)
}

#[allow(dead_code)]
fn per_second(seconds: f64, mut f: impl FnMut() -> u64) -> f64 {
    let t = Instant::now();
    let mut n = 0u64;
    while t.elapsed().as_secs_f64() < seconds {
        n += f();
    }
    n as f64 / t.elapsed().as_secs_f64()
}

#[cfg(not(target_arch = "x86_64"))]
fn main() {
    eprintln!("this roofline is written for AVX-512VL and FMA (x86-64)");
    std::process::exit(2);
}

#[cfg(target_arch = "x86_64")]
fn main() {
    let seconds: f64 = std::env::args().nth(1).map_or(2.0, |s| s.parse().expect("SECONDS"));
    let simd = std::arch::is_x86_feature_detected!("avx512vl") && std::arch::is_x86_feature_detected!("fma");
    assert!(simd, "this roofline is written for AVX-512VL and FMA (x86-64)");
    let reps = 100_000;
    // SAFETY: the features were checked above.
    let fmas = per_second(seconds, || {
        black_box(unsafe { fma_chains_simd(reps) });
        (reps * CHAINS * LANES) as u64
    });
    let d2: Vec<f32> = (0..1024).map(|i| i as f32 * 24.0 / 1024.0).collect();
    let mut out = vec![0.0f32; d2.len()];
    let exps_per_s = per_second(seconds, || {
        black_box(unsafe { exps_simd(&d2, &mut out, 1000) });
        1000 * d2.len() as u64
    });
    // 8 blocks (64 candidates) and 64 points that all see one another.
    let (forward, forward_backward) = CpuBackend::kernel_ceiling(8, 64, seconds);
    println!(
        "{}",
        serde_json::json!({
            "fma_lanes_per_s": fmas,
            "exp_per_s": exps_per_s,
            "lane_code_forward_evals_per_s": forward,
            "lane_code_forward_backward_evals_per_s": forward_backward,
        })
    );
}
