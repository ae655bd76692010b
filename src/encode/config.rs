//! What decides the model an encode produces: the budget, the schedule of
//! iterations and points (METHOD.md "Schedules"), seeds, relocation, the
//! learning rate and loss weights, and the regime of a warm-started step.

use crate::encode::relocate::RELOCATE_AT;
use crate::error::{Error, Result};
use crate::math::loss::LossWeights;

/// Named iteration x point schedules (METHOD.md "Schedules").
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Schedule {
    /// 3000 x 16384 (4000 iterations for particles).
    Full,
    /// 1500 x 3072: the grid-seeded encoder's published training budget.
    Matched,
    /// 500 x 8192 (the paper also runs 300 x 8192: `--iters 300`).
    Short,
}

impl Schedule {
    pub const ALL: [Schedule; 3] = [Schedule::Full, Schedule::Matched, Schedule::Short];

    pub fn from_name(s: &str) -> Result<Schedule> {
        Schedule::ALL
            .into_iter()
            .find(|v| v.name() == s)
            .ok_or_else(|| Error::arg(format!("unknown schedule '{s}' (full, matched, short)")))
    }

    pub fn name(self) -> &'static str {
        match self {
            Schedule::Full => "full",
            Schedule::Matched => "matched",
            Schedule::Short => "short",
        }
    }
    /// Iterations; `particles` selects the longer full schedule of SPH input.
    pub fn iterations(self, particles: bool) -> usize {
        match self {
            Schedule::Full if particles => 4000,
            Schedule::Full => 3000,
            Schedule::Matched => 1500,
            Schedule::Short => 500,
        }
    }
    pub fn points(self) -> usize {
        match self {
            Schedule::Full => 16384,
            Schedule::Matched => 3072,
            Schedule::Short => 8192,
        }
    }
}

/// Everything that decides what model an encode produces.
#[derive(Clone, Debug)]
pub struct EncodeConfig {
    /// Number of primitives N.
    pub budget: usize,
    pub schedule: Schedule,
    /// Overrides of the schedule's iterations and points per iteration.
    pub iterations: Option<usize>,
    pub points: Option<usize>,
    /// Seed of the seeding draws (0 by default).
    pub seed_init: u64,
    /// Seed of the point sampler (1 by default).
    pub seed_sample: u64,
    /// Relocation passes at 35, 55 and 75 % of the iterations.
    pub relocation: bool,
    pub learning_rate: f32,
    /// What the encode fits: the loss terms and the training strata.
    pub objective: Objective,
    /// True for SPH particle input (longer full schedule); the pipeline
    /// sets it from the input's form.
    pub particles: bool,
    /// Not part of the model: lets another thread stop the encode between
    /// iterations (it then fails with `Error::Cancelled`).
    pub cancel: Option<Cancel>,
}

/// What an encode fits (METHOD.md "Objective").
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Objective {
    /// gsenc's default: the paper's four terms and `L_empty`, which pulls the
    /// decoded value to the reference where the reference is empty, on
    /// training points that include a band around the data's support.
    #[default]
    Field,
    /// The paper's objective and training strata exactly: nothing looks at
    /// empty space.
    Paper,
}

/// Weight of `L_empty` in the `field` objective (METHOD.md "Objective").
pub const EMPTY_WEIGHT: f32 = 1.0;
/// Share of the training points drawn from the band around the support.
pub const BAND_SHARE: f64 = 0.10;
/// Width of that band, in voxels.
pub const BAND_VOXELS: usize = 4;

fn experiment<T: std::str::FromStr>(name: &str, default: T) -> T {
    std::env::var(name).ok().and_then(|v| v.parse().ok()).unwrap_or(default)
}

impl Objective {
    pub const ALL: [Objective; 2] = [Objective::Field, Objective::Paper];

    pub fn name(self) -> &'static str {
        match self {
            Objective::Field => "field",
            Objective::Paper => "paper",
        }
    }

    pub fn from_name(s: &str) -> Result<Objective> {
        Objective::ALL
            .into_iter()
            .find(|v| v.name() == s)
            .ok_or_else(|| Error::arg(format!("unknown objective '{s}' (field, paper)")))
    }

    /// The weights of the loss terms.
    pub fn weights(self) -> LossWeights {
        match self {
            Objective::Paper => LossWeights::default(),
            Objective::Field => LossWeights { empty: experiment("GSENC_EXP_EMPTY", EMPTY_WEIGHT), ..LossWeights::default() },
        }
    }

    /// The band stratum of the training points: its share, and its width in
    /// voxels (no band in the paper's strata).
    pub fn band(self) -> (f64, usize) {
        match self {
            Objective::Paper => (0.0, 0),
            Objective::Field => (experiment("GSENC_EXP_BAND_SHARE", BAND_SHARE), experiment("GSENC_EXP_BAND_VOXELS", BAND_VOXELS)),
        }
    }
}

/// A flag another thread sets to stop an encode.
#[derive(Clone, Debug, Default)]
pub struct Cancel(std::sync::Arc<std::sync::atomic::AtomicBool>);

impl Cancel {
    pub fn set(&self, on: bool) {
        self.0.store(on, std::sync::atomic::Ordering::SeqCst);
    }
    pub fn is_set(&self) -> bool {
        self.0.load(std::sync::atomic::Ordering::SeqCst)
    }
}

impl EncodeConfig {
    pub fn new(budget: usize, schedule: Schedule) -> EncodeConfig {
        EncodeConfig {
            budget,
            schedule,
            iterations: None,
            points: None,
            seed_init: 0,
            seed_sample: 1,
            relocation: true,
            learning_rate: 8e-3,
            objective: Objective::default(),
            particles: false,
            cancel: None,
        }
    }
    pub fn iterations(&self) -> usize {
        self.iterations.unwrap_or(self.schedule.iterations(self.particles))
    }
    pub fn points(&self) -> usize {
        self.points.unwrap_or(self.schedule.points())
    }
    /// Iterations at which relocation runs (empty when disabled).
    pub fn relocation_iterations(&self) -> Vec<usize> {
        if !self.relocation {
            return vec![];
        }
        let t = self.iterations();
        RELOCATE_AT.iter().map(|f| (f * t as f64).floor() as usize).filter(|&i| i < t).collect()
    }
}

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
    pub const ALL: [WarmStart; 3] = [WarmStart::Off, WarmStart::Coarse, WarmStart::Dense];

    pub fn from_name(s: &str) -> Result<WarmStart> {
        WarmStart::ALL
            .into_iter()
            .find(|v| v.name() == s)
            .ok_or_else(|| Error::arg(format!("unknown warm start '{s}' (off, coarse, dense)")))
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

