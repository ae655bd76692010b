//! The packed payload's precision, chosen per model by measuring
//! (METHOD.md "Payloads"): the fewest bits per parameter group that keep
//! the stored model's PSNR against its reference within
//! [`MAX_PSNR_LOSS_DB`] of the float32 model's.
//!
//! The measure is the PSNR at [`POINTS`] voxel centres drawn from the
//! reference, or at every one where it has no more (from its support when
//! the model stores one: elsewhere both decode to the outside's prediction,
//! within `[0, 0.005]` and nearly alike, so the ratio of the errors, and so
//! the PSNR change, is about the whole lattice's; the check below is
//! exact). The
//! search allows the caller's loss on the sample:
//!
//! 1. each group in turn is searched alone (bisection), the others held at
//!    their finest ([`Precision::FINEST`], with centres as coarse as a wide
//!    domain needs), for the fewest bits that cost at most an equal share
//!    of the allowance; a group is a centre class's lattice (searched only
//!    when the class holds primitives: an empty one keeps its finest), the
//!    scales, the rotations, the values or the weights;
//! 2. then, while the allowance lasts, the group whose next bit costs the
//!    least PSNR per stored bit (three numbers a primitive for scales and
//!    rotations, three per primitive of the class for a centre class, one
//!    for values and weights) gives it up;
//! 3. should the groups together exceed the allowance, every group gains a
//!    bit until they do not.
//!
//! [`measure_precision`] then checks the choice on the whole lattice (the
//! pipeline decodes the stored model there anyway, to score it), and
//! searches again with a smaller allowance ([`SEARCH_ALLOWANCES`]) when the
//! sample's estimate missed.

use crate::backend::Backend;
use crate::encode::stored::decode_as_stored;
use crate::encode::validation::Validation;
use crate::error::Result;
use crate::field::Grid;
use crate::format::packed::{class_counts, Packed, Precision, GROUPS};
use crate::format::Payload;
use crate::math::kernel::Primitive;
use crate::math::loss::MASK_REF;
use crate::math::rng::Rng;
use crate::model::metrics::voxel_psnr;
use crate::model::Model;
use std::collections::HashMap;

/// The most the packed payload may lower a model's PSNR, in dB.
pub const MAX_PSNR_LOSS_DB: f64 = 0.1;
/// The losses (dB) the search allows on the sample, tried in turn until the
/// whole lattice's loss is within [`MAX_PSNR_LOSS_DB`].
pub const SEARCH_ALLOWANCES: [f64; 3] = [0.1, 0.06, 0.03];
/// Numbers a primitive stores per bit of each group but the centre
/// classes' (scale, rotation, value, weight).
const NUMBERS: [f64; 4] = [3.0, 3.0, 1.0, 1.0];
/// Voxel centres the search scores.
pub const POINTS: usize = 1 << 16;
const SEED: u64 = 0x9ac4_ed00;

/// A packed model's decode on its reference lattice, as stored.
pub struct Measured {
    /// x fastest.
    pub decoded: Vec<f32>,
    /// Voxel PSNR of `decoded` against the reference.
    pub psnr: f64,
    /// That of the float32 model.
    pub float32_psnr: f64,
}

/// Sets `model`'s packed precision: chosen on the sample, then checked on
/// the whole reference lattice, where it must lose at most
/// [`MAX_PSNR_LOSS_DB`]; when it loses more, searched again with the next
/// smaller allowance, and after the last one given a bit more in every
/// group until it passes (or is at its finest). Sets its support's outside
/// too, fitted to the packed parameters ([`decode_as_stored`]).
pub fn measure_precision(model: &mut Model, reference: &Grid, backend: &mut dyn Backend) -> Result<Measured> {
    measure_with(model, reference, backend, &SEARCH_ALLOWANCES, MAX_PSNR_LOSS_DB)
}

