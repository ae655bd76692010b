//! The one encode pipeline. Every caller takes this path: `gsenc encode`
//! through [`encode`], the series encoder (and so `gsenc encode-series`, the
//! background queue, the C API and MPI) through [`encode_prepared`].
//!
//! 1. **Prepare** the input ([`crate::input::prepare`]): the index frame,
//!    the value range, the samples and the reference grid.
//! 2. **Resolve the configuration** ([`config_for`]): the schedule's length
//!    follows the input's form (the `full` schedule runs longer for
//!    particles), a warm start follows its regime.
//! 3. **Encode**: seeded from the samples, or warm-started from a previous
//!    model's parameters ([`crate::encode::refine`]).
//! 4. **Build the model**: its metadata, and its support (where the
//!    reference holds data; METHOD.md "Support") unless the request asks
//!    for the paper's model.
//! 5. **Score the model as it will be stored**: for the packed payload,
//!    first measure the precision it needs ([`crate::encode::precision`]);
//!    then the payload's round trip, decoded on the reference lattice with
//!    the support, against the reference.
//!
//! No I/O: the caller writes the model ([`crate::io`]).

use crate::backend::Backend;
use crate::encode::config::{EncodeConfig, WarmStart};
use crate::encode::precision::measure_precision;
use crate::encode::refine::{encode_validated, EncodeOutput, Progress};
pub use crate::encode::stored::decode_as_stored;
use crate::encode::validation::Validation;
use crate::error::Result;
use crate::format::Payload;
use crate::input::{prepare, Form, Input, Prepared, RangeSpec};
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
    /// so that it decodes to zero where the data are empty; `false`: the
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

/// Prepares `input` and encodes it: the whole pipeline for one field of one step.
pub fn encode(
    input: &Input,
    range: &RangeSpec,
    request: &Request,
    backend: &mut dyn Backend,
    progress: &mut dyn FnMut(&Progress),
) -> Result<(Prepared, Encoded)> {
    let prepared = prepare(input, range)?;
    let encoded = encode_prepared(&prepared, request, backend, progress)?;
    Ok((prepared, encoded))
}

/// Encodes a prepared input, scores the model as stored and builds it.
pub fn encode_prepared(
    prepared: &Prepared,
    request: &Request,
    backend: &mut dyn Backend,
    progress: &mut dyn FnMut(&Progress),
) -> Result<Encoded> {
    let cfg = config_for(&request.config, prepared.form, &request.start);
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
    };
    let support = request.store_support.then(|| Support::from_reference(&prepared.reference)).flatten();
    let mut model = Model { meta, params: output.params.clone(), support };

    let started = Instant::now();
    let (decoded, psnr, float32_psnr) = if request.payload == Payload::Packed {
        let m = measure_precision(&mut model, &prepared.reference, backend)?;
        (m.decoded, m.psnr, Some(m.float32_psnr))
    } else {
        let decoded = decode_as_stored(request.payload, &model, backend)?;
        let psnr = voxel_psnr(&decoded, &prepared.reference.values);
        (decoded, psnr, None)
    };
    let decode_seconds = started.elapsed().as_secs_f64();
    model.meta.encode_psnr = Some(psnr);
    Ok(Encoded { model, output, config: cfg, warm_started: init.is_some(), psnr, float32_psnr, decoded, decode_seconds })
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
