//! A quality instead of a budget (METHOD.md "A quality instead of a
//! budget"): the number of primitives chosen so that the model, as stored,
//! reaches a voxel PSNR.
//!
//! Over the range that matters, a model's PSNR rises about linearly with the
//! logarithm of its budget, and with the logarithm of its iterations, by
//! slopes of each dataset's own (BENCHMARKS.md, "Quality per byte" and "A
//! quality instead of a budget"). So:
//!
//! 1. **Probe**: at a first budget (from the occupied voxels), and at four
//!    times or a quarter of it (towards the target), two short seeded
//!    encodes of a quarter and half of the schedule's iterations. Per
//!    budget, their difference extrapolates to the whole schedule; across
//!    the two budgets, the full-length PSNR's slope per doubling.
//! 2. **Predict**: from the probe budget nearer the aim (`target +
//!    AIM_DB`), the budget that slope says reaches it, within
//!    `[MIN_BUDGET, cap]`, encoded with the whole schedule.
//! 3. **Correct**, when that model does not land (`target - LANDS_BELOW_DB`
//!    to `target + LANDS_ABOVE_DB`), at most `MAX_CORRECTIONS` times: a
//!    fresh encode of the budget the slope says (between two tries on either
//!    side of the aim, their own slope). The model is then exactly what a
//!    fixed-budget encode of its budget gives.
//!
//! A warm-started step of a series skips 1 and 2: it keeps the previous
//! step's budget and grows it only when it falls short of the target: by
//! insertion where it misses (`insert.rs`; by `MIN_GROWTH` to `MAX_FACTOR`
//! times, to what the series' slopes say, else `DEFAULT_CURVE`'s), trained
//! on for half the schedule (with relocation unless the request has none),
//! and not grown again once a growth lost PSNR (`growth_pays`).
//! One above the target keeps its budget: a fresh encode of fewer
//! primitives would lose what the series' training built (a test series:
//! 88 primitives warm, 42.4 dB; 34 fresh, 34.4 dB, against 40), and the
//! next steps' training adds to it again.
//!
//! Why a seeded encode is not grown by insertion too: a grown model trains
//! longer than a fresh one, and what that gains varies too much to predict
//! (hydrogen, `matched` cut to 600 iterations: 125 primitives fresh 39.0
//! dB, grown to 157 and trained 300 more 43.5 dB, where the slope says
//! 40.2; at the full 1,500 iterations, 620 primitives trained 750 more
//! gain 0.5 dB), so its corrections overshoot and undershoot in turn.
//!
//! The model kept is the one that landed; when none did, the smallest that
//! reached `target - LANDS_BELOW_DB`, else the best. The report says which,
//! with every probe and try. A target beyond what the schedule reaches ends
//! at the cap, reported as not landed.

use crate::backend::Backend;
pub use crate::encode::config::{Curve, MAX_TARGET_DB};
use crate::encode::config::{EncodeConfig, TargetPsnr, WarmStart};
use crate::encode::fixed::{config_for, encode_budget, Encoded, Request, Start};
pub use crate::encode::fixed::{TargetReport, Try};
use crate::encode::insert::grow;
use crate::encode::Progress;
use crate::error::Result;
use crate::format::Payload;
use crate::input::Prepared;
use crate::math::kernel::Primitive;
use crate::math::loss::MASK_REF;
use serde_json::{json, Value};
use std::time::Instant;

