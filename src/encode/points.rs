//! Stratified training points (METHOD.md "Training points").
//!
//! Strata, in this order within a batch: 30 % from voxels with `V_ref > 0.4`,
//! 30 % from voxels with `0.02 < V_ref <= 0.4` (uniform over each pool), 15 %
//! uniform over the domain, under the `field` objective a share from the band
//! of empty voxels around the data's support, and the rest (25 %, less the
//! band's) at random sample positions plus N(0, 0.75^2) noise. Every point
//! gets U(-0.5, 0.5) jitter per axis and is clamped to the domain
//! `[0, D_a - 1]`; an empty pool's share goes to the uniform stratum.
//! Reference values are trilinear interpolations of the reference grid.

use crate::backend::PointBatch;
use crate::encode::config::Objective;
use crate::field::Grid;
use crate::input::samples::SampleSet;
use crate::math::loss::MASK_REF;
use crate::math::rng::Rng;

pub const HIGH_THRESHOLD: f32 = 0.4;
pub const MID_THRESHOLD: f32 = 0.02;
pub const SAMPLE_NOISE_SIGMA: f64 = 0.75;

/// Draws batches from one sequential random stream (seed 1 by default).
pub struct PointSampler {
    high: Vec<u32>,
    mid: Vec<u32>,
    /// Empty voxels near the support (the `field` objective's band).
    band: Vec<u32>,
    band_share: f64,
    rng: Rng,
}

/// How many points each stratum gets for a batch of `p`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct StratumCounts {
    pub high: usize,
    pub mid: usize,
    pub uniform: usize,
    pub band: usize,
    pub samples: usize,
}

impl PointSampler {
    pub fn new(reference: &Grid, seed: u64, objective: Objective) -> PointSampler {
        let mut high = vec![];
        let mut mid = vec![];
        for (i, &v) in reference.values.iter().enumerate() {
            if v > HIGH_THRESHOLD {
                high.push(i as u32);
            } else if v > MID_THRESHOLD {
                mid.push(i as u32);
            }
        }
        let (band_share, width) = objective.band();
        let band = if band_share > 0.0 { band_voxels(reference, width) } else { vec![] };
        PointSampler { high, mid, band, band_share, rng: Rng::new(seed) }
    }

    pub fn counts(&self, p: usize, have_samples: bool) -> StratumCounts {
        let mut c = StratumCounts {
            high: (0.30 * p as f64).round() as usize,
            mid: (0.30 * p as f64).round() as usize,
            uniform: (0.15 * p as f64).round() as usize,
            band: (self.band_share * p as f64).round() as usize,
            samples: 0,
        };
        if std::env::var("GSENC_EXP_BAND_FROM").as_deref() == Ok("uniform") {
            let take = c.band.min(c.uniform);
            c.uniform -= take;
            c.band = take;
        }
        c.samples = p - c.high - c.mid - c.uniform - c.band;
        if self.high.is_empty() {
            c.uniform += std::mem::take(&mut c.high);
        }
        if self.mid.is_empty() {
            c.uniform += std::mem::take(&mut c.mid);
        }
        if self.band.is_empty() {
            c.uniform += std::mem::take(&mut c.band);
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
        let from_pool = |rng: &mut Rng, pos: &mut Vec<[f32; 3]>, pool: &[u32], count: usize| {
            for _ in 0..count {
                let idx = pool[rng.below(pool.len() as u64) as usize] as usize;
                let v = reference.coords(idx);
                pos.push(jitter_clamp(rng, [v[0] as f64, v[1] as f64, v[2] as f64]));
            }
        };
        from_pool(rng, &mut pos, &self.high, c.high);
        from_pool(rng, &mut pos, &self.mid, c.mid);
        for _ in 0..c.uniform {
            let q = [
                rng.range(0.0, (dims[0] - 1) as f64),
                rng.range(0.0, (dims[1] - 1) as f64),
                rng.range(0.0, (dims[2] - 1) as f64),
            ];
            pos.push(jitter_clamp(rng, q));
        }
        from_pool(rng, &mut pos, &self.band, c.band);
        for _ in 0..c.samples {
            let s = samples.get(rng.below(samples.len() as u64) as usize);
            let q = [
                s.q[0] as f64 + SAMPLE_NOISE_SIGMA * rng.normal(),
                s.q[1] as f64 + SAMPLE_NOISE_SIGMA * rng.normal(),
                s.q[2] as f64 + SAMPLE_NOISE_SIGMA * rng.normal(),
            ];
            pos.push(jitter_clamp(rng, q));
        }
        let vref = pos.iter().map(|&x| reference.trilinear(x)).collect();
        PointBatch { pos, vref }
    }
}

/// The empty voxels (reference at most the loss's mask) within `width`
/// voxels (per axis) of an occupied one: where the tails of the support's
/// Gaussians fall. A box dilation of the occupied voxels, one axis at a time.
pub fn band_voxels(reference: &Grid, width: usize) -> Vec<u32> {
    let dims = reference.dims;
    let mut near: Vec<bool> = reference.values.iter().map(|&v| v > MASK_REF).collect();
    let stride = [1, dims[0], dims[0] * dims[1]];
    for a in 0..3 {
        let mut next = near.clone();
        for (i, out) in next.iter_mut().enumerate() {
            if *out {
                continue;
            }
            let c = (i / stride[a]) % dims[a];
            let (lo, hi) = (c.saturating_sub(width), (c + width).min(dims[a] - 1));
            *out = (lo..=hi).any(|k| near[i - c * stride[a] + k * stride[a]]);
        }
        near = next;
    }
    (0..reference.len()).filter(|&i| near[i] && reference.values[i] <= MASK_REF).map(|i| i as u32).collect()
}
