//! The repair of a warm start (METHOD.md "Warm start", `auto`): the
//! previous step's model, scored on the new step's samples, keeps its
//! primitives where it still fits and moves the others to where it does not.
//!
//! 1. **Residual**: the previous model's `V_eval` at (up to
//!    `max(RESIDUAL_SAMPLES, 2N)`, evenly strided) samples of the new step,
//!    against the reference there. A sample is *high-residual* when the
//!    reference holds data there (above the objective's mask) and the
//!    model misses it by more than `RESIDUAL_THRESHOLD` of the range.
//! 2. **Share**: a fresh seeding would put a share `f` of its N primitives
//!    on the high-residual samples, `f` their share of the samples scored;
//!    the repair moves `k = max(vanished, round(f N))` primitives. No
//!    constant share: a step that did not change moves none.
//! 3. **Which**: first every *vanished* primitive (no reference voxel
//!    within `VANISHED_RADIUS` of its centre holds data: it gets no
//!    gradient from the objective and would stay where the field was), then
//!    the smallest effective support `w prod exp(l)`, as relocation picks.
//! 4. **Where**: the seeding rules (`seeding.rs`) run on the high-residual
//!    samples alone for `k` primitives, with the scale a seeding of all
//!    samples would give (the same samples per primitive there).
//!
//! Whether the previous model, the repaired one or a fresh seeding starts
//! the step is decided on validation points by [`choose_start`].

use crate::backend::Backend;
use crate::encode::relocate::effective_support;
use crate::encode::seeding::{seed, seed_with_spread, spread};
use crate::encode::validation::Validation;
use crate::error::Result;
use crate::field::Grid;
use crate::input::samples::{Sample, SampleSet};
use crate::input::Target;
use crate::math::kernel::{layout, Primitive};
use crate::math::loss::{v_eval, MASK_REF};
use crate::model::{WarmRecord, WarmTaken};

/// A sample the previous model misses by more than this (normalised
/// range) is high-residual.
pub const RESIDUAL_THRESHOLD: f32 = 0.05;
/// Samples scored at least (all of them when there are fewer; at least
/// twice the budget when it is larger).
pub const RESIDUAL_SAMPLES: usize = 1 << 16;
/// Voxels around a primitive's centre that must all be empty for it to
/// count as vanished.
pub const VANISHED_RADIUS: i64 = 2;
/// Mixed into the encode's seeding seed for the repair's seeds.
const REPAIR_SEED: u64 = 0x5e9a_17ed;

/// A repaired start.
#[derive(Clone, Debug)]
pub struct Repair {
    /// The previous parameters with `moved` replaced.
    pub params: Vec<Primitive>,
    /// Indices of the moved primitives (vanished first).
    pub moved: Vec<usize>,
    /// Of those, how many had vanished.
    pub vanished: usize,
    /// Share of the scored samples that were high-residual.
    pub high_share: f64,
}

/// Samples of `inner` at the indices `idx`.
struct Subset<'a> {
    inner: &'a dyn SampleSet,
    idx: Vec<usize>,
}

impl SampleSet for Subset<'_> {
    fn len(&self) -> usize {
        self.idx.len()
    }
    fn get(&self, i: usize) -> Sample {
        self.inner.get(self.idx[i])
    }
    fn uniform_importance(&self) -> bool {
        self.inner.uniform_importance()
    }
}

/// Where a model misses its target: the indices of the high-residual
/// samples among those scored.
pub struct Residual {
    /// Indices into the target's samples of the high-residual ones.
    pub high: Vec<usize>,
    /// Samples scored (evenly strided over all of them).
    pub scored: usize,
}

impl Residual {
    /// Share of the scored samples that were high-residual.
    pub fn share(&self) -> f64 {
        self.high.len() as f64 / self.scored.max(1) as f64
    }
}

