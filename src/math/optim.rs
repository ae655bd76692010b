//! Adam with a cosine-decayed learning rate (METHOD.md "Optimisation": beta1 0.9, beta2 0.999,
//! eps 1e-8, lr 8e-3 on every parameter (0.04 in the `tuned` schedule),
//! decaying to 5 % of it over the run).

use crate::math::kernel::Primitive;
use crate::math::loss::{regularize_run, LossWeights, RegTerms};
#[cfg(any(doc, test))]
use crate::math::loss::regularizers;
use crate::math::simd::simd_dispatch;
use crate::profile;
use rayon::prelude::*;

pub const BETA1: f32 = 0.9;
pub const BETA2: f32 = 0.999;
pub const EPS: f32 = 1e-8;
pub const FINAL_LR_FRACTION: f32 = 0.05;

/// `lr(t) = lr0 (f + (1 - f) (1 + cos(pi t / T)) / 2)` with `f = 0.05`,
/// for iteration `t` in `0..T`.
pub fn cosine_lr(lr0: f32, t: usize, total: usize) -> f32 {
    let x = if total > 1 { t as f64 / (total - 1) as f64 } else { 1.0 };
    let c = 0.5 * (1.0 + (std::f64::consts::PI * x).cos());
    (lr0 as f64 * (FINAL_LR_FRACTION as f64 + (1.0 - FINAL_LR_FRACTION as f64) * c)) as f32
}

/// Adam moments, one per parameter, and the step counter.
#[derive(Clone, Debug)]
pub struct Adam {
    pub m: Vec<Primitive>,
    pub v: Vec<Primitive>,
    pub t: u32,
}

impl Adam {
    pub fn new(n: usize) -> Adam {
        Adam { m: vec![[0.0; 12]; n], v: vec![[0.0; 12]; n], t: 0 }
    }

    /// One Adam step on every parameter with learning rate `lr`.
    pub fn step(&mut self, params: &mut [Primitive], grad: &[Primitive], lr: f32) {
        let (bc1, bc2) = self.advance();
        let chunk = super::primitives_per_task(params.len());
        params
            .par_chunks_mut(chunk)
            .zip(grad.par_chunks(chunk))
            .zip(self.m.par_chunks_mut(chunk).zip(self.v.par_chunks_mut(chunk)))
            .with_max_len(1)
            .for_each(|((p, g), (m, v))| profile::task("adam", || update_dispatch(p, g, m, v, lr, bc1, bc2)));
    }

    /// The regularisers' gradients added to `grad`, then one Adam step:
    /// one pass over the primitives instead of two, in the same tasks, so
    /// the same bits as [`regularizers`] and [`Adam::step`] in turn (each
    /// primitive's terms read only its own parameters). Returns the
    /// regularisers' terms.
    pub fn step_regularized(&mut self, params: &mut [Primitive], grad: &mut [Primitive], w: &LossWeights, lr: f32) -> RegTerms {
        let (bc1, bc2) = self.advance();
        let n = params.len();
        let chunk = super::primitives_per_task(n);
        let runs: Vec<(f64, f64)> = params
            .par_chunks_mut(chunk)
            .zip(grad.par_chunks_mut(chunk))
            .zip(self.m.par_chunks_mut(chunk).zip(self.v.par_chunks_mut(chunk)))
            .with_max_len(1)
            .map(|((p, g), (m, v))| {
                profile::task("regularisers and adam", || regularize_and_update(p, g, m, v, (w, n), (lr, bc1, bc2)))
            })
            .collect();
        RegTerms::sum(&runs)
    }

    /// Counts a step; its bias corrections.
    fn advance(&mut self) -> (f32, f32) {
        self.t += 1;
        (1.0 - BETA1.powi(self.t as i32), 1.0 - BETA2.powi(self.t as i32))
    }

    /// Forgets the moments of one primitive (after relocation).
    pub fn reset(&mut self, i: usize) {
        self.m[i] = [0.0; 12];
        self.v[i] = [0.0; 12];
    }
}

simd_dispatch!(fn update_dispatch(p: &mut [Primitive], g: &[Primitive], m: &mut [Primitive], v: &mut [Primitive], lr: f32, bc1: f32, bc2: f32) -> () => update);
simd_dispatch!(fn regularize_and_update(p: &mut [Primitive], g: &mut [Primitive], m: &mut [Primitive], v: &mut [Primitive], reg: (&LossWeights, usize), step: (f32, f32, f32)) -> (f64, f64) => regularize_then_update);

/// [`regularize_run`], then [`update`], on one run of primitives.
#[inline(always)]
fn regularize_then_update(p: &mut [Primitive], g: &mut [Primitive], m: &mut [Primitive], v: &mut [Primitive], (w, n): (&LossWeights, usize), (lr, bc1, bc2): (f32, f32, f32)) -> (f64, f64) {
    let terms = regularize_run(p, g, w, n);
    update(p, g, m, v, lr, bc1, bc2);
    terms
}

