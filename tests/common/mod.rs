//! Shared helpers for the integration tests: a dense f64 transcription of
//! the method (docs/METHOD.md "Representation", "Objective"; no binning, no
//! SIMD, libm exp) to check the library against, small synthetic fields, and
//! the repository's real data.
#![allow(dead_code)]

pub mod disk;

use gsenc::field::{Grid, IndexFrame, Transform, ValueRange};
use gsenc::model::{Model, ModelMeta};
use gsenc::math::kernel::Primitive;
use gsenc::backend::{Backend, PointBatch};
use gsenc::math::loss::LossWeights;
use gsenc::math::rng::Rng;

/// The choices of a random walk (over the C API, `capi/walk_tests/`; over
/// the tool, `cli/tests/walk.rs`): the library's generator, seeded by the
/// walk's number, with the draws a walk makes.
pub struct Draws(Rng);

impl Draws {
    pub fn new(seed: u64) -> Draws {
        Draws(Rng::new(seed))
    }
    pub fn next(&mut self) -> u64 {
        self.0.next_u64()
    }
    /// 0..n.
    pub fn below(&mut self, n: usize) -> usize {
        self.0.below(n as u64) as usize
    }
    /// True with probability `p`.
    pub fn chance(&mut self, p: f64) -> bool {
        self.0.uniform() < p
    }
    pub fn unit(&mut self) -> f64 {
        self.0.uniform()
    }
    pub fn pick<T: Copy>(&mut self, all: &[T]) -> T {
        all[self.below(all.len())]
    }
}

/// Primitives over a `size`^3 box with every parameter group varied:
/// rotations, anisotropy, scales beyond the clamp, weights and values.
pub fn random_model(rng: &mut Rng, n: usize, size: f64) -> Vec<Primitive> {
    (0..n)
        .map(|i| {
            let mut p = [0f32; 12];
            for a in 0..3 {
                p[a] = rng.range(0.0, size) as f32;
                p[3 + a] = rng.range(0.5f64.ln(), 3.0f64.ln()) as f32;
            }
            if i % 5 == 1 {
                p[3] = 9.0f32.ln(); // clamped at SIGMA_MAX
            }
            if i % 5 == 2 {
                p[4] = 0.25f32.ln(); // clamped at SIGMA_MIN, and under the scale penalty's 0.3
            }
            for q in 0..4 {
                p[6 + q] = rng.range(-1.0, 1.0) as f32;
            }
            p[6] += 1.2;
            p[10] = rng.range(-2.0, 2.0) as f32;
            p[11] = rng.range(-2.0, 2.0) as f32;
            p
        })
        .collect()
}

/// `count` points over a `size`^3 box, every ninth masked (a tiny value).
pub fn random_batch(rng: &mut Rng, count: usize, size: f64) -> PointBatch {
    let mut b = PointBatch::default();
    for i in 0..count {
        b.pos.push([0, 1, 2].map(|_| rng.range(0.0, size) as f32));
        b.vref.push(if i % 9 == 0 { 0.001 } else { rng.range(0.0, 1.0) as f32 });
    }
    b
}

/// A batch sorted into the backend's bricks ahead of the call (as the
/// encoder sorts the next batch beside the gradient) gives the loss and
/// gradient of the same batch sorted in the call, bit for bit, and a sort
/// of another edge is not read (it would cut other bricks, and sum in
/// another order).
pub fn check_sorted_ahead(backend: &mut dyn Backend, params: &[Primitive], plain: &PointBatch) {
    let edge = backend.brick_edge().expect("a backend that sorts into bricks");
    let w = LossWeights::default();
    let mut run = |b: &PointBatch| {
        let mut grad = vec![[0.0f32; 12]; params.len()];
        let loss = backend.point_loss_grad(params, b, &w, &mut grad).unwrap();
        (loss.val.to_bits(), loss.cov.to_bits(), grad.as_flattened().iter().map(|x| x.to_bits()).collect::<Vec<_>>())
    };
    let reference = run(plain);
    assert!(reference.2.iter().any(|&x| x != 0), "the gradient must not vanish");
    let mut ahead = plain.clone();
    ahead.sort_into_bricks(edge);
    assert!(run(&ahead) == reference, "sorted ahead into bricks of {edge}");
    let mut other = plain.clone();
    other.sort_into_bricks(edge / 4.0);
    assert!(run(&other) == reference, "a sort into bricks of {} must not be read", edge / 4.0);
}

