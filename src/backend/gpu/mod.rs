//! The GPU backend: the same [`Backend`] as the CPU's, run by wgpu compute
//! shaders (Vulkan, Metal, DX12; Mesa's lavapipe in tests).
//!
//! A training iteration is one command buffer (`points.rs`):
//! 1. `frames`: each primitive's `Hot` record and the bricks its box overlaps;
//! 2. per coarse cell of 4^3 bricks the primitives that reach it, then per
//!    occupied brick its candidates from its coarse cell's list, both in
//!    primitive order: `bin_rows` `count`, `total`, `scan`, `bin_rows`
//!    `fill` (one workgroup per chunk of a parent's list, which marks each
//!    entry in the bit rows of the children it reaches) at the brick level,
//!    and at the coarse level where the coarse grid is at most 4 cells a
//!    side; else `bin` `count`, `scan`, `bin` `fill` (one workgroup per
//!    chunk of the primitives and cell, gathers); the lists get a capacity,
//!    and the scans' totals, read back with the results, say whether they
//!    fitted (if not, the call runs again with room for them);
//! 3. `forward`: per piece of a brick's points (8), the points' density and
//!    numerator, and each point's loss terms;
//! 4. `backward`: per (brick, candidate) the pair sums of `GradAcc`, each in
//!    its own slot (8 workgroups a brick, each a slice of its candidates);
//! 5. `reduce`: per primitive, its slots summed in brick order (a team of
//!    threads finds them, one adds them), then `Frame::finalize`; in
//!    resident training (`resident.rs`) the same thread goes on with the
//!    regularisers and the Adam step on parameters and moments that stay on
//!    the device (reduce.wgsl `step`), and holds back the steps queued
//!    after one whose lists overflowed (two submissions of steps may be in
//!    flight: `points::IN_FLIGHT`); `loss`: the batch's loss terms.
//!
//! No float atomics anywhere (the integer OR of bin_rows.wgsl gives the
//! same bits in any order), so a call gives the same bits run after run
//! on one adapter. The points are sorted into bricks on the host
//! ([`crate::backend::bricks::PointBricks`], as the CPU backend does) and
//! uploaded. `point_loss_grad` brings the gradient back; `evaluate_points`
//! runs steps 1-3; `decode_lattice` (`decode.rs`) bins per slab of lattice
//! bricks (the slab's primitives, then each brick's) and gathers per
//! lattice point. docs/DESIGN.md "The GPU backend" has the whole account.

pub mod device;

mod buffers;
mod decode;
mod kernels;
mod points;
mod resident;
mod staged;
mod timer;

use self::buffers::Buffers;
use self::device::{DeviceRequest, Gpu};
use self::kernels::{BindGroups, Kernels};
use self::points::Pass;
use self::timer::{Timer, Totals};
use super::bricks::PointBricks;
use super::{check_len, Backend, Lattice, PointBatch, PointLoss};
use crate::error::{Error, Result};
use crate::math::kernel::Primitive;
use crate::math::loss::LossWeights;
use std::borrow::Cow;
use std::collections::VecDeque;

