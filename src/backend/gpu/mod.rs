//! The GPU backend: the same [`Backend`] as the CPU's, run by wgpu compute
//! shaders (Vulkan, Metal, DX12; Mesa's lavapipe in tests).
//!
//! A training call (`point_loss_grad`) records one command buffer:
//! 1. `frames`: each primitive's `Hot` record and the bricks its box overlaps;
//! 2. `bin` `count`, `scan`, `bin` `fill`, twice: per coarse cell of 4^3
//!    bricks the primitives that reach it, then per occupied brick its
//!    candidates from its coarse cell's list, in primitive order (one
//!    workgroup per cell gathers, so no atomics); the lists get a capacity,
//!    and the scans' totals, read back with the results, say whether they
//!    fitted (if not, the call runs again with room for them);
//! 3. `forward`: per brick, the points' density and numerator with the
//!    candidates staged in workgroup memory, and each point's loss terms;
//! 4. `backward`: per (brick, candidate) the pair sums of `GradAcc`, each in
//!    its own slot;
//! 5. `reduce`: per primitive, its slots summed in brick order, then
//!    `Frame::finalize`; `loss`: the batch's L_val and L_cov.
//!
//! No float atomics anywhere, so a call gives the same bits run after run
//! on one adapter. The points are sorted into bricks on the host
//! ([`PointBricks`], as the CPU backend does) and uploaded with the
//! parameters; the gradient, the loss and the list sizes come back.
//! `evaluate_points` runs steps 1-3 without the loss; `decode_lattice` bins
//! per slab of lattice bricks (the slab's primitives, then each brick's)
//! and gathers per lattice point (`decode.wgsl`).

pub mod device;

mod buffers;
mod kernels;
mod timer;

use self::buffers::{uniform, Readback, Slot};
use self::device::{DeviceRequest, Gpu};
use self::kernels::*;
use self::timer::Timer;
use super::bricks::PointBricks;
use super::{check_len, Backend, Lattice, PointBatch, PointLoss};
use crate::error::{Error, Result};
use crate::math::kernel::Primitive;
use crate::math::loss::{LossWeights, PointNorm};

/// Bytes of device memory per primitive, per point and per (brick,
/// candidate) pair of a training call (docs/DESIGN.md "GPU backend").
pub const BYTES_PER_PRIMITIVE: usize = 48 + 64 + 32 + 48 + 4;
pub const BYTES_PER_POINT: usize = 16 + 8 + 16;
pub const BYTES_PER_PAIR: usize = 4 + 48;

/// Every device buffer the backend keeps between calls.
struct Buffers {
    params: Slot,
    hot: Slot,
    ranges: Slot,
    identity: Slot,
    identity_bounds: Slot,
    cells: Slot,
    counts: Slot,
    starts: Slot,
    lists: Slot,
    brick_points: Slot,
    points: Slot,
    occupied: Slot,
    rho_n: Slot,
    terms: Slot,
    partial: Slot,
    grad: Slot,
    loss: Slot,
    /// The first level of binning: coarse cells (training), the slab (decoding).
    coarse_cells: Slot,
    coarse_counts: Slot,
    coarse_starts: Slot,
    coarse_lists: Slot,
    slab: Slot,
    readback: Readback,
}

impl Default for Buffers {
    fn default() -> Self {
        Buffers {
            params: Slot::storage("params"),
            hot: Slot::storage("hot"),
            ranges: Slot::storage("ranges"),
            identity: Slot::storage("identity"),
            identity_bounds: Slot::storage("identity bounds"),
            cells: Slot::storage("cells"),
            counts: Slot::storage("counts"),
            starts: Slot::storage("starts"),
            lists: Slot::storage("candidate lists"),
            brick_points: Slot::storage("brick points"),
            points: Slot::storage("points"),
            occupied: Slot::storage("occupied"),
            rho_n: Slot::storage("rho n"),
            terms: Slot::storage("terms"),
            partial: Slot::storage("partial sums"),
            grad: Slot::storage("gradient"),
            loss: Slot::storage("loss"),
            coarse_cells: Slot::storage("coarse cells"),
            coarse_counts: Slot::storage("coarse counts"),
            coarse_starts: Slot::storage("coarse starts"),
            coarse_lists: Slot::storage("coarse lists"),
            slab: Slot::storage("slab values"),
            readback: Readback::default(),
        }
    }
}

