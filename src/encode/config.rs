//! What decides the model an encode produces: the budget, the schedule of
//! iterations and points (METHOD.md "Schedules"), seeds, relocation, the
//! learning rate and loss weights, and the regime of a warm-started step.

use crate::encode::relocate::RELOCATE_AT;
use crate::error::{by_name, Result};
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
    /// gsenc's: matched's 1500 x 3072 at five times the paper's learning
    /// rate, with gsenc's training points ([`PointRule::GSENC`]) and
    /// objective ([`LossWeights::GSENC`]; METHOD.md "Schedules"): at
    /// matched's cost, more than `full` gives.
    Tuned,
    /// gsenc's: full's iterations and points (4000 iterations for
    /// particles) at `tuned`'s learning rate, points and objective: 1.2x
    /// `full`'s cost, for the most quality per primitive (METHOD.md
    /// "Schedules").
    TunedFull,
}

/// How an encode's training points are drawn (METHOD.md "Training points").
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PointRule {
    /// Every point at a voxel centre, with the voxel's own reference value
    /// (gsenc's schedules); `false`: the paper's half-voxel jitter and
    /// trilinear reference values.
    pub on_lattice: bool,
    /// The share of each batch drawn from the occupied voxels in proportion
    /// to the current model's absolute error there, refreshed every tenth
    /// of the run (0: no such stratum, the paper's).
    pub error_share: f32,
}

impl PointRule {
    /// The paper's: jittered points, four strata.
    pub const PAPER: PointRule = PointRule { on_lattice: false, error_share: 0.0 };
    /// gsenc's (`tuned`, `tuned-full`): voxel centres, and 30 % of each
    /// batch where the model is wrong.
    pub const GSENC: PointRule = PointRule { on_lattice: true, error_share: 0.3 };
}

/// The paper's learning rate, of every schedule but `tuned` and `tuned-full`.
pub const PAPER_LEARNING_RATE: f32 = 8e-3;
/// The most points a training batch or a validation set may hold: 2^24, a
/// thousand times the largest batch of the paper's schedules (16,384). A
/// batch takes about 50 bytes a point, so a count beyond this is a mistake
/// rather than a plan, refused before anything is allocated.
pub const MAX_POINTS: usize = 1 << 24;
/// The most iterations an encode may run: 10^7, 2,500 times the longest
/// of the paper's schedules (4,000), some hours at a millisecond an
/// iteration. A count beyond it (an uninitialised 0xCDCDCDCD from C, say)
/// is a mistake rather than a plan: refused before the encode starts,
/// instead of keeping the queue busy for weeks.
pub const MAX_ITERATIONS: usize = 10_000_000;

/// Refuses `iterations` beyond [`MAX_ITERATIONS`]; `what` names them.
pub fn check_iterations(iterations: usize, what: &str) -> crate::error::Result<()> {
    match iterations > MAX_ITERATIONS {
        true => Err(crate::error::Error::arg(format!("{what} {iterations} are more than the {MAX_ITERATIONS} an encode may run"))),
        false => Ok(()),
    }
}
/// The learning rate of the `tuned` and `tuned-full` schedules.
pub const TUNED_LEARNING_RATE: f32 = 0.04;

impl Schedule {
    pub const ALL: [Schedule; 5] = [Schedule::Full, Schedule::Matched, Schedule::Short, Schedule::Tuned, Schedule::TunedFull];

    pub fn from_name(s: &str) -> Result<Schedule> {
        by_name(&Schedule::ALL, Schedule::name, s, "schedule")
    }

    pub fn name(self) -> &'static str {
        match self {
            Schedule::Full => "full",
            Schedule::Matched => "matched",
            Schedule::Short => "short",
            Schedule::Tuned => "tuned",
            Schedule::TunedFull => "tuned-full",
        }
    }
    /// Iterations; `particles` selects the longer full schedule of SPH input.
    pub fn iterations(self, particles: bool) -> usize {
        match self {
            Schedule::Full | Schedule::TunedFull if particles => 4000,
            Schedule::Full | Schedule::TunedFull => 3000,
            Schedule::Matched | Schedule::Tuned => 1500,
            Schedule::Short => 500,
        }
    }
    pub fn points(self) -> usize {
        match self {
            Schedule::Full | Schedule::TunedFull => 16384,
            Schedule::Matched | Schedule::Tuned => 3072,
            Schedule::Short => 8192,
        }
    }
    /// Peak learning rate of the cosine decay.
    pub fn learning_rate(self) -> f32 {
        match self {
            Schedule::Tuned | Schedule::TunedFull => TUNED_LEARNING_RATE,
            _ => PAPER_LEARNING_RATE,
        }
    }
    /// How the schedule draws its training points.
    pub fn point_rule(self) -> PointRule {
        match self {
            Schedule::Tuned | Schedule::TunedFull => PointRule::GSENC,
            _ => PointRule::PAPER,
        }
    }
    /// The schedule's objective (METHOD.md "Objective").
    pub fn loss_weights(self) -> LossWeights {
        match self {
            Schedule::Tuned | Schedule::TunedFull => LossWeights::GSENC,
            _ => LossWeights::PAPER,
        }
    }
}