/// Scores `params` on up to `max(RESIDUAL_SAMPLES, 2 N)` evenly strided
/// samples of `target` (step 1 of the module's account).
pub fn residual(target: &Target, params: &[Primitive], backend: &mut dyn Backend) -> Result<Residual> {
    let samples = target.samples;
    let ns = samples.len();
    let scored = RESIDUAL_SAMPLES.max(2 * params.len()).min(ns);
    let idx: Vec<usize> = (0..scored).map(|j| (j as u128 * ns as u128 / scored as u128) as usize).collect();
    let pos: Vec<[f32; 3]> = idx.iter().map(|&i| samples.get(i).q).collect();
    let (mut rho, mut num) = (vec![0f32; scored], vec![0f32; scored]);
    backend.evaluate_points(params, &pos, &mut rho, &mut num)?;
    let high = (0..scored)
        .filter(|&j| {
            let vref = target.reference.trilinear(pos[j]);
            vref > MASK_REF && (v_eval(rho[j], num[j]) - vref).abs() > RESIDUAL_THRESHOLD
        })
        .map(|j| idx[j])
        .collect();
    Ok(Residual { high, scored })
}

/// `k` primitives seeded on the high-residual samples of `r` (step 4 of
/// the module's account), or on all samples when none is high-residual.
pub fn seed_on_residual(target: &Target, r: Residual, k: usize, seed: u64) -> Result<Vec<Primitive>> {
    let ns = target.samples.len();
    // `represented`: the samples of the whole step the pool stands for.
    let (pool, represented) = if r.high.is_empty() {
        ((0..ns).collect(), ns)
    } else {
        let represented = (r.high.len() as f64 * ns as f64 / r.scored as f64).round() as usize;
        (r.high, represented)
    };
    let subset = Subset { inner: target.samples, idx: pool };
    Ok(seed_with_spread(&subset, target.reference.dims, k, seed, spread(represented, k))?.params)
}

/// Repairs `prev` for `target` (see the module's account); `seed` is the
/// encode's seeding seed.
pub fn repair(target: &Target, prev: &[Primitive], seed: u64, backend: &mut dyn Backend) -> Result<Repair> {
    let n = prev.len();
    let r = residual(target, prev, backend)?;
    let high_share = r.share();

    let mut moved: Vec<usize> = (0..n).filter(|&i| vanished(target.reference, &prev[i])).collect();
    let vanished_count = moved.len();
    let k = vanished_count.max((high_share * n as f64).round() as usize).min(n);
    if k > vanished_count {
        let mut rest: Vec<(f32, usize)> = (0..n).filter(|i| moved.binary_search(i).is_err()).map(|i| (effective_support(&prev[i]), i)).collect();
        rest.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        moved.extend(rest.iter().take(k - vanished_count).map(|&(_, i)| i));
    }
    let mut params = prev.to_vec();
    if k > 0 {
        // Vanished primitives with no high-residual sample to go to are
        // seeded over all samples instead.
        for (&i, p) in moved.iter().zip(seed_on_residual(target, r, k, seed ^ REPAIR_SEED)?) {
            params[i] = p;
        }
    }
    Ok(Repair { params, moved, vanished: vanished_count, high_share })
}

/// The start of an `auto` warm-started step: the previous model as it is,
/// repaired, or a fresh seeding of `prev.len()` primitives (seed `seed`),
/// whichever scores the highest PSNR on `validation` (ties in that order).
pub fn choose_start(target: &Target, prev: &[Primitive], seed_init: u64, validation: &Validation, backend: &mut dyn Backend) -> Result<(Vec<Primitive>, WarmRecord)> {
    let r = repair(target, prev, seed_init, backend)?;
    let moved = r.moved.len() as u32;
    let kept = validation.psnr(backend, prev)?;
    let repaired = if moved > 0 { validation.psnr(backend, &r.params)? } else { f64::NEG_INFINITY };
    let fresh = seed(target.samples, target.reference.dims, prev.len(), seed_init)?.params;
    let fresh_psnr = validation.psnr(backend, &fresh)?;
    tracing::info!(kept, repaired, fresh = fresh_psnr, moved, vanished = r.vanished, high_share = r.high_share, "auto warm start");
    Ok(match best_start(kept, repaired, fresh_psnr) {
        WarmTaken::Fresh => (fresh, WarmRecord { taken: WarmTaken::Fresh, moved }),
        WarmTaken::Repaired => (r.params, WarmRecord { taken: WarmTaken::Repaired, moved }),
        WarmTaken::Kept => (prev.to_vec(), WarmRecord { taken: WarmTaken::Kept, moved: 0 }),
    })
}

