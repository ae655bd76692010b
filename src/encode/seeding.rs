//! Three-stream seeding of a budget of N primitives from samples
//! (METHOD.md "Seeding"; the paper's "Seeding from Samples").
//!
//! Streams and their order:
//! 1. importance, `round(0.45 N)`: without replacement, probability
//!    proportional to `m^0.6` (Efraimidis-Spirakis keys `ln(u) / m^0.6`);
//! 2. peak, up to `round(0.15 N)`: the highest-valued sample of each 2x2x2-voxel
//!    bin when it exceeds 0.55, highest values first; peak seeds may coincide
//!    with importance seeds (they carry a different scale and weight);
//! 3. uniform, the rest (including the unused peak share): uniform without
//!    replacement over samples drawn by neither stream above.
//!
//! With fewer samples than N, the peak stream is drawn as usual, every other
//! seed slot first takes each sample once (uniform stream) and the remaining
//! slots are copies drawn with replacement proportional to `m^0.6`
//! (importance stream), jittered by U(-0.5, 0.5) voxel per axis.

use crate::error::{Error, Result};
use crate::math::kernel::{isotropic, Primitive};
use crate::math::rng::Rng;
use crate::input::samples::SampleSet;

pub const IMPORTANCE_SHARE: f64 = 0.45;
pub const PEAK_SHARE: f64 = 0.15;
pub const IMPORTANCE_EXPONENT: f64 = 0.6;
pub const PEAK_THRESHOLD: f32 = 0.55;
pub const SPREAD_SCALE_CLIP: (f32, f32) = (0.35, 6.0);
pub const PEAK_SCALE_CLIP: (f32, f32) = (0.35, 2.5);
pub const SPREAD_WEIGHT: f32 = 0.35;
pub const PEAK_WEIGHT: f32 = 0.6;

/// Which stream produced a seed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stream {
    Importance,
    Uniform,
    Peak,
}

/// The seeded primitives, with the stream and sample each one came from.
#[derive(Clone, Debug)]
pub struct Seeding {
    pub params: Vec<Primitive>,
    pub stream: Vec<Stream>,
    pub sample: Vec<usize>,
}

impl Seeding {
    pub fn count(&self, s: Stream) -> usize {
        self.stream.iter().filter(|&&x| x == s).count()
    }
}

/// Seeds `n` primitives from `samples` on a reference grid of `dims`.
pub fn seed(samples: &dyn SampleSet, dims: [usize; 3], n: usize, seed: u64) -> Result<Seeding> {
    seed_with_spread(samples, dims, n, seed, spread(samples.len(), n))
}

/// The factor of a spread seed's scale: the cube root of the samples per
/// primitive, at least 1.
pub fn spread(samples: usize, n: usize) -> f32 {
    (samples as f32 / n as f32).cbrt().max(1.0)
}

/// [`seed`] with the factor of the spread streams' scales given: a seeding
/// of part of the samples (a warm start's repair, `repair.rs`) scales its
/// seeds as a seeding of all of them would.
pub fn seed_with_spread(samples: &dyn SampleSet, dims: [usize; 3], n: usize, seed: u64, spread: f32) -> Result<Seeding> {
    let ns = samples.len();
    if ns == 0 {
        return Err(Error::data("no samples to seed from"));
    }
    if n == 0 {
        return Err(Error::arg("budget must be at least 1 primitive"));
    }
    let mut rng = Rng::new(seed);
    let n_imp = (IMPORTANCE_SHARE * n as f64).round() as usize;
    let peak_share = (PEAK_SHARE * n as f64).round() as usize;
    let mut out = Seeding { params: Vec::with_capacity(n), stream: Vec::with_capacity(n), sample: Vec::with_capacity(n) };
    let push = |out: &mut Seeding, idx: usize, stream: Stream, jitter: Option<[f32; 3]>| {
        let s = samples.get(idx);
        let (sigma, weight) = match stream {
            Stream::Peak => (s.h.clamp(PEAK_SCALE_CLIP.0, PEAK_SCALE_CLIP.1), PEAK_WEIGHT),
            _ => ((s.h * spread).clamp(SPREAD_SCALE_CLIP.0, SPREAD_SCALE_CLIP.1), SPREAD_WEIGHT),
        };
        let mut q = s.q;
        if let Some(j) = jitter {
            for a in 0..3 {
                q[a] += j[a];
            }
        }
        out.params.push(isotropic(q, sigma, s.v, weight));
        out.stream.push(stream);
        out.sample.push(idx);
    };

    let peaks = peak_candidates(samples, dims, peak_share);
    if ns >= n {
        let mut taken = vec![false; ns];
        let imp = if samples.uniform_importance() {
            uniform_without_replacement(&mut rng, &taken, ns, n_imp)
        } else {
            importance_without_replacement(&mut rng, samples, n_imp)?
        };
        for &i in &imp {
            taken[i] = true;
            push(&mut out, i, Stream::Importance, None);
        }
        let mut uni_taken = taken.clone();
        for &i in &peaks {
            uni_taken[i] = true;
        }
        let n_uni = n - n_imp - peaks.len();
        let available = ns - uni_taken.iter().filter(|&&t| t).count();
        if available < n_uni {
            return Err(Error::arg(format!("budget {n} exceeds the {available} samples left for the uniform stream")));
        }
        let uni = uniform_without_replacement(&mut rng, &uni_taken, available, n_uni);
        for &i in &uni {
            push(&mut out, i, Stream::Uniform, None);
        }
        for &i in &peaks {
            push(&mut out, i, Stream::Peak, None);
        }
    } else {
        let slots = n - peaks.len();
        for i in 0..ns.min(slots) {
            push(&mut out, i, Stream::Uniform, None);
        }
        if slots > ns {
            let cdf = importance_cdf(samples)?;
            for _ in 0..slots - ns {
                let u = rng.uniform() * cdf[ns - 1];
                let i = cdf.partition_point(|&c| c <= u).min(ns - 1);
                let j = [rng.range(-0.5, 0.5) as f32, rng.range(-0.5, 0.5) as f32, rng.range(-0.5, 0.5) as f32];
                push(&mut out, i, Stream::Importance, Some(j));
            }
        }
        for &i in &peaks {
            push(&mut out, i, Stream::Peak, None);
        }
    }
    debug_assert_eq!(out.params.len(), n);
    Ok(out)
}