/// [`measure_precision`] with the allowances it searches with, in turn,
/// and the whole lattice's loss it must meet.
fn measure_with(model: &mut Model, reference: &Grid, backend: &mut dyn Backend, allowances: &[f64], max_loss: f64) -> Result<Measured> {
    let float32_psnr = voxel_psnr(&decode_as_stored(Payload::Float32, model, reference, backend)?.decoded, &reference.values);
    let finest = finest_for(&model.params);
    // One search for every allowance: a retry scores only what the search
    // before it did not (most of its bisection repeats the first search's:
    // 25 of 76 scorings for hydrogen's `tuned` model at 300 iterations).
    let mut search = search(&model.params, reference, model.support.is_some(), backend)?;
    let mut allowances = allowances.iter();
    let mut p = finest;
    loop {
        if let Some(&allowed) = allowances.next() {
            p = match search.as_mut() {
                Some(search) => search.choose(allowed, backend)?,
                None => Precision::DEFAULT,
            };
        }
        model.meta.precision = Some(p);
        let stored = decode_as_stored(Payload::Packed, model, reference, backend)?;
        let psnr = voxel_psnr(&stored.decoded, &reference.values);
        if float32_psnr - psnr <= max_loss || p == finest {
            model.support = stored.support;
            return Ok(Measured { decoded: stored.decoded, psnr, float32_psnr });
        }
        if allowances.len() == 0 {
            p = finer(p, finest);
        }
    }
}

/// [`Precision::FINEST`] with centres as coarse as a wide domain needs. A
/// domain too wide even for whole voxels keeps it: packing then fails with
/// `Packed::of`'s error.
fn finest_for(params: &[Primitive]) -> Precision {
    Precision::FINEST.fitting(params).unwrap_or(Precision::FINEST)
}

/// The precision to pack `params` with, allowing a loss of `allowed` dB on
/// the sample: see the module documentation. `support`: whether the model
/// stores its support. A model without primitives, or a reference with
/// nothing to score, gets the default.
pub fn choose_precision(params: &[Primitive], reference: &Grid, support: bool, allowed: f64, backend: &mut dyn Backend) -> Result<Precision> {
    match search(params, reference, support, backend)? {
        Some(mut search) => search.choose(allowed, backend),
        None => Ok(Precision::DEFAULT),
    }
}

/// The search for `params` on the sample of `reference`: it scores the
/// sample's PSNR lost by packing at a precision. `None` when `params` is
/// empty or `reference` has nothing to score (the precision is then the
/// default).
fn search<'a>(params: &'a [Primitive], reference: &Grid, support: bool, backend: &mut dyn Backend) -> Result<Option<Search<impl FnMut(Precision, &mut dyn Backend) -> Result<f64> + 'a>>> {
    let Some(sample) = sample(reference, support) else { return Ok(None) };
    if params.is_empty() {
        return Ok(None);
    }
    let exact = sample.psnr(backend, params)?;
    let finest = finest_for(params);
    let score = move |p: Precision, backend: &mut dyn Backend| Ok(exact - sample.psnr(backend, &Packed::of(params, p)?.params()?)?);
    Ok(Some(Search::over(score, numbers(params, finest), finest)))
}

/// Numbers a primitive stores per bit of each group, on average: three a
/// primitive of its class for a centre class (so 0 for a class without
/// primitives), [`NUMBERS`] for the others.
fn numbers(params: &[Primitive], finest: Precision) -> [f64; GROUPS.len()] {
    let counts = class_counts(params, finest.scale);
    std::array::from_fn(|g| if Precision::is_centre(g) { 3.0 * counts[g] as f64 / params.len() as f64 } else { NUMBERS[g - counts.len()] })
}

/// One model's search: what it scores (`score`: the loss in dB of a
/// precision), the numbers each group stores, and the loss of every
/// precision scored so far, kept across allowances (a precision's loss on
/// the sample does not depend on the allowance).
struct Search<S> {
    score: S,
    /// Numbers stored per bit of each group ([`numbers`]); a group of none
    /// is not searched (it keeps `finest`'s bits).
    numbers: [f64; GROUPS.len()],
    finest: Precision,
    seen: HashMap<Precision, f64>,
    /// Precisions scored: each once, a repeat is read from `seen`.
    scored: usize,
}

