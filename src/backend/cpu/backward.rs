//! The training pass (`Backend::point_loss_grad`): forward, point loss and
//! backward for each work chunk's points into the chunk's own sparse sums
//! (`ChunkScratch`), a dense brick's points in parallel runs
//! ([`split_brick`]), then the fixed-order reduction of the chunks' sums
//! per primitive and the chain rule: step 4 of the module's account
//! (`mod.rs`).

use super::binning::{PointBins, WorkChunk};
use super::lanes::{BrickCands, BrickSoa, PointPass};
use crate::math::simd::simd_dispatch;
use super::{CpuBackend, Prepared};
use crate::backend::{check_len, PointBatch, PointLoss};
use crate::error::Result;
use crate::math::kernel::{Frame, GradAcc, Primitive};
use crate::math::loss::{point_terms, LossWeights, PointNorm};
use crate::math::primitives_per_task;
use crate::profile::{self, Part};
use crossbeam_utils::CachePadded;
use rayon::prelude::*;

/// Per-chunk sparse gradient accumulator, kept between iterations.
#[derive(Default)]
pub(super) struct ChunkScratch {
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
    #[inline(always)]
    fn add_block(&self, k: usize, block_len: usize, block: &mut [GradAcc]) {
        for &t in &self.by_block[self.block_start[k] as usize..self.block_start[k + 1] as usize] {
            block[self.touched[t as usize] as usize - k * block_len].add(&self.acc[t as usize]);
        }
    }
}

/// What a gradient work chunk reads.
struct GradJob<'a> {
    prep: &'a Prepared,
    bins: &'a PointBins<'a>,
    batch: &'a PointBatch,
    norm: &'a PointNorm,
    weights: &'a LossWeights,
}

simd_dispatch!(fn grad_chunk_dispatch(job: &GradJob, sc: &mut ChunkScratch, range: (usize, usize)) -> (f64, f64, u64) => grad_chunk);
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

simd_dispatch!(fn reduce_dispatch(chunks: &[CachePadded<ChunkScratch>], frames: &[Frame], block: (usize, usize), gs: &mut [Primitive], accs: &mut [GradAcc]) -> () => reduce_block);

/// Block `k` of `block_len` primitives (`block`): each primitive's sums
/// added chunk by chunk into `accs`, then the chain rule into `gs`;
/// `frames` starts at the block's first primitive.
#[inline(always)]
fn reduce_block(chunks: &[CachePadded<ChunkScratch>], frames: &[Frame], (k, block_len): (usize, usize), gs: &mut [Primitive], accs: &mut [GradAcc]) {
    accs.fill(GradAcc::default());
    for sc in chunks {
        sc.add_block(k, block_len, accs);
    }
    for ((g, a), f) in gs.iter_mut().zip(accs.iter()).zip(frames) {
        // Most primitives meet no point of a small batch; their sums are
        // zero and so is their gradient (up to the sign of zero, which no
        // later step sees), without reading the frame.
        *g = if a.0 == [0.0; 12] { [0.0; 12] } else { f.finalize(a) };
    }
}

impl CpuBackend {
    /// [`crate::backend::Backend::point_loss_grad`].
    pub(super) fn loss_grad(
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
            s.spawn_fifo(move |_| light.into_par_iter().with_max_len(1).for_each(|(sc, out, w)| *out = run(sc, w)));
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
        grad.par_chunks_mut(block_len)
            .zip(acc.par_chunks_mut(block_len))
            .enumerate()
            .with_max_len(1)
            .for_each(|(k, (gs, accs))| profile::task("reduction", || reduce_dispatch(chunks, &frames[k * block_len..], (k, block_len), gs, accs)));
        self.acc = acc;
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
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
}
