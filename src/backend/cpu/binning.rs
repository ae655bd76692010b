//! Binning, the first three steps of the CPU backend's pass over a batch
//! (the module's account, `mod.rs`): the points sorted into bricks, each
//! primitive listed in the occupied bricks its box overlaps, and the
//! occupied bricks cut into work chunks of similar cost, a cut that depends
//! on the batch only, never on the thread count.

use super::CpuBackend;
use crate::backend::bricks::PointBricks;
use crate::backend::csr::{csr, Keyed};
use crate::math::primitives_per_task;
use crate::profile;
use rayon::prelude::*;
use std::borrow::Cow;

/// Work chunks per batch: enough for load balance on many cores; fixed so that
/// the reduction order never depends on the thread count.
pub(super) const WORK_CHUNKS: usize = 64;
/// A brick that costs more than this many work chunks' shares is a chunk
/// of its own, its points cut into runs of at most that cost (and at least
/// `MIN_RUN_COST`) that share the brick's loaded candidates and run in
/// parallel (`backward::split_brick`).
pub(super) const SPLIT_SHARES: u64 = 2;
/// The least cost (points x (candidates + 1)) of a run of a split brick,
/// so that a small encode (few points, few candidates a brick) never
/// splits one: on hydrogen 64³ a run costs about 120 µs on one core and
/// the load before the runs and the merge after them about 20 µs each
/// (docs/BENCHMARKS.md "A dense brick's points in parallel runs").
pub(super) const MIN_RUN_COST: u64 = 1 << 15;

/// Points sorted into bricks and primitives listed per occupied brick.
pub(super) struct PointBins<'a> {
    pub(super) bricks: Cow<'a, PointBricks>,
    /// Per occupied brick: range into `cand`.
    pub(super) cand_start: Vec<u32>,
    pub(super) cand: Vec<u32>,
}

/// A gradient work chunk: whole bricks `bricks.0..bricks.1`, or one brick
/// (a dense one) whose points are cut into `runs` runs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct WorkChunk {
    pub(super) bricks: (usize, usize),
    /// Points x (candidates + 1), summed over the bricks.
    pub(super) cost: u64,
    pub(super) runs: usize,
}

impl CpuBackend {
    /// Lists, for each occupied brick of `bricks`, the primitives whose box
    /// overlaps it.
    pub(super) fn bin_points<'a>(&self, bricks: Cow<'a, PointBricks>) -> PointBins<'a> {
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

    /// Cuts the occupied bricks into about `WORK_CHUNKS` contiguous ranges
    /// of similar cost (points x (candidates + 1)); a brick above `split_shares`
    /// ranges' cost (unless 0) is a chunk of its own whose points run in
    /// parallel runs. The cut depends on the batch only, never on the
    /// thread count.
    pub(super) fn work_chunks(bins: &PointBins, split_shares: u64) -> Vec<WorkChunk> {
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
