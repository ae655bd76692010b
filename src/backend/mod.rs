//! Backends evaluate the mixture and the point terms of the loss.
//!
//! A backend receives the stored parameters, not precomputed frames, so that a
//! GPU backend can build its frames on the device. Both backends must return
//! the same numbers up to float rounding; they are tested against each other
//! and against the dense reference in `tests/`.
//!
//! Data layout for devices without float atomics: the point pass writes each
//! point's `(g_rho, g_n)`, and a primitive pass gathers, for each primitive,
//! the pair sums of [`crate::math::kernel::GradAcc`] over the points in its box. No
//! two threads ever add into one location.

pub mod bricks;
pub mod cpu;
mod csr;
#[cfg(feature = "gpu")]
pub mod gpu;
pub mod select;

use crate::error::{Error, Result};
use crate::math::kernel::Primitive;
use crate::math::loss::{LossWeights, RegTerms};
use crate::math::optim::Adam;
use bricks::PointBricks;
use std::borrow::Cow;

/// Points and their reference values, and perhaps their sort into bricks.
#[derive(Clone, Debug, Default)]
pub struct PointBatch {
    pub pos: Vec<[f32; 3]>,
    pub vref: Vec<f32>,
    /// The points sorted into bricks of an edge, made ahead of the pass that
    /// reads them ([`Self::sort_into_bricks`]).
    sorted: Option<(f32, PointBricks)>,
}

impl PointBatch {
    pub fn new(pos: Vec<[f32; 3]>, vref: Vec<f32>) -> PointBatch {
        PointBatch { pos, vref, sorted: None }
    }
    pub fn len(&self) -> usize {
        self.pos.len()
    }
    pub fn is_empty(&self) -> bool {
        self.pos.is_empty()
    }

    /// Sorts the points into bricks of `edge` voxels now and keeps the sort,
    /// so that a backend whose point passes use that edge
    /// ([`Backend::brick_edge`]) finds it done: the encoder sorts the next
    /// batch as it draws it, beside the current iteration's gradient, which
    /// takes the sort's passes off the iteration's path. The points must not
    /// change afterwards.
    pub fn sort_into_bricks(&mut self, edge: f32) {
        self.sorted = Some((edge, PointBricks::new(&self.pos, edge)));
    }

    /// The points sorted into bricks of `edge` voxels: the kept sort when it
    /// has that edge, else a new one ([`PointBricks::new`] either way).
    pub fn bricks(&self, edge: f32) -> Cow<'_, PointBricks> {
        match &self.sorted {
            Some((e, b)) if e.to_bits() == edge.to_bits() && b.order.len() == self.pos.len() => Cow::Borrowed(b),
            _ => Cow::Owned(PointBricks::new(&self.pos, edge)),
        }
    }
}

/// The unweighted point terms of the loss over a batch.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PointLoss {
    pub val: f64,
    pub cov: f64,
}

/// A regular lattice of evaluation points in the index frame:
/// point `(i, j, k)` is at `origin + (i, j, k) * step`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Lattice {
    pub dims: [usize; 3],
    pub origin: [f32; 3],
    pub step: [f32; 3],
}

impl Lattice {
    /// The voxel centres of the reference grid itself.
    pub fn reference(dims: [usize; 3]) -> Lattice {
        Lattice { dims, origin: [0.0; 3], step: [1.0; 3] }
    }

    /// `out_dims` voxels covering the same box as a reference grid of `dims`:
    /// `u = (i + 0.5) * D / D' - 0.5`.
    pub fn resampled(dims: [usize; 3], out_dims: [usize; 3]) -> Lattice {
        let mut l = Lattice { dims: out_dims, origin: [0.0; 3], step: [1.0; 3] };
        for a in 0..3 {
            l.step[a] = dims[a] as f32 / out_dims[a] as f32;
            l.origin[a] = 0.5 * l.step[a] - 0.5;
        }
        l
    }

    pub fn len(&self) -> usize {
        self.dims[0] * self.dims[1] * self.dims[2]
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    pub fn point(&self, i: usize, j: usize, k: usize) -> [f32; 3] {
        [
            self.origin[0] + i as f32 * self.step[0],
            self.origin[1] + j as f32 * self.step[1],
            self.origin[2] + k as f32 * self.step[2],
        ]
    }
}

/// The evaluation interface every backend implements. The CPU backend never
/// fails; a device backend returns [`crate::error::Error::Device`] when its
/// device is lost or a call exceeds its limits.
pub trait Backend: Send {
    /// A human-readable name ("cpu", "wgpu:" and the adapter's name).
    fn name(&self) -> String;

    /// Whether the heavy work runs on a device, so that the host needs
    /// one thread for it rather than a pool.
    fn on_device(&self) -> bool {
        false
    }

    /// Device seconds per kernel since the backend opened, with the number
    /// of passes timed: `(kernel, passes, seconds)`. Empty for a backend
    /// that does not time its kernels (the CPU's).
    fn kernel_seconds(&self) -> Vec<(String, u64, f64)> {
        vec![]
    }

    /// Host seconds per phase of a device backend's calls (arranging,
    /// writing, recording, submitting, waiting, reading back), with the
    /// number of times each ran: `(phase, times, seconds)`. Empty for the
    /// CPU backend.
    fn host_seconds(&self) -> Vec<(String, u64, f64)> {
        vec![]
    }