fn importance_weight(m: f32) -> Result<f64> {
    if !(m.is_finite() && m >= 0.0) {
        return Err(Error::data(format!("sample importance {m} is negative or not finite")));
    }
    Ok((m as f64).powf(IMPORTANCE_EXPONENT))
}

/// Efraimidis-Spirakis: the `k` largest keys `ln(u) / w` are a weighted draw
/// without replacement. Zero-weight samples come last (key -inf).
fn importance_without_replacement(rng: &mut Rng, samples: &dyn SampleSet, k: usize) -> Result<Vec<usize>> {
    let ns = samples.len();
    let mut keys: Vec<(f64, usize)> = Vec::with_capacity(ns);
    for i in 0..ns {
        let w = importance_weight(samples.get(i).m)?;
        let u = rng.uniform_open0();
        let key = if w > 0.0 { u.ln() / w } else { f64::NEG_INFINITY };
        keys.push((key, i));
    }
    let by_key_desc = |a: &(f64, usize), b: &(f64, usize)| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1));
    if k < ns {
        keys.select_nth_unstable_by(k, by_key_desc);
        keys.truncate(k);
    }
    keys.sort_by(by_key_desc);
    Ok(keys.into_iter().map(|(_, i)| i).collect())
}

fn importance_cdf(samples: &dyn SampleSet) -> Result<Vec<f64>> {
    let mut acc = 0.0;
    let mut cdf = Vec::with_capacity(samples.len());
    for i in 0..samples.len() {
        acc += importance_weight(samples.get(i).m)?;
        cdf.push(acc);
    }
    if acc <= 0.0 {
        return Err(Error::data("all sample importances are zero"));
    }
    Ok(cdf)
}

/// `k` distinct indices, uniform among the `available` ones not `taken`.
fn uniform_without_replacement(rng: &mut Rng, taken: &[bool], available: usize, k: usize) -> Vec<usize> {
    let ns = taken.len();
    if k == 0 {
        return vec![];
    }
    if k * 2 <= available {
        // Sparse draw: rejection against the taken set.
        let mut seen = taken.to_vec();
        let mut out = Vec::with_capacity(k);
        while out.len() < k {
            let i = rng.below(ns as u64) as usize;
            if !seen[i] {
                seen[i] = true;
                out.push(i);
            }
        }
        out
    } else {
        // Dense draw: partial Fisher-Yates over the free indices.
        let mut free: Vec<usize> = (0..ns).filter(|&i| !taken[i]).collect();
        for j in 0..k {
            let r = j + rng.below((free.len() - j) as u64) as usize;
            free.swap(j, r);
        }
        free.truncate(k);
        free
    }
}

/// The highest-valued sample of each 2x2x2-voxel bin whose value exceeds 0.55,
/// at most `share` of them, highest values first (ties: lower sample index).
fn peak_candidates(samples: &dyn SampleSet, dims: [usize; 3], share: usize) -> Vec<usize> {
    if share == 0 {
        return vec![];
    }
    let bd = [dims[0].div_ceil(2), dims[1].div_ceil(2), dims[2].div_ceil(2)];
    let mut best: Vec<(f32, u32)> = vec![(f32::NEG_INFINITY, u32::MAX); bd[0] * bd[1] * bd[2]];
    for i in 0..samples.len() {
        let s = samples.get(i);
        if s.v <= PEAK_THRESHOLD {
            continue;
        }
        let mut b = [0usize; 3];
        for a in 0..3 {
            b[a] = ((s.q[a] + 0.5).max(0.0) as usize / 2).min(bd[a] - 1);
        }
        let slot = &mut best[b[0] + bd[0] * (b[1] + bd[1] * b[2])];
        if s.v > slot.0 {
            *slot = (s.v, i as u32);
        }
    }
    let mut winners: Vec<(f32, u32)> = best.into_iter().filter(|x| x.1 != u32::MAX).collect();
    winners.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
    winners.truncate(share);
    winners.into_iter().map(|x| x.1 as usize).collect()
}
