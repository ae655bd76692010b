//! Where a lattice sits: the index frame of a reference grid in world
//! units (METHOD.md "Frames and units"), world boxes, boxes of lattice
//! indices, and the geometry between a lattice and its sub-lattices.

use crate::error::{Error, Result};
use rayon::prelude::*;

/// How far (in voxels) a sub-lattice's origin may sit from a whole voxel of
/// the lattice it is cut from.
pub(crate) const LATTICE_TOLERANCE: f64 = 1e-6;

/// Where the index frame sits in the world: `u = (x - bmin) * gamma - 0.5`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IndexFrame {
    pub dims: [usize; 3],
    pub bmin: [f64; 3],
    pub gamma: f64,
}

impl IndexFrame {
    /// Whether a frame read from a file can be decoded on: no empty axis,
    /// finite corners, a finite positive voxel size. The readers of model
    /// headers, store entries and step indexes check it.
    pub fn is_valid(&self) -> bool {
        !self.dims.contains(&0) && self.gamma > 0.0 && self.is_finite()
    }

    /// Whether the voxel size and both corners of the lattice's box are
    /// finite.
    fn is_finite(&self) -> bool {
        self.gamma.is_finite() && self.bmin.iter().chain(&self.world_box().max).all(|b| b.is_finite())
    }

    /// `gamma = min_a D_a / (bmax_a - bmin_a)`: isotropic voxels (METHOD.md
    /// "Frames and units").
    pub fn from_bounds(dims: [usize; 3], bmin: [f64; 3], bmax: [f64; 3]) -> Result<IndexFrame> {
        if dims.contains(&0) {
            return Err(Error::arg(format!("dims must be positive, got {dims:?}")));
        }
        let mut gamma = f64::INFINITY;
        for a in 0..3 {
            let ext = bmax[a] - bmin[a];
            if !(ext.is_finite() && ext > 0.0) {
                return Err(Error::arg(format!("bounds on axis {a} are empty or not finite: [{}, {}]", bmin[a], bmax[a])));
            }
            gamma = gamma.min(dims[a] as f64 / ext);
        }
        // Extents so narrow that a voxel's size is not a float64 (below
        // 1e-308 or so) would put every item at an infinite index.
        if !(gamma.is_finite() && gamma > 0.0) {
            return Err(Error::arg(format!("bounds [{bmin:?}, {bmax:?}] are too narrow for {dims:?} voxels of a size float64 can hold")));
        }
        Ok(IndexFrame { dims, bmin, gamma })
    }

    /// A grid whose voxel centres are `origin + i * spacing` (isotropic spacing).
    pub fn for_grid(dims: [usize; 3], origin: [f64; 3], spacing: f64) -> Result<IndexFrame> {
        if !(spacing.is_finite() && spacing > 0.0) {
            return Err(Error::arg(format!("grid spacing must be positive, got {spacing}")));
        }
        let frame = IndexFrame {
            dims,
            bmin: [origin[0] - 0.5 * spacing, origin[1] - 0.5 * spacing, origin[2] - 0.5 * spacing],
            gamma: 1.0 / spacing,
        };
        if !frame.is_finite() {
            return Err(Error::arg(format!("grid origin {origin:?} and spacing {spacing:?} must be finite (and the first and last voxels' corners too)")));
        }
        Ok(frame)
    }

    pub fn world_to_index(&self, x: [f64; 3]) -> [f64; 3] {
        [
            (x[0] - self.bmin[0]) * self.gamma - 0.5,
            (x[1] - self.bmin[1]) * self.gamma - 0.5,
            (x[2] - self.bmin[2]) * self.gamma - 0.5,
        ]
    }

    pub fn index_to_world(&self, u: [f64; 3]) -> [f64; 3] {
        [
            self.bmin[0] + (u[0] + 0.5) / self.gamma,
            self.bmin[1] + (u[1] + 0.5) / self.gamma,
            self.bmin[2] + (u[2] + 0.5) / self.gamma,
        ]
    }

    /// The world box of the lattice: `bmin` to `bmin + dims / gamma`.
    pub fn world_box(&self) -> Bounds {
        Bounds { min: self.bmin, max: std::array::from_fn(|a| self.bmin[a] + self.dims[a] as f64 / self.gamma) }
    }