impl<S: FnMut(Precision, &mut dyn Backend) -> Result<f64>> Search<S> {
    /// A search of the losses `score` gives, for groups that store
    /// `numbers` per bit and bits up to `finest`'s (the tests give it
    /// analytic losses).
    fn over(score: S, numbers: [f64; GROUPS.len()], finest: Precision) -> Search<S> {
        Search { score, numbers, finest, seen: HashMap::new(), scored: 0 }
    }

    /// The loss of packing at `p`.
    fn loss(&mut self, p: Precision, backend: &mut dyn Backend) -> Result<f64> {
        if let Some(&l) = self.seen.get(&p) {
            return Ok(l);
        }
        let l = (self.score)(p, backend)?;
        self.scored += 1;
        self.seen.insert(p, l);
        Ok(l)
    }

    /// The precision that loses at most `allowed` dB: the module
    /// documentation's three steps.
    fn choose(&mut self, allowed: f64, backend: &mut dyn Backend) -> Result<Precision> {
        let groups: Vec<usize> = (0..GROUPS.len()).filter(|&g| self.numbers[g] > 0.0).collect();
        let alone = self.each_alone(&groups, allowed, backend)?;
        let cheapest = self.give_up_cheapest(alone, &groups, allowed, backend)?;
        self.within(cheapest, allowed, backend)
    }

    /// Step 1: each of `groups` at the fewest bits that lose at most an
    /// equal share of `allowed`, the others at their finest.
    fn each_alone(&mut self, groups: &[usize], allowed: f64, backend: &mut dyn Backend) -> Result<Precision> {
        let finest = self.finest;
        // The loss of one group alone is about its share of the added error:
        // an equal share of the allowed error, in dB.
        let total_err = 10f64.powf(allowed / 10.0) - 1.0;
        let group_loss = 10.0 * (1.0 + total_err / groups.len() as f64).log10();
        let mut chosen = finest;
        for &g in groups {
            // The fewest bits in [lo, finest] whose loss is within the group's share.
            let (mut lo, mut hi) = (Precision::min_bits(g), finest.get(g));
            while lo < hi {
                let mid = lo + (hi - lo) / 2;
                if self.loss(finest.with(g, mid), backend)? <= group_loss {
                    hi = mid;
                } else {
                    lo = mid + 1;
                }
            }
            chosen = chosen.with(g, lo);
        }
        Ok(chosen)
    }

    /// Step 2: from `chosen`, while the allowance lasts, the group of
    /// `groups` whose next bit costs the least loss per stored number
    /// gives it up.
    fn give_up_cheapest(&mut self, mut chosen: Precision, groups: &[usize], allowed: f64, backend: &mut dyn Backend) -> Result<Precision> {
        let mut now = self.loss(chosen, backend)?;
        loop {
            let mut best: Option<(f64, Precision, f64)> = None;
            for &g in groups {
                if chosen.get(g) == Precision::min_bits(g) {
                    continue;
                }
                let candidate = chosen.with(g, chosen.get(g) - 1);
                let l = self.loss(candidate, backend)?;
                let per_number = (l - now).max(0.0) / self.numbers[g];
                if l <= allowed && best.is_none_or(|b| per_number < b.0) {
                    best = Some((per_number, candidate, l));
                }
            }
            let Some((_, candidate, l)) = best else { return Ok(chosen) };
            (chosen, now) = (candidate, l);
        }
    }

    /// Step 3: `chosen` with a bit more in every group until it loses at
    /// most `allowed` (or is the finest).
    fn within(&mut self, mut chosen: Precision, allowed: f64, backend: &mut dyn Backend) -> Result<Precision> {
        while self.loss(chosen, backend)? > allowed && chosen != self.finest {
            chosen = finer(chosen, self.finest);
        }
        Ok(chosen)
    }
}

/// One bit more in every group not yet at `finest`'s.
fn finer(p: Precision, finest: Precision) -> Precision {
    (0..GROUPS.len()).fold(p, |p, g| p.with(g, (p.get(g) + 1).min(finest.get(g))))
}

