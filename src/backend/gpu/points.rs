//! The point passes of the GPU backend: one command buffer per call that
//! bins the primitives into the batch's bricks (two levels), evaluates the
//! mixture at the points and, for training, the loss terms, the gradient
//! and (resident) the Adam step. Mirrors cpu/mod.rs `bin_points`, `grad_chunk`
//! and `eval_chunk`.

use super::buffers::{Buffers, Readback};
use super::device::Gpu;
use super::kernels::*;
use super::{bytes, count_u32, seq, words, GpuBackend};
use crate::backend::bricks::PointBricks;
use crate::error::{Error, Result};
use crate::math::kernel::Primitive;
use std::borrow::Cow;
use std::time::Instant;

/// What a point call computes after the forward pass.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Pass {
    /// Nothing: `rho` and `n` come back.
    Evaluate,
    /// The gradient and the point terms of the loss come back.
    Gradient,
    /// A training step on the resident parameters (reduce.wgsl `step`); the loss
    /// terms come back when `report`.
    Resident { report: bool },
}

/// Submissions of resident steps that may be in flight at once: two, so
/// that the device runs one while the host finishes the other (each of
/// `GpuBackend::batch` steps).
pub const IN_FLIGHT: usize = 2;

/// Resident steps one submission may carry (`GpuBackend::batch`).
pub const MAX_BATCH: usize = 4;

/// Read-back slots: each call in flight holds one.
pub const SLOTS: usize = IN_FLIGHT * MAX_BATCH;

/// Resident steps recorded into a command buffer that is not submitted
/// yet, because it carries `GpuBackend::batch` steps and has fewer; the
/// read-back slots of its calls, in order.
pub(super) struct Open {
    enc: wgpu::CommandEncoder,
    slots: Vec<usize>,
}

/// A point call submitted and not yet finished: what `finish_points`
/// needs to read it and to submit it again when its lists overflow.
pub(super) struct InFlight {
    pub p: Params,
    pub nbricks: usize,
    pub ncoarse: usize,
    pub pass: Pass,
    /// Its read-back (and timer) slot, which `submit_points` assigns.
    pub slot: usize,
    /// What it uploads: every submission of it (a rerun after its lists
    /// overflowed included) writes it anew (staged.rs `Staged`).
    pub upload: Upload,
}

/// A batch's points sorted into bricks and the bricks, as uploaded.
pub(super) struct Upload {
    sorted: Vec<[f32; 4]>,
    ranges: Vec<[u32; 2]>,
    /// The forward pass's workgroups: (brick, first point, end, 0), each
    /// brick's points cut into runs of `GpuBackend::forward_piece`.
    pieces: Vec<[u32; 4]>,
    coarse: Coarse,
    occupied: Vec<u32>,
}

/// Bricks per coarse cell along each axis: the first level of training
/// bins (bin_rows.wgsl `COARSE`).
const COARSE: u32 = 4;

/// The coarse cells (of `COARSE`^3 bricks) that hold occupied bricks: their
/// inclusive brick boxes (two vec4 each; bin.wgsl's `cells` with parent 0,
/// bin_rows.wgsl's parents of the bricks), and, where the coarse grid is at
/// most `COARSE` cells a side, what bin_rows.wgsl needs to make their lists
/// from bit rows: the dense map of the coarse grid to coarse cells and the
/// one root block's box in coarse cells.
pub(super) struct Coarse {
    cells: Vec<[u32; 4]>,
    /// Dense coarse cell index -> coarse cell, `NONE` where none; one
    /// `NONE` where `root` is `None`.
    map: Vec<u32>,
    root: Option<[[u32; 4]; 2]>,
}

const NONE: u32 = u32::MAX;

