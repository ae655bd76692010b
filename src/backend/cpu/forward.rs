//! The forward pass alone (`Backend::evaluate_points`, and
//! `Backend::evaluate_each` with each point's sums its own): each work
//! chunk's points evaluated over their brick's candidates, loaded into
//! lanes once a brick. A dense brick's points are cut into runs, as the
//! training pass cuts them, each run a task that loads the brick itself: a
//! point's sums depend only on its brick's candidates, so the cut changes
//! no bit, and no brick holds up a pass on many cores (a 65,536-point
//! sample of hydrogen 64³ has bricks of 7.5 % of the work). The same lane
//! code as the training pass's forward (`lanes.rs`).

use super::binning::PointBins;
use super::lanes::BrickSoa;
use crate::math::simd::simd_dispatch;
use super::{CpuBackend, Prepared};
use crate::backend::bricks::PointBricks;
use crate::backend::check_len;
use crate::error::Result;
use crate::math::kernel::Primitive;
use rayon::prelude::*;
use std::borrow::Cow;

simd_dispatch!(fn eval_chunk_dispatch(prep: &Prepared, bins: &PointBins, pos: &[[f32; 3]], task: EvalTask, pointwise: bool) -> (Vec<(u32, f32, f32)>, u64) => eval_chunk);

/// What one task of the forward pass evaluates: the points of bricks
/// `bricks.0..bricks.1`, or, of a dense brick (`runs > 1`), run `run` of
/// its points cut into `runs`.
#[derive(Clone, Copy)]
struct EvalTask {
    bricks: (usize, usize),
    run: usize,
    runs: usize,
}

/// `(point, rho, n)` for the points of `task`, and the kernel count;
/// `pointwise`: each point's sums its own (`BrickSoa::forward_pointwise`).
#[inline(always)]
fn eval_chunk(prep: &Prepared, bins: &PointBins, pos: &[[f32; 3]], task: EvalTask, pointwise: bool) -> (Vec<(u32, f32, f32)>, u64) {
    let mut soa = BrickSoa::default();
    let mut out = vec![];
    let mut evals = 0;
    for b in task.bricks.0..task.bricks.1 {
        let cands = &bins.cand[bins.cand_start[b] as usize..bins.cand_start[b + 1] as usize];
        if pointwise {
            soa.load_pointwise(&prep.hot, &prep.boxes, cands);
        } else {
            soa.load(&prep.hot, &prep.boxes, cands, false);
        }
        let (s, e) = bins.bricks.ranges[b];
        let points = &bins.bricks.order[s as usize..e as usize];
        let (r, runs) = (task.run, task.runs);
        for &pi in &points[r * points.len() / runs..(r + 1) * points.len() / runs] {
            let x = pos[pi as usize];
            let (r, nn) = if pointwise { soa.forward_pointwise(x, &mut evals) } else { soa.forward(x, &mut evals) };
            out.push((pi, r, nn));
        }
    }
    (out, evals)
}

impl CpuBackend {
    /// [`crate::backend::Backend::evaluate_points`], or with `pointwise`
    /// [`crate::backend::Backend::evaluate_each`].
    pub(super) fn forward_points(&mut self, params: &[Primitive], pos: &[[f32; 3]], rho: &mut [f32], n: &mut [f32], pointwise: bool) -> Result<()> {
        check_len("rho", rho.len(), pos.len())?;
        check_len("n", n.len(), pos.len())?;
        if pos.is_empty() {
            return Ok(());
        }
        self.prep.update(params);
        let bins = self.bin_points(Cow::Owned(PointBricks::new(pos, self.brick)));
        let tasks: Vec<EvalTask> = Self::work_chunks(&bins, self.split_shares)
            .into_iter()
            .flat_map(|w| (0..w.runs).map(move |run| EvalTask { bricks: w.bricks, run, runs: w.runs }))
            .collect();
        let prep = &self.prep;
        let results: Vec<(Vec<(u32, f32, f32)>, u64)> = tasks
            .par_iter()
            .with_max_len(1)
            .map(|&task| eval_chunk_dispatch(prep, &bins, pos, task, pointwise))
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
}
