//! What the tool's tests share: running it, reading its JSON, and the
//! inputs they write.
#![allow(dead_code)]

use crate::common::blobs;
use std::path::{Path, PathBuf};
use std::process::Command;

pub fn gsenc(args: &[&str]) -> (i32, String, String) {
    gsenc_env(args, &[])
}

/// [`gsenc`] with variables set in its environment.
pub fn gsenc_env(args: &[&str], vars: &[(&str, &str)]) -> (i32, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_gsenc")).args(args).envs(vars.iter().copied()).output().unwrap();
    (out.status.code().unwrap_or(-1), String::from_utf8_lossy(&out.stdout).into(), String::from_utf8_lossy(&out.stderr).into())
}

pub fn json(s: &str) -> serde_json::Value {
    serde_json::from_str(s.trim()).unwrap_or_else(|e| panic!("not JSON ({e}): {s}"))
}

/// A 20x16x12 float32 field scaled to [2, 12] (so that normalisation matters).
pub fn write_input(dir: &Path) -> (PathBuf, Vec<f32>) {
    let g = blobs([20, 16, 12], 5, 4);
    let vals: Vec<f32> = g.values.iter().map(|v| 2.0 + 10.0 * v).collect();
    let p = dir.join("field.f32");
    std::fs::write(&p, gsenc::io::raw::to_f32_bytes(&vals)).unwrap();
    (p, vals)
}

pub fn write_f32(path: &Path, v: &[f32]) {
    std::fs::write(path, gsenc::io::raw::to_f32_bytes(v)).unwrap();
}

/// Two steps of 600 particles in [0, 3] x [0, 2] x [0, 1], one file per array,
/// one row per step (the layout of dambreak3d_particles); values in [1, 100].
pub fn write_particles(dir: &Path) -> [PathBuf; 4] {
    let mut rng = gsenc::math::rng::Rng::new(8);
    let (mut pos, mut hh, mut mass, mut val) = (vec![], vec![], vec![], vec![]);
    for _ in 0..2 * 600 {
        let p = [rng.range(0.0, 3.0), rng.range(0.0, 2.0), rng.range(0.0, 1.0)];
        pos.extend(p.map(|c| c as f32));
        hh.push(rng.range(0.12, 0.25) as f32);
        mass.push(rng.range(0.5, 1.5) as f32);
        val.push((1.0 + 99.0 * (-(p[0] - 1.5).powi(2) - (p[1] - 1.0).powi(2)).exp()) as f32);
    }
    let names = ["pos.f32", "hh.f32", "mass.f32", "val.f32"].map(|n| dir.join(n));
    for (p, v) in names.iter().zip([&pos, &hh, &mass, &val]) {
        write_f32(p, v);
    }
    names
}
