//! One encode of a given budget: steps 2 to 5 of the pipeline
//! (`pipeline.rs`), and the types every encode shares: how it starts
//! ([`Start`]), what it is asked ([`Request`]) and what it gives
//! ([`Encoded`]). The pipeline calls `encode_budget` once, or the target
//! search (`target.rs`) once per try.

use crate::backend::Backend;
use crate::encode::config::{Curve, EncodeConfig, WarmStart};
use crate::encode::precision::measure_precision;
use crate::encode::refine::{encode_validated, EncodeOutput, Progress};
use crate::encode::stored::decode_as_stored;
use crate::encode::validation::Validation;
use crate::error::Result;
use crate::format::Payload;
use crate::input::{Form, Prepared};
use crate::math::kernel::Primitive;
use crate::model::metrics::voxel_psnr;
use crate::model::{Model, ModelMeta, Support};
use std::time::Instant;

/// How an encode starts.
#[derive(Clone, Copy, Debug)]
pub enum Start<'a> {
    /// Seeded from the prepared input's samples; the base schedule.
    Seeded,
    /// From a previous model's parameters (same budget), with the
    /// iterations and relocation of `regime`, or `iterations` when given.
    Warm { params: &'a [Primitive], regime: WarmStart, iterations: Option<usize> },
}

/// Where a model belongs: stored in its metadata, not used by the encode.
#[derive(Clone, Debug, PartialEq)]
pub struct Labels {
    pub field: String,
    pub step: u64,
    /// Simulation time, when known.
    pub time: Option<f64>,
    /// MPI rank of the piece (0 for a serial run).
    pub rank: u32,
}

impl Default for Labels {
    fn default() -> Labels {
        Labels { field: "scalar".into(), step: 0, time: None, rank: 0 }
    }
}

/// Everything an encode needs besides its input.
#[derive(Clone, Debug)]
pub struct Request<'a> {
    /// Budget, schedule, overrides and seeds of a seeded encode; a warm
    /// start derives its configuration from it ([`config_for`]).
    pub config: EncodeConfig,
    pub start: Start<'a>,
    /// The payload the model will be stored with: its PSNR is measured as stored.
    pub payload: Payload,
    /// Store the support of the reference with the model (gsenc's default),
    /// so that it decodes its outside where the data are empty; `false`: the
    /// paper's model exactly.
    pub store_support: bool,
    pub labels: Labels,
    /// Scored along the way when given (time to quality); does not change the model.
    pub validation: Option<&'a Validation>,
}

impl Request<'_> {
    /// A seeded encode with `config`, stored as float32 with its support,
    /// labelled "scalar" step 0.
    pub fn new(config: EncodeConfig) -> Request<'static> {
        Request { config, start: Start::Seeded, payload: Payload::Float32, store_support: true, labels: Labels::default(), validation: None }
    }
}

/// A finished encode.
pub struct Encoded {
    /// The model as it will be stored: its metadata complete, `encode_psnr`
    /// that of `payload`'s round trip.
    pub model: Model,
    pub output: EncodeOutput,
    /// The configuration the encode ran with.
    pub config: EncodeConfig,
    pub warm_started: bool,
    /// Voxel PSNR of the model as stored against the reference.
    pub psnr: f64,
    /// That of the float32 model, where the payload's precision was
    /// measured against it (packed).
    pub float32_psnr: Option<f64>,
    /// That decode, on the reference lattice (x fastest), for further scores.
    pub decoded: Vec<f32>,
    /// Seconds of the payload round trip and the decode (and of measuring
    /// the packed payload's precision).
    pub decode_seconds: f64,
    /// How the budget was chosen, for an encode with a target PSNR.
    pub target: Option<TargetReport>,
}

/// The configuration an encode of a `form` input runs with.
pub fn config_for(base: &EncodeConfig, form: Form, start: &Start) -> EncodeConfig {
    let mut cfg = match start {
        Start::Seeded => base.clone(),
        Start::Warm { regime, iterations, .. } => {
            let mut c = regime.step_config(base);
            c.iterations = iterations.or(c.iterations);
            c
        }
    };
    cfg.particles = form == Form::Particles;
    cfg
}