    /// A backend that can keep the parameters and Adam's moments on its
    /// device through a run of iterations ([`Resident`]) says so here.
    fn resident(&mut self) -> Option<&mut dyn Resident> {
        None
    }

    /// After `error` from this backend: whether it gave up its device and
    /// will run on the CPU from now on (`auto`), so that the work can be
    /// done again. A backend without a fall-back answers false.
    fn abandon_device(&mut self, _error: &Error) -> bool {
        false
    }

    /// Why this backend runs on the CPU although a GPU was asked for
    /// (`auto` after a device failure), if it does.
    fn fell_back(&self) -> Option<String> {
        None
    }

    /// The edge, in voxels, of the bricks this backend's point passes sort a
    /// batch into ([`PointBatch::bricks`]), so that a caller can sort a batch
    /// ahead ([`PointBatch::sort_into_bricks`]); `None` when it sorts none.
    fn brick_edge(&self) -> Option<f32> {
        None
    }

    /// Kernels `K(x)` evaluated by the point passes since creation: pairs of
    /// a point and a candidate primitive (for throughput figures).
    fn kernel_evaluations(&self) -> u64;

    /// Mixture density `rho` and numerator `n` at each point. The same bits
    /// for the same points, in the same order, whatever the thread count;
    /// but a point's sums follow the bricks the batch is sorted into, so
    /// its last bits may change with the other points of the call.
    fn evaluate_points(&mut self, params: &[Primitive], pos: &[[f32; 3]], rho: &mut [f32], n: &mut [f32]) -> Result<()>;

    /// [`Self::evaluate_points`] where each point's `rho` and `n` depend on
    /// that point and the primitives alone: not on the other points of the
    /// call, their number or order, nor the thread count (the CPU backend's
    /// `PointPass::forward_pointwise`). For [`crate::model::Model::evaluate`],
    /// whose answer at a point must not change with the points asked beside
    /// it. Device backends answer with the CPU backend's code, the default,
    /// so that every backend gives the same bits; the points asked of a
    /// model are few beside an encode's.
    fn evaluate_each(&mut self, params: &[Primitive], pos: &[[f32; 3]], rho: &mut [f32], n: &mut [f32]) -> Result<()> {
        cpu::CpuBackend::new().evaluate_each(params, pos, rho, n)
    }

    /// The point terms L_val and L_cov over `batch`, and the gradient of their
    /// weighted sum with respect to every parameter, written into `grad` (one
    /// entry per primitive): the pair sums of [`crate::math::kernel::GradAcc`] turned
    /// into parameter gradients by [`crate::math::kernel::Frame::finalize`]. The
    /// result must not depend on the thread count.
    fn point_loss_grad(
        &mut self,
        params: &[Primitive],
        batch: &PointBatch,
        weights: &LossWeights,
        grad: &mut [Primitive],
    ) -> Result<PointLoss>;

    /// The decoded value `V_eval` at every point of `lattice`, x fastest.
    fn decode_lattice(&mut self, params: &[Primitive], lattice: &Lattice, out: &mut [f32]) -> Result<()>;
}

/// An error when a backend's output slice does not match its input.
pub(crate) fn check_len(what: &str, got: usize, want: usize) -> Result<()> {
    if got == want {
        Ok(())
    } else {
        Err(Error::arg(format!("backend: {what} holds {got} entries, {want} expected")))
    }
}

/// Training with the parameters and Adam's moments kept on a device: the
/// loop uploads them once, runs whole iterations (point terms, regularisers,
/// gradient, Adam) on the device, and reads them back only when it needs
/// them on the host (relocation, validation, the end). One step computes
/// what [`Backend::point_loss_grad`], [`crate::math::loss::regularizers`]
/// and [`Adam::step`] compute, in the device's order of float sums.
pub trait Resident {
    /// Puts `params` and `adam`'s moments and step count on the device.
    fn load(&mut self, params: &[Primitive], adam: &Adam) -> Result<()>;

    /// Iterations that may be submitted and not yet finished at once.
    fn depth(&self) -> usize {
        1
    }

    /// Starts one iteration at learning rate `lr` (after those in flight)
    /// and returns without waiting for it, so that the host can draw the
    /// next batch meanwhile. Every submitted iteration must be finished
    /// before any call but `submit` (up to `depth` in flight) and `finish`.
    fn submit(&mut self, batch: &PointBatch, weights: &LossWeights, lr: f32, report: bool) -> Result<()>;

    /// Waits for the oldest submitted iteration; returns its unweighted
    /// loss terms when it was submitted with `report`. After an error no
    /// iteration is in flight, and the device needs a `load`.
    fn finish(&mut self) -> Result<Option<(PointLoss, RegTerms)>>;

    /// One iteration: `submit`, then `finish`.
    fn step(&mut self, batch: &PointBatch, weights: &LossWeights, lr: f32, report: bool) -> Result<Option<(PointLoss, RegTerms)>> {
        self.submit(batch, weights, lr, report)?;
        self.finish()
    }

    /// Copies the parameters, moments and step count back.
    fn store(&mut self, params: &mut [Primitive], adam: &mut Adam) -> Result<()>;
}
