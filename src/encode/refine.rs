//! The refinement loop: seeding (or a warm start), stratified points, the
//! four-term loss, Adam with cosine decay, and relocation at 35/55/75 %.

use crate::backend::{Backend, PointBatch, PointLoss};
use crate::encode::config::{Cancel, EncodeConfig};
use crate::encode::plateau::Plateau;
use crate::encode::points::PointSampler;
use crate::encode::repair::choose_start;
use crate::encode::relocate::{relocate, Relocation, RELOCATE_POINTS};
use crate::encode::seeding::{seed, Seeding};
use crate::encode::validation::Validation;
use crate::error::{Error, Result};
use crate::field::check_finite;
use crate::input::Target;
use crate::math::kernel::{morton_key, Primitive};
use crate::math::loss::RegTerms;
use crate::math::optim::{cosine_lr, Adam};
use crate::model::WarmRecord;
use crate::profile;
use std::time::Instant;

/// Under gsenc's point rule a run of `T` iterations maps the model's error
/// every `max(T / ERROR_MAPS_PER_RUN, 1)` iterations, its start excepted
/// (nine maps when 10 divides `T`; `encode::points`).
pub const ERROR_MAPS_PER_RUN: usize = 10;

/// Where the optimisation loop's host threads spend their time (seconds,
/// summed over the loop). The next batch is drawn beside the rest of the
/// iteration when the pool has a second thread: beside the gradient on the
/// CPU backend, beside `submit` and `wait` of resident (GPU) steps. So
/// `draw` may overlap the others; `submit + wait` never exceeds the loop.
/// A batch drawn ahead is also sorted into the backend's bricks there
/// (`PointBatch::sort_into_bricks`); `submit` is the upload and recording
/// the command buffer (and the sort of a batch not drawn ahead); `wait`
/// the device's remaining time and the read-back.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LoopPhases {
    /// Drawing training points (relocations' batches included), and
    /// sorting a batch drawn ahead into bricks.
    pub draw: f64,
    /// Resident steps: queuing the step on the device.
    pub submit: f64,
    /// Resident steps: waiting for the step and reading its results.
    pub wait: f64,
}

/// Reported after every iteration.
#[derive(Clone, Copy, Debug)]
pub struct Progress {
    pub iteration: usize,
    pub iterations: usize,
    pub loss: f64,
}

/// Loss terms of the last iteration, unweighted.
#[derive(Clone, Copy, Debug, Default)]
pub struct LossTerms {
    pub val: f64,
    pub cov: f64,
    pub scale: f64,
    pub aniso: f64,
    pub total: f64,
}

pub struct EncodeOutput {
    /// The model, in spatial (Morton) order of the centres: the order of a
    /// model's primitives carries no meaning.
    pub params: Vec<Primitive>,
    /// Iterations run (fewer than the configuration's when an adaptive
    /// step stopped early).
    pub iterations: usize,
    pub points: usize,
    /// How an adaptive warm start began.
    pub warm: Option<WarmRecord>,
    /// The seeding result, absent for a warm start.
    pub seeding: Option<Seeding>,
    /// Each relocation pass; its indices refer to the primitive order at that
    /// moment (the encoder re-sorts spatially after every pass).
    pub relocations: Vec<Relocation>,
    pub last_loss: LossTerms,
    /// Seconds in seeding (or preparing the warm start: for an adaptive
    /// one, the repair and the scoring of its candidates).
    pub seed_seconds: f64,
    /// Seconds in the optimisation loop (the paper's reported time).
    pub loop_seconds: f64,
    /// `(iterations done, validation PSNR)`, when a [`Validation`] was given:
    /// at 0 (the initial model), every `every` iterations, and at the end.
    pub validation: Vec<(usize, f64)>,
    /// Seconds spent scoring the validation set (inside `loop_seconds`).
    pub validation_seconds: f64,
    /// Where the loop's host thread spent its time (inside `loop_seconds`).
    pub phases: LoopPhases,
    /// Kernel evaluations of the loop's point passes (its throughput).
    pub kernel_evaluations: u64,
    /// The backend that finished the encode ("cpu", "wgpu:" and the adapter's name).
    pub backend: String,
    /// Why it finished on the CPU although a GPU was asked for, if it did.
    pub fell_back: Option<String>,
}