pub fn sigmoid(x: f64) -> f64 {
    1.0 / (1.0 + (-x).exp())
}

/// `(rho, n)` of the mixture at `x`, straight from the formulas of METHOD.md.
pub fn dense_rho_n(params: &[[f64; 12]], x: [f64; 3]) -> (f64, f64) {
    let (mut rho, mut n) = (0.0, 0.0);
    for p in params {
        let qn = (p[6] * p[6] + p[7] * p[7] + p[8] * p[8] + p[9] * p[9]).sqrt();
        let (w, qx, qy, qz) = (p[6] / qn, p[7] / qn, p[8] / qn, p[9] / qn);
        let r = [
            [1.0 - 2.0 * (qy * qy + qz * qz), 2.0 * (qx * qy - w * qz), 2.0 * (qx * qz + w * qy)],
            [2.0 * (qx * qy + w * qz), 1.0 - 2.0 * (qx * qx + qz * qz), 2.0 * (qy * qz - w * qx)],
            [2.0 * (qx * qz - w * qy), 2.0 * (qy * qz + w * qx), 1.0 - 2.0 * (qx * qx + qy * qy)],
        ];
        let d = [x[0] - p[0], x[1] - p[1], x[2] - p[2]];
        let mut d2 = 0.0;
        for k in 0..3 {
            let sigma = p[3 + k].exp().clamp(0.4, 8.0);
            let yk = (r[0][k] * d[0] + r[1][k] * d[1] + r[2][k] * d[2]) / sigma;
            d2 += yk * yk;
        }
        if d2 < 25.0 {
            let kv = (-0.5 * d2).exp();
            let wt = sigmoid(p[11]);
            rho += wt * kv;
            n += wt * kv * sigmoid(p[10]);
        }
    }
    (rho, n)
}

fn huber(r: f64) -> f64 {
    if r.abs() <= 0.1 {
        0.5 * r * r
    } else {
        0.1 * (r.abs() - 0.05)
    }
}

/// The four loss terms, unweighted: (val, cov, scale, aniso), for an
/// objective whose occupied points weigh `fidelity[0] + fidelity[1] V_ref`
/// and whose L_aniso acts above `aniso_ratio` (the paper's: `[0.5, 1]`, 4).
pub fn dense_loss_terms(params: &[[f64; 12]], pos: &[[f32; 3]], vref: &[f32], fidelity: [f64; 2], aniso_ratio: f64) -> [f64; 4] {
    let omega = |v: f64| fidelity[0] + fidelity[1] * v;
    let mut wsum = 0.0;
    for &v in vref {
        if v as f64 > 0.005 {
            wsum += omega(v as f64);
        }
    }
    let (mut val, mut cov) = (0.0, 0.0);
    for (x, &v) in pos.iter().zip(vref) {
        let v = v as f64;
        if v <= 0.005 {
            continue;
        }
        let (rho, n) = dense_rho_n(params, [x[0] as f64, x[1] as f64, x[2] as f64]);
        val += omega(v) * huber(n / rho.max(1e-3) - v);
        cov += (0.05 - rho).max(0.0);
    }
    val /= wsum.max(1e-6);
    cov /= pos.len() as f64;
    let (mut scale, mut aniso) = (0.0, 0.0);
    for p in params {
        let e = [p[3].exp(), p[4].exp(), p[5].exp()];
        for a in 0..3 {
            scale += (e[a] - 8.0).max(0.0) + 0.05 * (0.30 - e[a]).max(0.0);
        }
        let mx = e[0].max(e[1]).max(e[2]);
        let mn = e[0].min(e[1]).min(e[2]);
        aniso += (mx / mn.max(1e-3) - aniso_ratio).max(0.0);
    }
    scale /= 3.0 * params.len() as f64;
    aniso /= params.len() as f64;
    [val, cov, scale, aniso]
}