pub struct GpuBackend {
    gpu: Gpu,
    kernels: Kernels,
    timer: Timer,
    bufs: Buffers,
    /// Edge of a training brick in voxels (as the CPU backend's).
    pub brick: f32,
    /// Fill every buffer with garbage before each call (tests).
    pub garbage: bool,
    /// Room in the candidate lists of training calls, grown on overflow.
    capacity: usize,
    /// Room in the coarse cells' lists of training calls.
    coarse_capacity: usize,
    /// Room in the per-brick lists of a decode slab, grown on overflow.
    slab_capacity: usize,
    evaluations: u64,
    /// Calls that ran again because the candidate lists overflowed.
    pub reruns: u64,
}

fn bytes<T: bytemuck::Pod>(v: &[T]) -> &[u8] {
    bytemuck::cast_slice(v)
}

fn words(b: &[u8]) -> Vec<u32> {
    bytemuck::pod_collect_to_vec(b)
}

fn floats(b: &[u8]) -> Vec<f32> {
    bytemuck::pod_collect_to_vec(b)
}

fn count_u32(what: &str, n: usize) -> Result<u32> {
    u32::try_from(n).map_err(|_| Error::Device(format!("{n} {what} exceed the GPU backend's 32-bit indices")))
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

/// `(binding, buffer)` pairs for bindings 0, 1, 2, ...
fn seq<'a>(bufs: &[&'a wgpu::Buffer]) -> Vec<(u32, &'a wgpu::Buffer)> {
    bufs.iter().enumerate().map(|(i, &b)| (i as u32, b)).collect()
}

impl GpuBackend {
    /// Opens the adapter `req` names and compiles the kernels.
    pub fn new(req: &DeviceRequest) -> Result<GpuBackend> {
        let gpu = Gpu::open(req)?;
        let kernels = Kernels::new(&gpu)?;
        let timer = Timer::new(&gpu);
        Ok(GpuBackend {
            gpu,
            kernels,
            timer,
            bufs: Buffers::default(),
            brick: 16.0,
            garbage: false,
            capacity: 1 << 16,
            coarse_capacity: 1 << 16,
            slab_capacity: 1 << 16,
            evaluations: 0,
            reruns: 0,
        })
    }

    /// Starts the candidate lists of training calls and decode slabs at
    /// `slots` entries (they grow when a call needs more); tests use it to
    /// make the lists overflow.
    pub fn set_capacity(&mut self, slots: usize) {
        self.capacity = slots.max(1);
        self.coarse_capacity = slots.max(1);
        self.slab_capacity = slots.max(1);
    }

    /// The adapter this backend runs on.
    pub fn adapter(&self) -> &device::AdapterSummary {
        &self.gpu.adapter
    }

