//! The CPU backend: spatial bricks, rayon, no locks or atomics on the hot path.
//!
//! Training (`point_loss_grad`, `evaluate_points`):
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

mod lanes;
mod simd;

use self::lanes::{BrickCands, BrickSoa, Hot, PointPass, LANES};
use self::simd::simd_dispatch;
use super::bricks::PointBricks;
use super::csr::{csr, Keyed};
use super::{check_len, Backend, Lattice, PointLoss};
use crate::error::Result;
use crate::math::kernel::{Frame, GradAcc, Primitive, CUTOFF_D2};
use crate::math::loss::{point_terms, v_eval, LossWeights, PointNorm};
use crate::math::primitives_per_task;
use crate::profile::{self, Part};
use crate::backend::PointBatch;
use rayon::prelude::*;
use crossbeam_utils::CachePadded;
use std::borrow::Cow;

/// Work chunks per batch: enough for load balance on many cores; fixed so that
/// the reduction order never depends on the thread count.
const WORK_CHUNKS: usize = 64;
/// A brick that costs more than this many work chunks' shares is a chunk
/// of its own, its points cut into runs of at most that cost (and at least
/// `MIN_RUN_COST`) that share the brick's loaded candidates and run in
/// parallel ([`split_brick`]).
const SPLIT_SHARES: u64 = 2;
/// The least cost (points x (candidates + 1)) of a run of a split brick,
/// so that a small encode (few points, few candidates a brick) never
/// splits one: on hydrogen 64³ a run costs about 120 µs on one core and
/// the load before the runs and the merge after them about 20 µs each
/// (docs/BENCHMARKS.md "A dense brick's points in parallel runs").
const MIN_RUN_COST: u64 = 1 << 15;
/// Edge of a decode brick in lattice voxels.
const DECODE_BRICK: usize = 8;

/// Per-chunk sparse gradient accumulator, kept between iterations.
#[derive(Default)]
struct ChunkScratch {
    /// Primitive -> position in `acc`, `u32::MAX` when untouched.
    slot: Vec<u32>,
    touched: Vec<u32>,
    acc: Vec<GradAcc>,
    /// Positions in `touched` grouped by block of `block_len` primitives
    /// (`ChunkScratch::group`): block `k`'s are
    /// `by_block[block_start[k]..block_start[k + 1]]`.
    by_block: Vec<u32>,
    block_start: Vec<u32>,
    soa: BrickSoa,
    /// The passes of a split brick's runs after the first (which is
    /// `soa.pass`), each on cache lines of its own: every point writes its
    /// pass, and the runs go on different cores.
    runs: Vec<CachePadded<PointPass>>,
}

impl ChunkScratch {
    /// Ready for a chunk's sums over `np` primitives: no slot taken, nothing
    /// touched.
    fn fresh(&mut self, np: usize) {
        if self.slot.len() != np {
            self.slot.clear();
            self.slot.resize(np, u32::MAX);
        }
        self.touched.clear();
        self.acc.clear();
    }

    /// Groups the touched primitives by block of `block_len` (a counting
    /// sort), so that the reduction can run block by block in parallel,
    /// and forgets their slots.
    fn group(&mut self, block_len: usize, blocks: usize) {
        let ChunkScratch { slot, touched, by_block, block_start, .. } = self;
        block_start.clear();
        block_start.resize(blocks + 1, 0);
        for &g in touched.iter() {
            block_start[g as usize / block_len + 1] += 1;
        }
        for k in 0..blocks {
            block_start[k + 1] += block_start[k];
        }
        by_block.resize(touched.len(), 0);
        for (t, &g) in touched.iter().enumerate() {
            let at = &mut block_start[g as usize / block_len];
            by_block[*at as usize] = t as u32;
            *at += 1;
            slot[g as usize] = u32::MAX;
        }
        // Each start moved to the next block's: shift them back.
        for k in (1..=blocks).rev() {
            block_start[k] = block_start[k - 1];
        }
        block_start[0] = 0;
    }

    /// Adds this chunk's sums of the primitives of block `k` (of the
    /// `block_len` that `group` was given) into `block`, that block's slice
    /// of the per-primitive sums.
    fn add_block(&self, k: usize, block_len: usize, block: &mut [GradAcc]) {
        for &t in &self.by_block[self.block_start[k] as usize..self.block_start[k + 1] as usize] {
            block[self.touched[t as usize] as usize - k * block_len].add(&self.acc[t as usize]);
        }
    }
}

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