    /// World bounds from which [`IndexFrame::from_bounds`] gives back this
    /// frame bit for bit, its `dims` over them; `None` where none is found.
    /// One axis sets the voxel size: its upper bound is the frame's box
    /// edge, moved by up to 64 units in the last place (`EXACT_ULPS`) until
    /// the size recomputed from it is the frame's (the box edge itself may
    /// round to another); the other axes end a little short of the box, so
    /// that they do not set it. What a series restarted from a stored model
    /// deposits particles and cells in, the bounds of its first step being
    /// lost with it.
    pub fn exact_bounds(&self) -> Option<Bounds> {
        let edge = self.world_box().max;
        for tight in 0..3 {
            let mut max: [f64; 3] = std::array::from_fn(|a| self.bmin[a] + (edge[a] - self.bmin[a]) * (1.0 - 1e-9));
            for k in 0..=EXACT_ULPS {
                for m in ulps_apart(edge[tight], k) {
                    max[tight] = m;
                    if IndexFrame::from_bounds(self.dims, self.bmin, max).is_ok_and(|f| f == *self) {
                        return Some(Bounds { min: self.bmin, max });
                    }
                }
            }
        }
        None
    }

    /// The frame of the voxels `b` of this lattice: the same voxel size, the
    /// origin moved by whole voxels.
    pub fn sub_frame(&self, b: &IndexBox) -> IndexFrame {
        IndexFrame { dims: b.dims(), bmin: std::array::from_fn(|a| self.bmin[a] + b.lo[a] as f64 / self.gamma), gamma: self.gamma }
    }

    /// The box that the lattice of `piece` (same voxel size) covers in this
    /// lattice; an error when it is off this lattice by a fraction of a voxel
    /// or reaches outside it. The inverse of [`IndexFrame::sub_frame`].
    pub fn box_of(&self, piece: &IndexFrame) -> Result<IndexBox> {
        let mut lo = [0usize; 3];
        let mut hi = [0usize; 3];
        for a in 0..3 {
            let voxels = (piece.bmin[a] - self.bmin[a]) * self.gamma;
            if voxels < -LATTICE_TOLERANCE || (voxels - voxels.round()).abs() > LATTICE_TOLERANCE {
                return Err(Error::arg(format!(
                    "the piece starts {voxels:?} voxels from the global corner along axis {a}: it is not on the global lattice"
                )));
            }
            lo[a] = voxels.round() as usize;
            hi[a] = lo[a] + piece.dims[a];
            if hi[a] > self.dims[a] {
                return Err(Error::arg("the piece reaches outside the global frame"));
            }
        }
        Ok(IndexBox { lo, hi })
    }

    /// The voxels whose cells meet the world box `min..max`, grown by `halo`
    /// voxels on every side and clipped to the lattice (never empty).
    pub fn covering_box(&self, min: [f64; 3], max: [f64; 3], halo: usize) -> IndexBox {
        let mut b = IndexBox { lo: [0; 3], hi: [0; 3] };
        for a in 0..3 {
            let d = self.dims[a] as i64;
            let lo = ((min[a] - self.bmin[a]) * self.gamma).floor() as i64 - halo as i64;
            let hi = ((max[a] - self.bmin[a]) * self.gamma).ceil() as i64 + halo as i64;
            let lo = lo.clamp(0, d - 1);
            b.lo[a] = lo as usize;
            b.hi[a] = hi.clamp(lo + 1, d) as usize;
        }
        b
    }
}

/// A half-open box `[lo, hi)` of lattice indices.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct IndexBox {
    pub lo: [usize; 3],
    pub hi: [usize; 3],
}

impl IndexBox {
    pub fn whole(dims: [usize; 3]) -> IndexBox {
        IndexBox { lo: [0; 3], hi: dims }
    }

    pub fn dims(&self) -> [usize; 3] {
        [0, 1, 2].map(|a| self.hi[a].saturating_sub(self.lo[a]))
    }

    pub(crate) fn check_within(&self, dims: [usize; 3]) -> Result<()> {
        if (0..3).any(|a| self.lo[a] >= self.hi[a] || self.hi[a] > dims[a]) {
            return Err(Error::arg(format!(
                "sub-box {:?}..{:?} is empty or not inside the lattice of {dims:?}",
                self.lo, self.hi
            )));
        }
        Ok(())
    }
}

/// How far (units in the last place) [`IndexFrame::exact_bounds`] looks.
const EXACT_ULPS: usize = 64;

/// `x` moved `k` units in the last place up, and `k` down: where a search
/// for a float that rounds as another computation did looks next.
pub fn ulps_apart(x: f64, k: usize) -> [f64; 2] {
    let (mut up, mut down) = (x, x);
    for _ in 0..k {
        (up, down) = (up.next_up(), down.next_down());
    }
    [up, down]
}