pub struct GpuBackend {
    gpu: Gpu,
    kernels: Kernels,
    timer: Timer,
    /// The host's seconds per phase of the point calls, with the number of
    /// times each ran: where the host's share of a training step goes. A
    /// GPU's driver and wgpu's no-op device split it differently, so the
    /// figures come from the machine that runs the encode. The phases, in
    /// a call's order:
    /// - `arrange`: the batch's points, bricks, pieces and coarse cells laid
    ///   out as the device reads them;
    /// - `write`: copying them and the call's uniforms into its staging
    ///   buffer (staged.rs `Staged`; with `GSENC_GPU_UPLOAD=writes`, handing
    ///   each to the queue, which copies it into staging memory of its own);
    /// - `record`: recording the command buffer (bind groups, dispatches, the
    ///   read-back's copies) inside wgpu's error scopes;
    /// - `submit`: finishing and submitting it;
    /// - `wait`: waiting for the device to finish it and map the results;
    /// - `read`: copying the mapped results out.
    host: Totals,
    bufs: Buffers,
    binds: BindGroups,
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
    /// Source entries a workgroup of a bin pass from every primitive tests
    /// (`kernels::BIN_CHUNK`; tests make it small).
    bin_chunk: usize,
    /// Chunks each coarse cell's list is cut into at the brick level of
    /// training binning; `None`: by the lists' size
    /// (`kernels::brick_chunks_for`).
    brick_chunks: Option<u32>,
    /// Points a forward workgroup evaluates, and backward workgroups per
    /// brick (`kernels::FORWARD_PIECE`, `kernels::BACKWARD_SLICES`; tests
    /// vary them).
    forward_piece: usize,
    backward_slices: u32,
    /// Threads that reduce one primitive; `None`: by the primitive count
    /// (`kernels::reduce_team_for`).
    reduce_team: Option<u32>,
    evaluations: u64,
    /// What resident training holds on the device once the steps in
    /// flight are finished, after a `load`.
    loaded: Option<resident::Loaded>,
    /// The point calls submitted and not yet finished, oldest first
    /// (points.rs): at most one, or `depth` resident steps.
    in_flight: VecDeque<points::InFlight>,
    /// The resident steps submitted and not yet finished (resident.rs).
    steps: VecDeque<resident::Step>,
    /// Submissions of resident steps that may be in flight at once (1 or
    /// `points::IN_FLIGHT`, the default): with two, the device runs one
    /// while the host waits for the other's results and records the next.
    pub depth: usize,
    /// Resident steps a submission carries (1, the default, to
    /// `points::MAX_BATCH`; `GSENC_GPU_BATCH`): the steps are recorded into
    /// one command buffer, submitted once it holds this many (or when one
    /// of them is read back), so that a driver's cost per submission is
    /// paid once for them. Up to `depth × batch` steps are then in flight.
    /// The same bits whatever the batch (tested). Uploads written buffer by
    /// buffer (`upload_per_buffer`) land before a whole submission's
    /// commands, so they take one step a submission.
    pub batch: usize,
    /// The resident steps recorded and not yet submitted (points.rs).
    open: Option<points::Open>,
    /// Hand a point call's uploads to the queue buffer by buffer, as
    /// before 2026-12-05, rather than through its slot's mapped staging
    /// buffer (staged.rs `Staged`): the same bits, for measuring what the
    /// staging buffer saves (`GSENC_GPU_UPLOAD=writes`).
    pub upload_per_buffer: bool,
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

/// `(binding, buffer)` pairs for bindings 0, 1, 2, ...
fn seq<'a>(bufs: &[&'a wgpu::Buffer]) -> Vec<(u32, &'a wgpu::Buffer)> {
    bufs.iter().enumerate().map(|(i, &b)| (i as u32, b)).collect()
}

/// `GSENC_GPU_DEPTH=1` keeps one resident step in flight instead of
/// [`points::IN_FLIGHT`] (the same models; for measuring what the second
/// one gains).
fn depth_from_env() -> usize {
    match std::env::var("GSENC_GPU_DEPTH").ok().and_then(|s| s.trim().parse::<usize>().ok()) {
        Some(d) => d.clamp(1, points::IN_FLIGHT),
        None => points::IN_FLIGHT,
    }
}

/// `GSENC_GPU_BATCH=K`: resident steps a submission carries
/// ([`GpuBackend::batch`]), 1 to [`points::MAX_BATCH`]; unset or empty, 1.
/// The same models whatever it is; for measuring what a driver's cost per
/// submission takes from a step (`benches/gpu.sh`).
fn batch_from_env() -> Result<usize> {
    let Ok(v) = std::env::var("GSENC_GPU_BATCH") else { return Ok(1) };
    if v.trim().is_empty() {
        return Ok(1);
    }
    v.trim()
        .parse::<usize>()
        .ok()
        .filter(|k| (1..=points::MAX_BATCH).contains(k))
        .ok_or_else(|| Error::arg(format!("GSENC_GPU_BATCH={v:?}: expected resident steps a submission, 1 to {}", points::MAX_BATCH)))
}

/// What `GSENC_GPU_SPLIT=PIECE,SLICES[,CHUNK[,TEAM[,BRICK_CHUNKS]]]`
/// sets: how the point passes' work is cut into workgroups.
struct Split {
    piece: usize,
    slices: u32,
    chunk: Option<usize>,
    team: Option<u32>,
    brick_chunks: Option<u32>,
}

