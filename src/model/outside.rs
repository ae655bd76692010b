//! What a model with a support decodes outside it (METHOD.md "Support"):
//! there the reference is known to lie in `[0, MASK_REF]` (that is what
//! put a voxel outside), and the Gaussians' own value `V` is unsupervised
//! (the objective never looks there). The decoder predicts the reference
//! as an affine function of `V`, clamped to that interval:
//!
//! `E(V) = clamp(offset + gain * min(V, MASK_REF), 0, MASK_REF)`
//!
//! with the two coefficients fitted by the encoder (least squares over the
//! empty voxels, on the model as stored). A flat background (the
//! Richtmyer-Meshkov light fluid at 4 of 3..230) gets an offset, a smooth
//! decay (the hydrogen atom's tail) a gain on the Gaussians' own tail, a
//! truly empty space (a fluid's outside) zero: the paper's decode times
//! the support, exactly.

use crate::math::loss::MASK_REF;

/// The least share of a decode's squared error an outside must take off
/// to be stored (0.004 dB): below it (a truly empty space with a faint
/// rim, where the fit's offset would be a few millionths and take off a
/// millionth of the error) the outside stays zero, and the empty voxels
/// decode to exactly 0.
pub const MIN_GAIN: f64 = 0.001;

/// The two coefficients of [`Outside::value`]; both 0 (the default): 0
/// outside.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Outside {
    pub offset: f32,
    pub gain: f32,
}

impl Outside {
    pub const ZERO: Outside = Outside { offset: 0.0, gain: 0.0 };

    pub fn is_zero(&self) -> bool {
        self.offset == 0.0 && self.gain == 0.0
    }

    /// Both coefficients finite (a reader refuses others).
    pub fn is_finite(&self) -> bool {
        self.offset.is_finite() && self.gain.is_finite()
    }

    /// The decoded value at an empty voxel where the Gaussians give `v`.
    #[inline]
    pub fn value(&self, v: f32) -> f32 {
        (self.offset + self.gain * v.min(MASK_REF)).clamp(0.0, MASK_REF)
    }

    /// The outside a decode stores: the [`Outside::fit`] of `decoded` (the
    /// Gaussians' own `V`) against `reference` over the indices `empty`
    /// picks, in index order, when it lowers the squared error of the whole
    /// decode (the other indices as decoded; zero outside: `r^2` at the
    /// empty ones) by at least [`MIN_GAIN`]; else zero. The encoder calls it
    /// on the reference lattice, a validation set on its points.
    pub fn choose(decoded: &[f32], reference: &[f32], empty: impl Fn(usize) -> bool) -> Outside {
        debug_assert_eq!(decoded.len(), reference.len());
        let fit = Outside::fit((0..decoded.len()).filter(|&i| empty(i)).map(|i| (decoded[i], reference[i])));
        if fit.is_zero() {
            return fit;
        }
        let (mut inside, mut zero, mut fitted) = (0f64, 0f64, 0f64);
        for (i, (&v, &r)) in decoded.iter().zip(reference).enumerate() {
            let r = r as f64;
            if empty(i) {
                zero += r * r;
                fitted += (fit.value(v) as f64 - r).powi(2);
            } else {
                inside += (v as f64 - r).powi(2);
            }
        }
        if zero - fitted >= MIN_GAIN * (inside + zero) {
            fit
        } else {
            Outside::ZERO
        }
    }

