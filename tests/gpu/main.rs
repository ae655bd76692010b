//! The GPU backend against the CPU backend, on whatever adapter there is:
//! a hardware GPU, or Mesa's lavapipe (llvmpipe) on a machine without one.
//! Every test fills the device buffers with garbage before each call.
//!
//! Without an adapter the tests say so and pass, unless GSENC_REQUIRE_GPU=1
//! (CI sets it), which makes a missing adapter a failure.
#![cfg(feature = "gpu")]

#[path = "../common/mod.rs"]
mod common;
use common::*;
use gsenc::backend::gpu::device::{adapters, instances_made};
use gsenc::backend::gpu::GpuBackend;
use gsenc::backend::bricks::PointBricks;
use gsenc::backend::{cpu::CpuBackend, Backend, Lattice, PointBatch, PointLoss};
use gsenc::encode::config::EncodeConfig;
use gsenc::encode::relocate::relocate;
use gsenc::encode::{encode, encode_validated, Schedule, Validation, WarmStart};
use gsenc::field::{Grid, Transform, ValueRange};
use gsenc::input::Target;
use gsenc::io::raw::{read_raw, DType, Order};
use gsenc::math::kernel::{isotropic, Primitive};
use gsenc::math::loss::{regularizers, LossWeights, RegTerms};
use gsenc::math::optim::Adam;
use gsenc::math::rng::Rng;
use gsenc::model::metrics::voxel_psnr;

// The tests, by what they compare.
mod decode;
mod encode;
mod kernels;
mod resident;

/// Every enumeration and every device of the process go through one wgpu
/// instance: NVIDIA's driver stops listing its GPU in a process that has
/// made 30 (the H200, 2026-12-04), which a simulation opening an encoder
/// per output step reached after 15.
#[test]
fn devices_opened_and_dropped_share_one_instance() {
    let Some(g) = gpu() else { return };
    drop(g);
    for round in 0..40 {
        assert!(!adapters().is_empty(), "round {round}: the adapter is gone");
    }
    drop(gpu().expect("the adapter seen above"));
    assert_eq!(instances_made(), 1, "wgpu instances made by this process");
}

/// The same parameters bit for bit.
fn same_bits(a: &[Primitive], b: &[Primitive]) -> bool {
    a.len() == b.len() && a.iter().flatten().zip(b.iter().flatten()).all(|(x, y)| x.to_bits() == y.to_bits())
}

/// The `short` schedule at 250 primitives, cut to `iterations` of `points`.
fn short(iterations: usize, points: usize) -> EncodeConfig {
    let mut cfg = EncodeConfig::new(250, Schedule::Short);
    cfg.iterations = Some(iterations);
    cfg.points = Some(points);
    cfg
}

fn rel_close(a: f32, b: f32, tol: f32) -> bool {
    (a - b).abs() <= tol * a.abs().max(b.abs()).max(1e-3)
}

/// Relative L2 distance of two gradients over all parameters.
fn rel_l2(a: &[Primitive], b: &[Primitive]) -> f64 {
    let (mut d, mut s) = (0.0f64, 0.0f64);
    for (x, y) in a.iter().flatten().zip(b.iter().flatten()) {
        d += ((x - y) as f64).powi(2);
        s += (*y as f64).powi(2);
    }
    (d / s.max(1e-30)).sqrt()
}


/// The repository's hydrogen_atom at 32^3, normalised by its own range.
fn hydrogen32() -> Grid {
    let raw = read_raw(repo_data("hydrogen_atom.float32.zst"), [64; 3], DType::F32, Order::XFastest).unwrap().downsample(2).unwrap();
    let r = ValueRange::from_data(&raw.values, Transform::Linear).unwrap();
    Grid::new(raw.dims, r.normalize(&raw.values).unwrap().values).unwrap()
}