/// Points sorted into bricks and primitives listed per occupied brick.
struct PointBins<'a> {
    bricks: Cow<'a, PointBricks>,
    /// Per occupied brick: range into `cand`.
    cand_start: Vec<u32>,
    cand: Vec<u32>,
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
            .for_each(|(((fs, hs), bs), ps)| {
                profile::task("frames", || {
                    for (((f, h), b), p) in fs.iter_mut().zip(hs).zip(bs).zip(ps) {
                        *f = Frame::new(p);
                        *h = Hot::new(f);
                        *b = [f.mu[0] - f.ext[0], f.mu[1] - f.ext[1], f.mu[2] - f.ext[2], f.mu[0] + f.ext[0], f.mu[1] + f.ext[1], f.mu[2] + f.ext[2]];
                    }
                })
            });
    }
}

impl CpuBackend {
    pub fn new() -> Self {
        Self::default()
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

    /// Lists, for each occupied brick of `bricks`, the primitives whose box
    /// overlaps it.
    fn bin_points<'a>(&self, bricks: Cow<'a, PointBricks>) -> PointBins<'a> {
        let (bd, occ) = (bricks.dims, &bricks.occupied);
        // List every primitive in the occupied bricks its box overlaps.
        // Occupancy of each row of bricks as a bit mask (rows of up to 64 bricks).
        let row_mask: Option<Vec<u64>> = profile::serial("binning: rows", || (bd[0] <= 64).then(|| {
            let mut m = vec![0u64; bd[1] * bd[2]];
            for (id, &o) in occ.iter().enumerate() {
                if o != u32::MAX {
                    m[id / bd[0]] |= 1u64 << (id % bd[0]);
                }
            }
            m
        }));
        let boxes = &self.prep.boxes;
        let task = primitives_per_task(boxes.len());
        let nb = bricks.ranges.len();
        let parts: Vec<Keyed> = (0..boxes.len().div_ceil(task))
            .into_par_iter()
            .map(|c| profile::task("binning", || {
                let mut out = Keyed::new(nb, 0);
                let end = ((c + 1) * task).min(boxes.len());
                for g in c * task..end {
                    let Some((r0, r1)) = bricks.range_of(&boxes[g]) else { continue };
                    for z in r0[2]..=r1[2] {
                        for y in r0[1]..=r1[1] {
                            let row = y + bd[1] * z;
                            if let Some(masks) = &row_mask {
                                // Only the occupied bricks of this row, in x order.
                                let span = if r1[0] - r0[0] >= 63 { u64::MAX } else { (1u64 << (r1[0] - r0[0] + 1)) - 1 };
                                let mut m = masks[row] & (span << r0[0]);
                                while m != 0 {
                                    let x = m.trailing_zeros() as usize;
                                    m &= m - 1;
                                    out.push(occ[bd[0] * row + x], g as u32);
                                }
                            } else {
                                for x in r0[0]..=r1[0] {
                                    let o = occ[bd[0] * row + x];
                                    if o != u32::MAX {
                                        out.push(o, g as u32);
                                    }
                                }
                            }
                        }
                    }
                }
                out
            }))
            .collect();
        let (cand_start, cand) = profile::even("binning: sort", parts.len(), || csr(nb, parts));
        PointBins { bricks, cand_start, cand }
    }

    /// Contiguous ranges of bricks of similar cost, in order.
    fn work_ranges(bins: &PointBins) -> Vec<(usize, usize)> {
        Self::work_chunks(bins, 0).into_iter().map(|w| w.bricks).collect()
    }

    /// Cuts the occupied bricks into about `WORK_CHUNKS` contiguous ranges
    /// of similar cost (points x (candidates + 1)); a brick above `split_shares`
    /// ranges' cost (unless 0) is a chunk of its own whose points run in
    /// parallel runs. The cut depends on the batch only, never on the
    /// thread count.
    fn work_chunks(bins: &PointBins, split_shares: u64) -> Vec<WorkChunk> {
        let nb = bins.bricks.ranges.len();
        let cost = |b: usize| {
            let (s, e) = bins.bricks.ranges[b];
            (e - s) as u64 * (bins.cand_start[b + 1] - bins.cand_start[b] + 1) as u64
        };
        let total: u64 = (0..nb).map(cost).sum();
        let target = total / WORK_CHUNKS as u64 + 1;
        let mut chunks = vec![];
        let (mut start, mut acc) = (0, 0u64);
        for b in 0..nb {
            let c = cost(b);
            let runs = if split_shares == 0 { 1 } else { c.div_ceil(split_shares * target).min(c / MIN_RUN_COST).max(1) as usize };
            if runs > 1 {
                if start < b {
                    chunks.push(WorkChunk { bricks: (start, b), cost: acc, runs: 1 });
                }
                chunks.push(WorkChunk { bricks: (b, b + 1), cost: c, runs });
                start = b + 1;
                acc = 0;
                continue;
            }
            acc += c;
            if acc >= target {
                chunks.push(WorkChunk { bricks: (start, b + 1), cost: acc, runs: 1 });
                start = b + 1;
                acc = 0;
            }
        }
        if start < nb {
            chunks.push(WorkChunk { bricks: (start, nb), cost: acc, runs: 1 });
        }
        chunks
    }
}

