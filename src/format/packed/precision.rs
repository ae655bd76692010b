//! How many bits each parameter group of the packed payload is stored
//! with ([`Precision`]), and the limits a stored payload's precision must
//! keep.

use super::{AXIS_BITS, CENTRE_CLASSES};
use crate::error::{Error, Result};
use crate::math::kernel::{layout, Primitive};

/// Bits per parameter group of the packed payload.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Precision {
    /// Centres of each centre class on a lattice of `2^-centre[j]` voxel
    /// (0..=8 each).
    pub centre: [u8; CENTRE_CLASSES],
    /// Each log scale (1..=16).
    pub scale: u8,
    /// Each of the three stored rotation components (1..=16).
    pub rotation: u8,
    /// The value `sigmoid(alpha)` (1..=16).
    pub value: u8,
    /// The weight logit `beta` (1..=16).
    pub weight: u8,
}

/// Names of the groups, in the order of [`Precision::get`]: a centre
/// lattice per centre class, then the other four.
pub const GROUPS: [&str; CENTRE_CLASSES + 4] = ["centre (class 0)", "centre (class 1)", "centre (class 2)", "centre (class 3)", "scale", "rotation", "value", "weight"];
/// Finest centre lattice: 1/256 voxel.
pub const MAX_CENTRE_BITS: u8 = 8;
/// Most bits of the other groups.
pub const MAX_BITS: u8 = 16;
impl Precision {
    /// The precision a model is packed with when its encode measured none
    /// (a model converted from another payload, no reference at hand;
    /// centres coarser where a domain is too wide for it, [`Precision::fitting`]):
    /// finer than every measured choice on the benchmark corpus
    /// (docs/BENCHMARKS.md "Quality per byte").
    pub const DEFAULT: Precision = Precision { centre: [5; CENTRE_CLASSES], scale: 10, rotation: 9, value: 11, weight: 9 };
    /// Where the measured search starts, and the most it will give a group.
    pub const FINEST: Precision = Precision { centre: [7; CENTRE_CLASSES], scale: 12, rotation: 12, value: 14, weight: 12 };

    /// This precision with every centre class on a lattice of `2^-bits` voxel.
    pub fn with_centres(self, bits: u8) -> Precision {
        Precision { centre: [bits; CENTRE_CLASSES], ..self }
    }

    /// Bits of group `g` (in the order of [`GROUPS`]).
    pub fn get(&self, g: usize) -> u8 {
        match g.checked_sub(CENTRE_CLASSES) {
            None => self.centre[g],
            Some(k) => [self.scale, self.rotation, self.value, self.weight][k],
        }
    }

    /// This precision with group `g` at `bits`.
    pub fn with(mut self, g: usize, bits: u8) -> Precision {
        match g.checked_sub(CENTRE_CLASSES) {
            None => self.centre[g] = bits,
            Some(k) => *[&mut self.scale, &mut self.rotation, &mut self.value, &mut self.weight][k] = bits,
        }
        self
    }

    /// Whether group `g` is a centre class's lattice.
    pub fn is_centre(g: usize) -> bool {
        g < CENTRE_CLASSES
    }

    /// Fewest bits group `g` may have.
    pub fn min_bits(g: usize) -> u8 {
        if Precision::is_centre(g) {
            0
        } else {
            1
        }
    }

    /// Most bits group `g` may have.
    pub fn max_bits(g: usize) -> u8 {
        if Precision::is_centre(g) {
            MAX_CENTRE_BITS
        } else {
            MAX_BITS
        }
    }

    /// This precision with its centre lattices made coarse enough for the
    /// centres of `params` to fit 2^21 steps an axis (unchanged when they
    /// do); `None` when not even whole voxels fit (centres over 2^21
    /// voxels apart).
    pub fn fitting(self, params: &[Primitive]) -> Option<Precision> {
        let span = (0..3)
            .map(|a| {
                let (lo, hi) = params.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), p| {
                    let v = p[layout::MU + a] as f64;
                    (lo.min(v), hi.max(v))
                });
                if lo <= hi { hi - lo.floor() } else { 0.0 }
            })
            .fold(0.0, f64::max);
        // The code of the farthest centre must round below 2^21.
        let finest = *self.centre.iter().max().unwrap();
        let fits = (0..=finest).rev().find(|&c| (span * (1u64 << c) as f64).round() < (1u64 << AXIS_BITS) as f64)?;
        Some(Precision { centre: self.centre.map(|c| c.min(fits)), ..self })
    }

    pub fn check(&self) -> Result<Precision> {
        for (g, name) in GROUPS.iter().enumerate() {
            let b = self.get(g);
            if b < Precision::min_bits(g) || b > Precision::max_bits(g) {
                return Err(Error::format(format!(
                    "packed payload: {b} bits for the {name} group (allowed {}..={})",
                    Precision::min_bits(g),
                    Precision::max_bits(g)
                )));
            }
        }
        Ok(*self)
    }
}
