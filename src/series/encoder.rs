//! The series encoder (METHOD.md "Warm start"): per field, the last model
//! and the series' value range and index frame. Step t+1 of a field starts
//! from step t's model (arrays copied, no seeding, same N, same range) or,
//! with warm starts off, is encoded on its own; either way through the one
//! encode pipeline ([`crate::encode::pipeline`]). Every step comes out as a
//! complete model, scored as stored. No I/O: the caller stores the models.

use crate::backend::Backend;
use crate::encode::pipeline::{encode_prepared, Encoded, Labels, Request, Start};
use crate::encode::{EncodeConfig, Progress, Validation, WarmStart};
use crate::error::{Error, Result};
use crate::field::{Bounds, IndexFrame, Transform, ValueRange};
use crate::format::{check_field_name, Payload};
use crate::input::{prepare, Input, Prepared, RangeSpec};
use crate::model::Model;
use std::collections::BTreeMap;

/// The value range of a series.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum SeriesRange {
    /// Given by the user for every step.
    Fixed(ValueRange),
    /// Taken from the first step's data (after the transform); later steps
    /// clamp values outside it and count them.
    FirstStep(Transform),
}

impl From<RangeSpec> for SeriesRange {
    /// A series' range from a single encode's: a fixed range for every
    /// step, or, from the data, the first step's.
    fn from(spec: RangeSpec) -> SeriesRange {
        match spec {
            RangeSpec::Fixed(r) => SeriesRange::Fixed(r),
            RangeSpec::FromData(t) => SeriesRange::FirstStep(t),
        }
    }
}

#[derive(Clone, Debug)]
pub struct SeriesConfig {
    /// Budget, schedule and seeds of the first step and of independent steps.
    pub encode: EncodeConfig,
    pub warm: WarmStart,
    pub range: SeriesRange,
    /// Points of the fixed validation set (drawn once per field, on the first
    /// step's lattice, scored against each step's own reference) and how
    /// often they are scored; 0 points: no validation log (in situ, where
    /// nobody reads it and it costs time).
    pub validation_points: usize,
    pub validation_every: usize,
    pub validation_seed: u64,
    /// Iterations of a warm-started step instead of its regime's (1000
    /// coarse, 1500 dense), to trade quality for time per step.
    pub warm_iterations: Option<usize>,
    /// The payload models are stored with; their PSNR is measured as stored.
    pub payload: Payload,
    /// MPI rank recorded in the models (0 for a serial run).
    pub rank: u32,
    /// Store each step's support with its model (METHOD.md "Support");
    /// `false`: the paper's models exactly.
    pub store_support: bool,
}

impl SeriesConfig {
    pub fn new(encode: EncodeConfig, warm: WarmStart, range: SeriesRange) -> SeriesConfig {
        SeriesConfig { encode, warm, range, validation_points: 1 << 16, validation_every: 50, validation_seed: 0x7a11_da7e, warm_iterations: None, payload: Payload::Float32, rank: 0, store_support: true }
    }

    /// Whether a series of this configuration can continue from `model`:
    /// it needs a field name and primitives, this rank's, and the
    /// configured value range (a fixed range, or a transform).
    pub fn check_resumable(&self, model: &Model) -> Result<()> {
        let (field, step) = (&model.meta.field, model.meta.step);
        check_field_name(field)?;
        if model.params.is_empty() {
            return Err(Error::data(format!("the model of field '{field}' step {step} holds no primitives")));
        }
        if model.meta.rank != self.rank {
            return Err(Error::arg(format!("field '{field}' step {step}: the model is rank {}'s piece; this is rank {}", model.meta.rank, self.rank)));
        }
        let range = model.meta.range;
        let mismatch = match self.range {
            SeriesRange::Fixed(r) => (r != range).then(|| format!("[{}, {}] ({})", r.vmin, r.vmax, r.transform.name())),
            SeriesRange::FirstStep(t) => (t != range.transform).then(|| format!("a range of the {} transform", t.name())),
        };
        match mismatch {
            Some(want) => Err(Error::arg(format!(
                "field '{field}' step {step}: the model's value range [{}, {}] ({}) is not the configured {want}; a resumed series keeps its range",
                range.vmin,
                range.vmax,
                range.transform.name()
            ))),
            None => Ok(()),
        }
    }
}

