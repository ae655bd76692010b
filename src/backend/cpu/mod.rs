//! The CPU backend: spatial bricks, rayon, no locks or atomics on the hot path.
//!
//! Training (`point_loss_grad`, `evaluate_points`; `evaluate_each` the same
//! with each primitive in lane `g % 8`, so that a point's sums are its own):
//! 1. points are counting-sorted into cubic bricks (`brick` voxels a side);
//! 2. each primitive is listed in every occupied brick that its tight 5-sigma
//!    box overlaps (a CSR built by a stable counting sort, so every list is in
//!    primitive order);
//! 3. the occupied bricks are cut into a fixed number of contiguous work chunks
//!    that depends only on the data, never on the thread count; each chunk runs
//!    forward, point loss and backward for its points and accumulates the pair
//!    sums into its own sparse accumulator (`ChunkScratch`);
//! 4. the chunk accumulators are added in chunk order. Float sums therefore
//!    happen in the same order with 1 thread or 64, and models are
//!    byte-identical whatever the thread count.
//!
//! Decoding (`decode_lattice`) splats primitives brick by brick: each z-slab
//! of bricks is one parallel task that writes its own slice of the output.
//!
//! The files read in that order: `binning.rs` (steps 1 to 3: the bricks,
//! the lists, the cut into chunks), `backward.rs` (what a chunk runs, and
//! step 4: `point_loss_grad`), `forward.rs` (the same chunks forward only,
//! a dense brick's points in runs: `evaluate_points`), `decode.rs`; `lanes.rs` holds the 8-lane kernel
//! loops they share (`math/simd.rs` picks which build of them runs). This file
//! holds the backend, what it derives from the parameters once a call, and
//! the trait's entry points.

mod backward;
mod binning;
mod decode;
mod forward;
mod lanes;

use self::backward::ChunkScratch;
use self::binning::SPLIT_SHARES;
use self::lanes::{BrickSoa, Hot, LANES};
use crate::math::simd::simd_dispatch;
use super::bricks::PointBricks;
use super::{Backend, Lattice, PointBatch, PointLoss};
use crate::error::Result;
use crate::math::kernel::{Frame, GradAcc, Primitive};
use crate::math::loss::LossWeights;
use crate::math::primitives_per_task;
use crate::profile;
use crossbeam_utils::CachePadded;
use rayon::prelude::*;
use std::borrow::Cow;

pub struct CpuBackend {
    /// Edge of a training brick in voxels.
    pub brick: f32,
    prep: Prepared,
    /// Each on cache lines of its own: the chunks run on different cores
    /// and each writes its scratch at every point.
    chunks: Vec<CachePadded<ChunkScratch>>,
    /// Reduced pair sums per primitive.
    acc: Vec<GradAcc>,
    /// Kernels evaluated by the point passes (for throughput figures).
    evaluations: u64,
    /// How many work chunks' shares a brick may cost before its points are
    /// cut into runs (`SPLIT_SHARES`); 0 keeps every brick whole, which
    /// gives the models of gsenc before dense bricks were split, bit for
    /// bit (the golden models of `tests/support.rs`).
    pub split_shares: u64,
}

impl Default for CpuBackend {
    fn default() -> Self {
        CpuBackend { brick: 16.0, prep: Prepared::default(), chunks: vec![], acc: vec![], evaluations: 0, split_shares: SPLIT_SHARES }
    }
}

/// Per-primitive data derived from the parameters once per call.
#[derive(Default)]
struct Prepared {
    frames: Vec<Frame>,
    hot: Vec<Hot>,
    /// Tight 5-sigma boxes: lo[3], hi[3].
    boxes: Vec<[f32; 6]>,
}

impl Prepared {
    fn update(&mut self, params: &[Primitive]) {
        let n = params.len();
        self.frames.resize(n, Frame::default());
        self.hot.resize(n, Hot::default());
        self.boxes.resize(n, [0.0; 6]);
        let task = primitives_per_task(n);
        self.frames
            .par_chunks_mut(task)
            .zip(self.hot.par_chunks_mut(task))
            .zip(self.boxes.par_chunks_mut(task))
            .zip(params.par_chunks(task))
            .with_max_len(1)
            .for_each(|(((fs, hs), bs), ps)| profile::task("frames", || frames_dispatch(fs, hs, bs, ps)));
    }
}

