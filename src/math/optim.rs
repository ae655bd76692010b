//! Adam with a cosine-decayed learning rate (METHOD.md "Optimisation": beta1 0.9, beta2 0.999,
//! eps 1e-8, lr 8e-3 on every parameter (0.04 in the `tuned` schedule),
//! decaying to 5 % of it over the run).

use crate::math::kernel::Primitive;
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
        self.t += 1;
        let bc1 = 1.0 - BETA1.powi(self.t as i32);
        let bc2 = 1.0 - BETA2.powi(self.t as i32);
        params
            .par_iter_mut()
            .zip(grad.par_iter())
            .zip(self.m.par_iter_mut().zip(self.v.par_iter_mut()))
            .with_min_len(2048)
            .for_each(|((p, g), (m, v))| {
                for i in 0..12 {
                    m[i] = BETA1 * m[i] + (1.0 - BETA1) * g[i];
                    v[i] = BETA2 * v[i] + (1.0 - BETA2) * g[i] * g[i];
                    let mh = m[i] / bc1;
                    let vh = v[i] / bc2;
                    p[i] -= lr * mh / (vh.sqrt() + EPS);
                }
            });
    }

    /// Forgets the moments of one primitive (after relocation).
    pub fn reset(&mut self, i: usize) {
        self.m[i] = [0.0; 12];
        self.v[i] = [0.0; 12];
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
}