/// What one step produced.
pub struct StepResult {
    /// The step's input as the encoder saw it: its reference (for scoring),
    /// the values clamped into the series' range, the particles or cells
    /// outside the series' box (they seed nothing; their support is clipped:
    /// data that move out of the first step's box need bounds that cover the
    /// whole series).
    pub prepared: Prepared,
    /// The model as stored, scored, and how its encode went.
    pub encoded: Encoded,
}

/// Per-field state carried from step to step.
struct FieldState {
    range: ValueRange,
    frame: IndexFrame,
    /// The world box particles or cells are deposited in (their first step's).
    bounds: Option<Bounds>,
    /// Drawn on the first step encoded here (a resumed series draws the same
    /// points: they depend only on the lattice and the seed).
    validation: Option<Validation>,
    /// The previous step's model; with a target PSNR its curve (how the
    /// PSNR rises with the budget, as the first step's search measured it)
    /// corrects the next warm step's budget.
    last: Model,
}

/// Encodes steps of any number of fields, each warm-started from its own
/// previous step.
pub struct SeriesEncoder {
    cfg: SeriesConfig,
    fields: BTreeMap<String, FieldState>,
    /// Ranges agreed elsewhere (across MPI ranks) for fields not begun yet.
    agreed_ranges: BTreeMap<String, ValueRange>,
}

impl SeriesEncoder {
    pub fn new(cfg: SeriesConfig) -> Result<SeriesEncoder> {
        if cfg.validation_points > 0 && cfg.validation_every == 0 {
            return Err(Error::arg("validation needs a positive interval"));
        }
        cfg.encode.check()?;
        if let Some(w) = cfg.warm_iterations {
            crate::encode::config::check_iterations(w, "warm iterations")?;
        }
        Ok(SeriesEncoder { cfg, fields: BTreeMap::new(), agreed_ranges: BTreeMap::new() })
    }

    /// The range of `field`'s series, once its first step is encoded.
    pub fn range(&self, field: &str) -> Option<ValueRange> {
        self.fields.get(field).map(|f| f.range)
    }

    /// Sets the range of `field`'s series before its first step (a range
    /// agreed across the ranks of an MPI run). A field with steps keeps the
    /// range it has.
    pub fn set_range(&mut self, field: &str, range: ValueRange) {
        if !self.fields.contains_key(field) {
            self.agreed_ranges.insert(field.to_owned(), range);
        }
    }

    /// The last model of `field`.
    pub fn last_model(&self, field: &str) -> Option<&Model> {
        self.fields.get(field).map(|f| &f.last)
    }

    /// Continues a series from `model`, its last stored step (a restart from
    /// a checkpoint): the field's next step starts from it, on its lattice
    /// and value range, exactly as if the series had not stopped. Particles
    /// and cells of later steps are deposited on the model's lattice, as
    /// the first step's box put them (through bounds that give it back bit
    /// for bit, [`IndexFrame::exact_bounds`]); a grid must come on it.
    /// Refuses what [`SeriesConfig::check_resumable`] refuses, and a field
    /// with steps.
    pub fn resume(&mut self, model: Model) -> Result<()> {
        self.cfg.check_resumable(&model)?;
        let field = model.meta.field.clone();
        if self.fields.contains_key(&field) {
            return Err(Error::arg(format!("field '{field}' already has steps in this series; resume before the first")));
        }
        if self.cfg.encode.target.is_some() && model.meta.curve.is_none() {
            // A model from before model file 1.5, or of an encode to a budget.
            tracing::warn!(field = %field, step = model.meta.step, "the model holds no target curve: the next steps correct their budget with the default slopes, not the ones the series measured");
        }
        let (range, frame) = (model.meta.range, model.meta.frame);
        self.fields.insert(field, FieldState { range, frame, bounds: frame.exact_bounds(), validation: None, last: model });
        Ok(())
    }