/// [`POINTS`] voxel centres of `reference`, drawn uniformly with
/// replacement from its support (the voxels above the mask) when the model
/// stores one, else from every voxel; every candidate once, in lattice
/// order, where there are no more than [`POINTS`] (the sample is then the
/// lattice, at less cost); `None` when there is none. Memory is that of the
/// draws, whatever the lattice: ranks among the candidates are drawn,
/// sorted, and found in one pass (the points stay in draw order).
fn sample(reference: &Grid, support: bool) -> Option<Validation> {
    let candidate = |i: usize| !support || reference.values[i] > MASK_REF;
    let count = (0..reference.len()).filter(|&i| candidate(i)).count();
    if count == 0 {
        return None;
    }
    let at = |picks: Vec<usize>| Validation {
        points: picks.iter().map(|&i| reference.centre(i)).collect(),
        values: picks.iter().map(|&i| reference.values[i]).collect(),
        every: 1,
        support,
    };
    if count <= POINTS {
        return Some(at((0..reference.len()).filter(|&i| candidate(i)).collect()));
    }
    let mut rng = Rng::new(SEED);
    // (rank among the candidates, draw), in rank order.
    let mut ranks: Vec<(usize, usize)> = (0..POINTS).map(|d| (rng.below(count as u64) as usize, d)).collect();
    ranks.sort_unstable();
    let mut picks = vec![0; POINTS]; // voxel of each draw, in draw order
    let (mut rank, mut next) = (0, ranks.iter().peekable());
    for i in (0..reference.len()).filter(|&i| candidate(i)) {
        while let Some(&(_, draw)) = next.next_if(|r| r.0 == rank) {
            picks[draw] = i;
        }
        rank += 1;
    }
    Some(at(picks))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::backend::cpu::CpuBackend;
    use crate::backend::Lattice;
    use crate::field::{IndexFrame, Transform, ValueRange};
    use crate::format::packed::{CENTRE_CLASSES, MAX_BITS};
    use crate::math::kernel::layout;
    use crate::math::loss::v_eval;
    use crate::model::{ModelMeta, Support};

    /// Sharp primitives (class 0) that carry the field and broad ones of
    /// almost no weight (class 3) that carry nothing, and a reference: the
    /// model at every voxel centre of a 24^3 lattice plus noise (so that the
    /// float32 model's PSNR is finite, about 40 dB).
    fn two_class_model() -> (Vec<Primitive>, Grid) {
        let mut rng = Rng::new(5);
        let dims = [24, 24, 24];
        let mut prim = |sigma: f32, beta: f32| {
            let mut p = [0f32; 12];
            (0..3).for_each(|a| p[layout::MU + a] = rng.range(2.0, 21.0) as f32);
            (0..3).for_each(|a| p[layout::LOG_SCALE + a] = sigma.ln());
            p[layout::QUAT] = 1.0;
            p[layout::ALPHA] = 0.5 * rng.normal() as f32;
            p[layout::BETA] = beta;
            p
        };
        let mut params: Vec<Primitive> = (0..300).map(|_| prim(0.7, 2.0)).collect();
        params.extend((0..40).map(|_| prim(5.0, -14.0)));
        let points: Vec<[f32; 3]> = (0..dims.iter().product()).map(|i| [(i % 24) as f32, (i / 24 % 24) as f32, (i / 576) as f32]).collect();
        let (mut rho, mut n) = (vec![0.0; points.len()], vec![0.0; points.len()]);
        CpuBackend::new().evaluate_points(&params, &points, &mut rho, &mut n).unwrap();
        let values = (0..points.len()).map(|i| v_eval(rho[i], n[i]) + 0.01 * rng.normal() as f32).collect();
        (params, Grid::new(dims, values).unwrap())
    }

    /// The broad primitives shape nothing, so their centres may go anywhere
    /// on a whole voxel: the search gives their class the coarsest lattice
    /// and keeps the sharp ones' fine.
    #[test]
    fn a_centre_class_that_shapes_nothing_gets_a_coarser_lattice() {
        let (params, reference) = two_class_model();
        let mut backend = CpuBackend::new();
        let p = choose_precision(&params, &reference, false, MAX_PSNR_LOSS_DB, &mut backend).unwrap();
        assert_eq!(class_counts(&params, p.scale), [300, 0, 0, 40], "{p:?}");
        assert_eq!(p.centre[3], 0, "{p:?}");
        assert!(p.centre[0] >= 3, "{p:?}");
        // Within the allowance on the sample, and the empty classes keep the finest.
        let stored = Packed::of(&params, p).unwrap().params().unwrap();
        let sample = sample(&reference, false).unwrap();
        let loss = sample.psnr(&mut backend, &params).unwrap() - sample.psnr(&mut backend, &stored).unwrap();
        assert!((0.0..=MAX_PSNR_LOSS_DB).contains(&loss), "{loss} dB");
        assert_eq!([p.centre[1], p.centre[2]], [finest_for(&params).centre[1]; 2]);
    }

    /// One search kept across the allowances chooses what a fresh search
    /// for each would, and scores again none of what it scored before: each
    /// smaller allowance repeats at least the bisection of the groups whose
    /// share of the error it leaves alone, so it scores fewer than a fresh
    /// search does.
    #[test]
    fn a_retry_reuses_the_scores_of_the_searches_before_it() {
        let (params, reference) = two_class_model();
        let mut backend = CpuBackend::new();
        let mut shared = search(&params, &reference, false, &mut backend).unwrap().unwrap();
        for (i, &allowed) in SEARCH_ALLOWANCES.iter().enumerate() {
            let mut fresh = search(&params, &reference, false, &mut backend).unwrap().unwrap();
            let want = fresh.choose(allowed, &mut backend).unwrap();
            let before = shared.seen.len();
            assert_eq!(shared.choose(allowed, &mut backend).unwrap(), want, "allowance {allowed}");
            let scored = shared.seen.len() - before;
            if i == 0 {
                assert_eq!(scored, fresh.seen.len());
            } else {
                assert!(scored < fresh.seen.len(), "allowance {allowed}: {scored} scored again of a fresh search's {}", fresh.seen.len());
            }
            assert_eq!(shared.seen.iter().filter(|(p, _)| fresh.seen.contains_key(p)).count(), fresh.seen.len());
            // Each precision was scored once.
            assert_eq!((shared.scored, fresh.scored), (shared.seen.len(), fresh.seen.len()));
        }
    }

    #[test]
    fn the_sample_is_drawn_from_the_support_only_and_covers_it() {
        // A 96 x 48 x 48 lattice (221,184 voxels) with data in one half
        // along x only (110,592 voxels, more than POINTS).
        let dims = [96, 48, 48];
        let values: Vec<f32> = (0..96 * 48 * 48).map(|i| if i % 96 < 48 { 0.5 } else { 0.0 }).collect();
        let grid = Grid::new(dims, values).unwrap();
        let s = sample(&grid, true).unwrap();
        assert_eq!(s.points.len(), POINTS);
        assert!(s.points.iter().all(|p| p[0] < 48.0), "a point outside the support");
        assert!(s.values.iter().all(|&v| v == 0.5));
        // Every octant of the support's own 48^3 box is drawn from.
        let mut octants = [0usize; 8];
        s.points.iter().for_each(|p| octants[(p[0] >= 24.0) as usize + 2 * (p[1] >= 24.0) as usize + 4 * (p[2] >= 24.0) as usize] += 1);
        assert!(octants.iter().all(|&n| n > POINTS / 16), "{octants:?}");
        // Without a support, every voxel is a candidate; with no data at all, none.
        let all = sample(&grid, false).unwrap();
        assert_eq!(all.points.len(), POINTS);
        assert!(all.points.iter().any(|p| p[0] >= 48.0));
        assert!(sample(&Grid::new(dims, vec![0.0; dims.iter().product()]).unwrap(), true).is_none());
        // A lattice of no more candidates than POINTS is scored whole, each voxel once.
        let small = Grid::new([40, 40, 40], (0..64000).map(|i| if i % 40 < 20 { 0.5 } else { 0.0 }).collect()).unwrap();
        let s = sample(&small, true).unwrap();
        assert_eq!(s.points.len(), 32000);
        assert!(s.points.iter().all(|p| p[0] < 20.0) && s.values.iter().all(|&v| v == 0.5));
        let mut seen: Vec<[u32; 3]> = s.points.iter().map(|p| p.map(|c| c as u32)).collect();
        seen.sort_unstable();
        seen.dedup();
        assert_eq!(seen.len(), 32000, "a voxel twice");
        assert_eq!(sample(&small, false).unwrap().points.len(), 64000);
    }

    /// A voxel exactly at the mask is outside the support (as the
    /// support's own rule: above it), and a lattice of exactly [`POINTS`]
    /// candidates is scored whole, each voxel once, in lattice order.
    #[test]
    fn the_sample_at_the_mask_and_at_exactly_its_size() {
        let mut values = vec![MASK_REF; 64];
        values[37] = MASK_REF.next_up();
        let s = sample(&Grid::new([4, 4, 4], values).unwrap(), true).unwrap();
        assert_eq!((s.points, s.values), (vec![[1.0, 1.0, 2.0]], vec![MASK_REF.next_up()]));
        let whole = Grid::new([64, 32, 32], vec![0.5; POINTS]).unwrap();
        assert_eq!(sample(&whole, false).unwrap().points, (0..POINTS).map(|i| whole.centre(i)).collect::<Vec<_>>());
    }

    /// A model of `params` on `reference`'s lattice, with the support of
    /// `reference` when `support`.
    fn model_of(params: &[Primitive], reference: &Grid, support: bool) -> Model {
        let frame = IndexFrame::for_grid(reference.dims, [0.0; 3], 1.0).unwrap();
        let meta = ModelMeta::new(frame, ValueRange::new(0.0, 1.0, Transform::Linear).unwrap());
        Model { meta, params: params.to_vec(), support: if support { Support::from_reference(reference) } else { None } }
    }

    #[test]
    fn a_model_without_primitives_or_without_a_sample_gets_the_default() {
        let (params, reference) = two_class_model();
        let mut backend = CpuBackend::new();
        assert_eq!(choose_precision(&[], &reference, false, MAX_PSNR_LOSS_DB, &mut backend).unwrap(), Precision::DEFAULT);
        let nothing = Grid::new(reference.dims, vec![0.0; reference.len()]).unwrap();
        assert_eq!(choose_precision(&params, &nothing, true, MAX_PSNR_LOSS_DB, &mut backend).unwrap(), Precision::DEFAULT);
        let mut empty = model_of(&[], &reference, false);
        let m = measure_precision(&mut empty, &reference, &mut backend).unwrap();
        assert_eq!((empty.meta.precision, m.psnr), (Some(Precision::DEFAULT), m.float32_psnr));
    }

    /// When the lattice loses more than the sample promised, the search
    /// runs again with the next allowance, and after the last one every
    /// group gains a bit (none past the finest) until the lattice loses at
    /// most `max_loss`, and no more bits than that. Allowances far beyond
    /// it (5 and 3 dB) make both searches miss.
    #[test]
    fn a_miss_on_the_lattice_searches_again_then_adds_a_bit_to_every_group() {
        let (params, reference) = two_class_model();
        let mut backend = CpuBackend::new();
        let float32 = voxel_psnr(&decode_as_stored(Payload::Float32, &model_of(&params, &reference, false), &reference, &mut backend).unwrap().decoded, &reference.values);
        let lattice_loss = |p: Precision| {
            let mut m = model_of(&params, &reference, false);
            m.meta.precision = Some(p);
            float32 - voxel_psnr(&decode_as_stored(Payload::Packed, &m, &reference, &mut CpuBackend::new()).unwrap().decoded, &reference.values)
        };
        let (first, last) = [5.0, 3.0].map(|allowed| choose_precision(&params, &reference, false, allowed, &mut backend).unwrap()).into();
        assert!(lattice_loss(first) > MAX_PSNR_LOSS_DB && lattice_loss(last) > MAX_PSNR_LOSS_DB);

        let mut model = model_of(&params, &reference, false);
        let m = measure_with(&mut model, &reference, &mut backend, &[5.0, 3.0], MAX_PSNR_LOSS_DB).unwrap();
        let p = model.meta.precision.unwrap();
        let finest = finest_for(&params);
        let plus = |k: u8| (0..GROUPS.len()).fold(last, |q, g| q.with(g, (last.get(g) + k).min(finest.get(g))));
        let k = (1..=MAX_BITS).find(|&k| plus(k) == p).unwrap_or_else(|| panic!("{p:?} is not {last:?} with bits added"));
        assert!((0..GROUPS.len()).all(|g| p.get(g) <= finest.get(g)), "{p:?} past the finest");
        assert_eq!(m.float32_psnr, float32);
        assert!((float32 - m.psnr - lattice_loss(p)).abs() < 1e-12 && lattice_loss(p) <= MAX_PSNR_LOSS_DB, "{p:?}");
        assert!(lattice_loss(plus(k - 1)) > MAX_PSNR_LOSS_DB, "{k} bits added, one fewer was enough");
    }

    /// The support is stored with its outside fitted to the packed
    /// parameters' decode, not the float32 ones' (which differ: the test
    /// can tell them apart). The reference is the model's own decode, with
    /// noise only inside the support, so that its tail outside is what an
    /// outside fits.
    #[test]
    fn the_support_is_stored_with_its_outside_fitted_to_the_packed_decode() {
        let (params, _) = two_class_model();
        let mut backend = CpuBackend::new();
        let dims = [24, 24, 24];
        let decode = |params: &[Primitive]| {
            let mut out = vec![0f32; 24 * 24 * 24];
            CpuBackend::new().decode_lattice(params, &Lattice::reference(dims), &mut out).unwrap();
            out
        };
        let mut rng = Rng::new(8);
        let reference = Grid::new(dims, decode(&params).iter().map(|&v| if v > 0.02 { v + 0.01 * rng.normal() as f32 } else { v }).collect()).unwrap();
        let mut model = model_of(&params, &reference, true);
        measure_precision(&mut model, &reference, &mut backend).unwrap();
        let support = model.support.as_ref().expect("the model keeps its support");
        let packed = Packed::of(&params, model.meta.precision.unwrap()).unwrap().params().unwrap();
        let fitted = support.fit_outside(&decode(&packed), &reference);
        assert!(!fitted.is_zero());
        assert_eq!(support.outside(), fitted);
        assert_ne!(support.outside(), support.fit_outside(&decode(&params), &reference));
    }

    /// Numbers a primitive stores per bit in the analytic searches below:
    /// no centre class is searched.
    const ANALYTIC_NUMBERS: [f64; GROUPS.len()] = [0.0, 0.0, 0.0, 0.0, 3.0, 3.0, 1.0, 1.0];

    /// An analytic loss in dB: each group but the centres' adds an error
    /// `c 4^-bits` (a quantisation step's square) to an error of 1, summed
    /// or (`compound`) as the cube of the sum of their cube roots, up to
    /// 16 times their sum: groups that each lose their share then lose
    /// more together.
    fn analytic(c: [f64; 4], compound: bool) -> impl Fn(Precision) -> f64 {
        move |p| {
            let e = (0..4).map(|i| c[i] * 4f64.powi(-(p.get(CENTRE_CLASSES + i) as i32)));
            10.0 * (1.0 + if compound { e.map(f64::cbrt).sum::<f64>().powi(3) } else { e.sum() }).log10()
        }
    }

    fn analytic_search(loss: impl Fn(Precision) -> f64) -> Search<impl FnMut(Precision, &mut dyn Backend) -> Result<f64>> {
        Search::over(move |p: Precision, _: &mut dyn Backend| Ok(loss(p)), ANALYTIC_NUMBERS, Precision::FINEST)
    }

    fn stored_bits(p: Precision) -> f64 {
        (0..GROUPS.len()).map(|g| ANALYTIC_NUMBERS[g] * p.get(g) as f64).sum()
    }

    /// Every precision of the searched groups (the centres at the finest)
    /// that loses at most `allowed`: the fewest bits stored.
    fn fewest_bits(loss: &impl Fn(Precision) -> f64, allowed: f64) -> f64 {
        let f = Precision::FINEST;
        let mut best = f64::INFINITY;
        for scale in 1..=f.scale {
            for rotation in 1..=f.rotation {
                for value in 1..=f.value {
                    for weight in 1..=f.weight {
                        let p = Precision { scale, rotation, value, weight, ..f };
                        if loss(p) <= allowed {
                            best = best.min(stored_bits(p));
                        }
                    }
                }
            }
        }
        best
    }

    /// Error constants of the analytic losses: groups alike, one group
    /// far costlier than the others, and between.
    const ANALYTIC_CASES: [[f64; 4]; 4] = [[40.0, 10.0, 200.0, 3.0], [1.0, 1000.0, 5.0, 50.0], [300.0, 300.0, 300.0, 300.0], [2.0, 30.0, 4000.0, 0.5]];

    /// Step 1 against its rule: each group alone (the others at their
    /// finest) at the fewest bits whose loss is within an equal share of
    /// the allowed error, the shares adding up to the allowance (in error,
    /// not in dB).
    #[test]
    fn each_group_alone_takes_the_fewest_bits_within_its_share() {
        let groups = [4, 5, 6, 7];
        for c in ANALYTIC_CASES {
            for allowed in [0.03, 0.1, 0.5] {
                let loss = analytic(c, false);
                let p = analytic_search(&loss).each_alone(&groups, allowed, &mut CpuBackend::new()).unwrap();
                let share = 10.0 * (1.0 + (10f64.powf(allowed / 10.0) - 1.0) / 4.0).log10();
                assert!((4.0 * (10f64.powf(share / 10.0) - 1.0) - (10f64.powf(allowed / 10.0) - 1.0)).abs() < 1e-12);
                for g in groups {
                    let alone = |bits: u8| loss(Precision::FINEST.with(g, bits));
                    assert!(alone(p.get(g)) <= share, "{c:?} {allowed}: group {g} at {p:?}");
                    assert!(p.get(g) == 1 || alone(p.get(g) - 1) > share, "{c:?} {allowed}: group {g} at {p:?} could give up a bit");
                }
                assert!(loss(p) <= allowed + 1e-12);
            }
        }
    }

    /// The whole search on analytic losses (the cases above and 40 drawn
    /// at random), against every precision: it loses at most the
    /// allowance and stores less than one bit of the most numerous group
    /// (3 numbers) more than the fewest that do (the greedy steps are not
    /// exact: up to 2 more here; a search that weighed each bit's loss
    /// alone, not per number stored, went 4 over).
    #[test]
    fn the_search_stores_nearly_the_fewest_bits_within_the_allowance() {
        let mut rng = Rng::new(3);
        let drawn: Vec<[f64; 4]> = (0..40).map(|_| std::array::from_fn(|_| 10f64.powf(rng.range(-0.5, 3.5)))).collect();
        for &c in ANALYTIC_CASES.iter().chain(&drawn) {
            for allowed in [0.03, 0.1, 0.5] {
                let loss = analytic(c, false);
                let p = analytic_search(&loss).choose(allowed, &mut CpuBackend::new()).unwrap();
                assert!(loss(p) <= allowed, "{c:?} {allowed}: {p:?} loses {}", loss(p));
                let (bits, fewest) = (stored_bits(p), fewest_bits(&loss, allowed));
                assert!(bits < fewest + 3.0, "{c:?} {allowed}: {p:?} stores {bits} bits, {fewest} lose no more");
            }
        }
    }

    /// When the groups, each within its share, lose more than the
    /// allowance together, every group gains a bit until they do not.
    #[test]
    fn groups_that_lose_more_together_gain_bits_until_within_the_allowance() {
        for c in ANALYTIC_CASES {
            let loss = analytic(c, true);
            let mut search = analytic_search(&loss);
            let alone = search.each_alone(&[4, 5, 6, 7], 0.1, &mut CpuBackend::new()).unwrap();
            assert!(loss(alone) > 0.1, "{c:?}: the shares add up");
            let p = search.choose(0.1, &mut CpuBackend::new()).unwrap();
            assert!(loss(p) <= 0.1, "{c:?}: {p:?} loses {}", loss(p));
        }
    }
}
