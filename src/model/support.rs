//! The stored support of a model (METHOD.md "Support"): one bit per voxel of
//! the reference lattice, set where the reference exceeds the objective's
//! mask (0.005). The objective never looks at the other voxels, so the
//! Gaussians' tails that reach them are unsupervised; the decoder blends
//! `V_eval` with the support's [`Outside`] prediction `E(V_eval)` by the
//! trilinear interpolation `S` of the bits, `S V + (1 - S) E(V)`: exactly
//! `V` inside at every voxel centre (left untouched), exactly `E(V)`
//! outside (0 when the outside is zero, the paper's decode times the
//! bits), and a fall over one voxel between centres.

use crate::backend::Lattice;
use crate::error::{Error, Result};
use crate::field::{Grid, IndexBox};
use crate::math::loss::MASK_REF;
use crate::model::outside::Outside;
use rayon::prelude::*;

/// Which voxels of a reference lattice hold data, and what the decode
/// gives at the others.
#[derive(Clone, Debug, PartialEq)]
pub struct Support {
    dims: [usize; 3],
    /// Bit `i` (x fastest) of byte `i / 8`, least significant bit first.
    bits: Vec<u8>,
    /// The decoded value outside, fitted by the encoder (zero unless set).
    outside: Outside,
}

/// Whether a support voxel's four (y, z) neighbours of a lattice row are
/// all in the support, all out of it, or neither ([`Support::apply`]).
#[derive(Clone, Copy, PartialEq)]
enum Mark {
    In,
    Out,
    Mixed,
}

impl Support {
    /// The voxels of `reference` (normalised) above the objective's mask;
    /// `None` when that is every voxel (nothing to store).
    pub fn from_reference(reference: &Grid) -> Option<Support> {
        if reference.values.iter().all(|&v| v > MASK_REF) {
            return None;
        }
        let mut bits = vec![0u8; reference.len().div_ceil(8)];
        for (byte, chunk) in bits.iter_mut().zip(reference.values.chunks(8)) {
            *byte = chunk.iter().enumerate().fold(0u8, |b, (k, &v)| b | (((v > MASK_REF) as u8) << k));
        }
        Some(Support { dims: reference.dims, bits, outside: Outside::ZERO })
    }

    /// A support of `dims` from its packed bits (as `bits()` gives them);
    /// refuses a length that does not fit the lattice or stray bits past it.
    pub fn from_bits(dims: [usize; 3], bits: Vec<u8>) -> Result<Support> {
        let n = dims.iter().try_fold(1usize, |a, &d| a.checked_mul(d)).filter(|&n| n > 0);
        let n = n.ok_or_else(|| Error::format(format!("support of dims {dims:?}")))?;
        if bits.len() != n.div_ceil(8) {
            return Err(Error::format(format!("support holds {} bytes; {dims:?} voxels need {}", bits.len(), n.div_ceil(8))));
        }
        if n % 8 != 0 && bits[bits.len() - 1] >> (n % 8) != 0 {
            return Err(Error::format("support has bits set past its lattice"));
        }
        Ok(Support { dims, bits, outside: Outside::ZERO })
    }

    /// This support with `outside` decoded at its empty voxels; refuses
    /// non-finite coefficients.
    pub fn with_outside(self, outside: Outside) -> Result<Support> {
        if !outside.is_finite() {
            return Err(Error::format(format!("support's outside fit {outside:?} is not finite")));
        }
        Ok(Support { outside, ..self })
    }

    pub fn outside(&self) -> Outside {
        self.outside
    }

    /// The [`Outside`] to store for `decoded` (the Gaussians' own `V_eval`
    /// on the reference lattice, x fastest) against `reference`: the least
    /// squares fit over the voxels outside this support, in lattice order,
    /// where it pays ([`Outside::choose`]).
    pub fn fit_outside(&self, decoded: &[f32], reference: &Grid) -> Outside {
        debug_assert_eq!((decoded.len(), reference.dims), (reference.len(), self.dims));
        Outside::choose(decoded, &reference.values, |v| !self.holds(v))
    }

    pub fn dims(&self) -> [usize; 3] {
        self.dims
    }

    /// The packed bits: voxel `i` (x fastest) is bit `i % 8` of byte `i / 8`.
    pub fn bits(&self) -> &[u8] {
        &self.bits
    }

