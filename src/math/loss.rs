//! The objective (METHOD.md "Objective"; the paper's Eq. 7-8):
//! `L = L_val + 2 L_cov + 0.1 L_scale + 0.05 L_aniso`.
//!
//! The two point terms are split into what each point contributes
//! ([`point_terms`]), which every backend calls, and the per-primitive
//! regularisers ([`regularizers`]), which do not depend on points.

use crate::math::kernel::{layout, Primitive};
use crate::profile;
use rayon::prelude::*;

/// Huber transition: `0.5 r^2` for `|r| <= 0.1`, else `0.1 (|r| - 0.05)`.
pub const HUBER_DELTA: f32 = 0.1;
/// Points whose reference value is at most this are masked from L_val and L_cov.
pub const MASK_REF: f32 = 0.005;
/// Target mixture density of the coverage term.
pub const COVER_RHO: f32 = 0.05;
/// Denominator guard of the training value `V_train = n / max(rho, 1e-3)`.
pub const TRAIN_FLOOR: f32 = 1e-3;
/// Denominator floor of the decoded value `V_eval = clamp(n / max(rho, 0.05))`.
pub const EVAL_FLOOR: f32 = 0.05;

/// Weights of the four loss terms, and the two shapes gsenc's schedules
/// change (METHOD.md "Objective"). The defaults are the paper's; tests set
/// all weights but one to zero to check each term's gradient on its own.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LossWeights {
    pub val: f32,
    pub cov: f32,
    pub scale: f32,
    pub aniso: f32,
    /// An occupied point's fidelity weight is
    /// `fidelity[0] + fidelity[1] V_ref` ([`fidelity_weight`]).
    pub fidelity: [f32; 2],
    /// The axis ratio `max_a sigma / min_a sigma` above which L_aniso acts.
    pub aniso_ratio: f32,
}

impl LossWeights {
    /// The paper's: fidelity weight `0.5 + V_ref`, anisotropy above 4.
    pub const PAPER: LossWeights = LossWeights { val: 1.0, cov: 2.0, scale: 0.1, aniso: 0.05, fidelity: [0.5, 1.0], aniso_ratio: 4.0 };
    /// gsenc's (`tuned`, `tuned-full`): every occupied point weighs alike,
    /// as in the voxel PSNR, and anisotropy is free up to 10.
    pub const GSENC: LossWeights = LossWeights { fidelity: [1.0, 0.0], aniso_ratio: 10.0, ..LossWeights::PAPER };
}

impl Default for LossWeights {
    fn default() -> Self {
        LossWeights::PAPER
    }
}

#[inline]
pub fn huber(r: f32) -> f32 {
    let a = r.abs();
    if a <= HUBER_DELTA {
        0.5 * r * r
    } else {
        HUBER_DELTA * (a - 0.5 * HUBER_DELTA)
    }
}

#[inline]
pub fn huber_grad(r: f32) -> f32 {
    r.clamp(-HUBER_DELTA, HUBER_DELTA)
}

/// The training value `V_train = n / max(rho, 1e-3)`.
#[inline]
pub fn v_train(rho: f32, n: f32) -> f32 {
    n / rho.max(TRAIN_FLOOR)
}

/// The decoded value `V_eval = clamp(n / max(rho, 0.05), 0, 1)`.
#[inline]
pub fn v_eval(rho: f32, n: f32) -> f32 {
    (n / rho.max(EVAL_FLOOR)).clamp(0.0, 1.0)
}

/// Fidelity weight of a point: `1[V_ref > 0.005] (fidelity[0] + fidelity[1] V_ref)`
/// (the paper's `0.5 + V_ref`).
#[inline]
pub fn fidelity_weight(vref: f32, w: &LossWeights) -> f32 {
    if vref > MASK_REF {
        w.fidelity[0] + w.fidelity[1] * vref
    } else {
        0.0
    }
}

/// Batch-wide normalisers of the point terms, known before any evaluation.
#[derive(Clone, Copy, Debug)]
pub struct PointNorm {
    /// `1 / max(sum_p omega_p, 1e-6)`.
    pub inv_weight_sum: f32,
    /// `1 / |P|`.
    pub inv_count: f32,
}

impl PointNorm {
    pub fn new(vref: &[f32], w: &LossWeights) -> PointNorm {
        let wsum: f64 = vref.iter().map(|&v| fidelity_weight(v, w) as f64).sum();
        PointNorm {
            inv_weight_sum: (1.0 / wsum.max(1e-6)) as f32,
            inv_count: 1.0 / vref.len().max(1) as f32,
        }
    }
}

