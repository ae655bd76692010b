//! Time series (SPEC.md "Warm start"): per field, the last model and the
//! series' value range and index frame. Step t+1 of a field starts from step
//! t's model (arrays copied, no seeding, same N, same range) or, with warm
//! starts off, is encoded on its own. Every step comes out as a complete
//! model. No I/O: the caller stores the models (`io::store`).

use crate::backend::Backend;
use crate::cells::Cells;
use crate::encoder::{encode_validated, EncodeConfig, EncodeOutput, Progress, Target, Validation};
use crate::error::{Error, Result};
use crate::field::{Grid, IndexFrame, Transform, ValueRange};
use crate::model::{Model, ModelMeta};
use crate::particles::Particles;
use crate::reference::{prepare_cells, prepare_particles, Bounds, Placement, Prepared, RangeSpec};
use crate::samples::GridSamples;
use std::collections::BTreeMap;

/// How a step after the first starts.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum WarmStart {
    /// Every step seeded and encoded on its own, with the base schedule.
    Off,
    /// From the previous model: 1000 iterations, no relocation (coarse stride).
    Coarse,
    /// From the previous model: 1500 iterations with relocation (dense stride).
    Dense,
}

impl WarmStart {
    pub fn from_name(s: &str) -> Result<WarmStart> {
        match s {
            "off" => Ok(WarmStart::Off),
            "coarse" => Ok(WarmStart::Coarse),
            "dense" => Ok(WarmStart::Dense),
            _ => Err(Error::arg(format!("unknown warm start '{s}' (off, coarse, dense)"))),
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            WarmStart::Off => "off",
            WarmStart::Coarse => "coarse",
            WarmStart::Dense => "dense",
        }
    }

    /// The configuration of a warm-started step, from the series' base one.
    pub fn step_config(self, base: &EncodeConfig) -> EncodeConfig {
        let mut cfg = base.clone();
        match self {
            WarmStart::Off => {}
            WarmStart::Coarse => {
                cfg.iterations = Some(1000);
                cfg.relocation = false;
            }
            WarmStart::Dense => {
                cfg.iterations = Some(1500);
                cfg.relocation = true;
            }
        }
        cfg
    }
}

/// The value range of a series.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum SeriesRange {
    /// Given by the user for every step.
    Fixed(ValueRange),
    /// Taken from the first step's data (after the transform); later steps
    /// clamp values outside it and count them.
    FirstStep(Transform),
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
}

impl SeriesConfig {
    pub fn new(encode: EncodeConfig, warm: WarmStart, range: SeriesRange) -> SeriesConfig {
        SeriesConfig { encode, warm, range, validation_points: 1 << 16, validation_every: 50, validation_seed: 0x7a11_da7e, warm_iterations: None }
    }
}

/// One step's input, in data units.
pub enum StepInput<'a> {
    /// A regular grid over `frame`.
    Grid { values: &'a Grid, frame: IndexFrame },
    /// SPH particles, deposited on `placement` at the field's first step;
    /// later steps reuse the first step's frame, whatever `placement` says.
    Particles { particles: &'a Particles<'a>, placement: Placement },
    /// SPH particles deposited as for `Particles`, then encoded as a grid:
    /// seeded from the deposit's voxels instead of the particles.
    ParticleDeposit { particles: &'a Particles<'a>, placement: Placement },
    /// Hexahedral cells, placed like particles.
    Cells { cells: &'a Cells<'a>, placement: Placement },
}

/// What one step produced.
pub struct StepResult {
    pub model: Model,
    pub output: EncodeOutput,
    /// Whether the step started from the previous model.
    pub warm_started: bool,
    /// Values clamped into the series' range at this step.
    pub clamped_values: usize,
    /// The normalised reference the step was fitted to, for scoring.
    pub reference: Grid,
    /// Particles or cells outside the series' box at this step (they seed
    /// nothing; their support is clipped). Data that move out of the first
    /// step's box need bounds that cover the whole series.
    pub outside_items: usize,
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
    /// and cells of later steps must be placed in the same box (give the
    /// bounds), which the frame check of `encode_step` enforces.
    pub fn resume(&mut self, model: Model) -> Result<()> {
        let field = model.meta.field.clone();
        if field.is_empty() {
            return Err(Error::arg("a resumed model needs a field name"));
        }
        if self.fields.contains_key(&field) {
            return Err(Error::arg(format!("field '{field}' already has steps in this series; resume before the first")));
        }
        if model.params.is_empty() {
            return Err(Error::data(format!("the model of field '{field}' holds no primitives")));
        }
        let (range, frame) = (model.meta.range, model.meta.frame);
        self.fields.insert(field, FieldState { range, frame, bounds: None, validation: None, last: model });
        Ok(())
    }