/// The search aims this far above the target.
pub const AIM_DB: f64 = 0.25;
/// A model lands when its PSNR is at most this far below the target...
pub const LANDS_BELOW_DB: f64 = 0.5;
/// ...and at most this far above it.
pub const LANDS_ABOVE_DB: f64 = 1.0;
/// Probes run this share of the schedule's iterations, and twice it (at
/// least `MIN_ITERATIONS`); a growing correction trains twice it.
pub const PROBE_SHARE: f64 = 0.25;
pub const MIN_ITERATIONS: usize = 100;
/// The fewest primitives the search chooses.
pub const MIN_BUDGET: usize = 16;
/// The first probe's budget: one primitive per this many occupied voxels,
/// and at least `MIN_PROBE` (the PSNR of fewer is mostly luck).
pub const PROBE_VOXELS_PER_PRIMITIVE: usize = 256;
pub const MIN_PROBE: usize = 64;
/// The default cap: one primitive per this many occupied voxels.
pub const CAP_VOXELS_PER_PRIMITIVE: usize = 32;
/// What a warm step assumes when its series measured nothing, and the
/// least slope per budget doubling trusted.
pub const DEFAULT_CURVE: Curve = Curve { per_budget_doubling: 1.5, per_iteration_doubling: 1.0 };
pub const MIN_SLOPE_DB: f64 = 0.3;
/// Corrections after the first full-length model, and the most a series'
/// step grows its budget by at once.
pub const MAX_CORRECTIONS: usize = 3;
pub const MAX_FACTOR: f64 = 4.0;
/// The least a series' growing step adds: the training it gets alone gains
/// little (hydrogen, 620 primitives: 48.98 dB, 750 more iterations 49.45).
pub const MIN_GROWTH: f64 = 1.15;
/// Mixed into the seeding seed per correction.
const CORRECTION_SEED: u64 = 0xc0_22ec;

/// The cap of a target with no budget given: one primitive per
/// `CAP_VOXELS_PER_PRIMITIVE` occupied voxels.
pub fn default_cap(prepared: &Prepared) -> usize {
    (occupied(prepared) / CAP_VOXELS_PER_PRIMITIVE).max(MIN_BUDGET)
}

fn occupied(prepared: &Prepared) -> usize {
    prepared.reference.values.iter().filter(|&&v| v > MASK_REF).count()
}

fn lands(psnr: f64, target: f64) -> bool {
    (target - LANDS_BELOW_DB..=target + LANDS_ABOVE_DB).contains(&psnr)
}

/// Encodes `prepared` to the budget that reaches `t` (see the module's
/// account); the budget of `request.config` is the cap (0: [`default_cap`]).
pub fn encode_to_target(
    prepared: &Prepared,
    request: &Request,
    t: TargetPsnr,
    backend: &mut dyn Backend,
    progress: &mut dyn FnMut(&Progress),
) -> Result<Encoded> {
    let started = Instant::now();
    let cap = match request.config.budget {
        0 => default_cap(prepared),
        b => b,
    }
    .min(prepared.reference.len())
    // A budget whose training cannot fit would fail the encode that tries
    // it (`refine::check_training_memory`): the search stays within what fits.
    .min(fitting_budget(crate::memory::available()?, request.config.points(), prepared.reference.len()));
    let mut search = Search { prepared, request, target: t.db, cap, backend, progress, probes: vec![], tries: vec![] };
    let (first, curve) = match request.start {
        Start::Seeded => {
            let guess = search.probe()?;
            let n = search.budget_for(guess.budget, guess.psnr, guess.curve.per_budget_doubling);
            (search.fresh(n)?, guess.curve)
        }
        Start::Warm { params, .. } => {
            let config = Search::with_budget(&request.config, params.len());
            (search.encode(Request { config, ..request.clone() })?, t.curve.unwrap_or(DEFAULT_CURVE))
        }
    };
    let mut models = vec![first];
    for round in 0..MAX_CORRECTIONS {
        let last = models.last().expect("one model at least");
        let (n, p) = (last.model.len(), last.psnr);
        if lands(p, t.db) || p.is_nan() {
            break;
        }
        // Between two tries that bracket the aim, their own slope; else the curve's.
        let slope = bracket_slope(&points(&search.tries), search.aim()).unwrap_or(curve.per_budget_doubling);
        let next = match request.start {
            // A series' step grows by insertion, or keeps its budget.
            Start::Warm { .. } if p < t.db => {
                let Some(want) = growth(&search.tries, n, search.budget_for(n, p, slope), cap) else {
                    break;
                };
                let seed = request.config.seed_init ^ CORRECTION_SEED ^ round as u64;
                let params = grow(&prepared.target(), &last.model.params, want - n, seed, search.backend)?;
                search.grown(&params, search.correction_iterations())?
            }
            Start::Warm { .. } => break,
            // A seeded encode is encoded again, to the budget the slope says.
            Start::Seeded => {
                let want = search.budget_for(n, p, slope);
                if search.tries.iter().any(|t| t.budget == want) {
                    break; // at the cap or the floor, or tried already
                }
                search.fresh(want)?
            }
        };
        models.push(next);
    }
    // `search.tries` records `models`, one for one.
    let chosen = choose(&points(&search.tries), t.db);
    let mut encoded = models.swap_remove(chosen);
    let landed = lands(encoded.psnr, t.db);
    // The model keeps the curve, for the series' next step, after a restart too.
    encoded.model.meta.curve = Some(curve);
    tracing::info!(target = t.db, psnr = encoded.psnr, budget = encoded.model.len(), landed, "target PSNR");
    encoded.target = Some(TargetReport { target: t.db, landed, cap, probes: search.probes, tries: search.tries, chosen, curve, seconds: started.elapsed().as_secs_f64() });
    Ok(encoded)
}