/// Checks a target and a configuration before any work is done.
pub fn validate(target: &Target, cfg: &EncodeConfig, init: Option<&[Primitive]>) -> Result<()> {
    let voxels = target.reference.len();
    if cfg.budget == 0 {
        return Err(Error::arg("budget must be at least 1 primitive"));
    }
    if cfg.budget > voxels {
        return Err(Error::arg(format!(
            "budget of {} primitives exceeds the {voxels} voxels of the reference grid; a model larger than its grid reduces nothing",
            cfg.budget
        )));
    }
    cfg.check()?;
    check_training_memory(cfg.budget, cfg.points(), voxels, crate::memory::available()?)?;
    if target.samples.is_empty() {
        return Err(Error::data("no samples"));
    }
    check_finite(&target.reference.values)?;
    if let Some(p) = target.reference.values.iter().position(|v| !(0.0..=1.0).contains(v)) {
        return Err(Error::data(format!(
            "reference value {} at index {p} is outside [0, 1]; normalise first",
            target.reference.values[p]
        )));
    }
    if let Some(init) = init {
        if init.len() != cfg.budget {
            return Err(Error::arg(format!("warm start has {} primitives, budget is {}", init.len(), cfg.budget)));
        }
        if init.iter().flatten().any(|v| !v.is_finite()) {
            return Err(Error::data("warm-start model holds non-finite parameters"));
        }
    }
    Ok(())
}

/// Host memory an encode's training state takes a primitive (parameters,
/// Adam's moments, gradients, frames, candidate lists, the backend's
/// scratch) and a point of a batch: the peak resident sizes of CPU encodes
/// of 0.5M and 2M primitives of RM 256³ differ by 807 bytes a primitive,
/// of a random 256³ grid by 843 (docs/BENCHMARKS.md "Memory of an
/// encode"). Only for refusing a budget that cannot fit before anything is
/// allocated for it (an allocation that fails aborts).
pub const TRAINING_BYTES_PER_PRIMITIVE: u64 = 800;
pub const TRAINING_BYTES_PER_POINT: u64 = 64;
/// What an encode holds a voxel of its reference beyond the reference and
/// the input it came from, which exist when the check runs (the decode
/// that scores it, the error map, the support's bits): the peak resident
/// size of CPU encodes of 128³ and 256³ grids at one budget differs by
/// 18.6 bytes a voxel, 8 of them the tool's input and reference
/// (docs/BENCHMARKS.md "Memory of an encode a voxel"); rounded up.
pub const TRAINING_BYTES_PER_VOXEL: u64 = 12;

/// Refuses a budget whose training state, with batches of `points` and a
/// reference of `voxels`, would take more than `available` bytes (what
/// [`crate::memory::available`] says; nothing is refused where it says
/// nothing).
pub fn check_training_memory(budget: usize, points: usize, voxels: usize, available: Option<u64>) -> Result<()> {
    let need = (budget as u64)
        .saturating_mul(TRAINING_BYTES_PER_PRIMITIVE)
        .saturating_add((points as u64).saturating_mul(TRAINING_BYTES_PER_POINT))
        .saturating_add((voxels as u64).saturating_mul(TRAINING_BYTES_PER_VOXEL));
    let what = format!("training a budget of {budget} primitives on {voxels} voxels (about {TRAINING_BYTES_PER_PRIMITIVE} bytes a primitive and {TRAINING_BYTES_PER_VOXEL} a voxel)");
    crate::memory::check_fits_in(&what, need, available)
}

/// Encodes `target` into `cfg.budget` primitives, seeded from its samples, or
/// warm-started from `init` (then seeding is skipped). Runs on the current
/// rayon pool; see [`crate::threads::with_threads`].
pub fn encode(
    target: &Target,
    cfg: &EncodeConfig,
    init: Option<&[Primitive]>,
    backend: &mut dyn Backend,
    progress: &mut dyn FnMut(&Progress),
) -> Result<EncodeOutput> {
    encode_validated(target, cfg, init, None, backend, progress)
}

/// [`encode`], also scoring `validation` (when given) along the way, with
/// the same backend. Scoring reads the parameters only: the model is the same
/// with or without it. When the backend's device fails and the backend falls
/// back to the CPU (`auto`), the encode starts again there.
pub fn encode_validated(
    target: &Target,
    cfg: &EncodeConfig,
    init: Option<&[Primitive]>,
    validation: Option<&Validation>,
    backend: &mut dyn Backend,
    progress: &mut dyn FnMut(&Progress),
) -> Result<EncodeOutput> {
    match refine(target, cfg, init, validation, backend, progress) {
        Err(e) if backend.abandon_device(&e) => {
            tracing::warn!(error = %e, "the encode starts again on the CPU");
            refine(target, cfg, init, validation, backend, progress)
        }
        other => other,
    }
}

