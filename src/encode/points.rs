//! Stratified training points (METHOD.md "Training points").
//!
//! Strata, in this order within a batch: 30 % from voxels with `V_ref > 0.4`,
//! 30 % from voxels with `0.02 < V_ref <= 0.4` (uniform over each pool), 15 %
//! uniform over the domain, 25 % at random sample positions plus N(0, 0.75^2)
//! noise. Every point gets U(-0.5, 0.5) jitter per axis and is clamped to the
//! domain `[0, D_a - 1]`; an empty pool's share goes to the uniform stratum.
//! Reference values are trilinear interpolations of the reference grid.
//!
//! gsenc's rule ([`PointRule::GSENC`]) puts every point at a voxel centre
//! instead (no jitter; the sample stratum's point is rounded), and draws a
//! share of each batch last, from the occupied voxels in proportion to the
//! current model's absolute error there (the error stratum), once the
//! encoder has given it an error map ([`PointSampler::map_errors`]).

use crate::backend::PointBatch;
use crate::encode::config::PointRule;
use crate::error::Result;
use crate::field::{prefetch, Grid};
use crate::input::samples::SampleSet;
use crate::math::loss::{v_eval, MASK_REF};
use crate::math::rng::{normal_from, open0_from, range_from, uniform_from, Rng};
use crate::profile;

pub const HIGH_THRESHOLD: f32 = 0.4;
pub const MID_THRESHOLD: f32 = 0.02;
pub const SAMPLE_NOISE_SIGMA: f64 = 0.75;
/// The error map covers at most this many occupied voxels: above it, a
/// fresh uniform draw of this many (with replacement) at each refresh.
pub const ERROR_MAP_VOXELS: usize = 1 << 20;
/// Voxels are evaluated in chunks of this many for the error map.
const ERROR_MAP_CHUNK: usize = 1 << 16;

/// Draws batches from one sequential random stream (seed 1 by default).
pub struct PointSampler {
    high: Vec<u32>,
    mid: Vec<u32>,
    /// Voxels with `V_ref > MASK_REF`: those an error map covers.
    occupied: Vec<u32>,
    rule: PointRule,
    /// The latest error map: voxels and the running sum of their errors.
    errors: Option<ErrorMap>,
    rng: Rng,
    /// The words of the latest batch (`draw`), kept for the next one.
    draws: Vec<Draw>,
}

struct ErrorMap {
    voxels: Vec<u32>,
    cumulative: Vec<f64>,
    /// The guide table of `cumulative` (its `Guide::build`), once mapped.
    guide: Guide,
}

/// A guide table (Chen and Asau's) over a non-decreasing running sum: the
/// index a draw selects by binary search over the whole sum, found by a
/// search over one bucket. Bucket `j` starts at `bound(j) = total * j / M`
/// and `first[j]` is the first index whose sum passes `bound(j)`, so the
/// answer for a draw in bucket `j` lies in `first[j] ..= first[j + 1]`:
/// the same index as the whole search, from two or three cache lines
/// instead of twenty (an error map holds up to a million voxels).
struct Guide {
    total: f64,
    /// `M`.
    buckets: usize,
    /// `M + 1` entries; the last is the sum's length.
    first: Vec<u32>,
}

impl Guide {
    /// One bucket per entry of `cumulative` (non-decreasing, non-empty,
    /// fewer than 2^32 entries).
    fn build(cumulative: &[f64]) -> Guide {
        let total = *cumulative.last().expect("a guide over an empty sum");
        let m = cumulative.len();
        let mut g = Guide { total, buckets: m, first: Vec::with_capacity(m + 1) };
        let mut k = 0;
        for j in 0..=m {
            let b = g.bound(j);
            while k < m && cumulative[k] <= b {
                k += 1;
            }
            g.first.push(k as u32);
        }
        g
    }

    /// Where bucket `j` of `M` starts. Non-decreasing in `j`.
    fn bound(&self, j: usize) -> f64 {
        self.total * (j as f64 / self.buckets as f64)
    }