/// The largest budget whose training, with batches of `points` on a
/// reference of `voxels`, fits in
/// three quarters of `available` bytes (as `refine::check_training_memory`
/// counts it; the quarter left is for what the search's own probes leave
/// mapped before the encode at the cap checks again: a 1.3M cap taken at
/// the whole was refused 19 MB short under `ulimit -v`), at least
/// [`MIN_BUDGET`], which the search needs to start; unbounded with `None`.
pub fn fitting_budget(available: Option<u64>, points: usize, voxels: usize) -> usize {
    use crate::encode::refine::{TRAINING_BYTES_PER_POINT, TRAINING_BYTES_PER_PRIMITIVE, TRAINING_BYTES_PER_VOXEL};
    available.map_or(usize::MAX, |m| {
        let fixed = (points as u64).saturating_mul(TRAINING_BYTES_PER_POINT).saturating_add((voxels as u64).saturating_mul(TRAINING_BYTES_PER_VOXEL));
        let n = (m / 4 * 3).saturating_sub(fixed) / TRAINING_BYTES_PER_PRIMITIVE;
        usize::try_from(n).unwrap_or(usize::MAX).max(MIN_BUDGET)
    })
}

/// Whether a series' step that falls short grows (again): not after a
/// growth that lost PSNR. The grown primitives then train too little to
/// pay (the step's schedule undertrains the larger model: the dam break at
/// 55 dB with `matched`, where a fresh encode at the cap falls short too),
/// and growing more loses more (BENCHMARKS.md "A target PSNR through a
/// time series": step 9 at 55 dB, before this rule, 45 → 73 → 182 → 623
/// primitives, 53.74 → 52.41 → 51.42 → 50.45 dB); the best try is kept
/// either way.
fn growth_pays(tries: &[Try]) -> bool {
    match tries {
        [.., before, last] => last.psnr >= before.psnr,
        _ => true,
    }
}

/// The budget a series' step of `n` primitives that fell short grows to,
/// from the `predicted` one (what the slope says, within the cap): by
/// `MIN_GROWTH` to `MAX_FACTOR` times, not past `cap`. `None` where it does
/// not grow: after a growth that lost PSNR ([`growth_pays`]), or at the
/// cap or past it (a later step's default cap follows its occupied voxels,
/// which may be far fewer than its predecessor's).
fn growth(tries: &[Try], n: usize, predicted: usize, cap: usize) -> Option<usize> {
    if !growth_pays(tries) {
        return None;
    }
    let least = (n as f64 * MIN_GROWTH).ceil() as usize;
    let want = predicted.clamp(least.min(cap), ((n as f64 * MAX_FACTOR) as usize).max(n));
    (want > n).then_some(want)
}

/// The budget the slope (dB per doubling) says reaches `aim` from `p` dB at
/// `n` primitives, within `[MIN_BUDGET, cap]` (`cap` when that is smaller).
fn budget_for(n: usize, p: f64, aim: f64, slope: f64, cap: usize) -> usize {
    let ratio = 2f64.powf((aim - p) / slope);
    let want = if ratio.is_finite() { n as f64 * ratio } else if ratio > 1.0 { f64::MAX } else { 0.0 };
    (want.min(usize::MAX as f64).round() as usize).clamp(MIN_BUDGET.min(cap), cap)
}