/// A gradient work chunk: whole bricks `bricks.0..bricks.1`, or one brick
/// (a dense one) whose points are cut into `runs` runs.
#[derive(Clone, Copy, Debug, PartialEq)]
struct WorkChunk {
    bricks: (usize, usize),
    /// Points x (candidates + 1), summed over the bricks.
    cost: u64,
    runs: usize,
}

/// What a gradient work chunk reads.
struct GradJob<'a> {
    prep: &'a Prepared,
    bins: &'a PointBins<'a>,
    batch: &'a PointBatch,
    norm: &'a PointNorm,
    weights: &'a LossWeights,
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
simd_dispatch!(fn grad_chunk_dispatch(job: &GradJob, sc: &mut ChunkScratch, range: (usize, usize)) -> (f64, f64, u64) => grad_chunk);
simd_dispatch!(fn eval_chunk_dispatch(prep: &Prepared, bins: &PointBins, pos: &[[f32; 3]], range: (usize, usize)) -> (Vec<(u32, f32, f32)>, u64) => eval_chunk);
simd_dispatch!(fn brick_run_dispatch(job: &GradJob, cands: &BrickCands, pass: &mut PointPass, points: &[u32], sums: &mut (f64, f64, u64)) -> bool => brick_run);

/// Forward, loss and backward for the points of bricks `b0..b1`; returns the
/// chunk's (L_val, L_cov, kernel evaluations) and leaves its gradient sums in
/// `sc`.
#[inline(always)]
fn grad_chunk(job: &GradJob, sc: &mut ChunkScratch, (b0, b1): (usize, usize)) -> (f64, f64, u64) {
    let mut sums = (0.0f64, 0.0f64, 0u64);
    let bins = job.bins;
    let ChunkScratch { slot, touched, acc, soa, .. } = sc;
    for b in b0..b1 {
        let cands = &bins.cand[bins.cand_start[b] as usize..bins.cand_start[b + 1] as usize];
        soa.load(&job.prep.hot, &job.prep.boxes, cands, true);
        let (s, e) = bins.bricks.ranges[b];
        if brick_run(job, &soa.cands, &mut soa.pass, &bins.bricks.order[s as usize..e as usize], &mut sums) {
            gather(cands, &soa.pass, slot, touched, acc);
        }
    }
    sums
}

/// Forward, loss and backward of `points` (a brick's, or a run of them) over
/// the brick's candidates: adds their (L_val, L_cov, kernel evaluations) to
/// `sums` and their pair terms to `pass`; returns whether any point had a
/// gradient.
#[inline(always)]
fn brick_run(job: &GradJob, cands: &BrickCands, pass: &mut PointPass, points: &[u32], sums: &mut (f64, f64, u64)) -> bool {
    let mut any = false;
    for &pi in points {
        let (rho, n) = pass.forward(cands, job.batch.pos[pi as usize], &mut sums.2);
        let t = point_terms(rho, n, job.batch.vref[pi as usize], job.norm, job.weights);
        sums.0 += t.val as f64;
        sums.1 += t.cov as f64;
        if t.g_rho != 0.0 || t.g_n != 0.0 {
            pass.backward(cands, t.g_rho, t.g_n);
            any = true;
        }
    }
    any
}