    /// The bucket [`Guide::find`] tries first for `u`.
    fn guess(&self, u: f64) -> usize {
        ((u / self.total * self.buckets as f64) as usize).min(self.buckets - 1)
    }

    /// Asks the cache for the bucket bounds `find` reads first for `u`.
    fn prefetch(&self, u: f64) {
        prefetch(&self.first, self.guess(u));
    }

    /// `cumulative.partition_point(|&s| s <= u)`, for `u >= 0`.
    fn find(&self, cumulative: &[f64], u: f64) -> usize {
        let m = self.buckets;
        // A first guess of the bucket, then the bucket whose bounds hold
        // `u` exactly as `build` computed them.
        let mut j = self.guess(u);
        while j > 0 && self.bound(j) > u {
            j -= 1;
        }
        while j + 1 < m && self.bound(j + 1) <= u {
            j += 1;
        }
        let (lo, hi) = (self.first[j] as usize, self.first[j + 1] as usize);
        lo + cumulative[lo..hi].partition_point(|&s| s <= u)
    }
}

/// How many points each stratum gets for a batch of `p`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct StratumCounts {
    pub high: usize,
    pub mid: usize,
    pub uniform: usize,
    pub samples: usize,
    /// Drawn in proportion to the model's error (gsenc's rule, once mapped).
    pub error: usize,
}

impl PointSampler {
    pub fn new(reference: &Grid, seed: u64, rule: PointRule) -> PointSampler {
        let mut high = vec![];
        let mut mid = vec![];
        let mut occupied = vec![];
        for (i, &v) in reference.values.iter().enumerate() {
            if v > HIGH_THRESHOLD {
                high.push(i as u32);
            } else if v > MID_THRESHOLD {
                mid.push(i as u32);
            }
            if rule.error_share > 0.0 && v > MASK_REF {
                occupied.push(i as u32);
            }
        }
        PointSampler { high, mid, occupied, rule, errors: None, rng: Rng::new(seed), draws: vec![] }
    }

    /// Whether this sampler draws an error stratum, and so wants error maps.
    pub fn wants_errors(&self) -> bool {
        self.rule.error_share > 0.0 && !self.occupied.is_empty()
    }

    /// Maps the current model's error `|V_eval - V_ref|` at the occupied
    /// voxels (at most [`ERROR_MAP_VOXELS`] of them, drawn from the stream
    /// when there are more), for the error stratum of the batches after it.
    /// `evaluate` gives the mixture's `rho` and `n` at voxel centres.
    pub fn map_errors(
        &mut self,
        reference: &Grid,
        mut evaluate: impl FnMut(&[[f32; 3]], &mut [f32], &mut [f32]) -> Result<()>,
    ) -> Result<()> {
        if !self.wants_errors() {
            return Ok(());
        }
        let drawn: Vec<u32>;
        let voxels: &[u32] = if self.occupied.len() <= ERROR_MAP_VOXELS {
            &self.occupied
        } else {
            let (occupied, rng) = (&self.occupied, &mut self.rng);
            drawn = (0..ERROR_MAP_VOXELS).map(|_| occupied[rng.below(occupied.len() as u64) as usize]).collect();
            &drawn
        };
        let (mut mapped, mut cumulative) = (Vec::with_capacity(voxels.len()), Vec::with_capacity(voxels.len()));
        let mut total = 0f64;
        let (mut rho, mut n) = (vec![0f32; ERROR_MAP_CHUNK], vec![0f32; ERROR_MAP_CHUNK]);
        for chunk in voxels.chunks(ERROR_MAP_CHUNK) {
            let pos: Vec<[f32; 3]> = chunk.iter().map(|&i| reference.centre(i as usize)).collect();
            let (rho, n) = (&mut rho[..chunk.len()], &mut n[..chunk.len()]);
            evaluate(&pos, rho, n)?;
            for (k, &i) in chunk.iter().enumerate() {
                let e = (v_eval(rho[k], n[k]) - reference.values[i as usize]).abs() as f64;
                if e > 0.0 {
                    total += e;
                    mapped.push(i);
                    cumulative.push(total);
                }
            }
        }
        self.errors = (!mapped.is_empty()).then(|| ErrorMap { guide: Guide::build(&cumulative), voxels: mapped, cumulative });
        Ok(())
    }

