//! A fixed set of validation points scored during an encode, so that
//! quality can be read against iterations (time to quality).

use crate::backend::Backend;
use crate::error::{Error, Result};
use crate::field::Grid;
use crate::math::kernel::Primitive;
use crate::math::loss::{v_eval, MASK_REF};
use crate::math::rng::Rng;
use crate::model::metrics::psnr_from_mse;
use crate::model::Outside;

/// A fixed set of voxel centres with their reference values, scored during
/// an encode so that quality can be read against iterations (time to quality).
/// Fixed by its seed, so every step of a series is scored on the same points.
#[derive(Clone, Debug)]
pub struct Validation {
    pub points: Vec<[f32; 3]>,
    pub values: Vec<f32>,
    /// Score every this many iterations (at least 1).
    pub every: usize,
    /// Score the model as it decodes with its support stored: at the
    /// points whose reference is empty, the outside's prediction, fitted
    /// on those points as the encoder fits it on the lattice's (METHOD.md
    /// "Support").
    pub support: bool,
}

impl Validation {
    /// `count` voxel centres of `reference` drawn uniformly with replacement.
    pub fn from_reference(reference: &Grid, count: usize, seed: u64, every: usize) -> Result<Validation> {
        if count == 0 || every == 0 {
            return Err(Error::arg("validation needs at least one point and a positive interval"));
        }
        if count > crate::encode::config::MAX_POINTS {
            return Err(Error::arg(format!("{count} validation points are more than the {} a validation set may hold", crate::encode::config::MAX_POINTS)));
        }
        let mut rng = Rng::new(seed);
        let mut points = Vec::with_capacity(count);
        let mut values = Vec::with_capacity(count);
        for _ in 0..count {
            let i = rng.below(reference.len() as u64) as usize;
            points.push(reference.centre(i));
            values.push(reference.values[i]);
        }
        Ok(Validation { points, values, every, support: false })
    }

    /// The same points with the values of another reference on the same
    /// lattice (the next step of a series).
    pub fn rescored(&self, reference: &Grid) -> Validation {
        let [dx, dy, _] = reference.dims;
        let values = self.points.iter().map(|p| reference.values[p[0] as usize + dx * (p[1] as usize + dy * p[2] as usize)]).collect();
        Validation { points: self.points.clone(), values, every: self.every, support: self.support }
    }

    /// PSNR of `V_eval` of `params` against the reference values at the
    /// points (with the support: the outside's prediction where the
    /// reference is empty).
    pub fn psnr(&self, backend: &mut dyn Backend, params: &[Primitive]) -> Result<f64> {
        let mut rho = vec![0.0; self.points.len()];
        let mut n = vec![0.0; self.points.len()];
        backend.evaluate_points(params, &self.points, &mut rho, &mut n)?;
        let v: Vec<f32> = rho.iter().zip(&n).map(|(&r, &n)| v_eval(r, n)).collect();
        let empty = |i: usize| self.support && self.values[i] <= MASK_REF;
        let outside = Outside::choose(&v, &self.values, empty);
        let decoded = |i: usize| if empty(i) { outside.value(v[i]) } else { v[i] };
        let se: f64 = (0..self.points.len()).map(|i| ((decoded(i) - self.values[i]) as f64).powi(2)).sum();
        Ok(psnr_from_mse(se / self.points.len() as f64))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::encode::config::MAX_POINTS;

    /// A validation set is refused before anything is allocated when it
    /// has no point, no interval, or more points than [`MAX_POINTS`] (a
    /// count of 4e9, 64 GB, aborted the tool before); a set within them
    /// holds the reference's values at its points.
    #[test]
    fn validation_sets_are_bounded_before_they_are_drawn() {
        let reference = Grid::new([4, 4, 4], (0..64).map(|i| i as f32 / 63.0).collect()).unwrap();
        for (count, every) in [(0, 10), (10, 0), (MAX_POINTS + 1, 10), (4_000_000_000, 10)] {
            assert!(matches!(Validation::from_reference(&reference, count, 1, every), Err(Error::InvalidArgument(_))), "{count} points every {every}");
        }
        let v = Validation::from_reference(&reference, 1000, 1, 10).unwrap();
        assert_eq!((v.points.len(), v.values.len()), (1000, 1000));
        assert!(v.points.iter().zip(&v.values).all(|(p, &x)| reference.values[p[0] as usize + 4 * (p[1] as usize + 4 * p[2] as usize)] == x));
    }
}