    /// Voxels in the support.
    pub fn count(&self) -> usize {
        self.bits.iter().map(|b| b.count_ones() as usize).sum()
    }

    /// Whether voxel `v` (x fastest) is in the support.
    #[inline]
    fn holds(&self, v: usize) -> bool {
        (self.bits[v / 8] >> (v % 8)) & 1 == 1
    }

    #[inline]
    fn bit(&self, i: usize, j: usize, k: usize) -> f32 {
        self.holds(i + self.dims[0] * (j + self.dims[1] * k)) as u8 as f32
    }

    /// The trilinear interpolation of the bits at an index-frame position,
    /// clamped to the lattice like the reference's own interpolation: the
    /// bit itself at a voxel centre.
    #[inline]
    pub fn factor(&self, u: [f32; 3]) -> f32 {
        let mut i0 = [0usize; 3];
        let mut i1 = [0usize; 3];
        let mut t = [0f32; 3];
        for a in 0..3 {
            let hi = (self.dims[a] - 1) as f32;
            let x = u[a].clamp(0.0, hi);
            let f = x.floor();
            i0[a] = f as usize;
            i1[a] = (i0[a] + 1).min(self.dims[a] - 1);
            t[a] = x - f;
        }
        let lerp = |a: f32, b: f32, t: f32| a + (b - a) * t;
        let plane = |k: usize| {
            let y0 = lerp(self.bit(i0[0], i0[1], k), self.bit(i1[0], i0[1], k), t[0]);
            let y1 = lerp(self.bit(i0[0], i1[1], k), self.bit(i1[0], i1[1], k), t[0]);
            lerp(y0, y1, t[1])
        };
        lerp(plane(i0[2]), plane(i1[2]), t[2])
    }

    /// The decoded value where the Gaussians give `v` and the support's
    /// factor ([`Support::factor`]) is `f`: `f v + (1 - f) E(v)`; with a
    /// zero outside exactly `v f`, as before outsides were fitted.
    #[inline]
    pub fn blend(&self, v: f32, f: f32) -> f32 {
        if self.outside.is_zero() {
            v * f
        } else {
            f * v + (1.0 - f) * self.outside.value(v)
        }
    }

    /// Blends the values decoded at `lattice`'s points (x fastest) with the
    /// outside by the support's factor there ([`Support::blend`]; the
    /// per-axis interpolation is worked out once per axis, not per point).
    pub fn apply(&self, lattice: &Lattice, out: &mut [f32]) {
        let [nx, ny, _] = lattice.dims;
        // Per axis and lattice index: (lower voxel, upper voxel, weight).
        let axis = |a: usize| -> Vec<(usize, usize, f32)> {
            (0..lattice.dims[a])
                .map(|i| {
                    let u = lattice.point(i * (a == 0) as usize, i * (a == 1) as usize, i * (a == 2) as usize)[a];
                    let x = u.clamp(0.0, (self.dims[a] - 1) as f32);
                    let f = x.floor();
                    let i0 = f as usize;
                    (i0, (i0 + 1).min(self.dims[a] - 1), x - f)
                })
                .collect()
        };
        let (ax, ay, az) = (axis(0), axis(1), axis(2));
        let lerp = |a: f32, b: f32, t: f32| a + (b - a) * t;
        // Where the lattice is at least as fine as the support along x, a
        // row first marks the support's voxels along x whose four (y, z)
        // neighbours of the row are all in it, or all out of it. Between two
        // such the factor is exactly 1, or exactly 0 (each lerp of equal
        // ends is that end), so the row knows it without the eight bits:
        // inside, a point keeps its value; outside, it takes the blend at 0.
        // The marks hold for every row between the same two support rows,
        // and so do the runs of lattice points they make: kept, skipped,
        // blended at 0, or blended by their own factor.
        let skim = nx >= self.dims[0];
        out.par_chunks_mut((nx * ny).max(1)).zip(az.par_iter()).for_each(|(layer, &(z0, z1, tz))| {
            let mut marks = vec![Mark::Mixed; if skim { self.dims[0] } else { 0 }];
            // Per support voxel along x, its bits at (y0, z0), (y1, z0),
            // (y0, z1) and (y1, z1) of the row.
            let mut corners = vec![[0f32; 4]; self.dims[0]];
            let mut runs: Vec<(usize, usize, Mark)> = Vec::new();
            let mut marked = None;
            for (j, &(y0, y1, ty)) in ay.iter().enumerate() {
                if marked != Some((y0, y1)) {
                    for (x, c) in corners.iter_mut().enumerate() {
                        *c = [(y0, z0), (y1, z0), (y0, z1), (y1, z1)].map(|(y, z)| self.bit(x, y, z));
                    }
                    for (m, c) in marks.iter_mut().zip(&corners) {
                        *m = match c {
                            [1.0, 1.0, 1.0, 1.0] => Mark::In,
                            [0.0, 0.0, 0.0, 0.0] => Mark::Out,
                            _ => Mark::Mixed,
                        };
                    }
                    runs.clear();
                    for (i, &(x0, x1, _)) in ax.iter().enumerate() {
                        let kind = if skim && marks[x0] == marks[x1] { marks[x0] } else { Mark::Mixed };
                        match runs.last_mut() {
                            Some((_, end, k)) if *k == kind => *end = i + 1,
                            _ => runs.push((i, i + 1, kind)),
                        }
                    }
                    marked = Some((y0, y1));
                }
                let row = &mut layer[nx * j..nx * (j + 1)];
                for &(start, end, kind) in &runs {
                    match kind {
                        Mark::In => {}
                        Mark::Out => row[start..end].iter_mut().for_each(|v| *v = self.blend(*v, 0.0)),
                        Mark::Mixed => {
                            for (v, &(x0, x1, tx)) in row[start..end].iter_mut().zip(&ax[start..end]) {
                                let (c0, c1) = (&corners[x0], &corners[x1]);
                                // The plane at z0 (corners 0, 1), then z1 (2, 3).
                                let plane = |k: usize| {
                                    let a = lerp(c0[k], c1[k], tx);
                                    let b = lerp(c0[k + 1], c1[k + 1], tx);
                                    lerp(a, b, ty)
                                };
                                let f = lerp(plane(0), plane(2), tz);
                                if f != 1.0 {
                                    *v = self.blend(*v, f);
                                }
                            }
                        }
                    }
                }
            }
        });
    }

