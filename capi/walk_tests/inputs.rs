//! What a walk hands over: configs, values and their dtypes, mostly
//! ordinary and sometimes not.

use super::{Rng, World};
use crate::config::*;
use crate::status::gsenc_status;
use crate::{GSENC_DTYPE_FLOAT32, GSENC_DTYPE_FLOAT64};
use std::ffi::CString;

/// A value as a careless caller might hand it over: mostly ordinary,
/// sometimes not a number, infinite, huge or negative.
pub(super) fn odd_f64(rng: &mut Rng, ordinary: f64) -> f64 {
    match rng.below(40) {
        0 => f64::NAN,
        1 => f64::INFINITY,
        2 => -ordinary,
        3 => 0.0,
        4 => 1e300,
        _ => ordinary,
    }
}

/// A short CPU encode of a few Gaussians, with the fixed range a resume
/// needs or the range of the first step's data.
pub(super) fn base_config(fixed_range: bool) -> gsenc_config {
    // SAFETY: a plain C struct, all zeros a valid value; then initialised.
    let mut c: gsenc_config = unsafe { std::mem::zeroed() };
    c.struct_size = std::mem::size_of::<gsenc_config>();
    assert_eq!(unsafe { gsenc_config_init(&mut c) }, gsenc_status::Ok);
    (c.budget, c.schedule, c.iterations, c.points, c.backend) = (6, GSENC_SCHEDULE_SHORT, 8, 48, GSENC_BACKEND_CPU);
    c.dims = [6, 5, 4];
    (c.has_bounds, c.bounds_min, c.bounds_max) = (1, [0.0; 3], [1.0; 3]);
    c.threads = 1;
    if fixed_range {
        (c.fixed_range, c.value_min, c.value_max) = (1, -1.0, 3.0);
    }
    c
}