pub fn to_f64(p: &[Primitive]) -> Vec<[f64; 12]> {
    p.iter().map(|q| q.map(|v| v as f64)).collect()
}

/// A smooth field: a sum of a few anisotropic blobs, in [0, 1].
pub fn blobs(dims: [usize; 3], seed: u64, count: usize) -> Grid {
    let mut rng = Rng::new(seed);
    let centres: Vec<([f64; 3], [f64; 3], f64)> = (0..count)
        .map(|_| {
            let c = [0, 1, 2].map(|a| rng.range(0.25, 0.75) * dims[a] as f64);
            let s = [0, 1, 2].map(|a| rng.range(0.06, 0.15) * dims[a] as f64);
            (c, s, rng.range(0.4, 1.0))
        })
        .collect();
    let mut v = Vec::with_capacity(dims[0] * dims[1] * dims[2]);
    for k in 0..dims[2] {
        for j in 0..dims[1] {
            for i in 0..dims[0] {
                let x = [i as f64, j as f64, k as f64];
                let mut f = 0.0;
                for (c, s, a) in &centres {
                    let d2: f64 = (0..3).map(|q| ((x[q] - c[q]) / s[q]).powi(2)).sum();
                    f += a * (-0.5 * d2).exp();
                }
                v.push(f.min(1.0) as f32);
            }
        }
    }
    Grid::new(dims, v).unwrap()
}

/// A file of the repository's `data/` (see data/README.md), from any crate
/// of the workspace.
pub fn repo_data(name: &str) -> std::path::PathBuf {
    let here = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let root = here.ancestors().find(|d| d.join("data/README.md").is_file()).expect("the repository's data/ folder");
    let p = root.join("data").join(name);
    assert!(p.is_file(), "test data {} is missing from the repository", p.display());
    p
}

