//! Resident training on the GPU: parameters and Adam's moments stay in
//! device buffers between iterations; a step uploads only the batch's points
//! and reads back only the list totals (and, when asked, four loss terms).
//! `submit` returns once the step is on the device's queue (or recorded
//! into a submission of several steps that is not full yet), so the host
//! draws the next batch while the device works; `finish` waits for the
//! oldest step. Two steps may be in flight (`GpuBackend::depth`): the
//! device runs the second while the host reads the first's results; with
//! `GpuBackend::batch` K, two submissions of K steps each.
//! Mirrors the iteration of encode/refine.rs: `point_loss_grad`, then
//! `regularizers` and `Adam::step` (reduce.wgsl `step`, after the reduction).

use super::points::{InFlight, IN_FLIGHT};
use super::{bytes, floats, GpuBackend, Pass};
use crate::backend::{check_len, PointBatch, PointLoss, Resident};
use crate::error::{Error, Result};
use crate::math::kernel::Primitive;
use crate::math::loss::{LossWeights, RegTerms};
use crate::math::optim::{Adam, BETA1, BETA2};
use std::borrow::Cow;

/// What the device holds between steps.
#[derive(Clone, Copy, Debug)]
pub(super) struct Loaded {
    /// Primitives.
    n: usize,
    /// Adam's step count.
    t: u32,
}

/// A resident step submitted and not yet finished.
pub(super) struct Step {
    /// What the device will hold once it finishes.
    loaded: Loaded,
    /// Each brick's range of points, for the count of kernel evaluations.
    ranges: Vec<(u32, u32)>,
    report: bool,
}

impl Resident for GpuBackend {
    fn load(&mut self, params: &[Primitive], adam: &Adam) -> Result<()> {
        self.idle("a load")?;
        check_len("Adam's m", adam.m.len(), params.len())?;
        check_len("Adam's v", adam.v.len(), params.len())?;
        self.loaded = None;
        self.upload_params(params)?;
        let moments: Vec<f32> = adam.m.iter().zip(&adam.v).flat_map(|(m, v)| m.iter().chain(v).copied()).collect();
        self.bufs.moments.upload(&self.gpu, bytes(&moments), self.garbage)?;
        self.clear_poison()?;
        self.loaded = Some(Loaded { n: params.len(), t: adam.t });
        Ok(())
    }

    fn depth(&self) -> usize {
        self.depth.clamp(1, IN_FLIGHT) * self.batch()
    }

    fn submit(&mut self, batch: &PointBatch, weights: &LossWeights, lr: f32, report: bool) -> Result<()> {
        self.gpu.in_its_process()?;
        // What the device will hold once the steps in flight are done.
        let base = self.steps.back().map(|s| s.loaded).or(self.loaded);
        let Loaded { n, t } = base.ok_or_else(|| Error::arg("GPU backend: a resident step before any load"))?;
        // Every other call finishes before it returns: what is in flight
        // are resident steps.
        debug_assert_eq!(self.in_flight.len(), self.steps.len());
        if self.steps.len() >= Resident::depth(self) {
            return Err(Error::arg(format!("GPU backend: a resident step while {} are in flight", self.steps.len())));
        }
        check_len("vref", batch.vref.len(), batch.pos.len())?;
        if batch.is_empty() || n == 0 {
            return Err(Error::arg("GPU backend: a resident step needs points and primitives"));
        }
        // Past the checks, a failure leaves the device in an unknown state.
        self.queue_step(n, t, batch, weights, lr, report).inspect_err(|_| self.abandon())
    }

    fn finish(&mut self) -> Result<Option<(PointLoss, RegTerms)>> {
        self.gpu.in_its_process()?;
        let Step { loaded, ranges, report } = self.steps.pop_front().ok_or_else(|| Error::arg("GPU backend: a resident finish without a step"))?;
        let (_, loss, starts) = self.finish_points()?;
        self.loaded = Some(loaded);
        self.count_evaluations(&ranges, &starts);
        Ok(report.then(|| {
            let l = floats(&loss);
            (PointLoss { val: l[0] as f64, cov: l[1] as f64 }, RegTerms { scale: l[2] as f64, aniso: l[3] as f64 })
        }))
    }

    fn store(&mut self, params: &mut [Primitive], adam: &mut Adam) -> Result<()> {
        let Loaded { n, t } = self.loaded.ok_or_else(|| Error::arg("GPU backend: a store before any load"))?;
        self.idle("a store")?;
        check_len("params", params.len(), n)?;
        let (gpu, b) = (&self.gpu, &mut self.bufs);
        let read = gpu.scoped("reading the parameters back", || {
            let mut enc = gpu.device.create_command_encoder(&Default::default());
            let (params, moments) = (b.params.ensure(gpu, 0, false)?, b.moments.ensure(gpu, 0, false)?);
            b.readback[0].record(gpu, &mut enc, &[(params, 48 * n as u64), (moments, 96 * n as u64)])?;
            b.readback[0].submit(gpu, enc);
            b.readback[0].read(gpu)
        })?;
        let (p, m) = (floats(&read[0]), floats(&read[1]));
        for (i, out) in params.iter_mut().enumerate() {
            out.copy_from_slice(&p[12 * i..12 * i + 12]);
        }
        adam.m.resize(n, [0.0; 12]);
        adam.v.resize(n, [0.0; 12]);
        for i in 0..n {
            adam.m[i].copy_from_slice(&m[24 * i..24 * i + 12]);
            adam.v[i].copy_from_slice(&m[24 * i + 12..24 * i + 24]);
        }
        adam.t = t;
        Ok(())
    }
}

impl GpuBackend {
    /// Uploads a resident step's batch and submits the step after those in
    /// flight: `n` primitives at Adam's step count `t` before it.
    fn queue_step(&mut self, n: usize, t: u32, batch: &PointBatch, weights: &LossWeights, lr: f32, report: bool) -> Result<()> {
        let (mut p, bricks, ncoarse, upload) = self.upload_points(n, &batch.pos, Some(&batch.vref), batch.bricks(self.brick))?;
        let t = t + 1;
        // As loss.rs `regularizers` and optim.rs `Adam::step` compute them on the host.
        let nf = n.max(1) as f32;
        p.set_objective(&batch.vref, weights);
        p.optim = [lr, 1.0 - BETA1.powi(t as i32), 1.0 - BETA2.powi(t as i32), 0.0];
        p.reg = [weights.scale, weights.aniso, 1.0 / (3.0 * nf), 1.0 / nf];
        p.stage[3] = 1;
        p.coarse[2] = report as u32;
        let nbricks = bricks.ranges.len();
        self.submit_points(InFlight { p, nbricks, ncoarse, pass: Pass::Resident { report }, slot: 0, upload })?;
        let ranges = match bricks {
            Cow::Owned(b) => b.ranges,
            Cow::Borrowed(b) => b.ranges.clone(),
        };
        self.steps.push_back(Step { loaded: Loaded { n, t }, ranges, report });
        Ok(())
    }
}