    /// Uploads the parameters and the identity source list of `n` primitives.
    fn upload_params(&mut self, params: &[Primitive]) -> Result<()> {
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
    fn upload_points(&mut self, n: usize, pos: &[[f32; 3]], vref: Option<&[f32]>) -> Result<(Params, PointBricks, usize)> {
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
        self.bufs.coarse_counts.ensure(&self.gpu, 2 * coarse.len() as u64, g)?;
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

    /// Records frames, binning and the forward pass (and, when `train`, the
    /// backward pass, the reduction and the loss) of one point call, reads
    /// back `(rho_n or gradient, loss, starts)`, and runs again with more
    /// room when a level of candidate lists overflowed.
    fn run_points(&mut self, mut p: Params, nbricks: usize, ncoarse: usize, train: bool) -> Result<(Vec<u8>, Vec<u8>, Vec<u32>)> {
        let n = p.counts[0] as usize;
        let npts = p.counts[3] as usize;
        loop {
            p.counts[2] = count_u32("candidate slots", self.capacity)?;
            let coarse_p = Params { counts: [p.counts[0], count_u32("coarse cells", ncoarse)?, count_u32("candidate slots", self.coarse_capacity)?, 0], ..p };
            let g = self.garbage;
            let gpu = &self.gpu;
            let k = &self.kernels;
            let timer = &mut self.timer;
            let b = &mut self.bufs;
            b.coarse_starts.ensure(gpu, 4 * (ncoarse as u64 + 1), g)?;
            b.coarse_lists.ensure(gpu, 4 * self.coarse_capacity as u64, g)?;
            b.starts.ensure(gpu, 4 * (nbricks as u64 + 1), g)?;
            b.lists.ensure(gpu, 4 * self.capacity as u64, g)?;
            if train {
                b.partial.ensure(gpu, 48 * self.capacity as u64, g)?;
                b.grad.ensure(gpu, 48 * n as u64, g)?;
                b.loss.ensure(gpu, 8, g)?;
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
                let (nb, nc) = (nbricks as u32, ncoarse as u32);
                dispatch(gpu, &mut enc, timer, &k.frames, &seq(&[&u, params, hot, ranges]), groups_for(n));
                // Each coarse cell's primitives, from all of them.
                dispatch(gpu, &mut enc, timer, &k.count, &seq(&[&u1, ranges, ident, ident_bounds, cells1, counts1]), nc);
                dispatch(gpu, &mut enc, timer, &k.scan, &seq(&[&u1, counts1, starts1]), 1);
                dispatch(gpu, &mut enc, timer, &k.fill, &[(0, &u1), (1, ranges), (2, ident), (3, ident_bounds), (4, cells1), (6, starts1), (7, lists1)], nc);
                // Each brick's, from its coarse cell's.
                dispatch(gpu, &mut enc, timer, &k.count, &seq(&[&u, ranges, lists1, starts1, cells, counts]), nb);
                dispatch(gpu, &mut enc, timer, &k.scan, &seq(&[&u, counts, starts]), 1);
                dispatch(gpu, &mut enc, timer, &k.fill, &[(0, &u), (1, ranges), (2, lists1), (3, starts1), (4, cells), (6, starts), (7, lists)], nb);
                dispatch(gpu, &mut enc, timer, &k.forward, &seq(&[&u, hot, starts, lists, bp, pts, rho_n, terms]), nb);
                let (first, first_len) = if train {
                    let (partial, occ, grad, loss) = (b.partial.ensure(gpu, 0, false)?, b.occupied.ensure(gpu, 0, false)?, b.grad.ensure(gpu, 0, false)?, b.loss.ensure(gpu, 0, false)?);
                    dispatch(gpu, &mut enc, timer, &k.backward, &seq(&[&u, hot, starts, lists, bp, pts, terms, partial]), nb);
                    dispatch(gpu, &mut enc, timer, &k.reduce, &seq(&[&u, params, ranges, occ, starts, lists, partial, grad]), groups_for(n));
                    dispatch(gpu, &mut enc, timer, &k.loss, &seq(&[&u, terms, loss]), 1);
                    (grad, 48 * n as u64)
                } else {
                    (rho_n, 8 * npts as u64)
                };
                let loss = b.loss.ensure(gpu, 8, false)?;
                let times = timer.resolve(&mut enc).unwrap_or((loss, 0));
                b.readback.record(
                    gpu,
                    &mut enc,
                    &[(first, first_len), (loss, if train { 8 } else { 0 }), (starts, 4 * (nbricks as u64 + 1)), (starts1, 4 * (ncoarse as u64 + 1)), times],
                )?;
                gpu.queue.submit([enc.finish()]);
                b.readback.read(gpu)
            });
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
        }
    }

    /// Hands a submission's timestamps (its last read-back region) to the
    /// timer and returns the other regions.
    fn timed(&mut self, read: Result<Vec<Vec<u8>>>) -> Result<Vec<Vec<u8>>> {
        match read {
            Ok(mut regions) => {
                self.timer.record(&regions.pop().unwrap_or_default());
                Ok(regions)
            }
            Err(e) => {
                self.timer.discard();
                Err(e)
            }
        }
    }

    /// Kernel evaluations of a forward pass: points times candidates per brick.
    fn count_evaluations(&mut self, bricks: &PointBricks, starts: &[u32]) {
        for (b, &(s, e)) in bricks.ranges.iter().enumerate() {
            self.evaluations += (e - s) as u64 * (starts[b + 1] - starts[b]) as u64;
        }
    }
}

impl Backend for GpuBackend {
    fn name(&self) -> String {
        format!("wgpu:{}", self.gpu.adapter.name)
    }