/// Loss terms are read back from a resident backend every this many
/// iterations (and at the last): reading them waits for the device.
pub const LOSS_EVERY: usize = 10;

fn refine(
    target: &Target,
    cfg: &EncodeConfig,
    init: Option<&[Primitive]>,
    validation: Option<&Validation>,
    backend: &mut dyn Backend,
    progress: &mut dyn FnMut(&Progress),
) -> Result<EncodeOutput> {
    validate(target, cfg, init)?;
    if let Some(v) = validation {
        if v.every == 0 || v.points.is_empty() || v.points.len() != v.values.len() {
            return Err(Error::arg("validation set is empty, mismatched, or has a zero interval"));
        }
    }
    if cfg.adaptive && validation.is_none() {
        return Err(Error::arg("an adaptive encode needs a validation set"));
    }
    let t_seed = Instant::now();
    // An adaptive warm start begins from the previous model, repaired, or
    // a fresh seeding (repair.rs).
    let mut warm = None;
    let chosen;
    let init = match (init, validation) {
        (Some(p), Some(v)) if cfg.adaptive => {
            let (params, record) = choose_start(target, p, cfg.seed_init, v, backend)?;
            warm = Some(record);
            chosen = params;
            Some(&chosen[..])
        }
        _ => init,
    };
    // Primitives are kept in spatial (Morton) order, which makes the backend's
    // candidate blocks compact; the seeding record follows the same permutation.
    let (mut params, seeding) = match init {
        Some(p) => (permute(p, &spatial_order(p)), None),
        None => {
            let s = seed(target.samples, target.reference.dims, cfg.budget, cfg.seed_init)?;
            let order = spatial_order(&s.params);
            let s = Seeding {
                params: permute(&s.params, &order),
                stream: permute(&s.stream, &order),
                sample: permute(&s.sample, &order),
            };
            (s.params.clone(), Some(s))
        }
    };
    let seed_seconds = t_seed.elapsed().as_secs_f64();
    tracing::info!(
        budget = cfg.budget,
        iterations = cfg.iterations(),
        points = cfg.points(),
        warm_start = init.is_some(),
        backend = %backend.name(),
        seed_seconds,
        "encode starts"
    );

    let t_loop = Instant::now();
    let evaluations_before = backend.kernel_evaluations();
    let iterations = cfg.iterations();
    let points = cfg.points();
    let reloc_at = cfg.relocation_iterations();
    let n = params.len();
    let mut sampler = PointSampler::new(target.reference, cfg.seed_sample, cfg.point_rule);
    // gsenc's rule maps the model's error every tenth of the run, for the
    // error stratum of the batches after it (points.rs).
    let (maps, map_every) = (sampler.wants_errors(), (iterations / ERROR_MAPS_PER_RUN).max(1));
    let maps_at = |t: usize| maps && t > 0 && t.is_multiple_of(map_every);
    // An iteration that relocates or maps draws its own batch after that:
    // none is drawn ahead of it.
    let draws_own = |t: usize| reloc_at.contains(&t) || maps_at(t);
    let mut adam = Adam::new(n);
    let mut grad: Vec<Primitive> = vec![[0.0; 12]; n];
    let mut relocations = vec![];
    let mut last = LossTerms::default();
    let mut scores: Vec<(usize, f64)> = Vec::new();
    let mut validation_seconds = 0.0;
    let mut phases = LoopPhases::default();
    // Seconds `f` takes, added to `*into`.
    fn timed<T>(into: &mut f64, f: impl FnOnce() -> T) -> T {
        let started = Instant::now();
        let out = f();
        *into += started.elapsed().as_secs_f64();
        out
    }
    let mut score = |t: usize, params: &[Primitive], backend: &mut dyn Backend| -> Result<Option<f64>> {
        let Some(v) = validation else { return Ok(None) };
        let started = Instant::now();
        let psnr = v.psnr(backend, params)?;
        scores.push((t, psnr));
        validation_seconds += started.elapsed().as_secs_f64();
        Ok(Some(psnr))
    };
    // An adaptive step stops when its validation PSNR stops rising
    // (plateau.rs) and keeps its best-scoring parameters.
    let mut plateau = validation.filter(|_| cfg.adaptive).map(|v| Plateau::new(iterations, v.every));
    let mut best: Option<(f64, Vec<Primitive>)> = None;
    // A resident backend keeps the parameters and moments on its device;
    // they come back to the host only when the host needs them. `on_host`
    // says whether the host's copies are current.
    let resident = backend.resident().is_some();
    let mut on_host = true;
    // Resident steps submitted and not yet finished: up to the backend's
    // depth, so that the device runs one while the host waits for another.
    let mut pending = 0usize;
    // A batch drawn beside the last iteration, sorted into the bricks of
    // the backend's point passes (`edge`) there too, so that the iteration
    // that reads it does not sort it first (profiled as work beside the
    // iteration's passes: `benches/scaling_model.py`).
    let mut ahead: Option<PointBatch> = None;
    let draw_ahead = |sampler: &mut PointSampler, edge: Option<f32>| {
        profile::beside(|| {
            let mut batch = sampler.draw(points, target.reference, target.samples);
            if let Some(edge) = edge {
                batch.sort_into_bricks(edge);
            }
            batch
        })
    };
    let terms = |pl: PointLoss, reg: RegTerms| {
        let w = &cfg.weights;
        LossTerms {
            val: pl.val,
            cov: pl.cov,
            scale: reg.scale,
            aniso: reg.aniso,
            total: w.val as f64 * pl.val + w.cov as f64 * pl.cov + w.scale as f64 * reg.scale + w.aniso as f64 * reg.aniso,
        }
    };
    let end = |plateau: &Option<Plateau>| plateau.as_ref().map_or(iterations, Plateau::end);
    let mut t = 0;
    while t < end(&plateau) {
        // The host needs the parameters at a score, a map and a relocation:
        // the steps in flight finish first.
        let scores_at = t % validation.map_or(usize::MAX, |v| v.every) == 0;
        if pending > 0 && (scores_at || maps_at(t) || reloc_at.contains(&t)) {
            if let Some((pl, reg)) = timed(&mut phases.wait, || finish_steps(backend, &mut pending))? {
                last = terms(pl, reg);
            }
        }
        if cfg.cancel.as_ref().is_some_and(Cancel::is_set) {
            finish_steps(backend, &mut pending)?;
            return Err(Error::Cancelled(format!("at iteration {t} of {iterations}")));
        }
        if scores_at {
            to_host(&mut params, &mut adam, &mut on_host, backend)?;
            let psnr = score(t, &params, backend)?;
            if let (Some(p), Some(psnr)) = (plateau.as_mut(), psnr) {
                p.score(t, psnr, cfg.learning_rate);
                if best.as_ref().is_none_or(|b| psnr > b.0) {
                    best = Some((psnr, params.clone()));
                }
            }
        }
        if maps_at(t) {
            to_host(&mut params, &mut adam, &mut on_host, backend)?;
            sampler.map_errors(target.reference, |pos, rho, n| backend.evaluate_points(&params, pos, rho, n))?;
        }
        if reloc_at.contains(&t) {
            to_host(&mut params, &mut adam, &mut on_host, backend)?;
            let batch = timed(&mut phases.draw, || sampler.draw(RELOCATE_POINTS, target.reference, target.samples));
            let r = relocate(backend, &mut params, &mut adam, &batch)?;
            tracing::debug!(iteration = t, moved = r.moved.len(), "relocation");
            let order = spatial_order(&params);
            params = permute(&params, &order);
            adam.m = permute(&adam.m, &order);
            adam.v = permute(&adam.v, &order);
            relocations.push(r);
        }
        let batch = match ahead.take() {
            Some(b) => b,
            None => timed(&mut phases.draw, || sampler.draw(points, target.reference, target.samples)),
        };
        let lr = plateau.as_ref().map_or_else(|| cosine_lr(cfg.learning_rate, t, iterations), |p| p.lr(cfg.learning_rate, t));
        if resident {
            let report = t % LOSS_EVERY == 0 || t + 1 == end(&plateau);
            // The next batch is drawn while the device works, and beside
            // the host's share of the steps when the pool has a second
            // thread (else first: a step is still in flight meanwhile,
            // unless the backend keeps only one). The stream's order stays
            // the host loop's: a relocation draws its own batch first, and
            // an error map changes the draws, so none is drawn ahead of
            // either. (An adaptive step's end moves only at a score, never
            // below the iteration after it.)
            let draw_next = t + 1 < end(&plateau) && !draws_own(t + 1);
            let edge = backend.brick_edge();
            let (next, reported) = rayon::join(
                || draw_next.then(|| timed(&mut phases.draw, || draw_ahead(&mut sampler, edge))),
                || -> Result<Option<(PointLoss, RegTerms)>> {
                    let r = backend.resident().expect("checked above");
                    if on_host {
                        r.load(&params, &adam)?;
                        on_host = false;
                    }
                    timed(&mut phases.submit, || r.submit(&batch, &cfg.weights, lr, report))?;
                    pending += 1;
                    // Then the oldest step in flight finishes, unless there
                    // is room for one more (this one's loss terms come one
                    // iteration late).
                    let mut reported = None;
                    while pending >= r.depth() {
                        pending -= 1;
                        reported = timed(&mut phases.wait, || r.finish())?.or(reported);
                    }
                    Ok(reported)
                },
            );
            ahead = next;
            if let Some((pl, reg)) = reported? {
                last = terms(pl, reg);
            }
        } else {
            // The next batch is drawn (one sequential stream, in the same
            // order as without this) while the pool works on this one, so
            // that drawing does not leave the other cores idle.
            let draw_next = t + 1 < end(&plateau) && !draws_own(t + 1);
            let edge = backend.brick_edge();
            let (pl, next) = rayon::join(
                || backend.point_loss_grad(&params, &batch, &cfg.weights, &mut grad),
                || draw_next.then(|| timed(&mut phases.draw, || draw_ahead(&mut sampler, edge))),
            );
            ahead = next;
            let pl = pl?;
            let reg = adam.step_regularized(&mut params, &mut grad, &cfg.weights, lr);
            last = terms(pl, reg);
        }
        if !last.total.is_finite() {
            finish_steps(backend, &mut pending)?;
            return Err(Error::data(format!("loss is not finite at iteration {t}: {last:?}")));
        }
        profile::iteration_end();
        progress(&Progress { iteration: t + 1, iterations: end(&plateau), loss: last.total });
        t += 1;
    }
    if pending > 0 {
        if let Some((pl, reg)) = timed(&mut phases.wait, || finish_steps(backend, &mut pending))? {
            last = terms(pl, reg);
        }
    }
    to_host(&mut params, &mut adam, &mut on_host, backend)?;
    let last_psnr = score(t, &params, backend)?;
    if let (Some((psnr, kept)), Some(last_psnr)) = (best, last_psnr) {
        if psnr > last_psnr {
            // The last entry of the log scores what the encode returns.
            params = kept;
            if let Some(l) = scores.last_mut() {
                l.1 = psnr;
            }
        }
    }
    if let Err(e) = profile::write() {
        tracing::warn!(error = %e, "cannot write the task profile");
    }
    let run = t;
    let loop_seconds = t_loop.elapsed().as_secs_f64();
    tracing::info!(loop_seconds, loss = last.total, backend = %backend.name(), "encode done");
    Ok(EncodeOutput {
        params,
        iterations: run,
        points,
        warm,
        seeding,
        relocations,
        last_loss: last,
        seed_seconds,
        loop_seconds,
        validation: scores,
        validation_seconds,
        phases,
        kernel_evaluations: backend.kernel_evaluations() - evaluations_before,
        backend: backend.name(),
        fell_back: backend.fell_back(),
    })
}

