//! The point passes of the GPU backend: one command buffer per call that
//! bins the primitives into the batch's bricks (two levels), evaluates the
//! mixture at the points and, for training, the loss terms, the gradient
//! and (resident) the Adam step. Mirrors cpu.rs `bin_points`, `grad_chunk`
//! and `eval_chunk`.

use super::buffers::uniform;
use super::kernels::*;
use super::{bytes, count_u32, seq, words, GpuBackend};
use crate::backend::bricks::PointBricks;
use crate::error::{Error, Result};
use crate::math::kernel::Primitive;

/// What a point call computes after the forward pass.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Pass {
    /// Nothing: `rho` and `n` come back.
    Evaluate,
    /// The gradient and the point terms of the loss come back.
    Gradient,
    /// A training step on the resident parameters (adam.wgsl); the loss
    /// terms come back when `report`.
    Resident { report: bool },
}

/// A point call submitted and not yet finished: what `finish_points`
/// needs to submit it again when its lists overflow.
#[derive(Clone, Copy, Debug)]
pub(super) struct InFlight {
    pub p: Params,
    pub nbricks: usize,
    pub ncoarse: usize,
    pub pass: Pass,
}

/// Bricks per coarse cell along each axis: the first level of training bins.
const COARSE: u32 = 4;

/// The coarse cells (of `COARSE`^3 bricks) that hold occupied bricks, as
/// bin.wgsl's `cells` (two vec4 each: the inclusive brick box, parent 0),
/// and the occupied bricks as `cells` whose parent is their coarse cell.
fn coarse_cells(bricks: &PointBricks) -> (Vec<[u32; 4]>, Vec<[u32; 4]>) {
    let mut index = std::collections::BTreeMap::new();
    let key = |c: &[u32; 3]| [c[2] / COARSE, c[1] / COARSE, c[0] / COARSE];
    for c in &bricks.coords {
        let n = index.len() as u32;
        index.entry(key(c)).or_insert(n);
    }
    let mut coarse = vec![[0u32; 4]; 2 * index.len()];
    for (k, &i) in &index {
        let hi = |a: usize, v: u32| (v * COARSE + COARSE - 1).min(bricks.dims[a] as u32 - 1);
        coarse[2 * i as usize] = [k[2] * COARSE, k[1] * COARSE, k[0] * COARSE, 0];
        coarse[2 * i as usize + 1] = [hi(0, k[2]), hi(1, k[1]), hi(2, k[0]), 0];
    }
    let cells = bricks.coords.iter().flat_map(|c| [[c[0], c[1], c[2], index[&key(c)]], [c[0], c[1], c[2], 0]]).collect();
    (coarse, cells)
}

impl GpuBackend {
    /// Uploads the parameters and the identity source list of `n` primitives.
    pub(super) fn upload_params(&mut self, params: &[Primitive]) -> Result<()> {
        let g = self.garbage;
        let n = count_u32("primitives", params.len())?;
        self.bufs.params.upload(&self.gpu, bytes(params), g)?;
        let ident: Vec<u32> = (0..n).collect();
        self.bufs.identity.upload(&self.gpu, bytes(&ident), g)?;
        self.bufs.identity_bounds.upload(&self.gpu, bytes(&[0u32, n]), g)?;
        self.bufs.hot.ensure(&self.gpu, 64 * params.len() as u64, g)?;
        self.bufs.ranges.ensure(&self.gpu, 32 * params.len() as u64, g)?;
        Ok(())
    }

    /// Points sorted into bricks: uploads them and the bricks, and returns
    /// the `Params` of the call (without the loss fields) and the bricks.
    /// Also returns the number of coarse cells.
    pub(super) fn upload_points(&mut self, n: usize, pos: &[[f32; 3]], vref: Option<&[f32]>) -> Result<(Params, PointBricks, usize)> {
        let g = self.garbage;
        let bricks = PointBricks::new(pos, self.brick);
        let sorted: Vec<[f32; 4]> = bricks
            .order
            .iter()
            .map(|&i| {
                let p = pos[i as usize];
                [p[0], p[1], p[2], vref.map_or(0.0, |v| v[i as usize])]
            })
            .collect();
        let ranges: Vec<[u32; 2]> = bricks.ranges.iter().map(|&(s, e)| [s, e]).collect();
        let (coarse, cells) = coarse_cells(&bricks);
        self.bufs.points.upload(&self.gpu, bytes(&sorted), g)?;
        self.bufs.brick_points.upload(&self.gpu, bytes(&ranges), g)?;
        self.bufs.cells.upload(&self.gpu, bytes(&cells), g)?;
        self.bufs.coarse_cells.upload(&self.gpu, bytes(&coarse), g)?;
        self.bufs.occupied.upload(&self.gpu, bytes(&bricks.occupied), g)?;
        let nb = bricks.ranges.len();
        self.bufs.counts.ensure(&self.gpu, 4 * nb as u64, g)?;
        self.bufs.rho_n.ensure(&self.gpu, 8 * pos.len() as u64, g)?;
        self.bufs.terms.ensure(&self.gpu, 16 * pos.len() as u64, g)?;
        let p = Params {
            grid_lo: [bricks.lo[0], bricks.lo[1], bricks.lo[2], bricks.inv_edge],
            grid_dims: [count_u32("bricks", bricks.dims[0])?, count_u32("bricks", bricks.dims[1])?, count_u32("bricks", bricks.dims[2])?, CELLS_TRAINING],
            counts: [count_u32("primitives", n)?, count_u32("bricks", nb)?, 0, count_u32("points", pos.len())?],
            stage: [BIN_LISTED, 0, 0, 0],
            ..Params::default()
        };
        Ok((p, bricks, coarse.len() / 2))
    }