/// `(budget, PSNR)` of each try.
fn points(tries: &[Try]) -> Vec<(usize, f64)> {
    tries.iter().map(|t| (t.budget, t.psnr)).collect()
}

/// The slope (dB per budget doubling) between the two tries nearest the
/// aim on either side of it, when there are such and it is at least
/// `MIN_SLOPE_DB`.
fn bracket_slope(tries: &[(usize, f64)], aim: f64) -> Option<f64> {
    let below = tries.iter().filter(|t| t.1 < aim).max_by(|a, b| a.1.total_cmp(&b.1))?;
    let above = tries.iter().filter(|t| t.1 >= aim).min_by(|a, b| a.1.total_cmp(&b.1))?;
    let slope = (above.1 - below.1) / (above.0 as f64 / below.0 as f64).log2();
    (slope.is_finite() && slope >= MIN_SLOPE_DB).then_some(slope)
}

/// Of `(budget, PSNR)` tries, the one to keep: the one that landed; else
/// the smallest that reached the band's floor; else the best.
fn choose(tries: &[(usize, f64)], target: f64) -> usize {
    let all = 0..tries.len();
    if let Some(i) = all.clone().rev().find(|&i| lands(tries[i].1, target)) {
        return i;
    }
    if let Some(i) = all.clone().filter(|&i| tries[i].1 >= target - LANDS_BELOW_DB).min_by_key(|&i| tries[i].0) {
        return i;
    }
    all.max_by(|&a, &b| tries[a].1.total_cmp(&tries[b].1)).expect("one try at least")
}

/// What the probes predict of a full-length encode.
struct Prediction {
    /// At this budget, this PSNR.
    budget: usize,
    psnr: f64,
    curve: Curve,
}

/// The state of one search.
struct Search<'a, 'r> {
    prepared: &'a Prepared,
    request: &'a Request<'r>,
    target: f64,
    cap: usize,
    backend: &'a mut dyn Backend,
    progress: &'a mut dyn FnMut(&Progress),
    probes: Vec<Try>,
    tries: Vec<Try>,
}

impl Search<'_, '_> {
    fn aim(&self) -> f64 {
        self.target + AIM_DB
    }

    /// Iterations of the schedule the request runs (a seeded encode's).
    fn schedule_iterations(&self) -> usize {
        config_for(&self.request.config, self.prepared.form, &Start::Seeded).iterations()
    }

    fn probe_iterations(&self) -> usize {
        ((PROBE_SHARE * self.schedule_iterations() as f64).round() as usize).max(MIN_ITERATIONS)
    }

    fn correction_iterations(&self) -> usize {
        2 * self.probe_iterations()
    }

    fn with_budget(config: &EncodeConfig, n: usize) -> EncodeConfig {
        EncodeConfig { budget: n, target: None, ..config.clone() }
    }

    fn budget_for(&self, n: usize, p: f64, slope: f64) -> usize {
        budget_for(n, p, self.aim(), slope, self.cap)
    }

    /// Runs the probes (see the module's account) and predicts from them.
    fn probe(&mut self) -> Result<Prediction> {
        let lo = MIN_BUDGET.min(self.cap);
        let na = (occupied(self.prepared) / PROBE_VOXELS_PER_PRIMITIVE).max(MIN_PROBE).clamp(lo, self.cap);
        let (pa, ga) = self.predict_full(na)?;
        let nb = if pa < self.aim() { na.saturating_mul(4) } else { na / 4 }.clamp(lo, self.cap);
        if nb == na {
            let curve = Curve { per_iteration_doubling: ga, ..DEFAULT_CURVE };
            return Ok(Prediction { budget: na, psnr: pa, curve });
        }
        let (pb, gb) = self.predict_full(nb)?;
        let slope = (pb - pa) / (nb as f64 / na as f64).log2();
        let per_budget_doubling = if slope.is_finite() { slope.max(MIN_SLOPE_DB) } else { DEFAULT_CURVE.per_budget_doubling };
        // Predict from the probe nearer the aim.
        let (budget, psnr, g) = if (pb - self.aim()).abs() < (pa - self.aim()).abs() { (nb, pb, gb) } else { (na, pa, ga) };
        Ok(Prediction { budget, psnr, curve: Curve { per_budget_doubling, per_iteration_doubling: g } })
    }

