//! Insertion (METHOD.md "A quality instead of a budget"): a target-PSNR
//! encode whose model falls short grows it where it misses and trains on,
//! instead of starting again.
//!
//! The new primitives are seeded on the samples the model misses (the
//! residual of a warm start's repair, `repair.rs`), with the scale a
//! seeding of all samples would give them; the model's own primitives stay
//! as they are, in their order. The training that follows (with
//! relocation) settles the rest.
//!
//! There is no pruning counterpart: a trained model pruned to a smaller
//! budget and trained on does worse than a fresh encode of that budget
//! (hydrogen: 350 primitives pruned to 101 and trained 750 iterations,
//! 29.0 dB; a fresh 1,500-iteration encode of 141, 42.4 dB), so a model
//! that overshoots is encoded again, smaller.

use crate::backend::Backend;
use crate::encode::repair::{residual, seed_on_residual};
use crate::error::Result;
use crate::input::Target;
use crate::math::kernel::Primitive;

/// Mixed into the encode's seeding seed for the inserted primitives' seeds.
const INSERT_SEED: u64 = 0x1a5e_47ed;

/// `params` with `add` primitives inserted where they miss `target` most
/// (the seeds depend on `seed`).
pub fn grow(target: &Target, params: &[Primitive], add: usize, seed: u64, backend: &mut dyn Backend) -> Result<Vec<Primitive>> {
    let mut out = params.to_vec();
    if add == 0 {
        return Ok(out);
    }
    let r = residual(target, params, backend)?;
    out.extend(seed_on_residual(target, r, add, seed ^ INSERT_SEED)?);
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::backend::cpu::CpuBackend;
    use crate::field::Grid;
    use crate::math::kernel::{isotropic, layout};
    use crate::input::samples::SampleSet;
    use crate::math::loss::v_eval;

    /// A model of a ball at (6,6,6).
    fn first_ball() -> Vec<Primitive> {
        (0..8).map(|i| isotropic([5.0 + (i % 2) as f32 * 2.0, 5.0 + (i / 2 % 2) as f32 * 2.0, 5.0 + (i / 4) as f32 * 2.0], 1.5, 0.8, 0.5)).collect()
    }

    /// On a 24^3 lattice: what `first_ball` decodes to within 5 voxels of
    /// (6,6,6), and a second ball at (17,17,17) it misses.
    fn two_balls() -> Grid {
        let d = 24;
        let pos: Vec<[f32; 3]> = (0..d * d * d).map(|i| [(i % d) as f32, (i / d % d) as f32, (i / (d * d)) as f32]).collect();
        let (mut rho, mut num) = (vec![0f32; pos.len()], vec![0f32; pos.len()]);
        CpuBackend::new().evaluate_points(&first_ball(), &pos, &mut rho, &mut num).unwrap();
        let v = (0..pos.len())
            .map(|i| {
                let r2 = |c: f32| pos[i].iter().map(|x| (x - c).powi(2)).sum::<f32>();
                let first = if r2(6.0) <= 25.0 { v_eval(rho[i], num[i]) } else { 0.0 };
                let second = 0.6 * (-r2(17.0) / 8.0).exp();
                let x = first + if second < 1e-3 { 0.0 } else { second };
                x.clamp(0.0, 1.0)
            })
            .collect();
        Grid::new([d; 3], v).unwrap()
    }

    #[test]
    fn insertion_goes_where_the_model_misses() {
        let reference = two_balls();
        let target = Target { reference: &reference, samples: &reference };
        // A model of the first ball only.
        let first = first_ball();
        let grown = grow(&target, &first, 12, 0, &mut CpuBackend::new()).unwrap();
        assert_eq!(grown.len(), 20);
        assert_eq!(&grown[..8], &first[..], "the model's own primitives stay");
        for p in &grown[8..] {
            let mu = &p[layout::MU..layout::MU + 3];
            let to_second = mu.iter().map(|m| (m - 17.0).powi(2)).sum::<f32>().sqrt();
            assert!(to_second < 6.0, "an inserted primitive at {mu:?} is not at the missed ball");
        }
        // Nothing missed: the seeds spread over all samples instead.
        let fitted = Grid::new(reference.dims, reference.values.iter().enumerate().map(|(i, &v)| if reference.get(i).q.iter().all(|&x| x < 12.0) { v } else { 0.0 }).collect()).unwrap();
        let target = Target { reference: &fitted, samples: &fitted };
        assert_eq!(grow(&target, &first, 5, 0, &mut CpuBackend::new()).unwrap().len(), 13);
        assert_eq!(grow(&target, &first, 0, 0, &mut CpuBackend::new()).unwrap(), first);
    }
}
