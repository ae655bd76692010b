//! Stratified training points (METHOD.md "Training points").
//!
//! Strata, in this order within a batch: 30 % from voxels with `V_ref > 0.4`,
//! 30 % from voxels with `0.02 < V_ref <= 0.4` (uniform over each pool), 15 %
//! uniform over the domain, 25 % at random sample positions plus N(0, 0.75^2)
//! noise. Every point gets U(-0.5, 0.5) jitter per axis and is clamped to the
//! domain `[0, D_a - 1]`; an empty pool's share goes to the uniform stratum.
//! Reference values are trilinear interpolations of the reference grid.

use crate::field::Grid;
use crate::math::rng::Rng;
use crate::input::samples::SampleSet;
use crate::backend::PointBatch;
use rayon::prelude::*;

pub const HIGH_THRESHOLD: f32 = 0.4;
pub const MID_THRESHOLD: f32 = 0.02;
pub const SAMPLE_NOISE_SIGMA: f64 = 0.75;

/// Draws batches from one sequential random stream (seed 1 by default).
pub struct PointSampler {
    high: Vec<u32>,
    mid: Vec<u32>,
    rng: Rng,
}

/// How many points each stratum gets for a batch of `p`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct StratumCounts {
    pub high: usize,
    pub mid: usize,
    pub uniform: usize,
    pub samples: usize,
}

impl PointSampler {
    pub fn new(reference: &Grid, seed: u64) -> PointSampler {
        let mut high = vec![];
        let mut mid = vec![];
        for (i, &v) in reference.values.iter().enumerate() {
            if v > HIGH_THRESHOLD {
                high.push(i as u32);
            } else if v > MID_THRESHOLD {
                mid.push(i as u32);
            }
        }
        PointSampler { high, mid, rng: Rng::new(seed) }
    }

    pub fn counts(&self, p: usize, have_samples: bool) -> StratumCounts {
        let mut c = StratumCounts {
            high: (0.30 * p as f64).round() as usize,
            mid: (0.30 * p as f64).round() as usize,
            uniform: (0.15 * p as f64).round() as usize,
            samples: 0,
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

    pub fn draw(&mut self, p: usize, reference: &Grid, samples: &dyn SampleSet) -> PointBatch {
        let c = self.counts(p, !samples.is_empty());
        let dims = reference.dims;
        let mut pos = Vec::with_capacity(p);
        let rng = &mut self.rng;
        let jitter_clamp = |rng: &mut Rng, q: [f64; 3]| -> [f32; 3] {
            let mut out = [0f32; 3];
            for a in 0..3 {
                let x = q[a] + rng.range(-0.5, 0.5);
                out[a] = x.clamp(0.0, (dims[a] - 1) as f64) as f32;
            }
            out
        };
        for (pool, count) in [(&self.high, c.high), (&self.mid, c.mid)] {
            for _ in 0..count {
                let idx = pool[rng.below(pool.len() as u64) as usize] as usize;
                let v = reference.coords(idx);
                pos.push(jitter_clamp(rng, [v[0] as f64, v[1] as f64, v[2] as f64]));
            }
        }
        for _ in 0..c.uniform {
            let q = [
                rng.range(0.0, (dims[0] - 1) as f64),
                rng.range(0.0, (dims[1] - 1) as f64),
                rng.range(0.0, (dims[2] - 1) as f64),
            ];
            pos.push(jitter_clamp(rng, q));
        }
        for _ in 0..c.samples {
            let s = samples.get(rng.below(samples.len() as u64) as usize);
            let q = [
                s.q[0] as f64 + SAMPLE_NOISE_SIGMA * rng.normal(),
                s.q[1] as f64 + SAMPLE_NOISE_SIGMA * rng.normal(),
                s.q[2] as f64 + SAMPLE_NOISE_SIGMA * rng.normal(),
            ];
            pos.push(jitter_clamp(rng, q));
        }
        // The positions come from one sequential stream; their reference
        // values are independent lookups, done in parallel.
        let vref = pos.par_iter().with_min_len(512).map(|&x| reference.trilinear(x)).collect();
        PointBatch { pos, vref }
    }
}