    /// Encodes step `step` (simulation time `time`) of `field`. Steps of a
    /// field must come in increasing order, on the lattice of its first step.
    pub fn encode_step(
        &mut self,
        field: &str,
        step: u64,
        time: Option<f64>,
        input: StepInput,
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
        let prepared = prepare_step(&input, state.and_then(|s| s.bounds), &range_spec)?;
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
            None => Some(Validation::from_reference(
                &prepared.reference,
                self.cfg.validation_points,
                self.cfg.validation_seed,
                self.cfg.validation_every,
            )?),
        };
        let warm = state.filter(|_| self.cfg.warm != WarmStart::Off).map(|s| s.last.params.as_slice());
        let cfg = match warm {
            Some(_) => {
                let mut c = self.cfg.warm.step_config(&self.cfg.encode);
                c.iterations = self.cfg.warm_iterations.or(c.iterations);
                c
            }
            None => self.cfg.encode.clone(),
        };
        let samples_grid;
        let target = match &prepared.samples {
            Some(s) => Target { reference: &prepared.reference, samples: s.as_ref() },
            None => {
                samples_grid = GridSamples { grid: &prepared.reference };
                Target { reference: &prepared.reference, samples: &samples_grid }
            }
        };
        let output = encode_validated(&target, &cfg, warm, validation.as_ref(), backend, progress)?;
        let mut meta = ModelMeta::new(prepared.frame, prepared.range);
        meta.field = field.to_owned();
        meta.step = step;
        meta.time = time;
        meta.schedule = match warm {
            Some(_) => format!("warm-{}", self.cfg.warm.name()),
            None => cfg.schedule.name().to_owned(),
        };
        meta.iterations = output.iterations as u32;
        meta.points = output.points as u32;
        meta.seed_init = cfg.seed_init;
        meta.seed_sample = cfg.seed_sample;
        let model = Model { meta, params: output.params.clone() };
        let warm_started = warm.is_some();
        let bounds = state.map_or(prepared.bounds, |s| s.bounds);
        let (range, frame) = (prepared.range, prepared.frame);
        self.fields.insert(field.to_owned(), FieldState { range, frame, bounds, validation, last: model.clone() });
        Ok(StepResult { model, output, warm_started, clamped_values: prepared.clamped_values,
            reference: prepared.reference,
            outside_items: prepared.outside_items,
        })
    }
}

/// A step's reference, samples (for particles and cells), frame and range.
struct PreparedStep {
    reference: Grid,
    samples: Option<Box<dyn crate::samples::SampleSet>>,
    frame: IndexFrame,
    range: ValueRange,
    bounds: Option<Bounds>,
    clamped_values: usize,
    outside_items: usize,
}

fn prepare_step(input: &StepInput, series_bounds: Option<Bounds>, range: &RangeSpec) -> Result<PreparedStep> {
    let from_items = |p: Prepared, bounds: Bounds| PreparedStep {
        reference: p.reference,
        samples: Some(Box::new(p.samples)),
        frame: p.frame,
        range: p.range,
        bounds: Some(bounds),
        clamped_values: p.clamped_values,
        outside_items: p.deposit.outside,
    };
    match input {
        StepInput::Grid { values, frame } => {
            if values.dims != frame.dims {
                return Err(Error::arg(format!("grid of {:?} voxels, frame of {:?}", values.dims, frame.dims)));
            }
            let range = range.resolve(&values.values)?;
            let norm = range.normalize(&values.values)?;
            Ok(PreparedStep {
                reference: Grid::new(values.dims, norm.values)?,
                samples: None,
                frame: *frame,
                range,
                bounds: None,
                clamped_values: norm.clamped,
                outside_items: 0,
            })
        }
        StepInput::Particles { particles, placement } | StepInput::ParticleDeposit { particles, placement } => {
            let bounds = series_bounds.or(placement.bounds).unwrap_or_else(|| particles.bounds());
            let placement = Placement { dims: placement.dims, bounds: Some(bounds) };
            let mut step = from_items(prepare_particles(particles, &placement, range)?, bounds);
            if matches!(input, StepInput::ParticleDeposit { .. }) {
                step.samples = None;
            }
            Ok(step)
        }
        StepInput::Cells { cells, placement } => {
            let bounds = series_bounds.or(placement.bounds).unwrap_or_else(|| cells.bounds());
            let placement = Placement { dims: placement.dims, bounds: Some(bounds) };
            Ok(from_items(prepare_cells(cells, &placement, range)?, bounds))
        }
    }
}