    /// Records frames, binning and the forward pass, then what `pass` adds,
    /// reads back `(rho_n or gradient, loss terms, brick list starts)`, and
    /// runs again with more room when a level of candidate lists overflowed.
    pub(super) fn run_points(&mut self, p: Params, nbricks: usize, ncoarse: usize, pass: Pass) -> Result<(Vec<u8>, Vec<u8>, Vec<u32>)> {
        self.submit_points(InFlight { p, nbricks, ncoarse, pass })?;
        self.finish_points()
    }

    /// Waits for the call `submit_points` started and returns what
    /// `run_points` does, submitting it again (and waiting) with more room
    /// while a level of candidate lists overflows.
    pub(super) fn finish_points(&mut self) -> Result<(Vec<u8>, Vec<u8>, Vec<u32>)> {
        loop {
            let call = self.in_flight.take().ok_or_else(|| Error::arg("GPU backend: nothing submitted to finish"))?;
            let gpu = &self.gpu;
            let b = &mut self.bufs;
            let out = gpu.scoped("reading a point pass back", || b.readback.read(gpu));
            let out = self.timed(out)?;
            let mut out = out.into_iter();
            let mut next = || out.next().unwrap_or_default();
            let (first, loss, starts, starts1) = (next(), next(), words(&next()), words(&next()));
            let (total, total1) = (starts.last().copied().unwrap_or(0) as usize, starts1.last().copied().unwrap_or(0) as usize);
            if total1 > self.coarse_capacity {
                self.coarse_capacity = total1 + total1 / 4;
            } else if total > self.capacity {
                self.capacity = total + total / 4;
            } else {
                return Ok((first, loss, starts));
            }
            self.reruns += 1;
            self.submit_points(call)?;
        }
    }