simd_dispatch!(fn frames_dispatch(fs: &mut [Frame], hs: &mut [Hot], bs: &mut [[f32; 6]], ps: &[Primitive]) -> () => frames_run);

/// The frames, hot data and boxes of a run of primitives.
#[inline(always)]
fn frames_run(fs: &mut [Frame], hs: &mut [Hot], bs: &mut [[f32; 6]], ps: &[Primitive]) {
    for (((f, h), b), p) in fs.iter_mut().zip(hs).zip(bs).zip(ps) {
        *f = Frame::new(p);
        *h = Hot::new(f);
        *b = [f.mu[0] - f.ext[0], f.mu[1] - f.ext[1], f.mu[2] - f.ext[2], f.mu[0] + f.ext[0], f.mu[1] + f.ext[1], f.mu[2] + f.ext[2]];
    }
}

impl CpuBackend {
    pub fn new() -> Self {
        Self::default()
    }

    /// The candidate lists of the training bricks of `pos` under `params`
    /// (`bin_points`): per occupied brick, in `PointBricks` order, the
    /// primitives whose box reaches it, in order. Tests compare the GPU
    /// backend's with them (`GpuBackend::candidate_lists`).
    #[doc(hidden)]
    pub fn candidate_lists(&mut self, params: &[Primitive], pos: &[[f32; 3]]) -> Vec<Vec<u32>> {
        self.prep.update(params);
        let bins = self.bin_points(Cow::Owned(PointBricks::new(pos, self.brick)));
        bins.cand_start.windows(2).map(|w| bins.cand[w[0] as usize..w[1] as usize].to_vec()).collect()
    }

    /// The ceiling of this backend's lane code on one core: `blocks`
    /// blocks of 8 candidates that all cover `points` points, evaluated
    /// over and over from cache (no binning, no culling, no memory
    /// traffic), forward only and forward with backward; returns kernel
    /// evaluations a second for each (`benches/roofline.sh`).
    #[doc(hidden)]
    pub fn kernel_ceiling(blocks: usize, points: usize, seconds: f64) -> (f64, f64) {
        let n = blocks * LANES;
        let params: Vec<Primitive> = (0..n)
            .map(|i| {
                let t = i as f32 / n as f32;
                crate::math::kernel::isotropic([4.0 + t, 4.0 - t, 4.0 + 0.5 * t], 4.0, 0.5, 0.3 + 0.4 * t)
            })
            .collect();
        let mut prep = Prepared::default();
        prep.update(&params);
        let cands: Vec<u32> = (0..n as u32).collect();
        let xs: Vec<[f32; 3]> = (0..points).map(|i| { let t = i as f32 / points as f32; [3.0 + 2.0 * t, 5.0 - 2.0 * t, 4.0 + t] }).collect();
        let mut soa = BrickSoa::default();
        soa.load(&prep.hot, &prep.boxes, &cands, true);
        let rate = |soa: &mut BrickSoa, with_grad: bool| {
            let (mut evals, mut sink) = (0u64, 0.0f32);
            let t = std::time::Instant::now();
            while t.elapsed().as_secs_f64() < seconds {
                let (e, s) = ceiling_dispatch(soa, &xs, with_grad);
                evals += e;
                sink += s;
            }
            std::hint::black_box(sink);
            evals as f64 / t.elapsed().as_secs_f64()
        };
        (rate(&mut soa, false), rate(&mut soa, true))
    }

    #[doc(hidden)]
    pub fn profile_bin(&mut self, params: &[Primitive], pos: &[[f32; 3]]) -> (usize, usize) {
        self.prep.update(params);
        let b = self.bin_points(Cow::Owned(PointBricks::new(pos, self.brick)));
        (b.bricks.ranges.len(), b.cand.len())
    }
}

/// One pass of [`CpuBackend::kernel_ceiling`]: every point forward (and
/// backward), as the chunk loops run them.
#[inline(always)]
fn ceiling_pass(soa: &mut BrickSoa, xs: &[[f32; 3]], with_grad: bool) -> (u64, f32) {
    let (mut evals, mut sink) = (0u64, 0.0f32);
    for &x in xs {
        let (r, n) = soa.forward(x, &mut evals);
        sink += r + n;
        if with_grad {
            soa.backward(1e-3 * r, -1e-3 * n);
        }
    }
    (evals, sink)
}

