//! Voxel, sampled and occupied PSNR (METHOD.md "Metrics"), on fields in `[0, 1]`.

use crate::math::loss::MASK_REF;
use crate::math::rng::Rng;

/// Number of voxel centres of the sampled PSNR.
pub const SAMPLED_PSNR_POINTS: usize = 500_000;
/// The fixed seed of the sampled PSNR's voxel draw (with replacement).
pub const SAMPLED_PSNR_SEED: u64 = 0x5e_ed0f_9505;

/// `10 log10(1 / MSE)`; an exact match is reported as 200 dB (MSE 1e-20)
/// so that the figure stays finite in JSON.
pub fn psnr_from_mse(mse: f64) -> f64 {
    10.0 * (1.0 / mse.max(1e-20)).log10()
}

/// PSNR over every voxel.
pub fn voxel_psnr(decoded: &[f32], reference: &[f32]) -> f64 {
    assert_eq!(decoded.len(), reference.len());
    let se: f64 = decoded.iter().zip(reference).map(|(&a, &b)| ((a - b) as f64).powi(2)).sum();
    psnr_from_mse(se / decoded.len().max(1) as f64)
}

/// PSNR over the occupied voxels only, those with a reference value above the
/// loss's mask (`V_ref > 0.005`): the part of the field the objective fits.
/// Set beside the voxel PSNR, it tells errors in empty space from errors in
/// the structure. `None` when no voxel is occupied.
pub fn occupied_psnr(decoded: &[f32], reference: &[f32]) -> Option<f64> {
    assert_eq!(decoded.len(), reference.len());
    let (se, n) = decoded
        .iter()
        .zip(reference)
        .filter(|(_, &b)| b > MASK_REF)
        .fold((0.0f64, 0usize), |(se, n), (&a, &b)| (se + ((a - b) as f64).powi(2), n + 1));
    (n > 0).then(|| psnr_from_mse(se / n as f64))
}

/// PSNR over 500,000 voxels drawn uniformly with replacement (fixed seed).
pub fn sampled_psnr(decoded: &[f32], reference: &[f32]) -> f64 {
    assert_eq!(decoded.len(), reference.len());
    let mut rng = Rng::new(SAMPLED_PSNR_SEED);
    let mut se = 0.0f64;
    for _ in 0..SAMPLED_PSNR_POINTS {
        let i = rng.below(decoded.len() as u64) as usize;
        se += ((decoded[i] - reference[i]) as f64).powi(2);
    }
    psnr_from_mse(se / SAMPLED_PSNR_POINTS as f64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn occupied_psnr_ignores_empty_voxels() {
        let reference = [0.0, 0.004, 0.5, 1.0];
        let decoded = [0.3, 0.3, 0.6, 1.0];
        // Occupied: 0.5 and 1.0; squared errors 0.01 and 0: MSE 0.005.
        let p = occupied_psnr(&decoded, &reference).unwrap();
        // f32 inputs: 0.6 - 0.5 is exact only to about 1e-7.
        assert!((p - psnr_from_mse(0.005)).abs() < 1e-5);
        assert!(voxel_psnr(&decoded, &reference) < p);
        assert_eq!(occupied_psnr(&[0.1], &[0.0]), None);
    }
}