/// An axis-aligned box in world units.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Bounds {
    pub min: [f64; 3],
    pub max: [f64; 3],
}

impl Bounds {
    /// The smallest box holding every `(lo, hi)` corner pair.
    pub(crate) fn enclosing(boxes: impl ParallelIterator<Item = ([f64; 3], [f64; 3])>) -> Bounds {
        let empty = || Bounds { min: [f64::INFINITY; 3], max: [f64::NEG_INFINITY; 3] };
        boxes.fold(empty, |b, (lo, hi)| b.union(lo, hi)).reduce(empty, |a, b| a.union(b.min, b.max))
    }

    /// Dims with `longest` voxels along the box's longest axis and cubic
    /// voxels, so that an elongated box is not padded to a cube of empty space.
    pub fn fitted_dims(&self, longest: usize) -> Result<[usize; 3]> {
        let ext = [0, 1, 2].map(|a| self.max[a] - self.min[a]);
        if longest == 0 || ext.iter().any(|e| !(e.is_finite() && *e >= 0.0)) {
            return Err(Error::arg(format!("cannot fit {longest} voxels to the box {:?} .. {:?}", self.min, self.max)));
        }
        let emax = ext.iter().cloned().fold(0.0, f64::max);
        if emax <= 0.0 {
            return Err(Error::arg("the box is a single point; give bounds explicitly"));
        }
        Ok(ext.map(|e| ((e / emax * longest as f64).round() as usize).max(1)))
    }