/// Everything that decides what model an encode produces.
#[derive(Clone, Debug)]
pub struct EncodeConfig {
    /// Number of primitives N; with a `target`, the most it may choose (0:
    /// [`crate::encode::target::default_cap`]).
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
    /// How training points are drawn (the schedule's by default).
    pub point_rule: PointRule,
    pub weights: LossWeights,
    /// True for SPH particle input (longer full schedule).
    pub particles: bool,
    /// An `auto` warm start: begin from the previous model, repaired, or a
    /// fresh seeding, whichever validates best (`repair.rs`), and stop when
    /// the validation PSNR stops rising (`plateau.rs`), `iterations` being
    /// the cap. Needs a validation set.
    pub adaptive: bool,
    /// A quality instead of a budget (`target.rs`): the number of
    /// primitives is chosen to reach this PSNR.
    pub target: Option<TargetPsnr>,
    /// Not part of the model: lets another thread stop the encode between
    /// iterations (it then fails with `Error::Cancelled`).
    pub cancel: Option<Cancel>,
}

/// The voxel PSNR an encode is to reach, as stored (METHOD.md "A quality
/// instead of a budget").
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TargetPsnr {
    /// dB.
    pub db: f64,
    /// How the PSNR rises with the budget and the iterations, when an
    /// earlier step of the series measured it: a warm step that misses its
    /// target corrects its budget with it (else with `DEFAULT_CURVE`).
    pub curve: Option<Curve>,
}

impl TargetPsnr {
    pub fn new(db: f64) -> Result<TargetPsnr> {
        if !(db.is_finite() && db > 0.0 && db <= MAX_TARGET_DB) {
            return Err(crate::error::Error::arg(format!("target PSNR must be more than 0 and at most {MAX_TARGET_DB} dB, got {db:?}")));
        }
        Ok(TargetPsnr { db, curve: None })
    }
}

/// Targets are in (0, MAX_TARGET_DB].
pub const MAX_TARGET_DB: f64 = 120.0;

pub use crate::model::Curve;

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
            learning_rate: schedule.learning_rate(),
            point_rule: schedule.point_rule(),
            weights: schedule.loss_weights(),
            particles: false,
            adaptive: false,
            target: None,
            cancel: None,
        }
    }
    pub fn iterations(&self) -> usize {
        self.iterations.unwrap_or(self.schedule.iterations(self.particles))
    }
    /// What can be checked before there are data: points per iteration
    /// within 1..=[`MAX_POINTS`], iterations at most [`MAX_ITERATIONS`], a
    /// positive learning rate. Every encode checks it; so do a series and
    /// the background queue when they are made, so that a C caller's
    /// create refuses it rather than its first step.
    pub fn check(&self) -> crate::error::Result<()> {
        use crate::error::Error;
        if self.points() == 0 {
            return Err(Error::arg("points per iteration must be at least 1"));
        }
        if self.points() > MAX_POINTS {
            return Err(Error::arg(format!("{} points per iteration are more than the {MAX_POINTS} a batch may hold", self.points())));
        }
        check_iterations(self.iterations(), "iterations")?;
        if !(self.learning_rate.is_finite() && self.learning_rate > 0.0) {
            return Err(Error::arg("learning rate must be positive"));
        }
        Ok(())
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
    /// From the previous model as it is, repaired where it misses the new
    /// step, or a fresh seeding, whichever validates best; the iterations
    /// stop when the validation PSNR stops rising, within the base
    /// schedule's (or the series' warm iterations); no relocation (the
    /// repair is its relocation). The default.
    Auto,
}

impl WarmStart {
    pub const ALL: [WarmStart; 4] = [WarmStart::Off, WarmStart::Coarse, WarmStart::Dense, WarmStart::Auto];

    pub fn from_name(s: &str) -> Result<WarmStart> {
        by_name(&WarmStart::ALL, WarmStart::name, s, "warm start")
    }

    pub fn name(self) -> &'static str {
        match self {
            WarmStart::Off => "off",
            WarmStart::Coarse => "coarse",
            WarmStart::Dense => "dense",
            WarmStart::Auto => "auto",
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
            WarmStart::Auto => {
                cfg.relocation = false;
                cfg.adaptive = true;
            }
        }
        cfg
    }
}

