//! SPH particles as encoder input (METHOD.md "Samples" and "Reference grid").
//!
//! A particle at world position `x` with smoothing length `hh`, mass `m` and
//! normalised value `v` is
//! - a sample `(u, 0.8 hh gamma, v, m)` when `u = frame(x)` lies inside the
//!   bounds; particles outside seed nothing but are counted;
//! - a splat of the M4 cubic spline of support radius `2 hh gamma` (index
//!   units) in the Shepard-normalised, mass-weighted deposit, clipped to the
//!   lattice. A particle inside the bounds whose support covers no voxel centre
//!   goes into its nearest voxel with weight `m` (its kernel's whole mass, as a
//!   voxel of the index frame has unit volume).

use crate::input::deposit::{inside_bounds, nearest_voxel_box, Shape, Splat};
use crate::error::{Error, Result};
use crate::field::IndexFrame;
use crate::field::Bounds;
use crate::input::first_bad;
use crate::input::items::{Conversion, Item};
use rayon::prelude::*;

/// Sample scale as a fraction of the smoothing length (METHOD.md "Samples").
pub const SAMPLE_SCALE: f64 = 0.8;

/// Particles in world units, borrowed from the caller (one entry per particle
/// in every array). Geometry is f64 because world coordinates of large boxes
/// need it; masses and values are f32 like grid values.
#[derive(Clone, Copy, Debug)]
pub struct Particles<'a> {
    pub positions: &'a [[f64; 3]],
    /// SPH smoothing length `hh` (the kernel's support radius is `2 hh`).
    pub smoothing_length: &'a [f64],
    pub mass: &'a [f32],
    /// Raw field values (before the transform and normalisation).
    pub values: &'a [f32],
}

impl Particles<'_> {
    pub fn len(&self) -> usize {
        self.positions.len()
    }

    pub fn is_empty(&self) -> bool {
        self.positions.is_empty()
    }

    /// Fails on empty or mismatched arrays, non-finite positions, smoothing
    /// lengths that are not positive, negative or non-finite masses, and
    /// masses all zero.
    pub fn validate(&self) -> Result<()> {
        if self.is_empty() {
            return Err(Error::data("no particles"));
        }
        self.validate_each(false)?;
        if self.mass.par_iter().all(|&m| m == 0.0) {
            return Err(Error::data("all particle masses are zero"));
        }
        Ok(())
    }

    /// What [`Self::validate`] asks of each particle alone: a rank's part of
    /// a decomposed field, which may hold none or only massless ones.
    /// `serial`: on the calling thread alone (no rayon pool woken).
    pub fn validate_each(&self, serial: bool) -> Result<()> {
        let n = self.len();
        for (name, len) in [
            ("smoothing lengths", self.smoothing_length.len()),
            ("masses", self.mass.len()),
            ("values", self.values.len()),
        ] {
            if len != n {
                return Err(Error::data(format!("{n} particle positions but {len} {name}")));
            }
        }
        if let Some(i) = first_bad(n, serial, |i| !self.positions[i].iter().all(|c| c.is_finite())) {
            return Err(Error::data(format!("particle {i} has a non-finite position {:?}", self.positions[i])));
        }
        if let Some(i) = first_bad(n, serial, |i| !(self.smoothing_length[i].is_finite() && self.smoothing_length[i] > 0.0)) {
            return Err(Error::data(format!(
                "particle {i} has smoothing length {}; it must be positive and finite",
                self.smoothing_length[i]
            )));
        }
        if let Some(i) = first_bad(n, serial, |i| !(self.mass[i].is_finite() && self.mass[i] >= 0.0)) {
            return Err(Error::data(format!("particle {i} has mass {}; it must be finite and not negative", self.mass[i])));
        }
        Ok(())
    }

    /// The bounding box of the positions.
    pub fn bounds(&self) -> Bounds {
        Bounds::enclosing(self.positions.par_iter().map(|p| (*p, *p)))
    }
}

impl Conversion for Particles<'_> {
    fn item_count(&self) -> usize {
        self.len()
    }

    fn item(&self, j: usize, frame: &IndexFrame, value: f32) -> Item {
        let u = frame.world_to_index(self.positions[j]);
        let h = self.smoothing_length[j] * frame.gamma;
        let (m, v) = (self.mass[j] as f64, value as f64);
        let inside = inside_bounds(frame, u);
        let (splat, nearest) = match support_box(frame.dims, u, 2.0 * h) {
            Some((lo, hi)) => (Some(Splat { lo, hi, m, v, shape: Shape::Spline { u, h } }), false),
            None if inside => {
                let (lo, hi) = nearest_voxel_box(frame.dims, u);
                (Some(Splat { lo, hi, m, v, shape: Shape::Box }), true)
            }
            None => (None, false),
        };
        Item { u, sample_scale: SAMPLE_SCALE * h, importance: m, inside, splat, nearest }
    }
}