/// A config as a careless caller might fill it: mostly a short CPU encode
/// of a few Gaussians, each setting sometimes out of its range.
pub(super) fn config(rng: &mut Rng, world: &World, strings: &mut Vec<CString>) -> gsenc_config {
    let mut c = base_config(rng.chance(0.5));
    let changes = if rng.chance(0.5) { 0 } else { 1 + rng.below(2) };
    for _ in 0..changes {
        match rng.below(22) {
            0 => c.budget = rng.pick(&[0, 1, 40, 1 << 40, u64::MAX]),
            1 => c.schedule = rng.pick(&[GSENC_SCHEDULE_MATCHED, GSENC_SCHEDULE_TUNED, -1, 77]),
            2 => c.warm_start = rng.pick(&[GSENC_WARM_OFF, GSENC_WARM_COARSE, GSENC_WARM_DENSE, GSENC_WARM_AUTO, 9]),
            3 => c.iterations = rng.pick(&[0, 1, 3, u32::MAX]),
            4 => c.points = rng.pick(&[0, 1, 7, u32::MAX]),
            5 => c.transform = rng.pick(&[GSENC_TRANSFORM_LINEAR, GSENC_TRANSFORM_LOG10, 5]),
            6 => {
                c.fixed_range = rng.pick(&[0, 1, 2]);
                (c.value_min, c.value_max) = (odd_f64(rng, 0.0), odd_f64(rng, 1.0));
            }
            7 => c.dims = [rng.pick(&[0, 1, 3, 8]), rng.pick(&[1, 4, u32::MAX]), rng.pick(&[1, 5])],
            8 => {
                c.has_bounds = rng.pick(&[0, 1, 3]);
                c.bounds_min = [odd_f64(rng, 0.0), 0.0, -1.0];
                c.bounds_max = [odd_f64(rng, 1.0), 0.0, 1.0];
            }
            9 => c.payload = rng.pick(&[GSENC_PAYLOAD_F32, GSENC_PAYLOAD_8BIT, GSENC_PAYLOAD_8BIT_U16, GSENC_PAYLOAD_PACKED, 12]),
            10 => c.threads = rng.pick(&[0, 2, 100_000]),
            11 => (c.seed_init, c.seed_sample) = (rng.next(), rng.next()),
            12 => c.rank = rng.pick(&[1, u32::MAX]),
            13 => c.support = rng.pick(&[GSENC_SUPPORT_STORED, GSENC_SUPPORT_NONE, 3]),
            14 => {
                let dir = match rng.below(3) {
                    0 => world.dir.join("out").to_str().unwrap().to_owned(),
                    1 => "/nonexistent-gsenc-walk/out".to_owned(),
                    _ => String::new(),
                };
                strings.push(CString::new(dir).unwrap());
                c.output_dir = strings.last().unwrap().as_ptr();
                c.output_format = rng.pick(&[GSENC_OUTPUT_FOLDER, GSENC_OUTPUT_FOLDER, GSENC_OUTPUT_HDF5, 4]);
            }
            15 => c.warm_iterations = rng.pick(&[0, 2, u32::MAX]),
            16 => (c.when_full, c.queue_bytes) = (rng.pick(&[GSENC_QUEUE_BLOCK, GSENC_QUEUE_SKIP, GSENC_QUEUE_BUSY, 8]), rng.pick(&[0, 1, 400, 1 << 20])),
            17 => c.halo = rng.pick(&[1, u32::MAX]),
            18 => (c.backend, c.gpu_index) = (rng.pick(&[GSENC_BACKEND_AUTO, GSENC_BACKEND_CPU, GSENC_BACKEND_GPU, 9]), rng.pick(&[-1, 0, 7])),
            19 => {
                c.preview = rng.pick(&[GSENC_PREVIEW_NONE, GSENC_PREVIEW_SLICE, GSENC_PREVIEW_VOLUME, 6]);
                (c.preview_axis, c.preview_at) = (rng.pick(&[0, 2, 3, -1]), odd_f64(rng, 0.5));
                (c.preview_width, c.preview_height) = (rng.pick(&[0, 8, u32::MAX]), rng.pick(&[8, 1]));
                (c.preview_azimuth, c.preview_elevation) = (odd_f64(rng, 30.0), odd_f64(rng, 20.0));
            }
            20 => c.target_psnr = odd_f64(rng, 30.0),
            _ => {
                strings.push(CString::new(rng.pick(&["0", "0-1", "x", "99999", ""])).unwrap());
                c.encoder_cpus = strings.last().unwrap().as_ptr();
                c.encoder_priority = rng.pick(&[GSENC_PRIORITY_NORMAL, GSENC_PRIORITY_LOW, GSENC_PRIORITY_IDLE, 5]);
            }
        }
    }
    if rng.chance(0.04) {
        c.struct_size = rng.pick(&[0, 8, 64]);
    }
    c
}

/// Values of a smooth field at `n` points, some not numbers or infinite.
pub(super) fn values(rng: &mut Rng, n: usize) -> Vec<f64> {
    // Now and then constant, huge or below float32's normal range.
    let usual = 1.0 + rng.unit();
    let ordinary = rng.pick(&[usual, usual, usual, 0.0, 1e30, 1e-40]);
    let (scale, offset) = (odd_f64(rng, ordinary), if rng.chance(0.2) { -0.5 } else { 0.1 });
    let spoil = rng.chance(0.15);
    (0..n)
        .map(|i| match spoil && rng.chance(0.1) {
            true => rng.pick(&[f64::NAN, f64::INFINITY, 1e39]),
            false => offset + scale * (0.3 * i as f64).sin().abs(),
        })
        .collect()
}

/// `values` in the dtype the walk chose (`float32`, `float64`, or an
/// unknown one read as `float32`), as bytes that stay where they are.
pub(super) fn typed(values: &[f64], dtype: i32) -> Vec<u64> {
    let bytes: Vec<u8> = match dtype {
        GSENC_DTYPE_FLOAT64 => values.iter().flat_map(|v| v.to_ne_bytes()).collect(),
        _ => values.iter().flat_map(|&v| (v as f32).to_ne_bytes()).collect(),
    };
    // 8-byte aligned storage.
    bytes.chunks(8).map(|c| {
        let mut w = [0u8; 8];
        w[..c.len()].copy_from_slice(c);
        u64::from_ne_bytes(w)
    }).collect()
}

pub(super) fn dtype(rng: &mut Rng) -> i32 {
    if rng.chance(0.05) { 9 } else { rng.pick(&[GSENC_DTYPE_FLOAT32, GSENC_DTYPE_FLOAT64]) }
}