    /// The least-squares fit of the reference `r` by `offset + gain *
    /// min(v, MASK_REF)` over the pairs `(v, r)` of the empty voxels, in
    /// the order given (sums in f64, so the fit is the same on any thread
    /// count when the order is). Fewer than two distinct `v`: the mean as
    /// offset; no pairs: zero. A reference of zeros fits exactly zero.
    pub fn fit(pairs: impl Iterator<Item = (f32, f32)>) -> Outside {
        let (mut n, mut sx, mut sy, mut sxx, mut sxy) = (0f64, 0f64, 0f64, 0f64, 0f64);
        for (v, r) in pairs {
            let (x, y) = (v.min(MASK_REF) as f64, r as f64);
            n += 1.0;
            sx += x;
            sy += y;
            sxx += x * x;
            sxy += x * y;
        }
        if n == 0.0 {
            return Outside::ZERO;
        }
        // Centred sums: sxx - sx^2/n loses nothing that matters at these
        // magnitudes (x <= 0.005), and a spread below float noise is none.
        let var = sxx - sx * sx / n;
        let cov = sxy - sx * sy / n;
        let gain = if var > 1e-12 * sxx.max(f64::MIN_POSITIVE) { cov / var } else { 0.0 };
        let offset = (sy - gain * sx) / n;
        let out = Outside { offset: offset as f32, gain: gain as f32 };
        if out.is_finite() {
            out
        } else {
            Outside::ZERO
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::rng::Rng;

    fn sse(o: Outside, pairs: &[(f32, f32)]) -> f64 {
        pairs.iter().map(|&(v, r)| ((o.offset + o.gain * v.min(MASK_REF)) as f64 - r as f64).powi(2)).sum()
    }

    fn noisy(seed: u64) -> Vec<(f32, f32)> {
        let mut rng = Rng::new(seed);
        (0..5000)
            .map(|_| {
                let v = rng.uniform() as f32 * 0.008;
                (v, (0.001 + 0.6 * v.min(MASK_REF) + 0.0004 * (rng.uniform() as f32 - 0.5)).clamp(0.0, MASK_REF))
            })
            .collect()
    }

    #[test]
    fn an_exactly_affine_reference_is_recovered() {
        let pairs: Vec<(f32, f32)> = (0..100).map(|i| (i as f32 * 4e-5, 0.0005 + 0.5 * (i as f32 * 4e-5))).collect();
        let o = Outside::fit(pairs.iter().copied());
        assert!((o.offset - 0.0005).abs() < 1e-7 && (o.gain - 0.5).abs() < 1e-4, "{o:?}");
    }

    #[test]
    fn the_fit_is_the_least_squares_minimum() {
        // Independent check: no step of either coefficient lowers the
        // squared error (the normal equations' solution is the minimum).
        let pairs = noisy(3);
        let o = Outside::fit(pairs.iter().copied());
        let best = sse(o, &pairs);
        for (da, db) in [(1e-5, 0.0), (-1e-5, 0.0), (0.0, 1e-3), (0.0, -1e-3), (1e-5, -1e-3), (-1e-5, 1e-3)] {
            let moved = Outside { offset: o.offset + da, gain: o.gain + db };
            assert!(sse(moved, &pairs) > best, "{moved:?} beats the fit {o:?}");
        }
    }

    #[test]
    fn degenerate_inputs_fit_a_constant_or_zero() {
        assert_eq!(Outside::fit(std::iter::empty()), Outside::ZERO);
        assert_eq!(Outside::fit([(0.3f32, 0.0f32), (0.0, 0.0), (0.001, 0.0)].into_iter()), Outside::ZERO, "zeros fit zero");
        // One value of v (all past the mask): the mean, no gain.
        let o = Outside::fit([(0.2f32, 0.001f32), (0.3, 0.003)].into_iter());
        assert_eq!(o.gain, 0.0);
        assert!((o.offset - 0.002).abs() < 1e-9);
        // One value of v a thousand times, whose sums leave a spread of
        // rounding noise (3e-16 here), not a spread: no gain either.
        let o = Outside::fit((0..1000).map(|i| (0.0047f32, 0.001 * (i % 3) as f32)));
        assert_eq!(o.gain, 0.0);
        assert!((o.offset - 0.000999).abs() < 1e-6, "{o:?}");
    }

    /// `choose` on the empty pairs, plus one voxel inside the support whose
    /// squared error is `inside`.
    fn choose(pairs: &[(f32, f32)], inside: f64) -> Outside {
        let decoded: Vec<f32> = pairs.iter().map(|p| p.0).chain([inside.sqrt() as f32]).collect();
        let reference: Vec<f32> = pairs.iter().map(|p| p.1).chain([0.0]).collect();
        Outside::choose(&decoded, &reference, |i| i < pairs.len())
    }

    #[test]
    fn an_outside_is_chosen_only_where_it_pays() {
        let pairs = noisy(4);
        let zero: f64 = pairs.iter().map(|&(_, r)| (r as f64).powi(2)).sum();
        let fit = Outside::fit(pairs.iter().copied());
        assert_eq!(choose(&pairs, 0.0), fit);
        // The same gain, ten thousand times more error elsewhere: not worth it.
        assert_eq!(choose(&pairs, 1e4 * zero), Outside::ZERO);
        // A faint rim in empty space: zero, so that space decodes to 0.
        let rim: Vec<(f32, f32)> = (0..1000).map(|i| (0.0, if i < 3 { 0.004 } else { 0.0 })).collect();
        assert!(!Outside::fit(rim.iter().copied()).is_zero());
        assert_eq!(choose(&rim, 1e-3), Outside::ZERO);
    }

    #[test]
    fn values_are_clamped_to_the_empty_interval() {
        let o = Outside { offset: 0.004, gain: 2.0 };
        assert_eq!(o.value(0.0), 0.004);
        assert_eq!(o.value(1.0), MASK_REF, "min(v, mask) then clamp");
        assert_eq!(Outside { offset: -0.001, gain: 0.1 }.value(0.001), 0.0);
        assert_eq!(Outside::ZERO.value(0.7), 0.0);
    }
}