    fn on_device(&self) -> bool {
        true
    }

    fn kernel_seconds(&self) -> Vec<(String, u64, f64)> {
        self.timer.totals()
    }

    /// Counted as points times the candidates of their brick.
    fn kernel_evaluations(&self) -> u64 {
        self.evaluations
    }

    fn evaluate_points(&mut self, params: &[Primitive], pos: &[[f32; 3]], rho: &mut [f32], n: &mut [f32]) -> Result<()> {
        check_len("rho", rho.len(), pos.len())?;
        check_len("n", n.len(), pos.len())?;
        if pos.is_empty() {
            return Ok(());
        }
        if params.is_empty() {
            rho.fill(0.0);
            n.fill(0.0);
            return Ok(());
        }
        self.upload_params(params)?;
        let (p, bricks, ncoarse) = self.upload_points(params.len(), pos, None)?;
        let (rn, _, starts) = self.run_points(p, bricks.ranges.len(), ncoarse, false)?;
        self.count_evaluations(&bricks, &starts);
        let rn = floats(&rn);
        for (k, &i) in bricks.order.iter().enumerate() {
            rho[i as usize] = rn[2 * k];
            n[i as usize] = rn[2 * k + 1];
        }
        Ok(())
    }

    fn point_loss_grad(&mut self, params: &[Primitive], batch: &PointBatch, weights: &LossWeights, grad: &mut [Primitive]) -> Result<PointLoss> {
        check_len("grad", grad.len(), params.len())?;
        check_len("vref", batch.vref.len(), batch.pos.len())?;
        if batch.is_empty() || params.is_empty() {
            grad.fill([0.0; 12]);
            return Ok(PointLoss::default());
        }
        self.upload_params(params)?;
        let (mut p, bricks, ncoarse) = self.upload_points(params.len(), &batch.pos, Some(&batch.vref))?;
        let norm = PointNorm::new(&batch.vref);
        p.loss = [norm.inv_weight_sum, norm.inv_count, weights.val, weights.cov];
        p.stage[3] = 1;
        let (g, loss, starts) = self.run_points(p, bricks.ranges.len(), ncoarse, true)?;
        self.count_evaluations(&bricks, &starts);
        let g = floats(&g);
        for (i, out) in grad.iter_mut().enumerate() {
            out.copy_from_slice(&g[12 * i..12 * i + 12]);
        }
        let loss = floats(&loss);
        Ok(PointLoss { val: loss[0] as f64, cov: loss[1] as f64 })
    }