/// `GSENC_GPU_SPLIT` ([`GpuBackend::set_work_split`],
/// [`GpuBackend::set_bin_chunk`], [`GpuBackend::set_reduce_team`],
/// [`GpuBackend::set_brick_chunks`]): the same results whatever the split
/// (tested), for finding the fastest on a GPU (`benches/gpu_split.sh`).
/// Unset or empty: the defaults. Anything but two to five positive
/// integers, the fourth a power of two up to 128 and the fifth at most
/// `kernels::MAX_BRICK_CHUNKS`, is an error.
fn split_from_env() -> Result<Option<Split>> {
    let Ok(v) = std::env::var("GSENC_GPU_SPLIT") else { return Ok(None) };
    if v.trim().is_empty() {
        return Ok(None);
    }
    let bad = || {
        Error::arg(format!(
            "GSENC_GPU_SPLIT={v:?}: expected PIECE,SLICES[,CHUNK[,TEAM[,BRICK_CHUNKS]]] (positive integers: points a forward workgroup, \
             backward workgroups a brick, primitives a bin workgroup, threads a primitive's reduction, a power of two up to 128, \
             chunks a coarse cell's list at the brick level, up to {})",
            kernels::MAX_BRICK_CHUNKS
        ))
    };
    let n: Vec<usize> = v.split(',').map(|x| x.trim().parse::<usize>().ok().filter(|&n| n > 0)).collect::<Option<_>>().ok_or_else(bad)?;
    if !(2..=5).contains(&n.len()) {
        return Err(bad());
    }
    let team = match n.get(3) {
        Some(&t) if t.is_power_of_two() && t <= 128 => Some(t as u32),
        Some(_) => return Err(bad()),
        None => None,
    };
    let brick_chunks = match n.get(4) {
        Some(&k) if k <= kernels::MAX_BRICK_CHUNKS => Some(k as u32),
        Some(_) => return Err(bad()),
        None => None,
    };
    Ok(Some(Split { piece: n[0], slices: u32::try_from(n[1]).map_err(|_| bad())?, chunk: n.get(2).copied(), team, brick_chunks }))
}

impl GpuBackend {
    /// Opens the adapter `req` names and compiles the kernels.
    pub fn new(req: &DeviceRequest) -> Result<GpuBackend> {
        let split = split_from_env()?;
        let batch = batch_from_env()?;
        let gpu = Gpu::open(req)?;
        let kernels = Kernels::new(&gpu)?;
        let timer = Timer::new(&gpu, points::SLOTS);
        let mut b = GpuBackend {
            gpu,
            kernels,
            timer,
            host: Totals::default(),
            bufs: Buffers::default(),
            binds: BindGroups::default(),
            brick: 16.0,
            garbage: false,
            capacity: 1 << 16,
            coarse_capacity: 1 << 16,
            slab_capacity: 1 << 16,
            bin_chunk: kernels::BIN_CHUNK,
            brick_chunks: None,
            forward_piece: kernels::FORWARD_PIECE,
            backward_slices: kernels::BACKWARD_SLICES,
            reduce_team: None,
            evaluations: 0,
            loaded: None,
            in_flight: VecDeque::new(),
            steps: VecDeque::new(),
            depth: depth_from_env(),
            batch,
            open: None,
            upload_per_buffer: std::env::var("GSENC_GPU_UPLOAD").is_ok_and(|v| v.trim() == "writes"),
            reruns: 0,
        };
        if let Some(split) = split {
            b.set_work_split(split.piece, split.slices);
            if let Some(c) = split.chunk {
                b.set_bin_chunk(c);
            }
            if let Some(t) = split.team {
                b.set_reduce_team(t);
            }
            if let Some(k) = split.brick_chunks {
                b.set_brick_chunks(k);
            }
        }
        Ok(b)
    }

    /// Starts the candidate lists of training calls and decode slabs at
    /// `slots` entries (they grow when a call needs more); tests use it to
    /// make the lists overflow.
    pub fn set_capacity(&mut self, slots: usize) {
        self.capacity = slots.max(1);
        self.coarse_capacity = slots.max(1);
        self.slab_capacity = slots.max(1);
    }

    /// Resident steps a submission carries: `batch`, or one when uploads
    /// go buffer by buffer.
    fn batch(&self) -> usize {
        if self.upload_per_buffer {
            1
        } else {
            self.batch.clamp(1, points::MAX_BATCH)
        }
    }

    /// An error when a submitted call has not been finished: every call
    /// but `finish` needs the device to itself. (A submitted resident step
    /// is always a call in flight until `finish` takes both.) And in a
    /// process forked since the device was opened, where it cannot be used.
    fn idle(&self, what: &str) -> Result<()> {
        self.gpu.in_its_process()?;
        if !self.in_flight.is_empty() {
            return Err(Error::arg(format!("GPU backend: {what} while a submitted step is not finished")));
        }
        Ok(())
    }

    /// Splits the passes that bin from every primitive into chunks of
    /// `entries` (default `kernels::BIN_CHUNK`); the results do not depend
    /// on it, and tests use it to split small models.
    pub fn set_bin_chunk(&mut self, entries: usize) {
        self.bin_chunk = entries.max(1);
    }

    /// Cuts each coarse cell's list into `chunks` at the brick level of
    /// training binning, one workgroup each (default: by the lists' size,
    /// `kernels::brick_chunks_for`); the lists do not depend on it.
    pub fn set_brick_chunks(&mut self, chunks: u32) {
        self.brick_chunks = Some(chunks.clamp(1, kernels::MAX_BRICK_CHUNKS as u32));
    }