/// Adam's update of a run of primitives, over flat slices so that the
/// element loop vectorises (over `[f32; 12]` per primitive the compiler
/// left it scalar); every element gets the same operations, in the build
/// that `simd` picks (the same bits in each).
#[inline(always)]
fn update(p: &mut [Primitive], g: &[Primitive], m: &mut [Primitive], v: &mut [Primitive], lr: f32, bc1: f32, bc2: f32) {
    let (p, g, m, v) = (p.as_flattened_mut(), g.as_flattened(), m.as_flattened_mut(), v.as_flattened_mut());
    for (((p, &g), m), v) in p.iter_mut().zip(g).zip(m.iter_mut()).zip(v.iter_mut()) {
        *m = BETA1 * *m + (1.0 - BETA1) * g;
        *v = BETA2 * *v + (1.0 - BETA2) * g * g;
        let mh = *m / bc1;
        let vh = *v / bc2;
        *p -= lr * mh / (vh.sqrt() + EPS);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cosine_runs_from_lr_to_five_percent() {
        assert!((cosine_lr(8e-3, 0, 100) - 8e-3).abs() < 1e-9);
        assert!((cosine_lr(8e-3, 99, 100) - 4e-4).abs() < 1e-9);
        let mid = cosine_lr(8e-3, 50, 101);
        assert!((mid - 8e-3 * 0.525).abs() < 1e-7);
    }

    #[test]
    fn adam_first_step_moves_by_lr() {
        let mut p = vec![[1.0f32; 12]];
        let mut g = vec![[0.0f32; 12]];
        g[0][3] = 5.0;
        g[0][4] = -1e-3;
        let mut a = Adam::new(1);
        a.step(&mut p, &g, 0.01);
        assert!((p[0][3] - 0.99).abs() < 1e-6);
        assert!((p[0][4] - 1.01).abs() < 1e-5);
        assert_eq!(p[0][0], 1.0);
    }

    /// The fused pass (regularisers, then Adam, run by run) against the
    /// regularisers over the whole model and then the step: the same bits,
    /// the same terms, over several tasks and three steps, with primitives
    /// on both sides of every regulariser's bound.
    #[test]
    fn the_fused_pass_gives_the_bits_of_the_regularisers_then_the_step() {
        let mut rng = crate::math::rng::Rng::new(5);
        let n = 3000;
        let w = LossWeights::PAPER;
        let ls = crate::math::kernel::layout::LOG_SCALE;
        let mut p: Vec<Primitive> = (0..n).map(|_| std::array::from_fn(|_| rng.range(-1.0, 1.0) as f32)).collect();
        for q in p.iter_mut() {
            // Scales from 0.1 to 20 voxels: below 0.3, above 8, and ratios past the bound.
            for a in 0..3 {
                q[ls + a] = rng.range(0.1f64.ln(), 20f64.ln()) as f32;
            }
        }
        let (mut fused, mut apart) = (Adam::new(n), Adam::new(n));
        let mut q = p.clone();
        for t in 0..3 {
            let g: Vec<Primitive> = (0..n).map(|_| std::array::from_fn(|_| rng.range(-1.0, 1.0) as f32)).collect();
            let (mut g1, mut g2) = (g.clone(), g);
            let terms = fused.step_regularized(&mut p, &mut g1, &w, 0.01);
            let want = regularizers(&q, &w, &mut g2);
            apart.step(&mut q, &g2, 0.01);
            assert!(terms.scale > 0.0 && terms.aniso > 0.0, "step {t}: every term active ({terms:?})");
            assert_eq!((terms.scale.to_bits(), terms.aniso.to_bits()), (want.scale.to_bits(), want.aniso.to_bits()), "step {t}");
            let bits = |v: &[Primitive]| -> Vec<u32> { v.as_flattened().iter().map(|x| x.to_bits()).collect() };
            assert!(bits(&p) == bits(&q) && bits(&g1) == bits(&g2), "step {t}");
            assert!(bits(&fused.m) == bits(&apart.m) && bits(&fused.v) == bits(&apart.v) && fused.t == apart.t, "step {t}");
        }
    }

    /// The parallel, flattened step against the textbook update written
    /// out per element, over several chunks and three steps: equal bits.
    #[test]
    fn adam_matches_the_update_written_out() {
        let mut rng = crate::math::rng::Rng::new(3);
        let n = 5000; // 20 tasks of 256 primitives, the last one short
        let mut p: Vec<Primitive> = (0..n).map(|_| std::array::from_fn(|_| rng.range(-2.0, 2.0) as f32)).collect();
        let (mut want, mut m, mut v) = (p.clone(), vec![[0.0f32; 12]; n], vec![[0.0f32; 12]; n]);
        let mut a = Adam::new(n);
        for t in 1..=3 {
            let g: Vec<Primitive> = (0..n).map(|i| std::array::from_fn(|j| if (i + j) % 7 == 0 { 0.0 } else { rng.range(-1.0, 1.0) as f32 })).collect();
            let lr = 0.01 / t as f32;
            a.step(&mut p, &g, lr);
            let (bc1, bc2) = (1.0 - BETA1.powi(t), 1.0 - BETA2.powi(t));
            for i in 0..n {
                for j in 0..12 {
                    m[i][j] = BETA1 * m[i][j] + (1.0 - BETA1) * g[i][j];
                    v[i][j] = BETA2 * v[i][j] + (1.0 - BETA2) * g[i][j] * g[i][j];
                    want[i][j] -= lr * (m[i][j] / bc1) / ((v[i][j] / bc2).sqrt() + EPS);
                }
            }
        }
        assert!(p == want && a.m == m && a.v == v);
        assert!(p.iter().zip(&want).all(|(a, b)| a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits())));
    }
}