    /// Records and submits a point call without waiting for it: the host
    /// can prepare the next batch while the device works. `finish_points`
    /// must follow before any other call.
    pub(super) fn submit_points(&mut self, call: InFlight) -> Result<()> {
        self.idle("a call")?;
        let InFlight { mut p, nbricks, ncoarse, pass } = call;
        let n = p.counts[0] as usize;
        let npts = p.counts[3] as usize;
        p.counts[2] = count_u32("candidate slots", self.capacity)?;
        p.coarse[0] = count_u32("coarse cells", ncoarse)?;
        p.coarse[1] = count_u32("candidate slots", self.coarse_capacity)?;
        // The coarse level bins from every primitive, in chunks; the
        // brick level reads the coarse lists whole.
        let split = bin_split(n, self.bin_chunk)?;
        p.bin = [1, split, 0, 0];
        let coarse_p = Params { counts: [p.counts[0], p.coarse[0], p.coarse[1], 0], bin: [split, 1, 0, 0], ..p };
        let coarse_entries = ncoarse as u64 * split as u64;
        let coarse_groups = count_u32("coarse bin workgroups", coarse_entries as usize)?;
        let g = self.garbage;
        let gpu = &self.gpu;
        let k = &self.kernels;
        let timer = &mut self.timer;
        let b = &mut self.bufs;
        b.coarse_counts.ensure(gpu, 4 * coarse_entries, g)?;
        b.coarse_starts.ensure(gpu, 4 * (coarse_entries + 1), g)?;
        b.coarse_lists.ensure(gpu, 4 * self.coarse_capacity as u64, g)?;
        b.starts.ensure(gpu, 4 * (nbricks as u64 + 1), g)?;
        b.lists.ensure(gpu, 4 * self.capacity as u64, g)?;
        b.loss.ensure(gpu, 16, g)?;
        b.reg_terms.ensure(gpu, 8 * n as u64, g && pass != Pass::Gradient)?;
        if pass != Pass::Evaluate {
            b.partial.ensure(gpu, 48 * self.capacity as u64, g)?;
            b.grad.ensure(gpu, 48 * n as u64, g)?;
        }
        let out = gpu.scoped("a point pass", || {
            let (u, u1) = (uniform(gpu, &p), uniform(gpu, &coarse_p));
            let mut enc = gpu.device.create_command_encoder(&Default::default());
            let (params, hot, ranges) = (b.params.ensure(gpu, 0, false)?, b.hot.ensure(gpu, 0, false)?, b.ranges.ensure(gpu, 0, false)?);
            let (ident, ident_bounds) = (b.identity.ensure(gpu, 0, false)?, b.identity_bounds.ensure(gpu, 0, false)?);
            let (cells1, counts1, starts1, lists1) =
                (b.coarse_cells.ensure(gpu, 0, false)?, b.coarse_counts.ensure(gpu, 0, false)?, b.coarse_starts.ensure(gpu, 0, false)?, b.coarse_lists.ensure(gpu, 0, false)?);
            let (cells, counts, starts, lists) = (b.cells.ensure(gpu, 0, false)?, b.counts.ensure(gpu, 0, false)?, b.starts.ensure(gpu, 0, false)?, b.lists.ensure(gpu, 0, false)?);
            let (bp, pts, rho_n, terms) = (b.brick_points.ensure(gpu, 0, false)?, b.points.ensure(gpu, 0, false)?, b.rho_n.ensure(gpu, 0, false)?, b.terms.ensure(gpu, 0, false)?);
            let (loss, reg_terms) = (b.loss.ensure(gpu, 0, false)?, b.reg_terms.ensure(gpu, 0, false)?);
            let nb = nbricks as u32;
            dispatch(gpu, &mut enc, timer, &k.frames, &seq(&[&u, params, hot, ranges]), groups_for(n));
            // Each coarse cell's primitives, from all of them.
            dispatch(gpu, &mut enc, timer, &k.count, &seq(&[&u1, ranges, ident, ident_bounds, cells1, counts1]), coarse_groups);
            dispatch(gpu, &mut enc, timer, &k.scan, &seq(&[&u1, counts1, starts1]), 1);
            dispatch(gpu, &mut enc, timer, &k.fill, &[(0, &u1), (1, ranges), (2, ident), (3, ident_bounds), (4, cells1), (6, starts1), (7, lists1)], coarse_groups);
            // Each brick's, from its coarse cell's.
            dispatch(gpu, &mut enc, timer, &k.count, &seq(&[&u, ranges, lists1, starts1, cells, counts]), nb);
            dispatch(gpu, &mut enc, timer, &k.scan, &seq(&[&u, counts, starts]), 1);
            dispatch(gpu, &mut enc, timer, &k.fill, &[(0, &u), (1, ranges), (2, lists1), (3, starts1), (4, cells), (6, starts), (7, lists)], nb);
            dispatch(gpu, &mut enc, timer, &k.forward, &seq(&[&u, hot, starts, lists, bp, pts, rho_n, terms]), nb);
            let mut read: Vec<(&wgpu::Buffer, u64)> = vec![(rho_n, 0), (loss, 0)];
            if pass == Pass::Evaluate {
                read[0].1 = 8 * npts as u64;
            } else {
                let (partial, occ, grad) = (b.partial.ensure(gpu, 0, false)?, b.occupied.ensure(gpu, 0, false)?, b.grad.ensure(gpu, 0, false)?);
                dispatch(gpu, &mut enc, timer, &k.backward, &seq(&[&u, hot, starts, lists, bp, pts, terms, partial]), nb);
                dispatch(gpu, &mut enc, timer, &k.reduce, &seq(&[&u, params, ranges, occ, starts, lists, partial, grad]), groups_for(n));
                if pass == Pass::Gradient {
                    read = vec![(grad, 48 * n as u64), (loss, 8)];
                } else {
                    let moments = b.moments.ensure(gpu, 0, false)?;
                    dispatch(gpu, &mut enc, timer, &k.adam, &seq(&[&u, grad, params, moments, reg_terms, starts, starts1]), groups_for(n));
                }
                if pass != (Pass::Resident { report: false }) {
                    dispatch(gpu, &mut enc, timer, &k.loss, &seq(&[&u, terms, reg_terms, loss]), 1);
                    read[1].1 = 16;
                }
            }
            let times = timer.resolve(&mut enc).unwrap_or((loss, 0));
            read.extend([(starts, 4 * (nbricks as u64 + 1)), (starts1, 4 * (coarse_entries + 1)), times]);
            b.readback.record(gpu, &mut enc, &read)?;
            gpu.queue.submit([enc.finish()]);
            Ok(())
        });
        if let Err(e) = out {
            self.timer.discard();
            return Err(e);
        }
        self.in_flight = Some(InFlight { p, nbricks, ncoarse, pass });
        Ok(())
    }

    /// Kernel evaluations of a forward pass: points times candidates per brick.
    pub(super) fn count_evaluations(&mut self, bricks: &PointBricks, starts: &[u32]) {
        for (b, &(s, e)) in bricks.ranges.iter().enumerate() {
            self.evaluations += (e - s) as u64 * (starts[b + 1] - starts[b]) as u64;
        }
    }
}