    /// Encodes step `step` (simulation time `time`) of `field`. Steps of a
    /// field must come in increasing order, on the lattice of its first step.
    pub fn encode_step(
        &mut self,
        field: &str,
        step: u64,
        time: Option<f64>,
        input: Input,
        backend: &mut dyn Backend,
        progress: &mut dyn FnMut(&Progress),
    ) -> Result<StepResult> {
        if field.is_empty() {
            return Err(Error::arg("a series step needs a field name"));
        }
        let state = self.fields.get(field);
        if let Some(s) = state {
            if step <= s.last.meta.step {
                return Err(Error::arg(format!(
                    "field '{field}': step {step} does not follow step {} (steps must increase)",
                    s.last.meta.step
                )));
            }
        }
        let range_spec = match (state, self.cfg.range) {
            (Some(s), _) => RangeSpec::Fixed(s.range),
            (None, _) if self.agreed_ranges.contains_key(field) => RangeSpec::Fixed(self.agreed_ranges[field]),
            (None, SeriesRange::Fixed(r)) => RangeSpec::Fixed(r),
            (None, SeriesRange::FirstStep(t)) => RangeSpec::FromData(t),
        };
        // Particles and cells of every step go into the first step's box.
        let prepared = prepare(&input.with_bounds(state.and_then(|s| s.bounds)), &range_spec)?;
        if let Some(s) = state {
            if prepared.frame.dims != s.frame.dims {
                return Err(Error::arg(format!(
                    "field '{field}' step {step}: grid of {:?} voxels, but the series is on {:?}; every step of a field must share its lattice",
                    prepared.frame.dims, s.frame.dims
                )));
            }
            if prepared.frame != s.frame {
                return Err(Error::arg(format!(
                    "field '{field}' step {step}: the grid's box (origin {:?}, {} voxels per unit) is not the series' (origin {:?}, {} per unit); every step of a field must share its lattice",
                    prepared.frame.bmin, prepared.frame.gamma, s.frame.bmin, s.frame.gamma
                )));
            }
        }
        // The same points every step (drawn on the first), this step's values.
        let validation = match state.and_then(|s| s.validation.as_ref()) {
            Some(v) => Some(v.rescored(&prepared.reference)),
            None if self.cfg.validation_points == 0 => None,
            None => Some(Validation {
                support: self.cfg.store_support,
                ..Validation::from_reference(
                    &prepared.reference,
                    self.cfg.validation_points,
                    self.cfg.validation_seed,
                    self.cfg.validation_every,
                )?
            }),
        };
        let start = match state.filter(|_| self.cfg.warm != WarmStart::Off) {
            Some(s) => Start::Warm { params: &s.last.params, regime: self.cfg.warm, iterations: self.cfg.warm_iterations },
            None => Start::Seeded,
        };
        // A target's warm step corrects its budget with the slope measured before.
        let mut config = self.cfg.encode.clone();
        if let (Some(t), Some(s)) = (config.target.as_mut(), state) {
            t.curve = s.last.meta.curve;
        }
        let request = Request {
            config,
            start,
            payload: self.cfg.payload,
            store_support: self.cfg.store_support,
            labels: Labels { field: field.to_owned(), step, time, rank: self.cfg.rank },
            validation: validation.as_ref(),
        };
        let encoded = encode_prepared(&prepared, &request, backend, progress)?;
        let bounds = state.map_or(prepared.bounds, |s| s.bounds);
        let (range, frame, last) = (prepared.range, prepared.frame, encoded.model.clone());
        self.fields.insert(field.to_owned(), FieldState { range, frame, bounds, validation, last });
        Ok(StepResult { prepared, encoded })
    }
}
