//! Axis-aligned hexahedral cells (AMR leaves) as encoder input (METHOD.md
//! "Samples" and "Reference grid", the paper's Eq. 6).
//!
//! A cell with world centre `x`, volume `vol` and normalised value `v`, at
//! `u = frame(x)` with `h = 0.5 gamma vol^(1/3)`, is
//! - a sample `(u, h, v, vol)` when `u` lies inside the bounds; cells outside
//!   seed nothing but are counted;
//! - a stamp on the clamped voxel box `[floor(u - 2h), ceil(u + 2h))` with
//!   weight `vol` in the volume-weighted deposit. A cell inside the bounds
//!   whose box misses the lattice (possible within half a voxel of its edge)
//!   goes into its nearest voxel instead.

use crate::input::deposit::{inside_bounds, nearest_voxel_box, Shape, Splat};
use crate::error::{Error, Result};
use crate::field::IndexFrame;
use crate::field::Bounds;
use crate::input::first_bad;
use crate::input::items::{Conversion, Item};
use rayon::prelude::*;

/// How the cells' sizes are given.
#[derive(Clone, Copy, Debug)]
pub enum CellSize<'a> {
    /// Edge lengths per axis (world units).
    Edges(&'a [[f64; 3]]),
    /// Volumes (world units cubed); the bounds then assume cubic cells.
    Volumes(&'a [f64]),
}

impl CellSize<'_> {
    fn len(&self) -> usize {
        match self {
            CellSize::Edges(e) => e.len(),
            CellSize::Volumes(v) => v.len(),
        }
    }

    fn volume(&self, j: usize) -> f64 {
        match self {
            CellSize::Edges(e) => e[j][0] * e[j][1] * e[j][2],
            CellSize::Volumes(v) => v[j],
        }
    }

    fn half_edges(&self, j: usize) -> [f64; 3] {
        match self {
            CellSize::Edges(e) => e[j].map(|x| 0.5 * x),
            CellSize::Volumes(v) => [0.5 * v[j].cbrt(); 3],
        }
    }
}

/// Cells in world units, borrowed from the caller.
#[derive(Clone, Copy, Debug)]
pub struct Cells<'a> {
    pub centres: &'a [[f64; 3]],
    pub size: CellSize<'a>,
    /// Raw field values (before the transform and normalisation).
    pub values: &'a [f32],
}

impl Cells<'_> {
    pub fn len(&self) -> usize {
        self.centres.len()
    }

    pub fn is_empty(&self) -> bool {
        self.centres.is_empty()
    }

    /// Fails on empty or mismatched arrays, non-finite centres, and edges or
    /// volumes that are not positive and finite.
    pub fn validate(&self) -> Result<()> {
        if self.is_empty() {
            return Err(Error::data("no cells"));
        }
        self.validate_each(false)
    }

    /// What [`Self::validate`] asks of each cell alone: a rank's part of a
    /// decomposed field, which may hold none. `serial`: on the calling
    /// thread alone (no rayon pool woken).
    pub fn validate_each(&self, serial: bool) -> Result<()> {
        let n = self.len();
        let what = match self.size {
            CellSize::Edges(_) => "edge-length triples",
            CellSize::Volumes(_) => "volumes",
        };
        if self.size.len() != n {
            return Err(Error::data(format!("{n} cell centres but {} {what}", self.size.len())));
        }
        if self.values.len() != n {
            return Err(Error::data(format!("{n} cell centres but {} values", self.values.len())));
        }
        if let Some(i) = first_bad(n, serial, |i| !self.centres[i].iter().all(|c| c.is_finite())) {
            return Err(Error::data(format!("cell {i} has a non-finite centre {:?}", self.centres[i])));
        }
        let bad_size = |i: usize| {
            let vol = self.size.volume(i);
            let edges_ok = match self.size {
                CellSize::Edges(e) => e[i].iter().all(|x| x.is_finite() && *x > 0.0),
                CellSize::Volumes(_) => true,
            };
            !(edges_ok && vol.is_finite() && vol > 0.0)
        };
        if let Some(i) = first_bad(n, serial, bad_size) {
            let size = match self.size {
                CellSize::Edges(e) => format!("edges {:?}", e[i]),
                CellSize::Volumes(v) => format!("volume {}", v[i]),
            };
            return Err(Error::data(format!("cell {i} has {size}; sizes must be positive and finite")));
        }
        Ok(())
    }

    /// The box enclosing every cell. Cells whose size is missing (arrays of
    /// different lengths, which [`Self::validate`] refuses) are left out.
    pub fn bounds(&self) -> Bounds {
        Bounds::enclosing((0..self.len().min(self.size.len())).into_par_iter().map(|j| {
            let (c, e) = (self.centres[j], self.size.half_edges(j));
            ([c[0] - e[0], c[1] - e[1], c[2] - e[2]], [c[0] + e[0], c[1] + e[1], c[2] + e[2]])
        }))
    }
}