simd_dispatch!(fn ceiling_dispatch(soa: &mut BrickSoa, xs: &[[f32; 3]], with_grad: bool) -> (u64, f32) => ceiling_pass);

impl Backend for CpuBackend {
    fn name(&self) -> String {
        "cpu".into()
    }

    fn brick_edge(&self) -> Option<f32> {
        Some(self.brick)
    }

    /// Counted by the 8-lane blocks actually evaluated (blocks whose box
    /// misses the point are skipped, not counted).
    fn kernel_evaluations(&self) -> u64 {
        self.evaluations
    }
    fn evaluate_points(&mut self, params: &[Primitive], pos: &[[f32; 3]], rho: &mut [f32], n: &mut [f32]) -> Result<()> {
        self.forward_points(params, pos, rho, n, false)
    }

    fn evaluate_each(&mut self, params: &[Primitive], pos: &[[f32; 3]], rho: &mut [f32], n: &mut [f32]) -> Result<()> {
        self.forward_points(params, pos, rho, n, true)
    }

    fn point_loss_grad(&mut self, params: &[Primitive], batch: &PointBatch, weights: &LossWeights, grad: &mut [Primitive]) -> Result<PointLoss> {
        self.loss_grad(params, batch, weights, grad)
    }

    fn decode_lattice(&mut self, params: &[Primitive], lattice: &Lattice, out: &mut [f32]) -> Result<()> {
        self.splat_lattice(params, lattice, out)
    }
}