/// The voxels whose centres lie strictly within `radius` of `u`, as a clamped
/// box, or `None` when no voxel centre does.
fn support_box(dims: [usize; 3], u: [f64; 3], radius: f64) -> Option<([u32; 3], [u32; 3])> {
    let mut lo = [0u32; 3];
    let mut hi = [0u32; 3];
    let mut nearest_r2 = 0.0;
    for a in 0..3 {
        let first = (u[a] - radius).ceil().max(0.0);
        let last = (u[a] + radius).floor().min((dims[a] - 1) as f64);
        if first > last {
            return None;
        }
        // Per axis, the box's voxel centre nearest to u.
        let c = u[a].round().clamp(first, last);
        nearest_r2 += (c - u[a]) * (c - u[a]);
        lo[a] = first as u32;
        hi[a] = last as u32 + 1;
    }
    (nearest_r2 < radius * radius).then_some((lo, hi))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `validate_each` asks of each particle what `validate` does, on the
    /// calling thread or the pool alike (the same first bad particle), and
    /// takes what only a whole set can be refused for: none, or massless.
    #[test]
    fn each_particle_is_checked_alike_alone_or_in_a_set() {
        let n = 1000;
        let positions: Vec<[f64; 3]> = (0..n).map(|i| [i as f64, 0.5, 0.25]).collect();
        let (mut h, mut mass, values) = (vec![0.5; n], vec![1.0f32; n], vec![1.0f32; n]);
        let check = |h: &[f64], mass: &[f32]| {
            let p = Particles { positions: &positions, smoothing_length: h, mass, values: &values };
            let (serial, pooled, whole) = (p.validate_each(true), p.validate_each(false), p.validate());
            assert_eq!(format!("{serial:?}"), format!("{pooled:?}"));
            (serial.err().map(|e| e.to_string()), whole.err().map(|e| e.to_string()))
        };
        assert_eq!(check(&h, &mass), (None, None));
        (h[700], h[900]) = (-0.5, 0.0);
        let (each, whole) = check(&h, &mass);
        assert!(each.as_deref().is_some_and(|e| e.contains("particle 700 has smoothing length -0.5")), "{each:?}");
        assert_eq!(each, whole);
        h[700] = 0.5;
        mass[950] = f32::NAN;
        assert!(check(&h, &mass).0.is_some_and(|e| e.contains("particle 900 has smoothing length 0")));
        (h[900], mass[950]) = (0.5, -1.0);
        assert!(check(&h, &mass).0.is_some_and(|e| e.contains("particle 950 has mass -1")));
        // Massless, or none: a rank's part may be; a whole set may not.
        let (each, whole) = check(&h, &vec![0.0; n]);
        assert!(each.is_none() && whole.is_some_and(|e| e.contains("all particle masses are zero")));
        let none = Particles { positions: &[], smoothing_length: &[], mass: &[], values: &[] };
        assert!(none.validate_each(true).is_ok() && none.validate().is_err());
    }

    #[test]
    fn support_box_needs_a_voxel_centre_inside_the_sphere() {
        let dims = [8, 8, 8];
        // Radius 0.4 around (2.5, 2.5, 2.5): the nearest centres are at distance
        // sqrt(3)/2 = 0.87, so nothing is covered.
        assert_eq!(support_box(dims, [2.5, 2.5, 2.5], 0.4), None);
        assert_eq!(support_box(dims, [2.1, 3.0, 4.0], 0.4), Some(([2, 3, 4], [3, 4, 5])));
        // Clipped at the lattice's edge; a support wholly outside covers nothing.
        assert_eq!(support_box(dims, [-1.0, 0.0, 7.5], 1.6), Some(([0, 0, 6], [1, 2, 8])));
        assert_eq!(support_box(dims, [-3.0, 0.0, 0.0], 1.6), None);
        // Outside the lattice, the nearest centre is the box's, not the
        // one u rounds to: (-1, 0.5, 0.5) is 1.22 from (0, 0, 0) (and 0.71
        // from (-1, 0, 0), off the lattice), so a radius of 1.2 covers none.
        assert_eq!(support_box(dims, [-1.0, 0.5, 0.5], 1.2), None);
        assert_eq!(support_box(dims, [-1.0, 0.5, 0.5], 1.25), Some(([0, 0, 0], [1, 2, 2])));
        // A centre exactly on the sphere is not within it (the spline is 0
        // there): the particle takes the nearest-voxel fallback instead of
        // a splat of weight 0.
        assert_eq!(support_box(dims, [2.5, 3.0, 4.0], 0.5), None);
    }
}