    /// The full-length PSNR at `n` predicted from two short encodes (linear
    /// in the logarithm of the iterations), and the dB per doubling of them.
    fn predict_full(&mut self, n: usize) -> Result<(f64, f64)> {
        let short = self.probe_iterations();
        let p0 = self.run_probe(n, short)?;
        let p1 = self.run_probe(n, 2 * short)?;
        let g = if (p1 - p0).is_finite() { (p1 - p0).max(0.0) } else { 0.0 };
        let doublings = (self.schedule_iterations() as f64 / (2 * short) as f64).log2().max(0.0);
        Ok((p1 + g * doublings, g))
    }

    fn run_probe(&mut self, n: usize, iterations: usize) -> Result<f64> {
        let config = EncodeConfig { iterations: Some(iterations), ..Search::with_budget(&self.request.config, n) };
        let r = Request { config, start: Start::Seeded, payload: Payload::Float32, validation: None, ..self.request.clone() };
        let (e, t) = self.timed(&r)?;
        self.probes.push(t);
        tracing::info!(budget = n, iterations, psnr = e.psnr, "target PSNR: probe");
        Ok(e.psnr)
    }

    /// A seeded full-length model of `n` primitives.
    fn fresh(&mut self, n: usize) -> Result<Encoded> {
        let r = Request { config: Search::with_budget(&self.request.config, n), start: Start::Seeded, ..self.request.clone() };
        self.encode(r)
    }

    /// `params` (a grown model) trained on for `more` iterations, with
    /// relocation unless the request has none.
    fn grown(&mut self, params: &[Primitive], more: usize) -> Result<Encoded> {
        let regime = if self.request.config.relocation { WarmStart::Dense } else { WarmStart::Coarse };
        let start = Start::Warm { params, regime, iterations: Some(more) };
        let r = Request { config: Search::with_budget(&self.request.config, params.len()), start, ..self.request.clone() };
        self.encode(r)
    }

    /// Runs `r` and records the try.
    fn encode(&mut self, r: Request) -> Result<Encoded> {
        let (e, t) = self.timed(&r)?;
        self.tries.push(t);
        tracing::info!(budget = e.model.len(), psnr = e.psnr, "target PSNR: try");
        Ok(e)
    }

    /// Runs `r`; the model, and what it was as a try.
    fn timed(&mut self, r: &Request) -> Result<(Encoded, Try)> {
        let started = Instant::now();
        let e = encode_budget(self.prepared, r, self.backend, self.progress)?;
        let t = Try { budget: e.model.len(), psnr: e.psnr, iterations: e.output.iterations, seconds: started.elapsed().as_secs_f64() };
        Ok((e, t))
    }
}