    fn union(self, lo: [f64; 3], hi: [f64; 3]) -> Bounds {
        Bounds { min: [0, 1, 2].map(|a| self.min[a].min(lo[a])), max: [0, 1, 2].map(|a| self.max[a].max(hi[a])) }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_grid_frame_is_finite_or_refused() {
        let f = IndexFrame::for_grid([4; 3], [1.0, 2.0, 3.0], 0.5).unwrap();
        assert_eq!((f.bmin, f.gamma), ([0.75, 1.75, 2.75], 2.0));
        assert!(f.is_valid());
        for (origin, spacing) in [([f64::NAN, 0.0, 0.0], 1.0), ([0.0, f64::INFINITY, 0.0], 1.0), ([-f64::MAX, 0.0, 0.0], 1e300), ([0.0; 3], 1e-320), ([f64::MAX / 2.0, 0.0, 0.0], f64::MAX / 4.0), ([0.0; 3], f64::MAX / 2.0)] {
            let e = IndexFrame::for_grid([4; 3], origin, spacing).unwrap_err();
            assert!(matches!(e, Error::InvalidArgument(_)) && e.to_string().contains("finite"), "{origin:?} {spacing}: {e}");
        }
    }

    /// The lattice of any bounds is given back by bounds of its own, though
    /// its box's edges round to other voxel sizes (counted: the case is real).
    #[test]
    fn a_lattice_has_bounds_that_give_it_back() {
        let mut rng = crate::math::rng::Rng::new(0x2545_f491);
        let mut next = || rng.range(0.0, 1.0);
        let mut edges_differ = 0;
        for _ in 0..20_000 {
            let dims = [1 + (next() * 300.0) as usize, 1 + (next() * 300.0) as usize, 1 + (next() * 300.0) as usize];
            let scale = 10f64.powf(next() * 12.0 - 6.0);
            let min: [f64; 3] = std::array::from_fn(|_| (next() - 0.5) * 4.0 * scale);
            let max: [f64; 3] = std::array::from_fn(|a| min[a] + (0.01 + next()) * scale);
            let f = IndexFrame::from_bounds(dims, min, max).unwrap();
            let b = f.exact_bounds().unwrap_or_else(|| panic!("no bounds give {f:?} back"));
            assert_eq!(IndexFrame::from_bounds(dims, b.min, b.max).unwrap(), f);
            let w = f.world_box();
            edges_differ += (IndexFrame::from_bounds(dims, w.min, w.max).unwrap() != f) as usize;
        }
        assert!(edges_differ > 100, "{edges_differ} frames whose own box gives another");
    }

    #[test]
    fn bounds_are_refused_unless_their_voxels_have_a_size() {
        for (min, max) in [([0.0; 3], [1.0, 1.0, 0.0]), ([0.0; 3], [1.0, f64::INFINITY, 1.0]), ([f64::NAN, 0.0, 0.0], [1.0; 3]), ([0.0; 3], [1e-310; 3])] {
            let e = IndexFrame::from_bounds([16; 3], min, max).unwrap_err().to_string();
            assert!(e.contains("bounds"), "{min:?}..{max:?}: {e}");
        }
        let f = IndexFrame::from_bounds([16; 3], [0.0; 3], [1e-300; 3]).unwrap();
        assert!(f.is_valid() && f.gamma == 16.0 / 1e-300);
        // A frame read from a file whose far corner overflows is not valid.
        assert!(!IndexFrame { dims: [16; 3], bmin: [0.0; 3], gamma: 1e-308 }.is_valid());
        assert!(IndexFrame { dims: [16; 3], bmin: [0.0; 3], gamma: 1e-300 }.is_valid());
        assert!(IndexFrame::from_bounds([0, 16, 16], [0.0; 3], [1.0; 3]).unwrap_err().to_string().contains("dims must be positive"));
    }

    /// `box_of` gives back the box a sub-frame was cut from, up to the
    /// lattice's far end, and refuses a piece a fraction of a voxel off the
    /// lattice, one starting a whole voxel before its corner and one
    /// reaching a voxel past its end.
    #[test]
    fn a_piece_is_a_box_of_the_lattice_or_refused() {
        let global = IndexFrame { dims: [10, 8, 6], bmin: [1.0, 2.0, 3.0], gamma: 4.0 };
        for b in [IndexBox { lo: [2, 0, 1], hi: [7, 8, 6] }, IndexBox { lo: [3, 7, 0], hi: [10, 8, 6] }, IndexBox::whole(global.dims)] {
            assert_eq!(global.box_of(&global.sub_frame(&b)).unwrap(), b);
        }
        let piece = global.sub_frame(&IndexBox { lo: [2, 0, 1], hi: [7, 8, 6] });
        let moved = |a: usize, voxels: f64, dims: [usize; 3]| {
            let mut f = IndexFrame { dims, ..piece };
            f.bmin[a] += voxels / global.gamma;
            global.box_of(&f).unwrap_err().to_string()
        };
        let e = moved(1, 0.5, piece.dims);
        assert!(e.contains("0.5 voxels") && e.contains("axis 1") && e.contains("not on the global lattice"), "{e}");
        let e = moved(0, -3.0, piece.dims);
        assert!(e.contains("-1.0 voxels") && e.contains("axis 0") && e.contains("not on the global lattice"), "a voxel before the corner: {e}");
        let e = moved(2, 0.0, [5, 8, 6]);
        assert!(e.contains("reaches outside"), "a voxel past the end along z: {e}");
    }

    /// `covering_box` takes every voxel whose cell meets the world box,
    /// grows it by the halo, clips it to the lattice, and never gives an
    /// empty box (a box on a voxel face, or wholly outside the lattice).
    #[test]
    fn the_covering_box_is_the_cells_met_grown_by_the_halo() {
        let f = IndexFrame { dims: [10, 12, 8], bmin: [0.0, -1.0, 2.0], gamma: 2.0 };
        // x: [1.15, 2.8] is index 2.3..5.6, cells 2..=5; y: [-0.5, 2.0]
        // is 1.0..6.0, cells 1..=5 (a face on either side); z: 0.5..7.5.
        let (min, max) = ([1.15, -0.5, 2.25], [2.8, 2.0, 5.75]);
        let b = f.covering_box(min, max, 0);
        assert_eq!(b, IndexBox { lo: [2, 1, 0], hi: [6, 6, 8] });
        assert_eq!(f.covering_box(min, max, 2), IndexBox { lo: [0, 0, 0], hi: [8, 8, 8] });
        assert_eq!(f.covering_box(min, max, 100), IndexBox::whole(f.dims));
        // A point on a voxel face, and a point beyond the lattice: one voxel.
        assert_eq!(f.covering_box([1.5, 0.0, 3.0], [1.5, 0.0, 3.0], 0), IndexBox { lo: [3, 2, 2], hi: [4, 3, 3] });
        assert_eq!(f.covering_box([50.0; 3], [60.0; 3], 1), IndexBox { lo: [9, 11, 7], hi: [10, 12, 8] });
    }

    #[test]
    fn index_frame_round_trips() {
        let f = IndexFrame::from_bounds([64, 32, 32], [0.0, 0.0, 0.0], [2.0, 1.0, 1.0]).unwrap();
        assert_eq!(f.gamma, 32.0);
        let u = f.world_to_index([0.5 / 32.0, 0.0, 1.0]);
        assert!((u[0] - 0.0).abs() < 1e-12);
        let x = f.index_to_world(u);
        assert!((x[2] - 1.0).abs() < 1e-12);
    }
}