fn coarse_cells(bricks: &PointBricks) -> Coarse {
    let mut index = std::collections::BTreeMap::new();
    let key = |c: &[u32; 3]| [c[2] / COARSE, c[1] / COARSE, c[0] / COARSE];
    for c in &bricks.coords {
        let n = index.len() as u32;
        index.entry(key(c)).or_insert(n);
    }
    let mut cells = vec![[0u32; 4]; 2 * index.len()];
    for (k, &i) in &index {
        let hi = |a: usize, v: u32| (v * COARSE + COARSE - 1).min(bricks.dims[a] as u32 - 1);
        cells[2 * i as usize] = [k[2] * COARSE, k[1] * COARSE, k[0] * COARSE, 0];
        cells[2 * i as usize + 1] = [hi(0, k[2]), hi(1, k[1]), hi(2, k[0]), 0];
    }
    let d = bricks.dims.map(|n| (n as u32).div_ceil(COARSE));
    if d.iter().any(|&n| n > COARSE) {
        return Coarse { cells, map: vec![NONE], root: None };
    }
    let mut map = vec![NONE; (d[0] * d[1] * d[2]) as usize];
    for (k, &i) in &index {
        map[(k[2] + d[0] * (k[1] + d[1] * k[0])) as usize] = i;
    }
    Coarse { cells, map, root: Some([[0; 4], [d[0] - 1, d[1] - 1, d[2] - 1, 0]]) }
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

    /// Points sorted into `bricks` (of this backend's edge): uploads them and
    /// the bricks, and returns the `Params` of the call (without the loss
    /// fields), the bricks, the number of coarse cells and what was uploaded.
    pub(super) fn upload_points<'a>(
        &mut self,
        n: usize,
        pos: &[[f32; 3]],
        vref: Option<&[f32]>,
        mut bricks: Cow<'a, PointBricks>,
    ) -> Result<(Params, Cow<'a, PointBricks>, usize, Upload)> {
        let started = Instant::now();
        let sorted: Vec<[f32; 4]> = bricks
            .order
            .iter()
            .map(|&i| {
                let p = pos[i as usize];
                [p[0], p[1], p[2], vref.map_or(0.0, |v| v[i as usize])]
            })
            .collect();
        let ranges: Vec<[u32; 2]> = bricks.ranges.iter().map(|&(s, e)| [s, e]).collect();
        let piece = self.forward_piece.clamp(1, u32::MAX as usize) as u32;
        let pieces: Vec<[u32; 4]> = ranges
            .iter()
            .enumerate()
            .flat_map(|(b, &[s, e])| (s..e).step_by(piece as usize).map(move |p| [b as u32, p, p.saturating_add(piece).min(e), 0]))
            .collect();
        let coarse = coarse_cells(&bricks);
        // The dense brick map serves only the device: it moves to the upload
        // (a sort made ahead, borrowed from its batch, lends a copy).
        let occupied = match &mut bricks {
            Cow::Owned(b) => std::mem::take(&mut b.occupied),
            Cow::Borrowed(b) => b.occupied.clone(),
        };
        let team = self.reduce_team.unwrap_or_else(|| reduce_team_for(n));
        let split = [count_u32("forward pieces", pieces.len())?, self.backward_slices, team, 0];
        let upload = Upload { sorted, ranges, pieces, coarse, occupied };
        self.host.lap("arrange", started);
        let nb = bricks.ranges.len();
        let p = Params {
            grid_lo: [bricks.lo[0], bricks.lo[1], bricks.lo[2], bricks.inv_edge],
            grid_dims: [count_u32("bricks", bricks.dims[0])?, count_u32("bricks", bricks.dims[1])?, count_u32("bricks", bricks.dims[2])?, CELLS_TRAINING],
            counts: [count_u32("primitives", n)?, count_u32("bricks", nb)?, 0, count_u32("points", pos.len())?],
            stage: [BIN_LISTED, 0, 0, 0],
            split,
            ..Params::default()
        };
        let ncoarse = upload.coarse.cells.len() / 2;
        Ok((p, bricks, ncoarse, upload))
    }

    /// Clears the flag a resident step whose lists overflowed sets
    /// (reduce.wgsl `step`), so that the steps after it change the
    /// parameters again.
    pub(super) fn clear_poison(&mut self) -> Result<()> {
        self.bufs.poison.upload(&self.gpu, bytes(&[0u32; 4]), false)?;
        Ok(())
    }

    /// Records frames, binning and the forward pass, then what `pass` adds,
    /// reads back `(rho_n or gradient, loss terms, brick list starts)`, and
    /// runs again with more room when a level of candidate lists overflowed.
    pub(super) fn run_points(&mut self, p: Params, nbricks: usize, ncoarse: usize, pass: Pass, upload: Upload) -> Result<(Vec<u8>, Vec<u8>, Vec<u32>)> {
        self.submit_points(InFlight { p, nbricks, ncoarse, pass, slot: 0, upload })?;
        self.finish_points()
    }

    /// Waits for the oldest call in flight and returns what `run_points`
    /// does. While a level of its candidate lists overflows it runs again
    /// with more room (and waits); the calls queued after it ran on
    /// parameters it did not update and changed nothing (reduce.wgsl
    /// `step`), so they are waited for, and submitted again once it fits.
    /// An error abandons every call in flight.
    pub(super) fn finish_points(&mut self) -> Result<(Vec<u8>, Vec<u8>, Vec<u32>)> {
        let out = self.finish_oldest();
        if out.is_err() {
            self.abandon();
        }
        out
    }

    fn finish_oldest(&mut self) -> Result<(Vec<u8>, Vec<u8>, Vec<u32>)> {
        let mut later: Vec<InFlight> = vec![];
        let result = loop {
            let call = self.in_flight.pop_front().ok_or_else(|| Error::arg("GPU backend: nothing submitted to finish"))?;
            let (first, loss, starts, starts1) = self.read_call(call.slot)?;
            let (total, total1) = (starts.last().copied().unwrap_or(0) as usize, starts1.last().copied().unwrap_or(0) as usize);
            if total1 > self.coarse_capacity {
                self.coarse_capacity = total1 + total1 / 4;
            } else if total > self.capacity {
                self.capacity = total + total / 4;
            } else {
                break (first, loss, starts);
            }
            self.reruns += 1;
            while let Some(next) = self.in_flight.pop_front() {
                self.read_call(next.slot)?;
                later.push(next);
            }
            if let Pass::Resident { .. } = call.pass {
                self.clear_poison()?;
            }
            self.submit_points(call)?;
        };
        for call in later {
            self.submit_points(call)?;
        }
        Ok(result)
    }

    /// Waits for the call read back through `slot`: its first two regions
    /// and both levels' list starts.
    fn read_call(&mut self, slot: usize) -> Result<(Vec<u8>, Vec<u8>, Vec<u32>, Vec<u32>)> {
        if self.open.as_ref().is_some_and(|o| o.slots.contains(&slot)) {
            self.flush()?;
        }
        let started = Instant::now();
        let gpu = &self.gpu;
        let b = &mut self.bufs;
        let out = gpu.scoped("reading a point pass back", || b.readback[slot].read(gpu));
        let waited = b.readback[slot].waited;
        self.host.add("wait", waited);
        self.host.add("read", started.elapsed().saturating_sub(waited));
        let mut out = self.timed(slot, out)?.into_iter();
        let mut next = || out.next().unwrap_or_default();
        Ok((next(), next(), words(&next()), words(&next())))
    }

    /// Forgets every call and resident step in flight after an error
    /// (waiting for the device as far as it answers): what the device holds
    /// is then unknown, so resident training needs a `load` again.
    pub(super) fn abandon(&mut self) {
        for call in self.in_flight.drain(..) {
            self.timer.discard(call.slot);
        }
        self.steps.clear();
        self.loaded = None;
        self.open = None;
        let _ = self.gpu.wait(None);
    }

    /// Submits the resident steps recorded and not yet submitted, if any.
    pub(super) fn flush(&mut self) -> Result<()> {
        let Some(open) = self.open.take() else { return Ok(()) };
        let started = Instant::now();
        let (gpu, b) = (&self.gpu, &mut self.bufs);
        let out = gpu.scoped("submitting point passes", || {
            submit_open(gpu, b, open);
            Ok(())
        });
        self.host.add("submit", started.elapsed());
        out
    }

    /// Records and submits a point call, its upload first, without waiting
    /// for it: the host can prepare the next batch while the device works.
    /// A resident step is submitted with the steps recorded before it once
    /// they are `GpuBackend::batch` (or when one of them is read back).
    /// `finish_points` must follow before any other call.
    pub(super) fn submit_points(&mut self, call: InFlight) -> Result<()> {
        let slot = (0..SLOTS)
            .find(|s| self.in_flight.iter().all(|c| c.slot != *s))
            .ok_or_else(|| Error::arg("GPU backend: a call while every read-back slot is in flight"))?;
        let out = self.record_points(&call, slot);
        if let Err(e) = out {
            self.timer.discard(slot);
            return Err(e);
        }
        let InFlight { p, nbricks, ncoarse, pass, upload, .. } = call;
        self.in_flight.push_back(InFlight { p, nbricks, ncoarse, pass, slot, upload });
        Ok(())
    }

    fn record_points(&mut self, call: &InFlight, slot: usize) -> Result<()> {
        let InFlight { mut p, nbricks, ncoarse, pass, .. } = *call;
        let n = p.counts[0] as usize;
        let npts = p.counts[3] as usize;
        p.counts[2] = count_u32("candidate slots", self.capacity)?;
        p.coarse[0] = count_u32("coarse cells", ncoarse)?;
        p.coarse[1] = count_u32("candidate slots", self.coarse_capacity)?;
        // The coarse level from every primitive: from bit rows where the
        // coarse cells fit in one block, the primitives in chunks (its
        // counts and starts one a cell); else gathered by bin.wgsl, one
        // workgroup per (cell, chunk of the primitives) (counts and starts
        // one a (cell, chunk)). The brick level from bit rows, each coarse
        // cell's list in chunks.
        let cell_rows = call.upload.coarse.root.is_some();
        let split = bin_split(n, self.bin_chunk)?;
        let cell_chunks = cell_chunks_for(n);
        let stride = if cell_rows { 1 } else { split };
        let chunks = self.brick_chunks.unwrap_or_else(|| brick_chunks_for(self.coarse_capacity, ncoarse));
        p.bin = [1, stride, 0, 0];
        p.rows = [p.coarse[0], chunks, 0, stride];
        let coarse_p = Params {
            counts: [p.counts[0], p.coarse[0], p.coarse[1], 0],
            bin: [stride, 1, 0, 0],
            rows: [1, cell_chunks, COARSE.ilog2(), 1],
            ..p
        };
        let coarse_entries = ncoarse as u64 * stride as u64;
        let coarse_groups = count_u32("coarse bin workgroups", if cell_rows { cell_chunks as usize } else { coarse_entries as usize })?;
        let (g, per_buffer) = (self.garbage, self.upload_per_buffer);
        let batch = if matches!(pass, Pass::Resident { .. }) { self.batch() } else { 1 };
        let mut open = self.open.take();
        let gpu = &self.gpu;
        let k = &self.kernels;
        let timer = &mut self.timer;
        let binds = &mut self.binds;
        timer.begin(slot);
        let b = &mut self.bufs;
        b.coarse_counts.ensure(gpu, 4 * coarse_entries, g)?;
        b.coarse_starts.ensure(gpu, 4 * (coarse_entries + 1), g)?;
        b.coarse_lists.ensure(gpu, 4 * self.coarse_capacity as u64, g)?;
        b.starts.ensure(gpu, 4 * (nbricks as u64 + 1), g)?;
        let brick_groups = count_u32("brick bin workgroups", ncoarse * chunks as usize)?;
        let chunk_slots = (nbricks as u64 * chunks as u64).max(if cell_rows { ncoarse as u64 * cell_chunks as u64 } else { 0 });
        b.chunk_counts.ensure(gpu, 4 * chunk_slots.max(1), g)?;
        b.lists.ensure(gpu, 4 * self.capacity as u64, g)?;
        b.loss.ensure(gpu, 16, g)?;
        b.reg_terms.ensure(gpu, 8 * n as u64, g && pass != Pass::Gradient)?;
        if pass != Pass::Evaluate {
            b.partial.ensure(gpu, 48 * self.capacity as u64, g)?;
        }
        if pass == Pass::Gradient {
            b.grad.ensure(gpu, 48 * n as u64, g)?;
        }
        let up = &call.upload;
        let root = up.coarse.root.unwrap_or_default();
        let written = Instant::now();
        let sorted = up.sorted.len() as u64;
        let u = b.uniforms[slot][0].ensure(gpu, size_of::<Params>() as u64, g)?.clone();
        let u1 = b.uniforms[slot][1].ensure(gpu, size_of::<Params>() as u64, g)?.clone();
        // What the call uploads, and where (staged.rs `Staged`).
        let uploads = [
            (bytes(&up.sorted), b.points.ensure(gpu, 16 * sorted, g)?.clone()),
            (bytes(&up.ranges), b.brick_points.ensure(gpu, 8 * up.ranges.len() as u64, g)?.clone()),
            (bytes(&up.pieces), b.pieces.ensure(gpu, 16 * up.pieces.len() as u64, g)?.clone()),
            (bytes(&up.coarse.cells), b.coarse_cells.ensure(gpu, 16 * up.coarse.cells.len() as u64, g)?.clone()),
            (bytes(&up.coarse.map), b.coarse_map.ensure(gpu, 4 * up.coarse.map.len() as u64, g)?.clone()),
            (bytes(&root), b.root.ensure(gpu, 32, g)?.clone()),
            (bytes(&up.occupied), b.occupied.ensure(gpu, 4 * up.occupied.len() as u64, g)?.clone()),
            (bytemuck::bytes_of(&p), u.clone()),
            (bytemuck::bytes_of(&coarse_p), u1.clone()),
        ];
        b.counts.ensure(gpu, 4 * up.ranges.len() as u64, g)?;
        b.rho_n.ensure(gpu, 8 * sorted, g)?;
        b.terms.ensure(gpu, 16 * sorted, g)?;
        let host = &mut self.host;
        let mut recording = written;
        let mut submitted = None;
        binds.keep_while(b.made());
        let out = gpu.scoped("a point pass", || {
            let mut open = open.take().unwrap_or_else(|| Open { enc: gpu.device.create_command_encoder(&Default::default()), slots: vec![] });
            let enc = &mut open.enc;
            let regions: Vec<(&[u8], &wgpu::Buffer)> = uploads.iter().map(|(d, buf)| (*d, buf)).collect();
            b.staged[slot].record(gpu, enc, &regions, per_buffer)?;
            recording = host.lap("write", written);
            let (params, hot, ranges) = (b.params.ensure(gpu, 0, false)?, b.hot.ensure(gpu, 0, false)?, b.ranges.ensure(gpu, 0, false)?);
            let (ident, ident_bounds) = (b.identity.ensure(gpu, 0, false)?, b.identity_bounds.ensure(gpu, 0, false)?);
            let (cells1, counts1, starts1, lists1) =
                (b.coarse_cells.ensure(gpu, 0, false)?, b.coarse_counts.ensure(gpu, 0, false)?, b.coarse_starts.ensure(gpu, 0, false)?, b.coarse_lists.ensure(gpu, 0, false)?);
            let (counts, starts, lists) = (b.counts.ensure(gpu, 0, false)?, b.starts.ensure(gpu, 0, false)?, b.lists.ensure(gpu, 0, false)?);
            let (occ, chunk_counts) = (b.occupied.ensure(gpu, 0, false)?, b.chunk_counts.ensure(gpu, 0, false)?);
            let (coarse_map, root) = (b.coarse_map.ensure(gpu, 0, false)?, b.root.ensure(gpu, 0, false)?);
            let (bp, pts, rho_n, terms) = (b.brick_points.ensure(gpu, 0, false)?, b.points.ensure(gpu, 0, false)?, b.rho_n.ensure(gpu, 0, false)?, b.terms.ensure(gpu, 0, false)?);
            let pieces = b.pieces.ensure(gpu, 0, false)?;
            let (loss, reg_terms) = (b.loss.ensure(gpu, 0, false)?, b.reg_terms.ensure(gpu, 0, false)?);
            let nb = nbricks as u32;
            dispatch(gpu, enc, timer, binds, &k.frames, &seq(&[&u, params, hot, ranges]), groups_for(n));
            // Each coarse cell's primitives, from all of them; each brick's,
            // from its coarse cell's.
            if cell_rows {
                let l = RowLevel {
                    uniform: &u1, src: ident, src_starts: ident_bounds, parents: root, child_map: coarse_map, chunk_counts,
                    counts: counts1, starts: starts1, lists: lists1, children: ncoarse as u32, groups: coarse_groups,
                };
                bin_rows(gpu, enc, timer, binds, &k.cells, &k.scan, ranges, &l);
            } else {
                let l = ListLevel { uniform: &u1, cells: cells1, counts: counts1, starts: starts1, lists: lists1, groups: coarse_groups };
                bin_level(gpu, enc, timer, binds, k, ranges, (ident, ident_bounds), &l);
            }
            let l = RowLevel {
                uniform: &u, src: lists1, src_starts: starts1, parents: cells1, child_map: occ, chunk_counts,
                counts, starts, lists, children: nb, groups: brick_groups,
            };
            bin_rows(gpu, enc, timer, binds, &k.bricks, &k.scan, ranges, &l);
            dispatch(gpu, enc, timer, binds, &k.forward, &seq(&[&u, hot, starts, lists, pieces, pts, rho_n, terms]), p.split[0]);
            let mut read: Vec<(&wgpu::Buffer, u64)> = vec![(rho_n, 0), (loss, 0)];
            if pass == Pass::Evaluate {
                read[0].1 = 8 * npts as u64;
            } else {
                let partial = b.partial.ensure(gpu, 0, false)?;
                let backward_groups = count_u32("backward workgroups", nbricks * p.split[1].max(1) as usize)?;
                dispatch(gpu, enc, timer, binds, &k.backward, &seq(&[&u, hot, starts, lists, bp, pts, terms, partial]), backward_groups);
                // A team of `p.split[2]` threads a primitive.
                let reduce_groups = groups_for(count_u32("reduce threads", n * p.split[2] as usize)? as usize);
                let summed = [(0, &u), (1, params), (2, ranges), (3, occ), (4, starts), (5, lists), (6, partial)];
                if pass == Pass::Gradient {
                    let grad = b.grad.ensure(gpu, 0, false)?;
                    dispatch(gpu, enc, timer, binds, &k.reduce, &[&summed[..], &[(7, grad)]].concat(), reduce_groups);
                    read = vec![(grad, 48 * n as u64), (loss, 8)];
                } else {
                    // The reduction, the regularisers and the Adam step;
                    // it poisons the steps after this one if its lists
                    // overflowed.
                    let (moments, poison) = (b.moments.ensure(gpu, 0, false)?, b.poison.ensure(gpu, 0, false)?);
                    let step = [(8, moments), (9, reg_terms), (10, starts1), (11, poison)];
                    dispatch(gpu, enc, timer, binds, &k.step, &[&summed[..], &step].concat(), reduce_groups);
                }
                if pass != (Pass::Resident { report: false }) {
                    dispatch(gpu, enc, timer, binds, &k.loss, &seq(&[&u, terms, reg_terms, loss]), 1);
                    read[1].1 = 16;
                }
            }
            let times = timer.resolve(enc).unwrap_or((loss, 0));
            read.extend([(starts, 4 * (nbricks as u64 + 1)), (starts1, 4 * (coarse_entries + 1)), times]);
            b.readback[slot].record(gpu, enc, &read)?;
            open.slots.push(slot);
            if open.slots.len() < batch {
                return Ok(Some(open));
            }
            let submitting = Instant::now();
            submit_open(gpu, b, open);
            submitted = Some(submitting.elapsed());
            Ok(None)
        });
        host.add("record", recording.elapsed().saturating_sub(submitted.unwrap_or_default()));
        if let Some(s) = submitted {
            host.add("submit", s);
        }
        self.open = out?;
        Ok(())
    }

    /// The candidate lists the device makes for the training bricks of
    /// `pos` under `params` (an evaluation's binning): per occupied brick,
    /// in `PointBricks` order, its primitives in order. Tests compare them
    /// with the CPU backend's (`CpuBackend::candidate_lists`).
    #[doc(hidden)]
    pub fn candidate_lists(&mut self, params: &[Primitive], pos: &[[f32; 3]]) -> Result<Vec<Vec<u32>>> {
        self.idle("reading candidate lists")?;
        if params.is_empty() || pos.is_empty() {
            return Err(Error::arg("candidate lists: no primitives or no points"));
        }
        self.upload_params(params)?;
        let (p, bricks, ncoarse, upload) = self.upload_points(params.len(), pos, None, Cow::Owned(PointBricks::new(pos, self.brick)))?;
        let (_, _, starts) = self.run_points(p, bricks.ranges.len(), ncoarse, Pass::Evaluate, upload)?;
        let total = starts.last().copied().unwrap_or(0) as u64;
        let gpu = &self.gpu;
        let lists = self.bufs.lists.ensure(gpu, 0, false)?.clone();
        let mut back = Readback::default();
        let read = gpu.scoped("reading candidate lists back", || {
            let mut enc = gpu.device.create_command_encoder(&Default::default());
            back.record(gpu, &mut enc, &[(&lists, 4 * total)])?;
            back.submit(gpu, enc);
            back.read(gpu)
        })?;
        let all = words(&read[0]);
        Ok(starts.windows(2).map(|w| all[w[0] as usize..w[1] as usize].to_vec()).collect())
    }

    /// Kernel evaluations of a forward pass: points times candidates per brick.
    pub(super) fn count_evaluations(&mut self, ranges: &[(u32, u32)], starts: &[u32]) {
        for (b, &(s, e)) in ranges.iter().enumerate() {
            self.evaluations += (e - s) as u64 * (starts[b + 1] - starts[b]) as u64;
        }
    }
}

/// Submits the calls of `open` in one command buffer: each read-back slot
/// then waits for that submission, and each staging buffer is mapped again
/// once the device is done with it.
fn submit_open(gpu: &Gpu, b: &mut Buffers, open: Open) {
    let index = gpu.queue.submit([open.enc.finish()]);
    for &s in &open.slots {
        b.readback[s].submitted(index.clone());
        b.staged[s].remap();
    }
}