/// Finishes every resident step in flight, oldest first; returns the loss
/// terms the last reporting one gave.
fn finish_steps(backend: &mut dyn Backend, pending: &mut usize) -> Result<Option<(PointLoss, RegTerms)>> {
    let mut reported = None;
    while *pending > 0 {
        *pending -= 1;
        let r = backend.resident().ok_or_else(|| Error::Device("resident steps in flight on a backend that no longer has them".into()))?;
        reported = r.finish()?.or(reported);
    }
    Ok(reported)
}

/// Brings a resident backend's parameters and moments back to the host,
/// unless the host's copies are current.
fn to_host(params: &mut [Primitive], adam: &mut Adam, on_host: &mut bool, backend: &mut dyn Backend) -> Result<()> {
    if !*on_host {
        if let Some(r) = backend.resident() {
            r.store(params, adam)?;
        }
        *on_host = true;
    }
    Ok(())
}

/// The permutation that sorts primitives by the Morton key of their centres
/// (ties by index, so it is deterministic).
pub fn spatial_order(params: &[Primitive]) -> Vec<usize> {
    let mut keyed: Vec<(u64, usize)> = params.iter().enumerate().map(|(i, p)| (morton_key(p), i)).collect();
    keyed.sort_unstable();
    keyed.into_iter().map(|(_, i)| i).collect()
}

fn permute<T: Clone>(v: &[T], order: &[usize]) -> Vec<T> {
    order.iter().map(|&i| v[i].clone()).collect()
}