/// The start of the highest validation PSNR; on a tie the earlier of
/// kept, repaired, fresh.
fn best_start(kept: f64, repaired: f64, fresh: f64) -> WarmTaken {
    if fresh > kept.max(repaired) {
        WarmTaken::Fresh
    } else if repaired > kept {
        WarmTaken::Repaired
    } else {
        WarmTaken::Kept
    }
}

/// True when no voxel within `VANISHED_RADIUS` of the primitive's centre
/// (clamped to the lattice) holds data above the objective's mask.
fn vanished(reference: &Grid, p: &Primitive) -> bool {
    let mu = &p[layout::MU..layout::MU + 3];
    let mut lo = [0usize; 3];
    let mut hi = [0usize; 3];
    for a in 0..3 {
        let top = reference.dims[a] as i64 - 1;
        let c = mu[a].round().clamp(-1e9, 1e9) as i64;
        if c + VANISHED_RADIUS < 0 || c - VANISHED_RADIUS > top {
            return true; // outside the lattice altogether
        }
        lo[a] = (c - VANISHED_RADIUS).clamp(0, top) as usize;
        hi[a] = (c + VANISHED_RADIUS).clamp(0, top) as usize;
    }
    for k in lo[2]..=hi[2] {
        for j in lo[1]..=hi[1] {
            for i in lo[0]..=hi[0] {
                if reference.values[reference.index(i, j, k)] > MASK_REF {
                    return false;
                }
            }
        }
    }
    true
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::backend::cpu::CpuBackend;
    use crate::math::kernel::isotropic;

    fn ball(dims: usize, c: [f32; 3], r: f32) -> Grid {
        let mut v = vec![0f32; dims * dims * dims];
        for k in 0..dims {
            for j in 0..dims {
                for i in 0..dims {
                    let d2 = (i as f32 - c[0]).powi(2) + (j as f32 - c[1]).powi(2) + (k as f32 - c[2]).powi(2);
                    v[i + dims * (j + dims * k)] = (0.8 * (-d2 / (2.0 * r * r)).exp()).max(0.0);
                }
            }
        }
        for x in v.iter_mut() {
            if *x < 1e-3 {
                *x = 0.0;
            }
        }
        Grid::new([dims; 3], v).unwrap()
    }

    /// Primitives on a ball at `c` (isotropic, on a jittered lattice of centres).
    fn model_of(c: [f32; 3], n: usize) -> Vec<Primitive> {
        (0..n)
            .map(|i| {
                let f = i as f32 / n as f32;
                let q = [c[0] + 3.0 * (std::f32::consts::TAU * f).cos(), c[1] + 3.0 * (std::f32::consts::TAU * f).sin(), c[2] + 4.0 * (f - 0.5)];
                isotropic(q, 1.5, 0.6, 0.4)
            })
            .collect()
    }

    #[test]
    fn a_step_that_moved_far_moves_the_vanished_primitives_onto_the_new_data() {
        let reference = ball(24, [17.0, 17.0, 17.0], 2.5);
        let target = Target { reference: &reference, samples: &reference };
        let prev = model_of([6.0, 6.0, 6.0], 40);
        let r = repair(&target, &prev, 0, &mut CpuBackend::new()).unwrap();
        // Every primitive sat where the field vanished.
        assert_eq!(r.vanished, 40);
        assert_eq!(r.moved.len(), 40);
        assert!(r.high_share > 0.0);
        for p in &r.params {
            assert!(!vanished(&reference, p), "a repaired primitive at {:?} sits in empty space", &p[..3]);
        }
    }

    #[test]
    fn a_step_that_did_not_change_moves_nothing() {
        // The reference is what the previous model decodes to (where a ball
        // holds data): it misses no sample.
        let ball = ball(24, [12.0, 12.0, 12.0], 2.5);
        let prev: Vec<Primitive> = model_of([12.0, 12.0, 12.0], 30);
        let pos: Vec<[f32; 3]> = (0..ball.len()).map(|i| ball.get(i).q).collect();
        let (mut rho, mut num) = (vec![0f32; ball.len()], vec![0f32; ball.len()]);
        CpuBackend::new().evaluate_points(&prev, &pos, &mut rho, &mut num).unwrap();
        let fitted: Vec<f32> = (0..ball.len()).map(|i| if ball.values[i] > MASK_REF { v_eval(rho[i], num[i]) } else { 0.0 }).collect();
        let reference = Grid::new(ball.dims, fitted).unwrap();
        let target = Target { reference: &reference, samples: &reference };
        let r = repair(&target, &prev, 0, &mut CpuBackend::new()).unwrap();
        assert_eq!(r.high_share, 0.0);
        assert_eq!(r.vanished, 0, "no primitive of a model on its own data has vanished");
        assert!(r.moved.is_empty());
        assert_eq!(r.params, prev);
    }

    #[test]
    fn the_best_start_scores_highest_and_ties_go_to_the_earlier() {
        use WarmTaken::*;
        for (scores, want) in [
            ([3.0, 2.0, 1.0], Kept),
            ([1.0, 3.0, 2.0], Repaired),
            ([2.0, 3.0, 1.0], Repaired),
            ([1.0, 2.0, 3.0], Fresh),
            ([2.0, 1.0, 3.0], Fresh),
            ([1.0, 3.0, 2.5], Repaired),
            ([2.0, 2.0, 1.0], Kept),
            ([1.0, 2.0, 2.0], Repaired),
            ([2.0, 1.0, 2.0], Kept),
            ([1.0, f64::NEG_INFINITY, 2.0], Fresh), // nothing to repair
            ([1.0, f64::NEG_INFINITY, 0.5], Kept),
        ] {
            assert_eq!(best_start(scores[0], scores[1], scores[2]), want, "{scores:?}");
        }
    }

    /// Beyond the vanished, the high-residual share moves the primitives
    /// of least effective support (`w prod exp(l)`), smallest first.
    #[test]
    fn data_the_model_misses_take_the_primitives_of_least_support() {
        let (a, b) = (ball(24, [8.0, 8.0, 8.0], 2.5), ball(24, [17.0, 17.0, 17.0], 2.5));
        let values = a.values.iter().zip(&b.values).map(|(x, y)| x.max(*y)).collect();
        let reference = Grid::new([24; 3], values).unwrap();
        let target = Target { reference: &reference, samples: &reference };
        // On the first ball only, each wider than the one before, in an
        // order the support's is not.
        let mut prev = model_of([8.0, 8.0, 8.0], 30);
        for (k, p) in prev.iter_mut().enumerate() {
            let sigma = 1.0 + 0.03 * ((k * 7) % 30) as f32;
            p[layout::LOG_SCALE..layout::LOG_SCALE + 3].fill(sigma.ln());
        }
        let r = repair(&target, &prev, 0, &mut CpuBackend::new()).unwrap();
        assert_eq!(r.vanished, 0);
        assert!(!r.moved.is_empty() && r.moved.len() < 30, "{} moved", r.moved.len());
        let mut by_support: Vec<usize> = (0..30).collect();
        by_support.sort_by(|&i, &j| effective_support(&prev[i]).total_cmp(&effective_support(&prev[j])));
        assert_eq!(r.moved, by_support[..r.moved.len()], "the least supported move, in that order");
    }

    #[test]
    fn vanished_looks_around_the_centre() {
        let reference = ball(24, [12.0, 12.0, 12.0], 1.0);
        let at = |x: f32| isotropic([x, 12.0, 12.0], 1.0, 0.5, 0.5);
        assert!(!vanished(&reference, &at(12.0)));
        // Data within two voxels of the centre: not vanished.
        let edge = (0..24).rev().find(|&i| reference.values[reference.index(i, 12, 12)] > MASK_REF).unwrap() as f32;
        assert!(!vanished(&reference, &at(edge + 2.0)));
        assert!(vanished(&reference, &at(edge + 3.0)));
        assert!(vanished(&reference, &at(-10.0)));
        assert!(vanished(&reference, &isotropic([f32::MAX, 0.0, 0.0], 1.0, 0.5, 0.5)));
    }
}