/// One point's share of the (unweighted) L_val and L_cov, and the gradient of
/// the weighted loss with respect to the point's `rho` and `n`.
#[derive(Clone, Copy, Debug, Default)]
pub struct PointTerms {
    pub val: f32,
    pub cov: f32,
    pub g_rho: f32,
    pub g_n: f32,
}

#[inline]
pub fn point_terms(rho: f32, n: f32, vref: f32, norm: &PointNorm, w: &LossWeights) -> PointTerms {
    if vref <= MASK_REF {
        return PointTerms::default();
    }
    let omega = fidelity_weight(vref, w);
    let denom = rho.max(TRAIN_FLOOR);
    let r = n / denom - vref;
    let val = omega * huber(r) * norm.inv_weight_sum;
    let dl_dv = w.val * omega * huber_grad(r) * norm.inv_weight_sum;
    let mut g_rho = if rho > TRAIN_FLOOR { -dl_dv * n / (rho * rho) } else { 0.0 };
    let g_n = dl_dv / denom;
    let cov_gap = COVER_RHO - rho;
    let cov = if cov_gap > 0.0 { cov_gap * norm.inv_count } else { 0.0 };
    if cov_gap > 0.0 {
        g_rho -= w.cov * norm.inv_count;
    }
    PointTerms { val, cov, g_rho, g_n }
}

/// Values of the two per-primitive regularisers (unweighted).
#[derive(Clone, Copy, Debug, Default)]
pub struct RegTerms {
    pub scale: f64,
    pub aniso: f64,
}

/// Adds the weighted gradients of L_scale and L_aniso to `grad` and returns the
/// terms' values. Both act on `exp(l)` itself, not on the clamped sigma.
pub fn regularizers(params: &[Primitive], w: &LossWeights, grad: &mut [Primitive]) -> RegTerms {
    let chunk = super::primitives_per_task(params.len());
    let partial: Vec<(f64, f64)> = params
        .par_chunks(chunk)
        .zip(grad.par_chunks_mut(chunk))
        .with_max_len(1)
        .map(|(ps, gs)| profile::task("regularisers", || regularize_run(ps, gs, w, params.len())))
        .collect();
    RegTerms::sum(&partial)
}

/// [`regularizers`] of one run of primitives out of a model of `n`: adds
/// their weighted gradients to `gs` and returns the run's (scale,
/// anisotropy) terms; the model's terms are the runs' in order
/// ([`RegTerms::sum`]).
#[inline(always)]
pub fn regularize_run(ps: &[Primitive], gs: &mut [Primitive], w: &LossWeights, n: usize) -> (f64, f64) {
    let n = n.max(1) as f32;
    let inv_3n = 1.0 / (3.0 * n);
    let inv_n = 1.0 / n;
    let (mut sc, mut an) = (0.0f64, 0.0f64);
    for (p, g) in ps.iter().zip(gs.iter_mut()) {
        let e = [
            p[layout::LOG_SCALE].exp(),
            p[layout::LOG_SCALE + 1].exp(),
            p[layout::LOG_SCALE + 2].exp(),
        ];
        for a in 0..3 {
            if e[a] > 8.0 {
                sc += ((e[a] - 8.0) * inv_3n) as f64;
                g[layout::LOG_SCALE + a] += w.scale * e[a] * inv_3n;
            }
            if e[a] < 0.30 {
                sc += (0.05 * (0.30 - e[a]) * inv_3n) as f64;
                g[layout::LOG_SCALE + a] -= w.scale * 0.05 * e[a] * inv_3n;
            }
        }
        let (mut amax, mut amin) = (0, 0);
        for a in 1..3 {
            if e[a] > e[amax] {
                amax = a;
            }
            if e[a] < e[amin] {
                amin = a;
            }
        }
        let floor = e[amin].max(1e-3);
        let ratio = e[amax] / floor;
        if ratio > w.aniso_ratio && amax != amin {
            an += ((ratio - w.aniso_ratio) * inv_n) as f64;
            g[layout::LOG_SCALE + amax] += w.aniso * ratio * inv_n;
            if e[amin] > 1e-3 {
                g[layout::LOG_SCALE + amin] -= w.aniso * ratio * inv_n;
            }
        }
    }
    (sc, an)
}

impl RegTerms {
    /// The terms of a model from its runs', added in order.
    pub fn sum(runs: &[(f64, f64)]) -> RegTerms {
        let mut out = RegTerms::default();
        for (s, a) in runs {
            out.scale += s;
            out.aniso += a;
        }
        out
    }
}