/// How a target-PSNR encode chose its budget (null without a target), as
/// the tool's encode output prints it and a Python encode's `info` holds it.
pub fn report_json(report: Option<&TargetReport>) -> Value {
    let tries = |v: &[Try]| v.iter().map(|t| json!({"budget": t.budget, "psnr": t.psnr, "iterations": t.iterations, "seconds": t.seconds})).collect::<Vec<_>>();
    match report {
        None => Value::Null,
        Some(r) => json!({
            "target_psnr": r.target,
            "landed": r.landed,
            "cap": r.cap,
            "probes": tries(&r.probes),
            "tries": tries(&r.tries),
            "chosen": r.chosen,
            "db_per_budget_doubling": r.curve.per_budget_doubling,
            "db_per_iteration_doubling": r.curve.per_iteration_doubling,
            "seconds": r.seconds,
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_growth_that_lost_psnr_is_not_grown_again() {
        let t = |budget, psnr| Try { budget, psnr, iterations: 750, seconds: 0.0 };
        assert!(growth_pays(&[]) && growth_pays(&[t(45, 54.3)]), "the step's own model may grow");
        assert!(growth_pays(&[t(45, 54.3), t(60, 54.8)]), "a growth that gained may grow again");
        assert!(growth_pays(&[t(45, 54.3), t(60, 54.3)]));
        assert!(!growth_pays(&[t(45, 54.3), t(60, 53.8)]), "a growth that lost");
        assert!(!growth_pays(&[t(16, 50.0), t(45, 54.3), t(60, 53.8)]));
    }

    #[test]
    fn a_growth_is_by_its_least_to_its_most_factor_within_the_cap() {
        let one = [Try { budget: 100, psnr: 40.0, iterations: 750, seconds: 0.0 }];
        assert_eq!(growth(&one, 100, 300, 10_000), Some(300));
        assert_eq!(growth(&one, 100, 101, 10_000), Some(115), "at least MIN_GROWTH times");
        assert_eq!(growth(&one, 100, 90, 10_000), Some(115), "a prediction below the model");
        assert_eq!(growth(&one, 100, 5000, 10_000), Some(400), "at most MAX_FACTOR times");
        assert_eq!(growth(&one, 100, 110, 110), Some(110), "the cap is above the model but below its least growth");
        assert_eq!(growth(&one, 100, 100, 100), None, "at the cap");
        assert_eq!(growth(&one, 100, 16, 16), None, "past the cap");
        let lost = [one[0], Try { budget: 130, psnr: 39.0, ..one[0] }];
        assert_eq!(growth(&lost, 130, 400, 10_000), None, "after a growth that lost");
    }

    #[test]
    fn the_budget_follows_the_slope_within_its_bounds() {
        // 2 dB short at 3 dB per doubling: 2^(2/3) times the budget.
        assert_eq!(budget_for(1000, 38.0, 40.0, 3.0, 1 << 20), (1000.0 * 2f64.powf(2.0 / 3.0)).round() as usize);
        // 3 dB over at 1.5 dB per doubling: a quarter.
        assert_eq!(budget_for(1000, 43.0, 40.0, 1.5, 1 << 20), 250);
        assert_eq!(budget_for(1000, 80.0, 40.0, 1.5, 1 << 20), MIN_BUDGET);
        assert_eq!(budget_for(1000, 10.0, 40.0, 1.5, 5000), 5000);
        assert_eq!(budget_for(1000, f64::NEG_INFINITY, 40.0, 1.5, 5000), 5000);
        assert_eq!(budget_for(1000, f64::INFINITY, 40.0, 1.5, 5000), MIN_BUDGET);
        // A cap below the floor wins.
        assert_eq!(budget_for(1000, 80.0, 40.0, 1.5, 8), 8);
    }

    #[test]
    fn two_tries_on_either_side_give_their_slope() {
        // Nearest below 38 at 1000, nearest above 41 at 4000: 1.5 dB per doubling.
        let tries = [(500, 35.0), (1000, 38.0), (4000, 41.0), (8000, 44.0)];
        assert_eq!(bracket_slope(&tries, 40.0), Some(1.5));
        assert_eq!(bracket_slope(&tries[..2], 40.0), None, "nothing above the aim");
        assert_eq!(bracket_slope(&tries[2..], 40.0), None, "nothing below the aim");
        // A slope that falls with the budget (noise) is not trusted.
        assert_eq!(bracket_slope(&[(4000, 39.0), (1000, 40.5)], 40.0), None);
    }

    #[test]
    fn the_model_kept_is_the_one_that_landed_else_the_smallest_above_the_floor_else_the_best() {
        assert_eq!(choose(&[(100, 38.0), (200, 40.5), (150, 39.0)], 40.0), 1);
        // None within [39.5, 41]: the smallest at 39.5 or more.
        assert_eq!(choose(&[(100, 38.0), (400, 43.0), (300, 41.5)], 40.0), 2);
        // None at 39.5: the best.
        assert_eq!(choose(&[(100, 30.0), (400, 36.0), (300, 35.0)], 40.0), 1);
        assert!(lands(40.0 - LANDS_BELOW_DB, 40.0) && lands(40.0 + LANDS_ABOVE_DB, 40.0));
        assert!(!lands(f64::NAN, 40.0) && !lands(41.01, 40.0) && !lands(39.49, 40.0));
    }
}
