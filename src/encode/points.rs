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
use crate::math::rng::{normal_from, Rng};
use crate::profile;
use rayon::prelude::*;

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
        PointSampler { high, mid, occupied, rule, errors: None, rng: Rng::new(seed) }
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

    /// A batch of `p` points. Two passes: what each point takes from the
    /// random stream is drawn in turn on this thread (`Draw`); turning
    /// the draws into positions and reference values (the pool, sample and
    /// error-map lookups, the normals' logarithms and cosines, the
    /// interpolation) takes nothing more from the stream, so it runs in
    /// parallel point by point. The batch is the same bits as drawing and
    /// placing each point in turn, whatever the thread count.
    pub fn draw(&mut self, p: usize, reference: &Grid, samples: &dyn SampleSet) -> PointBatch {
        let c = self.counts(p, !samples.is_empty());
        let dims = reference.dims;
        let on_lattice = self.rule.on_lattice;
        let draws = profile::serial("draw: stream", || self.stream(&c, dims, samples.len()));
        // Where each stratum's points end in the batch.
        let ends = [c.high, c.high + c.mid, c.high + c.mid + c.uniform, c.high + c.mid + c.uniform + c.samples];
        let voxel = |i: u32| reference.centre(i as usize).map(f64::from);
        // Where point `i` of the batch lies before placing, by its stratum.
        let unplaced = |i: usize, d: &Draw| -> [f64; 3] {
            if i < ends[0] {
                voxel(self.high[d.pick as usize])
            } else if i < ends[1] {
                voxel(self.mid[d.pick as usize])
            } else if i < ends[2] {
                [d.u[0], d.u[1], d.u[2]]
            } else if i < ends[3] {
                let q = samples.position(d.pick as usize);
                [0, 1, 2].map(|a| q[a] as f64 + SAMPLE_NOISE_SIGMA * normal_from(d.u[2 * a], d.u[2 * a + 1]))
            } else {
                // The first mapped voxel whose running sum passes the draw.
                let map = self.errors.as_ref().expect("an error stratum only with a map");
                let k = map.guide.find(&map.cumulative, d.u[0] * map.guide.total).min(map.voxels.len() - 1);
                voxel(map.voxels[k])
            }
        };
        // The paper's points: jittered, then clamped to the domain; gsenc's:
        // rounded to the nearest voxel centre, then clamped.
        let place = |q: [f64; 3], jitter: [f64; 3]| -> [f32; 3] {
            std::array::from_fn(|a| {
                let x = if on_lattice { q[a].round() } else { q[a] + jitter[a] };
                x.clamp(0.0, (dims[a] - 1) as f64) as f32
            })
        };
        // At a voxel centre the trilinear value is the voxel's own, bit for
        // bit (every weight but its own is zero and the values are
        // finite), so gsenc's points read that one value rather than eight.
        // What placing point `i` reads at random (a pool's entry, a
        // sample's position), asked of the cache ahead of the point.
        let prefetch_unplaced = |i: usize| {
            let Some(d) = draws.get(i) else { return };
            if i < ends[0] {
                prefetch(&self.high, d.pick as usize);
            } else if i < ends[1] {
                prefetch(&self.mid, d.pick as usize);
            } else if i >= ends[2] && i < ends[3] {
                samples.prefetch_position(d.pick as usize);
            } else if let Some(map) = self.errors.as_ref().filter(|_| i >= ends[3]) {
                map.guide.prefetch(d.u[0] * map.guide.total);
            }
        };
        // Runs of points, each placed first and then read: apart, the
        // loops keep many independent cache misses in flight (one loop that
        // placed and read each point in turn was slower by a third); the
        // placing asks the cache for what it reads `AHEAD` points early,
        // and the reading for all of a run's values before it reads any.
        const RUN: usize = 512;
        const AHEAD: usize = 16;
        let (mut pos, mut vref) = (vec![[0f32; 3]; p], vec![0f32; p]);
        profile::even("draw: points", p.div_ceil(RUN), || {
            pos.par_chunks_mut(RUN).zip(vref.par_chunks_mut(RUN)).enumerate().for_each(|(r, (xs, vs))| {
                let first = r * RUN;
                (first..first + AHEAD.min(xs.len())).for_each(prefetch_unplaced);
                for (k, x) in xs.iter_mut().enumerate() {
                    if k + AHEAD < RUN {
                        prefetch_unplaced(first + k + AHEAD);
                    }
                    let d = &draws[first + k];
                    *x = place(unplaced(first + k, d), d.jitter);
                }
                // Where each point reads, asked of the cache as it is
                // found, then the reads.
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
            })
        });
        PointBatch::new(pos, vref)
    }

    /// What each point of a batch of counts `c` takes from the random
    /// stream, stratum by stratum, in the stream's order.
    fn stream(&mut self, c: &StratumCounts, dims: [usize; 3], samples: usize) -> Vec<Draw> {
        let on_lattice = self.rule.on_lattice;
        let rng = &mut self.rng;
        let mut draws = Vec::with_capacity(c.high + c.mid + c.uniform + c.samples + c.error);
        // The paper's points are jittered by half a voxel; gsenc's are not.
        let jitter = |rng: &mut Rng| if on_lattice { [0.0; 3] } else { [0, 1, 2].map(|_| rng.range(-0.5, 0.5)) };
        for (pool, count) in [(&self.high, c.high), (&self.mid, c.mid)] {
            for _ in 0..count {
                let pick = rng.below(pool.len() as u64);
                draws.push(Draw { pick, u: [0.0; 6], jitter: jitter(rng) });
            }
        }
        for _ in 0..c.uniform {
            let mut u = [0.0; 6];
            for a in 0..3 {
                u[a] = if on_lattice { rng.below(dims[a] as u64) as f64 } else { rng.range(0.0, (dims[a] - 1) as f64) };
            }
            draws.push(Draw { pick: 0, u, jitter: jitter(rng) });
        }
        for _ in 0..c.samples {
            let pick = rng.below(samples as u64);
            // Each axis's normal: its two uniforms, in `Rng::normal`'s order.
            let mut u = [0.0; 6];
            for a in 0..3 {
                u[2 * a] = rng.uniform_open0();
                u[2 * a + 1] = rng.uniform();
            }
            draws.push(Draw { pick, u, jitter: jitter(rng) });
        }
        if self.errors.is_some() {
            for _ in 0..c.error {
                let u = [rng.uniform(), 0.0, 0.0, 0.0, 0.0, 0.0];
                draws.push(Draw { pick: 0, u, jitter: jitter(rng) });
            }
        }
        draws
    }
}

/// What one point of a batch takes from the random stream, in the stream's
/// order: an index into its pool or the sample set (`pick`), the uniform
/// stratum's position or the sample stratum's three pairs of uniforms for
/// its normals or the error stratum's uniform (`u`), then its jitter.
#[derive(Clone, Copy)]
struct Draw {
    pick: u64,
    u: [f64; 6],
    jitter: [f64; 3],
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
    /// where that one does), on one thread and on three.
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
                                for p in [5, 2000] {
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