/// The stamp box `[floor(u - 2h), ceil(u + 2h))` clamped to the lattice, or
/// `None` when it misses the lattice.
pub fn stamp_box(dims: [usize; 3], u: [f64; 3], h: f64) -> Option<([u32; 3], [u32; 3])> {
    let mut lo = [0u32; 3];
    let mut hi = [0u32; 3];
    for a in 0..3 {
        let first = (u[a] - 2.0 * h).floor().max(0.0);
        let end = (u[a] + 2.0 * h).ceil().min(dims[a] as f64);
        if first >= end {
            return None;
        }
        lo[a] = first as u32;
        hi[a] = end as u32;
    }
    Some((lo, hi))
}

impl Conversion for Cells<'_> {
    fn item_count(&self) -> usize {
        self.len()
    }

    fn item(&self, j: usize, frame: &IndexFrame, value: f32) -> Item {
        let u = frame.world_to_index(self.centres[j]);
        let vol = self.size.volume(j);
        let h = 0.5 * frame.gamma * vol.cbrt();
        let inside = inside_bounds(frame, u);
        let (stamp, nearest) = match stamp_box(frame.dims, u, h) {
            Some(b) => (Some(b), false),
            None if inside => (Some(nearest_voxel_box(frame.dims, u)), true),
            None => (None, false),
        };
        let splat = stamp.map(|(lo, hi)| Splat { lo, hi, m: vol, v: value as f64, shape: Shape::Box });
        Item { u, sample_scale: h, importance: vol, inside, splat, nearest }
    }
}

/// Centre (mean of the nodes) and volume of a hexahedron given by its eight
/// nodes in VTK order (0-1-2-3 one face, 4-5-6-7 the opposite one, `i + 4`
/// above `i`), through six tetrahedra around the diagonal 0-6. Exact for
/// any hexahedron with planar faces; the magnitude is taken, so either
/// orientation works.
pub fn hexahedron_centre_volume(n: &[[f64; 3]; 8]) -> ([f64; 3], f64) {
    let centre = std::array::from_fn(|a| n.iter().map(|p| p[a]).sum::<f64>() / 8.0);
    let sub = |p: [f64; 3], q: [f64; 3]| [p[0] - q[0], p[1] - q[1], p[2] - q[2]];
    let det = |a: [f64; 3], b: [f64; 3], c: [f64; 3]| {
        a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0]) + a[2] * (b[0] * c[1] - b[1] * c[0])
    };
    let tets = [[1, 2], [2, 3], [3, 7], [7, 4], [4, 5], [5, 1]];
    let v: f64 = tets.iter().map(|&[i, j]| det(sub(n[i], n[0]), sub(n[j], n[0]), sub(n[6], n[0]))).sum();
    (centre, v.abs() / 6.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hexahedron_volumes_match_their_shapes() {
        let cube: [[f64; 3]; 8] =
            [[0., 0., 0.], [1., 0., 0.], [1., 1., 0.], [0., 1., 0.], [0., 0., 1.], [1., 0., 1.], [1., 1., 1.], [0., 1., 1.]];
        let (c, v) = hexahedron_centre_volume(&cube);
        assert_eq!(c, [0.5; 3]);
        assert!((v - 1.0).abs() < 1e-12);
        // A box of 2 x 3 x 0.5, shifted, then sheared in x by z (volume kept).
        let boxed = cube.map(|p| [2.0 * p[0] + 5.0 + 0.7 * p[2], 3.0 * p[1] - 1.0, 0.5 * p[2]]);
        let (c, v) = hexahedron_centre_volume(&boxed);
        assert!((v - 3.0).abs() < 1e-12, "{v}");
        assert!((c[0] - (6.0 + 0.35)).abs() < 1e-12 && (c[1] - 0.5).abs() < 1e-12 && (c[2] - 0.25).abs() < 1e-12);
        // The mirror image (inverted node order) has the same volume.
        let mirrored = cube.map(|p| [-p[0], p[1], p[2]]);
        assert!((hexahedron_centre_volume(&mirrored).1 - 1.0).abs() < 1e-12);
        // A frustum-like hexahedron: bottom 2 x 2, top 1 x 1 centred, height 1: volume 7/3.
        let f = [[0., 0., 0.], [2., 0., 0.], [2., 2., 0.], [0., 2., 0.], [0.5, 0.5, 1.], [1.5, 0.5, 1.], [1.5, 1.5, 1.], [0.5, 1.5, 1.]];
        assert!((hexahedron_centre_volume(&f).1 - 7.0 / 3.0).abs() < 1e-12);
    }

    /// Bounds are asked of arrays not yet validated (the data's box, for
    /// fit dims): a cell without a size is left out, not read past its array.
    #[test]
    fn bounds_leave_out_cells_without_a_size() {
        let centres = [[0.0; 3], [4.0, 5.0, 6.0]];
        let values = [1.0f32; 2];
        let one = Cells { centres: &centres, size: CellSize::Edges(&[[2.0; 3]]), values: &values };
        let b = one.bounds();
        assert_eq!((b.min, b.max), ([-1.0; 3], [1.0; 3]));
        let none = Cells { centres: &centres, size: CellSize::Volumes(&[]), values: &values };
        assert!(none.bounds().fitted_dims(8).is_err());
        assert!(none.validate().unwrap_err().to_string().contains("2 cell centres but 0 volumes"));
    }
}