    pub fn counts(&self, p: usize, have_samples: bool) -> StratumCounts {
        let error = if self.errors.is_some() { (self.rule.error_share as f64 * p as f64).round() as usize } else { 0 };
        let p = p - error;
        let mut c = StratumCounts {
            high: (0.30 * p as f64).round() as usize,
            mid: (0.30 * p as f64).round() as usize,
            uniform: (0.15 * p as f64).round() as usize,
            samples: 0,
            error,
        };
        c.samples = p - c.high - c.mid - c.uniform;
        if self.high.is_empty() {
            c.uniform += std::mem::take(&mut c.high);
        }
        if self.mid.is_empty() {
            c.uniform += std::mem::take(&mut c.mid);
        }
        if !have_samples {
            c.uniform += std::mem::take(&mut c.samples);
        }
        c
    }

    /// A batch of `p` points, in runs of `RUN`. Two passes: what each
    /// point takes from the random stream is drawn in turn on this thread
    /// (the words of a `Draw`, run by run); turning a run's words into
    /// positions and reference values (the conversions to uniforms, the
    /// pool, sample and error-map lookups, the normals' logarithms and
    /// cosines, the interpolation) takes nothing more from the stream, so
    /// each run is a task of its own, handed to the pool as soon as its
    /// words are drawn: the pool places the first runs while this thread
    /// draws the next. The batch is the same bits as drawing and placing
    /// each point in turn, whatever the thread count.
    pub fn draw(&mut self, p: usize, reference: &Grid, samples: &dyn SampleSet) -> PointBatch {
        let c = self.counts(p, !samples.is_empty());
        let dims = reference.dims;
        let PointSampler { high, mid, rule, errors, rng, draws, .. } = self;
        let (high, mid, errors, on_lattice) = (&*high, &*mid, errors.as_ref(), rule.on_lattice);
        // Where each stratum's points end in the batch.
        let ends = [c.high, c.high + c.mid, c.high + c.mid + c.uniform, c.high + c.mid + c.uniform + c.samples, p];
        // Point `i`'s stratum, without a branch.
        let stratum = |i: usize| ends[..ERROR].iter().map(|&e| (i >= e) as usize).sum::<usize>();
        let voxel = |i: u32| reference.centre(i as usize).map(f64::from);
        // Where point `i` of the batch lies before placing, by its stratum.
        let unplaced = |i: usize, d: &Draw| -> [f64; 3] {
            match stratum(i) {
                HIGH => voxel(high[d.pick as usize]),
                MID => voxel(mid[d.pick as usize]),
                UNIFORM if on_lattice => [0, 1, 2].map(|a| d.w[a] as f64),
                UNIFORM => [0, 1, 2].map(|a| range_from(0.0, (dims[a] - 1) as f64, d.w[a])),
                SAMPLES => {
                    let q = samples.position(d.pick as usize);
                    [0, 1, 2].map(|a| q[a] as f64 + SAMPLE_NOISE_SIGMA * normal_from(open0_from(d.w[2 * a]), uniform_from(d.w[2 * a + 1])))
                }
                _ => {
                    // The first mapped voxel whose running sum passes the draw.
                    let map = errors.expect("an error stratum only with a map");
                    let k = map.guide.find(&map.cumulative, uniform_from(d.w[0]) * map.guide.total).min(map.voxels.len() - 1);
                    voxel(map.voxels[k])
                }
            }
        };
        // The paper's points: jittered, then clamped to the domain; gsenc's:
        // rounded to the nearest voxel centre, then clamped.
        let place = |q: [f64; 3], d: &Draw| -> [f32; 3] {
            std::array::from_fn(|a| {
                let x = if on_lattice { q[a].round() } else { q[a] + range_from(-0.5, 0.5, d.w[JITTER + a]) };
                x.clamp(0.0, (dims[a] - 1) as f64) as f32
            })
        };
        // What placing point `i` reads at random (a pool's entry, a
        // sample's position), asked of the cache ahead of the point.
        let prefetch_unplaced = |i: usize, d: &Draw| match stratum(i) {
            HIGH => prefetch(high, d.pick as usize),
            MID => prefetch(mid, d.pick as usize),
            UNIFORM => {}
            SAMPLES => samples.prefetch_position(d.pick as usize),
            _ => {
                if let Some(map) = errors {
                    map.guide.prefetch(uniform_from(d.w[0]) * map.guide.total)
                }
            }
        };
        // A run, its points placed first and then read: apart, the loops
        // keep many independent cache misses in flight (one loop that placed
        // and read each point in turn was slower by a third); the placing
        // asks the cache for what it reads `AHEAD` points early, and the
        // reading for all of the run's values before it reads any.
        const AHEAD: usize = 16;
        let place_run = |first: usize, ds: &[Draw], xs: &mut [[f32; 3]], vs: &mut [f32]| {
            for (k, d) in ds.iter().enumerate().take(AHEAD) {
                prefetch_unplaced(first + k, d);
            }
            for (k, (x, d)) in xs.iter_mut().zip(ds).enumerate() {
                if let Some(ahead) = ds.get(k + AHEAD) {
                    prefetch_unplaced(first + k + AHEAD, ahead);
                }
                *x = place(unplaced(first + k, d), d);
            }
            // At a voxel centre the trilinear value is the voxel's own, bit
            // for bit (every weight but its own is zero and the values are
            // finite), so gsenc's points read that one value rather than eight.
            if on_lattice {
                let mut at = [0usize; RUN];
                for (a, &x) in at.iter_mut().zip(xs.iter()) {
                    *a = lattice_index(reference, x);
                    prefetch(&reference.values, *a);
                }
                for (v, &a) in vs.iter_mut().zip(at.iter()) {
                    *v = reference.values[a];
                }
            } else {
                let mut corners = [([0usize; 3], [0f32; 3]); RUN];
                for (c, &x) in corners.iter_mut().zip(xs.iter()) {
                    *c = reference.corner(x);
                    reference.prefetch_corner(c.0);
                }
                for (v, &(i0, t)) in vs.iter_mut().zip(corners.iter()) {
                    *v = reference.interpolate(i0, t);
                }
            }
        };
        // The stream's words of one point, in the stream's order: its pick
        // (or the uniform stratum's lattice coordinates), then its jitter.
        let take = |rng: &mut Rng, stratum: usize, d: &mut Draw| {
            match stratum {
                HIGH => d.pick = rng.below(high.len() as u64),
                MID => d.pick = rng.below(mid.len() as u64),
                UNIFORM if on_lattice => (0..3).for_each(|a| d.w[a] = rng.below(dims[a] as u64)),
                UNIFORM => (0..3).for_each(|a| d.w[a] = rng.next_u64()),
                // Each axis's normal: its two uniforms, in `Rng::normal`'s order.
                SAMPLES => {
                    d.pick = rng.below(samples.len() as u64);
                    (0..6).for_each(|k| d.w[k] = rng.next_u64());
                }
                _ => d.w[0] = rng.next_u64(),
            }
            // The paper's points are jittered by half a voxel; gsenc's are not.
            if !on_lattice {
                (0..3).for_each(|a| d.w[JITTER + a] = rng.next_u64());
            }
        };
        // A run's words, stratum by stratum.
        let take_run = |rng: &mut Rng, first: usize, ds: &mut [Draw]| {
            let mut from = 0;
            for (st, &end) in ends.iter().enumerate() {
                let to = end.saturating_sub(first).clamp(from, ds.len());
                ds[from..to].iter_mut().for_each(|d| take(rng, st, d));
                from = to;
            }
        };
        // Kept from batch to batch: a new one would be written whole first
        // (1.3 MB at 16,384 points), and every word a point reads is drawn
        // for it before it is read.
        if draws.len() < p {
            draws.resize(p, Draw::default());
        }
        let (mut pos, mut vref) = (vec![[0f32; 3]; p], vec![0f32; p]);
        rayon::scope(|s| {
            let runs = draws[..p].chunks_mut(RUN).zip(pos.chunks_mut(RUN)).zip(vref.chunks_mut(RUN));
            for (r, ((ds, xs), vs)) in runs.enumerate() {
                let first = r * RUN;
                profile::serial("draw: stream", || take_run(rng, first, ds));
                let (ds, place_run) = (&*ds, &place_run);
                s.spawn(move |_| profile::task("draw: points", || place_run(first, ds, xs, vs)));
            }
        });
        PointBatch::new(pos, vref)
    }
}