    /// Splits each brick's points into pieces of `points`, one forward
    /// workgroup each, and gives each brick `slices` backward workgroups
    /// (defaults `kernels::FORWARD_PIECE`, `kernels::BACKWARD_SLICES`);
    /// the results do not depend on them, and tests vary them.
    pub fn set_work_split(&mut self, points: usize, slices: u32) {
        self.forward_piece = points.max(1);
        self.backward_slices = slices.max(1);
    }

    /// Reduces each primitive's slots with a team of `threads` (rounded up
    /// to a power of two, at most 128; by default the team depends on the
    /// primitive count, `kernels::reduce_team_for`); the results do not
    /// depend on it, and tests vary it.
    pub fn set_reduce_team(&mut self, threads: u32) {
        self.reduce_team = Some(threads.clamp(1, 128).next_power_of_two());
    }

    /// The adapter this backend runs on.
    pub fn adapter(&self) -> &device::AdapterSummary {
        &self.gpu.adapter
    }

    /// Device buffers and bind groups this backend has made so far: once
    /// its buffers have grown to a run's batches, a training step makes
    /// neither (it rewrites its buffers and binds those of the step
    /// before).
    pub fn objects_made(&self) -> (u64, u64) {
        (self.bufs.made() + self.bufs.staged.iter().map(|s| s.made()).sum::<u64>(), self.binds.created)
    }

    /// Uploads so far (`Gpu::uploads`; garbage fills not counted): one a
    /// steady training step.
    pub fn uploads(&self) -> u64 {
        self.gpu.uploads()
    }

    /// Hands a submission's timestamps (its last read-back region, read
    /// through slot `slot`) to the timer and returns the other regions.
    fn timed(&mut self, slot: usize, read: Result<Vec<Vec<u8>>>) -> Result<Vec<Vec<u8>>> {
        match read {
            Ok(mut regions) => {
                self.timer.record(slot, &regions.pop().unwrap_or_default());
                Ok(regions)
            }
            Err(e) => {
                self.timer.discard(slot);
                Err(e)
            }
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

    fn brick_edge(&self) -> Option<f32> {
        Some(self.brick)
    }

    fn kernel_seconds(&self) -> Vec<(String, u64, f64)> {
        self.timer.totals()
    }

    /// The phases of the point calls (training steps, gradients,
    /// evaluations): `GpuBackend::host`.
    fn host_seconds(&self) -> Vec<(String, u64, f64)> {
        self.host.totals()
    }

    fn resident(&mut self) -> Option<&mut dyn super::Resident> {
        Some(self)
    }

    /// Counted as points times the candidates of their brick.
    fn kernel_evaluations(&self) -> u64 {
        self.evaluations
    }

    fn evaluate_points(&mut self, params: &[Primitive], pos: &[[f32; 3]], rho: &mut [f32], n: &mut [f32]) -> Result<()> {
        self.idle("an evaluation")?;
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
        let (p, bricks, ncoarse, upload) = self.upload_points(params.len(), pos, None, Cow::Owned(PointBricks::new(pos, self.brick)))?;
        let (rn, _, starts) = self.run_points(p, bricks.ranges.len(), ncoarse, Pass::Evaluate, upload)?;
        self.count_evaluations(&bricks.ranges, &starts);
        let rn = floats(&rn);
        for (k, &i) in bricks.order.iter().enumerate() {
            rho[i as usize] = rn[2 * k];
            n[i as usize] = rn[2 * k + 1];
        }
        Ok(())
    }

    fn point_loss_grad(&mut self, params: &[Primitive], batch: &PointBatch, weights: &LossWeights, grad: &mut [Primitive]) -> Result<PointLoss> {
        self.idle("a gradient")?;
        check_len("grad", grad.len(), params.len())?;
        check_len("vref", batch.vref.len(), batch.pos.len())?;
        if batch.is_empty() || params.is_empty() {
            grad.fill([0.0; 12]);
            return Ok(PointLoss::default());
        }
        self.upload_params(params)?;
        let (mut p, bricks, ncoarse, upload) = self.upload_points(params.len(), &batch.pos, Some(&batch.vref), batch.bricks(self.brick))?;
        p.set_objective(&batch.vref, weights);
        p.stage[3] = 1;
        let (g, loss, starts) = self.run_points(p, bricks.ranges.len(), ncoarse, Pass::Gradient, upload)?;
        self.count_evaluations(&bricks.ranges, &starts);
        let g = floats(&g);
        for (i, out) in grad.iter_mut().enumerate() {
            out.copy_from_slice(&g[12 * i..12 * i + 12]);
        }
        let loss = floats(&loss);
        Ok(PointLoss { val: loss[0] as f64, cov: loss[1] as f64 })
    }

    fn decode_lattice(&mut self, params: &[Primitive], lattice: &Lattice, out: &mut [f32]) -> Result<()> {
        self.idle("a decode")?;
        self.decode(params, lattice, out)
    }
}