/// [`crate::encode::pipeline::encode_prepared`] with the configuration's budget, whatever its target.
pub(crate) fn encode_budget(
    prepared: &Prepared,
    request: &Request,
    backend: &mut dyn Backend,
    progress: &mut dyn FnMut(&Progress),
) -> Result<Encoded> {
    let mut cfg = config_for(&request.config, prepared.form, &request.start);
    if !request.store_support {
        // Voxel-centre points teach nothing about the empty voxels beside
        // the data, which only a stored support zeroes; without one, the
        // paper's jittered points (METHOD.md "Training points").
        cfg.point_rule.on_lattice = false;
    }
    let init = match request.start {
        Start::Seeded => None,
        Start::Warm { params, .. } => Some(params),
    };
    // An adaptive step decides on validation points: its own when the
    // caller scores none.
    let own;
    let validation = match request.validation {
        None if cfg.adaptive => {
            own = auto_validation(prepared, cfg.iterations(), request.store_support)?;
            Some(&own)
        }
        v => v,
    };
    let output = encode_validated(&prepared.target(), &cfg, init, validation, backend, progress)?;

    let l = &request.labels;
    let meta = ModelMeta {
        frame: prepared.frame,
        range: prepared.range,
        field: l.field.clone(),
        step: l.step,
        schedule: match request.start {
            Start::Seeded => cfg.schedule.name().to_owned(),
            Start::Warm { regime, .. } => format!("warm-{}", regime.name()),
        },
        iterations: output.iterations as u32,
        points: output.points as u32,
        seed_init: cfg.seed_init,
        seed_sample: cfg.seed_sample,
        time: l.time,
        rank: l.rank,
        encode_psnr: None,
        fell_back: output.fell_back.clone(),
        warm: output.warm,
        precision: None,
        curve: None,
    };
    let support = request.store_support.then(|| Support::from_reference(&prepared.reference)).flatten();
    let mut model = Model { meta, params: output.params.clone(), support };

    let started = Instant::now();
    let (decoded, psnr, float32_psnr) = if request.payload == Payload::Packed {
        let m = measure_precision(&mut model, &prepared.reference, backend)?;
        (m.decoded, m.psnr, Some(m.float32_psnr))
    } else {
        let stored = decode_as_stored(request.payload, &model, &prepared.reference, backend)?;
        model.support = stored.support;
        let psnr = voxel_psnr(&stored.decoded, &prepared.reference.values);
        (stored.decoded, psnr, None)
    };
    let decode_seconds = started.elapsed().as_secs_f64();
    model.meta.encode_psnr = Some(psnr);
    Ok(Encoded { model, output, config: cfg, warm_started: init.is_some(), psnr, float32_psnr, decoded, decode_seconds, target: None })
}

/// Validation points of an `auto` warm step whose caller scores none.
pub const AUTO_VALIDATION_POINTS: usize = 1 << 14;
const AUTO_VALIDATION_SEED: u64 = 0xa070_5eed;

/// The validation set an `auto` warm step of at most `cap` iterations
/// scores when its caller gives none: `AUTO_VALIDATION_POINTS` voxel
/// centres, scored every `cap / 20` iterations (10 to 50).
fn auto_validation(prepared: &Prepared, cap: usize, support: bool) -> Result<Validation> {
    let every = (cap / 20).clamp(10, 50);
    let v = Validation::from_reference(&prepared.reference, AUTO_VALIDATION_POINTS, AUTO_VALIDATION_SEED, every)?;
    Ok(Validation { support, ..v })
}

/// One model the search trained.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Try {
    pub budget: usize,
    /// Voxel PSNR as stored (a probe's: as float32).
    pub psnr: f64,
    /// Iterations of this encode (a grown model's: after those it had).
    pub iterations: usize,
    pub seconds: f64,
}

/// How a target-PSNR encode chose its budget (`target.rs`).
#[derive(Clone, Debug)]
pub struct TargetReport {
    pub target: f64,
    /// The chosen model's PSNR is within the landing band of the target.
    pub landed: bool,
    /// The most primitives the search could choose.
    pub cap: usize,
    /// The short probes (none for a warm-started step).
    pub probes: Vec<Try>,
    /// The full-length models: the predicted budget's (or a warm step's),
    /// then each correction.
    pub tries: Vec<Try>,
    /// Which of `tries` is the model.
    pub chosen: usize,
    /// What the corrections went by (the probes', the series', or
    /// `DEFAULT_CURVE`).
    pub curve: Curve,
    /// Seconds of the whole search, probes and corrections included.
    pub seconds: f64,
}