/// Adds a brick's pair sums (`pass`, over its candidates `cands`) to the
/// chunk's per-primitive sums.
fn gather(cands: &[u32], pass: &PointPass, slot: &mut [u32], touched: &mut Vec<u32>, acc: &mut Vec<GradAcc>) {
    for (j, &g) in cands.iter().enumerate() {
        if let Some(ga) = pass.take(j) {
            let si = &mut slot[g as usize];
            if *si == u32::MAX {
                *si = acc.len() as u32;
                touched.push(g);
                acc.push(GradAcc::default());
            }
            acc[*si as usize].add(&ga);
        }
    }
}

/// [`grad_chunk`] for one dense brick `b` whose points are cut into `runs`
/// runs of consecutive points: the brick's candidates are loaded once (the
/// head), the runs go forward and backward over them in parallel, each into
/// its own sums, and the sums are added run by run in order, then grouped
/// as a chunk's (the tail). The cut depends on the batch only, so the bits
/// do not depend on the thread count (they differ from the whole brick's by
/// the order of the sums). `sc` must be fresh ([`ChunkScratch::fresh`]).
fn split_brick(job: &GradJob, sc: &mut ChunkScratch, b: usize, runs: usize, (block_len, blocks): (usize, usize)) -> (f64, f64, u64) {
    const PASS: &str = "gradient chunks";
    let bins = job.bins;
    let cands = &bins.cand[bins.cand_start[b] as usize..bins.cand_start[b + 1] as usize];
    let (s, e) = bins.bricks.ranges[b];
    let points = &bins.bricks.order[s as usize..e as usize];
    // Taken out of `sc` for the while, so that the tail may group `sc`.
    let (mut soa, mut extra) = (std::mem::take(&mut sc.soa), std::mem::take(&mut sc.runs));
    profile::part(PASS, Part::Head, || soa.load(&job.prep.hot, &job.prep.boxes, cands, true));
    if extra.len() < runs - 1 {
        extra.resize_with(runs - 1, CachePadded::default);
    }
    let nb = soa.blocks();
    let BrickSoa { cands: loaded, pass: first } = &mut soa;
    let loaded = &*loaded;
    let mut passes: Vec<&mut PointPass> = std::iter::once(first).chain(extra[..runs - 1].iter_mut().map(|p| &mut **p)).collect();
    let outs: Vec<((f64, f64, u64), bool)> = passes
        .par_iter_mut()
        .enumerate()
        .map(|(r, pass)| {
            profile::part(PASS, Part::Run, || {
                if r > 0 {
                    pass.reset(nb, true);
                }
                let mut sums = (0.0f64, 0.0f64, 0u64);
                let run = &points[r * points.len() / runs..(r + 1) * points.len() / runs];
                let any = brick_run_dispatch(job, loaded, pass, run, &mut sums);
                (sums, any)
            })
        })
        .collect();
    let (first, rest) = passes.split_first_mut().expect("at least one run");
    profile::part(PASS, Part::Tail, || {
        for pass in rest {
            first.add(pass);
        }
        if outs.iter().any(|o| o.1) {
            gather(cands, first, &mut sc.slot, &mut sc.touched, &mut sc.acc);
        }
        sc.group(block_len, blocks);
    });
    (sc.soa, sc.runs) = (soa, extra);
    let mut sums = (0.0f64, 0.0f64, 0u64);
    for ((v, c, e), _) in outs {
        sums.0 += v;
        sums.1 += c;
        sums.2 += e;
    }
    sums
}