/// A batch's strata, in the batch's and the stream's order.
const HIGH: usize = 0;
const MID: usize = 1;
const UNIFORM: usize = 2;
const SAMPLES: usize = 3;
const ERROR: usize = 4;
/// Points a task of the draw places; each task's draws are drawn before
/// it starts, while the tasks before it run.
const RUN: usize = 512;
/// Where a `Draw`'s jitter words begin.
const JITTER: usize = 6;

/// The words one point of a batch takes from the random stream, as drawn:
/// an index into its pool or the sample set (`pick`), then the uniform
/// stratum's three coordinates (on the lattice: already integers), the
/// sample stratum's three pairs of uniforms for its normals, or the error
/// stratum's uniform (`w[0..6]`), then its jitter (`w[6..9]`). Only the
/// words its stratum takes are drawn; the conversions to floats happen
/// where the point is placed.
#[derive(Clone, Copy, Default)]
struct Draw {
    pick: u64,
    w: [u64; 9],
}

/// The voxel whose centre `x` is (a lattice point inside the grid).
fn lattice_index(g: &Grid, x: [f32; 3]) -> usize {
    g.index(x[0] as usize, x[1] as usize, x[2] as usize)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::input::samples::SampleArrays;

    /// The sampler's draw as it was written before it had two passes:
    /// each point drawn and placed in turn, then the reference values.
    fn draw_in_turn(s: &mut PointSampler, p: usize, reference: &Grid, samples: &dyn SampleSet) -> PointBatch {
        let c = s.counts(p, !samples.is_empty());
        let dims = reference.dims;
        let on_lattice = s.rule.on_lattice;
        let mut pos = Vec::with_capacity(p);
        let rng = &mut s.rng;
        let place = |rng: &mut Rng, q: [f64; 3]| -> [f32; 3] {
            let mut out = [0f32; 3];
            for a in 0..3 {
                let x = if on_lattice { q[a].round() } else { q[a] + rng.range(-0.5, 0.5) };
                out[a] = x.clamp(0.0, (dims[a] - 1) as f64) as f32;
            }
            out
        };
        let voxel = |i: u32| reference.centre(i as usize).map(f64::from);
        for (pool, count) in [(&s.high, c.high), (&s.mid, c.mid)] {
            for _ in 0..count {
                let idx = pool[rng.below(pool.len() as u64) as usize];
                pos.push(place(rng, voxel(idx)));
            }
        }
        for _ in 0..c.uniform {
            let q = if on_lattice {
                [0, 1, 2].map(|a| rng.below(dims[a] as u64) as f64)
            } else {
                [0, 1, 2].map(|a| rng.range(0.0, (dims[a] - 1) as f64))
            };
            pos.push(place(rng, q));
        }
        for _ in 0..c.samples {
            let smp = samples.get(rng.below(samples.len() as u64) as usize);
            let q = [
                smp.q[0] as f64 + SAMPLE_NOISE_SIGMA * rng.normal(),
                smp.q[1] as f64 + SAMPLE_NOISE_SIGMA * rng.normal(),
                smp.q[2] as f64 + SAMPLE_NOISE_SIGMA * rng.normal(),
            ];
            pos.push(place(rng, q));
        }
        if let Some(map) = &s.errors {
            for _ in 0..c.error {
                let u = rng.uniform() * map.guide.total;
                let k = whole_search(&map.cumulative, u).min(map.voxels.len() - 1);
                pos.push(place(rng, voxel(map.voxels[k])));
            }
        }
        let vref = pos.iter().map(|&x| reference.trilinear(x)).collect();
        PointBatch::new(pos, vref)
    }

    /// Batches of both rules, with and without an error map, from a grid's
    /// voxels and from scattered samples, with an empty pool and a batch
    /// smaller than a parallel task: the two-pass draw gives the bits of
    /// the draw in turn, batch after batch (so it also leaves the stream
    /// where that one does), on one thread and on three, its kept words
    /// garbage at first and then the last batch's.
    #[test]
    fn the_two_pass_draw_gives_the_points_of_the_draw_in_turn() {
        let mut rng = Rng::new(17);
        let dims = [23usize, 17, 11];
        let n = dims.iter().product();
        // Values over every pool; the second grid has none above 0.4.
        let grids: Vec<Grid> = [1.0, 0.39]
            .iter()
            .map(|&top| Grid::new(dims, (0..n).map(|_| if rng.below(3) == 0 { 0.0 } else { (top * rng.uniform()) as f32 }).collect()).unwrap())
            .collect();
        let mut scattered = SampleArrays::default();
        for _ in 0..300 {
            let q = [0, 1, 2].map(|a| rng.range(-2.0, dims[a] as f64 + 2.0) as f32);
            scattered.push(crate::input::samples::Sample { q, h: 0.7, v: rng.uniform() as f32, m: 1.0 });
        }
        let none = SampleArrays::default();
        for threads in [1, 3] {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            pool.install(|| {
                for g in &grids {
                    for rule in [PointRule::PAPER, PointRule::GSENC] {
                        for samples in [g as &dyn SampleSet, &scattered, &none] {
                            let (mut two, mut one) = (PointSampler::new(g, 5, rule), PointSampler::new(g, 5, rule));
                            // Words it keeps between batches, garbage at first: a point
                            // must read only the words drawn for it.
                            two.draws = vec![Draw { pick: u64::MAX, w: [0x7ff8_dead_beef_f00d; 9] }; 6000];
                            for round in 0..3 {
                                if round == 1 {
                                    // A made-up error map (the same in both).
                                    let mut e = Rng::new(round);
                                    let mut errors = |pos: &[[f32; 3]], rho: &mut [f32], n: &mut [f32]| {
                                        for k in 0..pos.len() {
                                            (rho[k], n[k]) = (1.0, e.uniform() as f32);
                                        }
                                        Ok(())
                                    };
                                    two.map_errors(g, &mut errors).unwrap();
                                    let mut e = Rng::new(round);
                                    one.map_errors(g, |pos: &[[f32; 3]], rho: &mut [f32], n: &mut [f32]| {
                                        for k in 0..pos.len() {
                                            (rho[k], n[k]) = (1.0, e.uniform() as f32);
                                        }
                                        Ok(())
                                    })
                                    .unwrap();
                                }
                                for p in [5, 2000, 5000] {
                                    let (a, b) = (two.draw(p, g, samples), draw_in_turn(&mut one, p, g, samples));
                                    assert_eq!(a.len(), p);
                                    let bits = |b: &PointBatch| -> Vec<u32> { b.pos.iter().flatten().chain(&b.vref).map(|x| x.to_bits()).collect() };
                                    assert!(bits(&a) == bits(&b), "{threads} threads, rule {rule:?}, {} samples, round {round}, {p} points", samples.len());
                                }
                            }
                        }
                    }
                }
            });
        }
    }

    /// The plain search the guide table replaces.
    fn whole_search(cumulative: &[f64], u: f64) -> usize {
        cumulative.partition_point(|&s| s <= u)
    }

    #[test]
    fn the_guide_table_finds_what_a_search_of_the_whole_sum_finds() {
        let mut rng = Rng::new(5);
        // Sums of very uneven errors (spans of 1e-12 .. 1), with runs of
        // equal sums (errors too small to change the total), long and short.
        for len in [1usize, 2, 3, 7, 100, 4097] {
            let mut total = 0f64;
            let cumulative: Vec<f64> = (0..len)
                .map(|k| {
                    let e = if k % 5 == 3 { total * 1e-18 } else { 10f64.powf(-12.0 * rng.uniform()) };
                    total += e;
                    total
                })
                .collect();
            let guide = Guide::build(&cumulative);
            let mut draws: Vec<f64> = (0..20_000).map(|_| rng.uniform() * total).collect();
            // Every bucket bound and every sum, and their neighbours.
            for j in 0..=len {
                let b = guide.bound(j);
                draws.extend([b, b.next_down(), b.next_up()]);
            }
            for &s in &cumulative {
                draws.extend([s, s.next_down(), s.next_up()]);
            }
            draws.extend([0.0, total]);
            for u in draws.into_iter().filter(|u| (0.0..=total).contains(u)) {
                assert_eq!(guide.find(&cumulative, u), whole_search(&cumulative, u), "len {len}, u {u:e}");
            }
        }
    }

    #[test]
    fn the_guide_table_holds_when_sums_sit_on_its_bucket_bounds() {
        // Sums placed exactly on bucket bounds and one step above them:
        // where rounding puts a draw's first guess of its bucket one off.
        let mut rng = Rng::new(11);
        for _ in 0..2_000 {
            let m = 3 + rng.below(40) as usize;
            let total = rng.range(0.1, 1e6);
            let bound = |j: usize| total * (j as f64 / m as f64);
            let mut cumulative: Vec<f64> = (0..m - 1)
                .map(|_| {
                    let b = bound(1 + rng.below(m as u64 - 1) as usize);
                    if rng.below(2) == 0 { b } else { b.next_up() }
                })
                .collect();
            cumulative.sort_by(f64::total_cmp);
            cumulative.push(total);
            let guide = Guide::build(&cumulative);
            for j in 0..=m {
                let b = guide.bound(j);
                assert_eq!(b, bound(j));
                for u in [b, b.next_down(), b.next_up()].into_iter().filter(|u| (0.0..=total).contains(u)) {
                    assert_eq!(guide.find(&cumulative, u), whole_search(&cumulative, u), "m {m}, total {total}, u {u:e}");
                }
            }
        }
    }

    #[test]
    fn a_voxel_centres_own_value_is_its_trilinear_value_bit_for_bit() {
        let mut rng = Rng::new(9);
        for dims in [[5usize, 4, 3], [1, 1, 1], [1, 6, 2], [7, 1, 1]] {
            let n = dims.iter().product();
            // Zeros, ones, tiny and ordinary values in [0, 1].
            let values: Vec<f32> = (0..n)
                .map(|i| match i % 4 {
                    0 => 0.0,
                    1 => 1.0,
                    2 => 1e-30 * rng.uniform() as f32,
                    _ => rng.uniform() as f32,
                })
                .collect();
            let g = Grid::new(dims, values).unwrap();
            for i in 0..n {
                let x = g.centre(i);
                assert_eq!(g.values[lattice_index(&g, x)].to_bits(), g.trilinear(x).to_bits(), "{dims:?} voxel {i}");
                assert_eq!(lattice_index(&g, x), i);
            }
        }
    }
}