/// A fresh, empty folder for one test.
pub fn tmpdir(name: &str) -> TmpDir {
    let d = std::env::temp_dir().join(format!("gsenc-test-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    TmpDir(d)
}

/// A test's folder ([`tmpdir`]), removed with what it holds when the test
/// passes and kept when it fails (a panicking thread drops it), for a look
/// at what the test left.
pub struct TmpDir(std::path::PathBuf);

impl std::ops::Deref for TmpDir {
    type Target = std::path::Path;
    fn deref(&self) -> &std::path::Path {
        &self.0
    }
}

impl AsRef<std::path::Path> for TmpDir {
    fn as_ref(&self) -> &std::path::Path {
        &self.0
    }
}

impl Drop for TmpDir {
    fn drop(&mut self) {
        if std::thread::panicking() {
            eprintln!("kept for a look: {}", self.0.display());
        } else {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }
}

/// A model for the store tests whose parameters follow from (field, step, rank): a reader can
/// rebuild what a writer stored. `scale_hi` bounds the log standard deviations.
pub fn store_model(field: &str, step: u64, rank: u32, n: usize, scale_hi: f64) -> Model {
    let mut rng = Rng::new(step * 1000 + rank as u64 + field.len() as u64 * 7);
    let dims = [24, 16, 12];
    let mut meta = ModelMeta::new(
        IndexFrame { dims, bmin: [rank as f64 * 2.0, -1.0, 0.5], gamma: 12.0 },
        ValueRange::new(-2.0, 3.5, Transform::Linear).unwrap(),
    );
    meta.field = field.into();
    meta.step = step;
    meta.rank = rank;
    meta.time = Some(step as f64 * 0.25);
    meta.schedule = "matched".into();
    meta.iterations = 300 + step as u32;
    meta.points = 4096;
    meta.seed_init = step;
    meta.seed_sample = step + 1;
    meta.encode_psnr = Some(30.0 + step as f64);
    let params = (0..n)
        .map(|_| {
            std::array::from_fn(|k| match k {
                0..=2 => rng.range(-0.5, dims[k] as f64 - 0.5),
                3..=5 => rng.range(-1.5, scale_hi),
                _ => rng.range(-3.0, 3.0),
            } as f32)
        })
        .collect();
    Model { meta, params, support: None }
}


/// The pieces of a decomposed step (an MPI run's), as `gsenc store add`
/// stores a run's folder: rank 0 and rank 1 of a 24 x 16 x 12 lattice, a
/// halo of 2 voxels.
pub fn decomposed_step(field: &str, step: u64) -> (gsenc::format::step_index::StepIndex, Vec<gsenc::model::Model>) {
    use gsenc::field::{IndexBox, IndexFrame};
    let global = IndexFrame { dims: [24, 16, 12], bmin: [0.0, -1.0, 0.5], gamma: 12.0 };
    let boxes = [IndexBox { lo: [0, 0, 0], hi: [14, 16, 12] }, IndexBox { lo: [10, 0, 0], hi: [24, 16, 12] }];
    let pieces: Vec<_> = boxes
        .iter()
        .enumerate()
        .map(|(rank, b)| {
            let mut m = store_model(field, step, rank as u32, 60 + 10 * rank, 0.5);
            m.meta.frame = global.sub_frame(b);
            m
        })
        .collect();
    let names = (0..2).map(|r| format!("{field}_{step:06}_r{r}.gsm")).collect();
    let index = gsenc::format::step_index::StepIndex::new(field, step, pieces[0].meta.time, &pieces[0].meta.range, &global, &boxes, 2, names);
    (index, pieces)
}

/// Held by every test that opens HDF5 files or starts processes: HDF5 opens
/// files without close-on-exec, so a process started by one test would
/// inherit another test's open store, and its lock.
pub fn hdf5_serial() -> std::sync::MutexGuard<'static, ()> {
    static LOCK: std::sync::Mutex<()> = std::sync::Mutex::new(());
    LOCK.lock().unwrap_or_else(|e| e.into_inner())
}

/// The GPU backend (its buffers filled with garbage before each call) on
/// the adapter `GSENC_ADAPTER` names, else on the first hardware adapter,
/// else on llvmpipe; `None` (with a message) when wgpu sees no adapter at
/// all and GSENC_REQUIRE_GPU is not 1. An adapter that is there but fails
/// (a kernel that does not compile) always fails the test.
#[cfg(feature = "gpu")]
pub fn gpu() -> Option<gsenc::backend::gpu::GpuBackend> {
    use gsenc::backend::gpu::device::{adapters, DeviceRequest};
    let seen = adapters();
    if seen.is_empty() {
        assert!(
            std::env::var("GSENC_REQUIRE_GPU").as_deref() != Ok("1"),
            "GSENC_REQUIRE_GPU=1 and wgpu sees no adapter (install mesa-vulkan-drivers)"
        );
        eprintln!("NOT RUN: wgpu sees no adapter; install mesa-vulkan-drivers, or set GSENC_REQUIRE_GPU=1 to fail instead");
        return None;
    }
    let req = match std::env::var("GSENC_ADAPTER").ok().filter(|s| !s.is_empty()) {
        Some(name) => DeviceRequest { index: None, name: Some(name) },
        None if seen.iter().any(|a| !a.software()) => DeviceRequest::default(),
        None => DeviceRequest { index: None, name: Some(seen[0].name.clone()) },
    };
    let mut b = gsenc::backend::gpu::GpuBackend::new(&req).unwrap_or_else(|e| panic!("{e}"));
    b.garbage = true;
    Some(b)
}
