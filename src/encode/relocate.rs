//! Fixed-count relocation (METHOD.md "Relocation"; the paper's "Fidelity
//! Objective and Relocation").
//!
//! On a fresh stratified set of points, the 8 % of primitives with the
//! smallest effective support `w prod_a exp(l_a)` move to the points with the
//! largest masked error `|V_train - V_ref| 1[V_ref > 0.02]`, pairing the
//! smallest support with the largest error. Each moved primitive becomes
//! isotropic (scale 0.8), unrotated, with the reference value there and weight
//! 0.5, and its Adam moments are reset. N never changes.

use crate::backend::Backend;
use crate::math::kernel::{isotropic, layout, sigmoid, Primitive};
use crate::math::loss::v_train;
use crate::math::optim::Adam;
use crate::backend::PointBatch;
use crate::error::Result;

pub const RELOCATE_FRACTION: f64 = 0.08;
pub const RELOCATE_POINTS: usize = 1 << 16;
pub const RELOCATE_SCALE: f32 = 0.8;
pub const RELOCATE_WEIGHT: f32 = 0.5;
pub const ERROR_MASK: f32 = 0.02;
/// Iteration fractions at which relocation runs.
pub const RELOCATE_AT: [f64; 3] = [0.35, 0.55, 0.75];

/// What a relocation pass did.
#[derive(Clone, Debug, Default)]
pub struct Relocation {
    /// Indices of the moved primitives, smallest support first.
    pub moved: Vec<usize>,
    /// Index (into the point batch) each one moved to.
    pub targets: Vec<usize>,
}

/// `w * prod_a exp(l_a)` of a primitive.
pub fn effective_support(p: &Primitive) -> f32 {
    let l = &p[layout::LOG_SCALE..layout::LOG_SCALE + 3];
    sigmoid(p[layout::BETA]) * (l[0] + l[1] + l[2]).exp()
}

pub fn relocate(
    backend: &mut dyn Backend,
    params: &mut [Primitive],
    adam: &mut Adam,
    batch: &PointBatch,
) -> Result<Relocation> {
    let n = params.len();
    let k = ((RELOCATE_FRACTION * n as f64).round() as usize).min(batch.len());
    if k == 0 {
        return Ok(Relocation::default());
    }
    let mut rho = vec![0f32; batch.len()];
    let mut num = vec![0f32; batch.len()];
    backend.evaluate_points(params, &batch.pos, &mut rho, &mut num)?;
    let mut errors: Vec<(f32, usize)> = (0..batch.len())
        .map(|p| {
            let vref = batch.vref[p];
            let e = if vref > ERROR_MASK { (v_train(rho[p], num[p]) - vref).abs() } else { 0.0 };
            (e, p)
        })
        .collect();
    // Largest error first; ties by point index, so the choice is deterministic.
    errors.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
    let mut support: Vec<(f32, usize)> = params.iter().enumerate().map(|(i, p)| (effective_support(p), i)).collect();
    support.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    let mut out = Relocation::default();
    for j in 0..k {
        let (i, p) = (support[j].1, errors[j].1);
        params[i] = isotropic(batch.pos[p], RELOCATE_SCALE, batch.vref[p], RELOCATE_WEIGHT);
        adam.reset(i);
        out.moved.push(i);
        out.targets.push(p);
    }
    Ok(out)
}