    /// One support of a lattice of `dims` from those of its pieces, each at
    /// its box (a piece without a support is support everywhere on its box);
    /// voxels of no piece are outside (the pieces of a domain merged into
    /// one model). Its outside is the pieces' own, averaged over their
    /// empty voxels (each piece's decode blends with its own: this one
    /// serves the merged model only).
    pub fn place(supports: &[(Option<&Support>, IndexBox)], dims: [usize; 3]) -> Support {
        let n: usize = dims.iter().product();
        let mut bits = vec![0u8; n.div_ceil(8)];
        let (mut empty, mut offset, mut gain) = (0f64, 0f64, 0f64);
        for s in supports.iter().filter_map(|(s, _)| *s) {
            let e = (s.dims.iter().product::<usize>() - s.count()) as f64;
            (empty, offset, gain) = (empty + e, offset + e * s.outside.offset as f64, gain + e * s.outside.gain as f64);
        }
        let outside = if empty > 0.0 { Outside { offset: (offset / empty) as f32, gain: (gain / empty) as f32 } } else { Outside::ZERO };
        for (s, b) in supports {
            let bd = b.dims();
            for k in 0..bd[2] {
                for j in 0..bd[1] {
                    for i in 0..bd[0] {
                        if s.is_none_or(|s| s.bit(i, j, k) == 1.0) {
                            let v = (b.lo[0] + i) + dims[0] * ((b.lo[1] + j) + dims[1] * (b.lo[2] + k));
                            bits[v / 8] |= 1 << (v % 8);
                        }
                    }
                }
            }
        }
        Support { dims, bits, outside }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn support() -> Support {
        // 5 x 4 x 3 with a 2 x 2 x 2 block of data at (1..3, 1..3, 0..2).
        let mut g = Grid::new([5, 4, 3], vec![0.0; 60]).unwrap();
        for (i, j, k) in [(1, 1, 0), (2, 1, 0), (1, 2, 0), (2, 2, 0), (1, 1, 1), (2, 1, 1), (1, 2, 1), (2, 2, 1)] {
            let at = g.index(i, j, k);
            g.values[at] = 0.5;
        }
        g.values[0] = 0.005; // at the mask: outside
        Support::from_reference(&g).unwrap()
    }

    #[test]
    fn bits_at_centres_and_a_linear_fall_between() {
        let s = support();
        assert_eq!(s.count(), 8);
        assert_eq!(s.factor([1.0, 1.0, 0.0]), 1.0);
        assert_eq!(s.factor([0.0, 0.0, 0.0]), 0.0);
        assert_eq!(s.factor([4.0, 3.0, 2.0]), 0.0);
        assert!((s.factor([0.5, 1.0, 0.0]) - 0.5).abs() < 1e-7);
        assert!((s.factor([2.75, 1.5, 1.0]) - 0.25).abs() < 1e-6);
        // Clamped like the reference: beyond the lattice is its edge.
        assert_eq!(s.factor([-3.0, 1.0, 0.0]), 0.0);
        assert_eq!(s.factor([1.0, 1.0, -7.0]), 1.0);
    }

    #[test]
    fn bits_round_trip_and_bad_bits_are_refused() {
        let s = support();
        assert_eq!(Support::from_bits(s.dims(), s.bits().to_vec()).unwrap(), s);
        assert!(Support::from_bits([5, 4, 3], vec![0; 7]).is_err());
        let mut stray = s.bits().to_vec();
        *stray.last_mut().unwrap() |= 0x80; // voxel 63 of 60
        assert!(Support::from_bits([5, 4, 3], stray).is_err());
        let full = Grid::new([2, 2, 2], vec![0.3; 8]).unwrap();
        assert!(Support::from_reference(&full).is_none(), "a support of every voxel is not stored");
    }

    #[test]
    fn apply_zeroes_outside_and_keeps_inside_bit_for_bit() {
        let s = support();
        let lattice = Lattice::reference([5, 4, 3]);
        let mut out: Vec<f32> = (0..60).map(|i| 0.1 + i as f32 * 0.013).collect();
        let before = out.clone();
        s.apply(&lattice, &mut out);
        for (i, (a, b)) in out.iter().zip(&before).enumerate() {
            let inside = s.bit(i % 5, i / 5 % 4, i / 20) == 1.0;
            assert_eq!(*a, if inside { *b } else { 0.0 }, "voxel {i}");
        }
    }

    #[test]
    fn apply_multiplies_by_the_factor_at_every_point_of_any_lattice() {
        let s = support();
        for lattice in [Lattice::resampled([5, 4, 3], [11, 7, 5]), Lattice { dims: [3, 2, 2], origin: [0.75, 0.5, -0.25], step: [1.5, 0.4, 0.9] }] {
            let mut out = vec![2.0f32; lattice.len()];
            s.apply(&lattice, &mut out);
            let [nx, ny, nz] = lattice.dims;
            for k in 0..nz {
                for j in 0..ny {
                    for i in 0..nx {
                        let want = 2.0 * s.factor(lattice.point(i, j, k));
                        assert_eq!(out[i + nx * (j + ny * k)], want, "point {i},{j},{k}");
                    }
                }
            }
        }
    }

    /// A support of a ball with holes, on lattices finer than it (where a
    /// row skips the points whose neighbours are all in it), as fine, and
    /// coarser, shifted and stretched per axis: every point gets exactly
    /// the blend of its own factor.
    #[test]
    fn apply_blends_every_point_by_its_own_factor_where_rows_skip_full_cells() {
        let dims = [13, 11, 9];
        let mut g = Grid::new(dims, vec![0.0; 13 * 11 * 9]).unwrap();
        for k in 0..9 {
            for j in 0..11 {
                for i in 0..13 {
                    let r2 = [(i as f32 - 6.0) / 5.5, (j as f32 - 5.0) / 4.5, (k as f32 - 4.0) / 3.5].iter().map(|d| d * d).sum::<f32>();
                    let at = g.index(i, j, k);
                    g.values[at] = if r2 < 1.0 && (i * 7 + j * 3 + k * 5) % 11 != 0 { 0.5 } else { 0.0 };
                }
            }
        }
        let o = Outside { offset: 0.001, gain: 0.25 };
        let s = Support::from_reference(&g).unwrap().with_outside(o).unwrap();
        for lattice in [
            Lattice::resampled(dims, [40, 31, 20]),
            Lattice::reference(dims),
            Lattice::resampled(dims, [6, 5, 4]),
            Lattice { dims: [29, 17, 7], origin: [-0.6, 1.3, 2.1], step: [0.45, 0.61, 0.83] },
        ] {
            let before: Vec<f32> = (0..lattice.len()).map(|i| 0.002 + (i % 97) as f32 * 0.01).collect();
            let mut out = before.clone();
            s.apply(&lattice, &mut out);
            let [nx, ny, _] = lattice.dims;
            let (mut kept, mut blended) = (0, 0);
            for (i, (v, b)) in out.iter().zip(&before).enumerate() {
                let f = s.factor(lattice.point(i % nx, i / nx % ny, i / (nx * ny)));
                let want = if f == 1.0 { *b } else { s.blend(*b, f) };
                assert_eq!(v.to_bits(), want.to_bits(), "{lattice:?} point {i}: {v}, want {want} at factor {f}");
                if f == 1.0 { kept += 1 } else { blended += 1 }
            }
            assert!(kept > 0 && blended > 0, "{lattice:?}: {kept} kept, {blended} blended");
        }
    }

    #[test]
    fn apply_blends_with_a_fitted_outside() {
        let o = Outside { offset: 0.002, gain: 0.5 };
        let s = support().with_outside(o).unwrap();
        // At the reference centres: untouched inside, the outside's value of
        // the Gaussians' own value outside.
        let lattice = Lattice::reference([5, 4, 3]);
        let before: Vec<f32> = (0..60).map(|i| i as f32 * 1e-4).collect();
        let mut out = before.clone();
        s.apply(&lattice, &mut out);
        for (i, (a, b)) in out.iter().zip(&before).enumerate() {
            let inside = s.bit(i % 5, i / 5 % 4, i / 20) == 1.0;
            assert_eq!(*a, if inside { *b } else { (0.002 + 0.5 * b.min(MASK_REF)).clamp(0.0, MASK_REF) }, "voxel {i}");
        }
        // Between centres, the factor's blend of the two.
        let lattice = Lattice::resampled([5, 4, 3], [11, 7, 5]);
        let mut out = vec![0.3f32; lattice.len()];
        s.apply(&lattice, &mut out);
        let [nx, ny, _] = lattice.dims;
        let mut blended = 0;
        for (i, v) in out.iter().enumerate() {
            let f = s.factor(lattice.point(i % nx, i / nx % ny, i / (nx * ny)));
            assert!((v - (f * 0.3 + (1.0 - f) * o.value(0.3))).abs() < 1e-7, "point {i}: {v} at factor {f}");
            blended += (f > 0.0 && f < 1.0) as usize;
        }
        assert!(blended > 0);
        assert!(support().with_outside(Outside { offset: f32::NAN, gain: 0.0 }).is_err());
    }

    #[test]
    fn placed_supports_average_their_outsides_over_their_empty_voxels() {
        let s = support(); // 52 empty voxels of 60
        let a = s.clone().with_outside(Outside { offset: 0.004, gain: 0.0 }).unwrap();
        let b = s.with_outside(Outside { offset: 0.001, gain: 1.0 }).unwrap();
        let boxes = [IndexBox { lo: [0; 3], hi: [5, 4, 3] }, IndexBox { lo: [5, 0, 0], hi: [10, 4, 3] }];
        let g = Support::place(&[(Some(&a), boxes[0]), (Some(&b), boxes[1])], [10, 4, 3]);
        assert!((g.outside().offset - 0.0025).abs() < 1e-9 && g.outside().gain == 0.5, "{:?}", g.outside());
        let g = Support::place(&[(Some(&a), boxes[0]), (None, boxes[1])], [10, 4, 3]);
        assert_eq!(g.outside(), a.outside(), "a piece without a support has no empty voxel");
    }

    #[test]
    fn placed_supports_cover_their_boxes() {
        let s = support();
        let b = IndexBox { lo: [3, 0, 1], hi: [8, 4, 4] };
        let whole = IndexBox { lo: [0, 0, 0], hi: [2, 2, 2] };
        let g = Support::place(&[(Some(&s), b), (None, whole)], [8, 4, 4]);
        assert_eq!(g.count(), 8 + 8);
        assert_eq!(g.bit(3 + 1, 1, 1), 1.0);
        assert_eq!(g.bit(3, 0, 1), 0.0);
        assert_eq!(g.bit(1, 1, 1), 1.0, "a piece without a support is all support");
        assert_eq!(g.bit(2, 2, 0), 0.0, "outside every piece");
    }
}