/// `(point, rho, n)` for the points of bricks `b0..b1`, and the kernel count.
#[inline(always)]
fn eval_chunk(prep: &Prepared, bins: &PointBins, pos: &[[f32; 3]], (b0, b1): (usize, usize)) -> (Vec<(u32, f32, f32)>, u64) {
    let mut soa = BrickSoa::default();
    let mut out = vec![];
    let mut evals = 0;
    for b in b0..b1 {
        let cands = &bins.cand[bins.cand_start[b] as usize..bins.cand_start[b + 1] as usize];
        soa.load(&prep.hot, &prep.boxes, cands, false);
        let (s, e) = bins.bricks.ranges[b];
        for &pi in &bins.bricks.order[s as usize..e as usize] {
            let (r, nn) = soa.forward(pos[pi as usize], &mut evals);
            out.push((pi, r, nn));
        }
    }
    (out, evals)
}

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
        check_len("rho", rho.len(), pos.len())?;
        check_len("n", n.len(), pos.len())?;
        if pos.is_empty() {
            return Ok(());
        }
        self.prep.update(params);
        let bins = self.bin_points(Cow::Owned(PointBricks::new(pos, self.brick)));
        let ranges = Self::work_ranges(&bins);
        let prep = &self.prep;
        let results: Vec<(Vec<(u32, f32, f32)>, u64)> = ranges
            .par_iter()
            .map(|&range| eval_chunk_dispatch(prep, &bins, pos, range))
            .collect();
        for (part, evals) in results {
            self.evaluations += evals;
            for (i, r, nn) in part {
                rho[i as usize] = r;
                n[i as usize] = nn;
            }
        }
        Ok(())
    }

    fn point_loss_grad(
        &mut self,
        params: &[Primitive],
        batch: &PointBatch,
        weights: &LossWeights,
        grad: &mut [Primitive],
    ) -> Result<PointLoss> {
        check_len("grad", grad.len(), params.len())?;
        check_len("vref", batch.vref.len(), batch.pos.len())?;
        if batch.is_empty() || params.is_empty() {
            grad.par_iter_mut().for_each(|g| *g = [0.0; 12]);
            return Ok(PointLoss::default());
        }
        self.prep.update(params);
        let bins = self.bin_points(batch.bricks(self.brick));
        let work = profile::serial("work chunks", || Self::work_chunks(&bins, self.split_shares));
        let norm = PointNorm::new(&batch.vref, weights);
        let np = params.len();
        if self.chunks.len() < work.len() {
            self.chunks.resize_with(work.len(), CachePadded::default);
        }
        let mut acc = std::mem::take(&mut self.acc);
        acc.resize(np, GradAcc::default());
        let block_len = primitives_per_task(np);
        let blocks = np.div_ceil(block_len);
        let CpuBackend { prep, chunks, evaluations, .. } = self;
        let prep: &Prepared = prep;
        let chunks = &mut chunks[..work.len()];
        // Each chunk's sums are its own, so the order in which the chunks
        // run changes no bit. The chunks of more than twice the mean cost
        // (a dense brick's) are started first, longest first, each its own
        // task on a FIFO scope (its threads take the oldest task left), so
        // that none starts last and holds the whole pass up; the others
        // then run as one parallel iterator in brick order, whose
        // contiguous runs keep neighbouring bricks' candidates in a core's
        // cache (started longest first too, they ran 7 % slower on RM 128³
        // `full`: docs/BENCHMARKS.md).
        let job = GradJob { prep, bins: &bins, batch, norm: &norm, weights };
        let run = |sc: &mut ChunkScratch, w: WorkChunk| {
            if w.runs > 1 {
                sc.fresh(np);
                return split_brick(&job, sc, w.bricks.0, w.runs, (block_len, blocks));
            }
            profile::task("gradient chunks", || {
                sc.fresh(np);
                let out = grad_chunk_dispatch(&job, sc, w.bricks);
                sc.group(block_len, blocks);
                out
            })
        };
        let mean = work.iter().map(|w| w.cost).sum::<u64>() / work.len().max(1) as u64;
        let mut losses = vec![(0.0f64, 0.0f64, 0u64); work.len()];
        let mut items: Vec<_> = chunks.iter_mut().zip(losses.iter_mut()).zip(&work).map(|((sc, out), &w)| Some((sc, out, w))).collect();
        let mut heavy: Vec<usize> = (0..work.len()).filter(|&i| work[i].cost > 2 * mean).collect();
        heavy.sort_by_key(|&i| (std::cmp::Reverse(work[i].cost), i));
        let heavy: Vec<_> = heavy.into_iter().filter_map(|i| items[i].take()).collect();
        let light: Vec<_> = items.into_iter().flatten().collect();
        let run = &run;
        rayon::scope_fifo(|s| {
            for (sc, out, w) in heavy {
                s.spawn_fifo(move |_| *out = run(sc, w));
            }
            s.spawn_fifo(move |_| light.into_par_iter().for_each(|(sc, out, w)| *out = run(sc, w)));
        });
        let mut out = PointLoss::default();
        for (v, c, e) in losses {
            out.val += v;
            out.cov += c;
            *evaluations += e;
        }
        // Fixed-order reduction: each primitive's sums added chunk by chunk
        // (the same order, so the same bits, whatever the thread count),
        // in parallel over blocks of primitives; then the chain rule.
        let (chunks, frames) = (&*chunks, &prep.frames);
        grad.par_chunks_mut(block_len).zip(acc.par_chunks_mut(block_len)).enumerate().for_each(|(k, (gs, accs))| profile::task("reduction", || {
            accs.fill(GradAcc::default());
            for sc in chunks {
                sc.add_block(k, block_len, accs);
            }
            for (i, (g, a)) in gs.iter_mut().zip(accs.iter()).enumerate() {
                // Most primitives meet no point of a small batch; their sums
                // are zero and so is their gradient (up to the sign of
                // zero, which no later step sees), without reading the frame.
                *g = if a.0 == [0.0; 12] { [0.0; 12] } else { frames[k * block_len + i].finalize(a) };
            }
        }));
        self.acc = acc;
        Ok(out)
    }

    fn decode_lattice(&mut self, params: &[Primitive], lattice: &Lattice, out: &mut [f32]) -> Result<()> {
        check_len("out", out.len(), lattice.len())?;
        self.prep.update(params);
        let frames = &self.prep.frames;
        let dims = lattice.dims;
        // Each primitive's box in lattice indices (inclusive), or None when outside.
        let boxes: Vec<Option<[u32; 6]>> = frames
            .par_iter()
            .map(|f| {
                let mut r = [0u32; 6];
                for a in 0..3 {
                    let l = ((f.mu[a] - f.ext[a] - lattice.origin[a]) / lattice.step[a]).ceil();
                    let h = ((f.mu[a] + f.ext[a] - lattice.origin[a]) / lattice.step[a]).floor();
                    if !(h >= 0.0 && l <= (dims[a] - 1) as f32) || h < l {
                        return None;
                    }
                    r[a] = l.max(0.0) as u32;
                    r[a + 3] = h.min((dims[a] - 1) as f32) as u32;
                }
                Some(r)
            })
            .collect();
        let bs = DECODE_BRICK;
        let nlayers = dims[2].div_ceil(bs);
        let mut layer_pairs = vec![];
        for (g, b) in boxes.iter().enumerate() {
            if let Some(b) = b {
                for layer in b[2] as usize / bs..=b[5] as usize / bs {
                    layer_pairs.push((layer as u32, g as u32));
                }
            }
        }
        let (lstart, lcand) = csr(nlayers, vec![Keyed::from_pairs(nlayers, layer_pairs)]);
        let (nbx, nby) = (dims[0].div_ceil(bs), dims[1].div_ceil(bs));
        let slab_len = dims[0] * dims[1] * bs;
        out.par_chunks_mut(slab_len).enumerate().for_each(|(layer, slab)| {
            let cands = &lcand[lstart[layer] as usize..lstart[layer + 1] as usize];
            let z0 = layer * bs;
            let nz = slab.len() / (dims[0] * dims[1]);
            let mut pairs = vec![];
            for &g in cands {
                let b = boxes[g as usize].unwrap();
                for by in b[1] as usize / bs..=b[4] as usize / bs {
                    for bx in b[0] as usize / bs..=b[3] as usize / bs {
                        pairs.push(((bx + nbx * by) as u32, g));
                    }
                }
            }
            let (bstart, bcand) = csr(nbx * nby, vec![Keyed::from_pairs(nbx * nby, pairs)]);
            let mut rho = vec![0f32; bs * bs * bs];
            let mut num = vec![0f32; bs * bs * bs];
            for by in 0..nby {
                for bx in 0..nbx {
                    let (x0, y0) = (bx * bs, by * bs);
                    let (nx, ny) = (bs.min(dims[0] - x0), bs.min(dims[1] - y0));
                    rho.fill(0.0);
                    num.fill(0.0);
                    let id = bx + nbx * by;
                    for &g in &bcand[bstart[id] as usize..bstart[id + 1] as usize] {
                        let f = &frames[g as usize];
                        let a = f.scaled_axes();
                        let b = boxes[g as usize].unwrap();
                        let zr = (b[2] as usize).max(z0)..=(b[5] as usize).min(z0 + nz - 1);
                        let yr = (b[1] as usize).max(y0)..=(b[4] as usize).min(y0 + ny - 1);
                        let (i0, i1) = ((b[0] as usize).max(x0), (b[3] as usize).min(x0 + nx - 1));
                        for k in zr {
                            for j in yr.clone() {
                                let base = (j - y0) * bs + (k - z0) * bs * bs;
                                let p = lattice.point(i0, j, k);
                                let (dy, dz) = (p[1] - f.mu[1], p[2] - f.mu[2]);
                                let c = [0, 1, 2].map(|r| a[r][1] * dy + a[r][2] * dz);
                                let dx0 = p[0] - f.mu[0];
                                let row = base + i0 - x0..=base + i1 - x0;
                                // Branch-free over the row, so that it vectorises.
                                for (t, (r, n)) in rho[row.clone()].iter_mut().zip(num[row].iter_mut()).enumerate() {
                                    let dx = dx0 + t as f32 * lattice.step[0];
                                    let u0 = a[0][0] * dx + c[0];
                                    let u1 = a[1][0] * dx + c[1];
                                    let u2 = a[2][0] * dx + c[2];
                                    let d2 = u0 * u0 + u1 * u1 + u2 * u2;
                                    let e = crate::math::kernel::exp_neg_half(d2);
                                    let wk = f.w * if d2 < CUTOFF_D2 { e } else { 0.0 };
                                    *r += wk;
                                    *n += wk * f.s;
                                }
                            }
                        }
                    }
                    for k in 0..nz {
                        for j in 0..ny {
                            let row = x0 + dims[0] * (y0 + j + dims[1] * k);
                            for i in 0..nx {
                                let l = i + j * bs + k * bs * bs;
                                slab[row + i] = v_eval(rho[l], num[l]);
                            }
                        }
                    }
                }
            }
        });
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::kernel::isotropic;
    use crate::math::rng::Rng;

    /// The reduction by blocks of primitives (`group`, `add_block`) adds
    /// each primitive's sums in chunk order, as one pass over the chunks in
    /// turn does: the same bits. Chunks touch primitives in any order, in
    /// several blocks and the last, partial one; the scratch is reused.
    #[test]
    fn the_reduction_by_blocks_gives_the_bits_of_the_reduction_chunk_by_chunk() {
        let mut rng = Rng::new(4);
        let (block_len, np): (usize, usize) = (700, 3 * 700 + 123);
        let blocks = np.div_ceil(block_len);
        let mut chunks: Vec<ChunkScratch> = (0..5).map(|_| ChunkScratch { slot: vec![u32::MAX; np], ..Default::default() }).collect();
        for round in 0..2 {
            for sc in chunks.iter_mut() {
                sc.touched.clear();
                sc.acc.clear();
                for _ in 0..rng.below(3000) {
                    let g = rng.below(np as u64) as u32;
                    if sc.slot[g as usize] == u32::MAX {
                        sc.slot[g as usize] = sc.touched.len() as u32;
                        sc.touched.push(g);
                        sc.acc.push(GradAcc([0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11].map(|_| rng.range(-1.0, 1.0) as f32 * 10f32.powi(rng.below(8) as i32 - 4))));
                    }
                }
            }
            let mut want = vec![GradAcc::default(); np];
            for sc in &chunks {
                for (t, &g) in sc.touched.iter().enumerate() {
                    want[g as usize].add(&sc.acc[t]);
                }
            }
            for sc in chunks.iter_mut() {
                sc.group(block_len, blocks);
                assert!(sc.slot.iter().all(|&s| s == u32::MAX), "round {round}: slots left set");
            }
            let mut got = vec![GradAcc::default(); np];
            for (k, block) in got.chunks_mut(block_len).enumerate() {
                for sc in &chunks {
                    sc.add_block(k, block_len, block);
                }
            }
            for g in 0..np {
                assert_eq!(got[g].0.map(f32::to_bits), want[g].0.map(f32::to_bits), "round {round}, primitive {g}");
            }
        }
    }

    /// A batch crowded into a few bricks has chunks of more than twice the
    /// mean cost, which start first on their own, and bricks above
    /// `SPLIT_SHARES` chunks' shares, whose points run in runs: the gradient
    /// and the loss are the same bits on 1 and 3 threads, and on 3 threads
    /// again, and the gradient of whole bricks up to the order of the sums.
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