#[cfg(test)]
mod tests {
    use super::binning::{WorkChunk, MIN_RUN_COST, WORK_CHUNKS};
    use super::*;
    use crate::math::kernel::isotropic;
    use crate::math::rng::Rng;
    /// A batch crowded into a few bricks has chunks of more than twice the
    /// mean cost, which start first on their own, and bricks above
    /// `SPLIT_SHARES` chunks' shares, whose points run in runs: the gradient
    /// and the loss are the same bits on 1 and 3 threads, and on 3 threads
    /// again, and the gradient of whole bricks up to the order of the sums;
    /// the forward passes give whole bricks' bits.
    #[test]
    fn heavy_chunks_and_split_bricks_give_the_same_bits_on_any_thread_count() {
        let mut rng = Rng::new(8);
        let params = random_prims(&mut rng, 400);
        // Two crowded bricks (of edge 2) and points all over.
        let pos: Vec<[f32; 3]> = (0..3000)
            .map(|i| [0, 1, 2].map(|_| match i % 3 {
                0 => rng.range(0.2, 1.8),
                1 => rng.range(4.2, 5.8),
                _ => rng.range(0.0, 6.0),
            } as f32))
            .collect();
        let vref = (0..pos.len()).map(|_| rng.uniform() as f32).collect();
        let batch = PointBatch::new(pos, vref);
        let mut b = CpuBackend { brick: 2.0, ..CpuBackend::default() };
        b.prep.update(&params);
        let bins = b.bin_points(batch.bricks(2.0));
        let whole = CpuBackend::work_chunks(&bins, 0);
        let mean = whole.iter().map(|w| w.cost).sum::<u64>() / whole.len() as u64;
        assert!(whole.iter().filter(|w| w.cost > 2 * mean).count() >= 2, "no heavy chunks: {whole:?}");
        // The crowded bricks become chunks of their own, cut into runs of
        // at most two chunks' shares, unless that would make runs cheaper
        // than MIN_RUN_COST; every brick is in one chunk, in order.
        let work = CpuBackend::work_chunks(&bins, SPLIT_SHARES);
        let split: Vec<&WorkChunk> = work.iter().filter(|w| w.runs > 1).collect();
        assert!(split.len() >= 2 && split.iter().all(|w| w.bricks.1 == w.bricks.0 + 1 && w.runs >= 4), "{work:?}");
        let target = whole.iter().map(|w| w.cost).sum::<u64>() / WORK_CHUNKS as u64 + 1;
        assert!(split.iter().all(|w| w.cost / w.runs as u64 >= MIN_RUN_COST), "{work:?}");
        assert!(split.iter().all(|w| w.cost.div_ceil(w.runs as u64) <= SPLIT_SHARES * target || w.cost / (w.runs as u64 + 1) < MIN_RUN_COST), "{work:?}");
        assert_eq!(work[0].bricks.0, 0);
        assert!(work.windows(2).all(|p| p[0].bricks.1 == p[1].bricks.0) && work.last().unwrap().bricks.1 == bins.bricks.ranges.len());
        let run = |threads: usize, split_shares: u64| {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            pool.install(|| {
                let mut b = CpuBackend { brick: 2.0, split_shares, ..CpuBackend::default() };
                let mut grad = vec![[0.0f32; 12]; params.len()];
                let loss = b.point_loss_grad(&params, &batch, &LossWeights::default(), &mut grad).unwrap();
                (loss, grad)
            })
        };
        let bits = |(l, g): &(PointLoss, Vec<Primitive>)| (l.val.to_bits(), l.cov.to_bits(), g.as_flattened().iter().map(|x| x.to_bits()).collect::<Vec<_>>());
        let one = bits(&run(1, SPLIT_SHARES));
        assert!(one.2.iter().any(|&x| f32::from_bits(x) != 0.0));
        assert!(bits(&run(3, SPLIT_SHARES)) == one && bits(&run(3, SPLIT_SHARES)) == one);
        // Whole bricks: the same sums in another order.
        let (split_loss, split_grad) = run(2, SPLIT_SHARES);
        let (whole_loss, whole_grad) = run(2, 0);
        assert!((split_loss.val - whole_loss.val).abs() <= 1e-9 * whole_loss.val && (split_loss.cov - whole_loss.cov).abs() <= 1e-9 * whole_loss.cov.abs().max(1e-12));
        let (a, b) = (split_grad.as_flattened(), whole_grad.as_flattened());
        let diff: f64 = a.iter().zip(b).map(|(x, y)| ((x - y) as f64).powi(2)).sum::<f64>().sqrt();
        let norm: f64 = b.iter().map(|y| (*y as f64).powi(2)).sum::<f64>().sqrt();
        assert!(diff <= 1e-5 * norm, "split bricks' gradient off by {diff} of {norm}");

        // The forward pass cuts the same bricks into runs of points, and
        // a point's sums are its brick's whatever run it falls in: the
        // same bits as whole bricks, on any thread count, both forwards.
        let eval = |threads: usize, split_shares: u64, pointwise: bool| {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            pool.install(|| {
                let mut b = CpuBackend { brick: 2.0, split_shares, ..CpuBackend::default() };
                let (mut rho, mut n) = (vec![f32::NAN; batch.pos.len()], vec![f32::NAN; batch.pos.len()]);
                if pointwise {
                    b.evaluate_each(&params, &batch.pos, &mut rho, &mut n).unwrap();
                } else {
                    b.evaluate_points(&params, &batch.pos, &mut rho, &mut n).unwrap();
                }
                rho.iter().chain(&n).map(|x| x.to_bits()).collect::<Vec<_>>()
            })
        };
        for pointwise in [false, true] {
            let whole = eval(1, 0, pointwise);
            assert!(whole.iter().all(|&x| !f32::from_bits(x).is_nan()) && whole.iter().any(|&x| f32::from_bits(x) != 0.0));
            assert!(eval(3, SPLIT_SHARES, pointwise) == whole && eval(1, SPLIT_SHARES, pointwise) == whole, "pointwise {pointwise}");
        }
    }

    /// Primitives scattered over [0, 6)^3 with random rotations and sizes.
    pub(super) fn random_prims(rng: &mut Rng, n: usize) -> Vec<Primitive> {
        (0..n)
            .map(|_| {
                let mut p = isotropic([0, 1, 2].map(|_| rng.range(0.0, 6.0) as f32), 1.0, rng.uniform() as f32, rng.uniform() as f32);
                for i in 3..10 {
                    p[i] = rng.range(-1.0, 1.0) as f32;
                }
                p[6] += 1.0;
                p
            })
            .collect()
    }
}