    fn decode_lattice(&mut self, params: &[Primitive], lattice: &Lattice, out: &mut [f32]) -> Result<()> {
        check_len("out", out.len(), lattice.len())?;
        if out.is_empty() {
            return Ok(());
        }
        if params.is_empty() {
            out.fill(0.0);
            return Ok(());
        }
        self.upload_params(params)?;
        let d = lattice.dims;
        let bs = DECODE_BRICK;
        let nbx = d[0].div_ceil(bs);
        let nby = d[1].div_ceil(bs);
        let nbz = d[2].div_ceil(bs);
        let n = count_u32("primitives", params.len())?;
        let base = Params {
            grid_lo: [lattice.origin[0], lattice.origin[1], lattice.origin[2], 0.0],
            grid_step: [lattice.step[0], lattice.step[1], lattice.step[2], 0.0],
            grid_dims: [count_u32("bricks", nbx)?, count_u32("bricks", nby)?, count_u32("bricks", nbz)?, CELLS_LATTICE],
            lattice: [count_u32("points", d[0])?, count_u32("points", d[1])?, count_u32("points", d[2])?, bs as u32],
            counts: [n, 1, n, 0],
            ..Params::default()
        };
        let layer = d[0] * d[1];
        let ncells = count_u32("bricks", nbx * nby)?;
        let mut frames_done = false;
        let mut bz = 0;
        while bz < nbz {
            let z0 = bz * bs;
            let layers = bs.min(d[2] - z0);
            let slab_p = Params { counts: [n, 1, n, 0], stage: [BIN_SLAB, bz as u32, z0 as u32, 0], ..base };
            let brick_p = Params {
                counts: [n, ncells, count_u32("candidate slots", self.slab_capacity)?, 0],
                stage: [BIN_SLAB_BRICKS, bz as u32, z0 as u32, 0],
                ..base
            };
            let g = self.garbage;
            let gpu = &self.gpu;
            let k = &self.kernels;
            let timer = &mut self.timer;
            let b = &mut self.bufs;
            b.coarse_counts.ensure(gpu, 4, g)?;
            b.coarse_starts.ensure(gpu, 8, g)?;
            b.coarse_lists.ensure(gpu, 4 * n as u64, g)?;
            b.counts.ensure(gpu, 4 * ncells as u64, g)?;
            b.starts.ensure(gpu, 4 * (ncells as u64 + 1), g)?;
            b.lists.ensure(gpu, 4 * self.slab_capacity as u64, g)?;
            b.cells.ensure(gpu, 32, g)?;
            b.slab.ensure(gpu, 4 * (layer * layers) as u64, g)?;
            let read = gpu.scoped("a decode slab", || {
                let (u1, u2) = (uniform(gpu, &slab_p), uniform(gpu, &brick_p));
                let mut enc = gpu.device.create_command_encoder(&Default::default());
                let (params, hot, ranges) = (b.params.ensure(gpu, 0, false)?, b.hot.ensure(gpu, 0, false)?, b.ranges.ensure(gpu, 0, false)?);
                let (ident, ident_bounds, cells) = (b.identity.ensure(gpu, 0, false)?, b.identity_bounds.ensure(gpu, 0, false)?, b.cells.ensure(gpu, 0, false)?);
                let (sc, ss, sl) = (b.coarse_counts.ensure(gpu, 0, false)?, b.coarse_starts.ensure(gpu, 0, false)?, b.coarse_lists.ensure(gpu, 0, false)?);
                let (counts, starts, lists) = (b.counts.ensure(gpu, 0, false)?, b.starts.ensure(gpu, 0, false)?, b.lists.ensure(gpu, 0, false)?);
                let slab = b.slab.ensure(gpu, 0, false)?;
                if !frames_done {
                    dispatch(gpu, &mut enc, timer, &k.frames, &seq(&[&u1, params, hot, ranges]), groups_for(n as usize));
                }
                // The slab's primitives, from all of them.
                dispatch(gpu, &mut enc, timer, &k.count, &seq(&[&u1, ranges, ident, ident_bounds, cells, sc]), 1);
                dispatch(gpu, &mut enc, timer, &k.scan, &seq(&[&u1, sc, ss]), 1);
                dispatch(gpu, &mut enc, timer, &k.fill, &[(0, &u1), (1, ranges), (2, ident), (3, ident_bounds), (4, cells), (6, ss), (7, sl)], 1);
                // Each brick's, from the slab's.
                dispatch(gpu, &mut enc, timer, &k.count, &seq(&[&u2, ranges, sl, ss, cells, counts]), ncells);
                dispatch(gpu, &mut enc, timer, &k.scan, &seq(&[&u2, counts, starts]), 1);
                dispatch(gpu, &mut enc, timer, &k.fill, &[(0, &u2), (1, ranges), (2, sl), (3, ss), (4, cells), (6, starts), (7, lists)], ncells);
                dispatch(gpu, &mut enc, timer, &k.decode, &seq(&[&u2, hot, starts, lists, slab]), ncells);
                let times = timer.resolve(&mut enc).unwrap_or((slab, 0));
                b.readback.record(gpu, &mut enc, &[(slab, 4 * (layer * layers) as u64), (starts, 4 * (ncells as u64 + 1)), times])?;
                gpu.queue.submit([enc.finish()]);
                b.readback.read(gpu)
            });
            let read = self.timed(read)?;
            frames_done = true;
            let total = words(&read[1]).last().copied().unwrap_or(0) as usize;
            if total > self.slab_capacity {
                self.slab_capacity = total + total / 4;
                self.reruns += 1;
                continue;
            }
            out[z0 * layer..(z0 + layers) * layer].copy_from_slice(&floats(&read[0]));
            bz += 1;
        }
        Ok(())
    }
}
