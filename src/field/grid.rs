//! A scalar field on a regular lattice, x fastest.

use crate::error::{Error, Result};
use rayon::prelude::*;

/// A scalar field on a regular lattice, x fastest (C order `[z][y][x]`).
/// Voxel `(i, j, k)` has its centre at index-frame position `(i, j, k)`.
#[derive(Clone, Debug, PartialEq)]
pub struct Grid {
    pub dims: [usize; 3],
    pub values: Vec<f32>,
}

impl Grid {
    pub fn new(dims: [usize; 3], values: Vec<f32>) -> Result<Grid> {
        if dims.contains(&0) {
            return Err(Error::arg(format!("grid dims must be positive, got {dims:?}")));
        }
        let n = dims[0]
            .checked_mul(dims[1])
            .and_then(|v| v.checked_mul(dims[2]))
            .ok_or_else(|| Error::arg(format!("grid dims {dims:?} overflow")))?;
        if values.len() != n {
            return Err(Error::data(format!(
                "grid of dims {}x{}x{} needs {} values, got {}",
                dims[0], dims[1], dims[2], n, values.len()
            )));
        }
        Ok(Grid { dims, values })
    }

    pub fn len(&self) -> usize {
        self.values.len()
    }

    pub fn is_empty(&self) -> bool {
        self.values.is_empty()
    }

    #[inline]
    pub fn index(&self, i: usize, j: usize, k: usize) -> usize {
        i + self.dims[0] * (j + self.dims[1] * k)
    }

    /// Voxel coordinates of a linear index.
    #[inline]
    pub fn coords(&self, idx: usize) -> [usize; 3] {
        let plane = self.dims[0] * self.dims[1];
        // In 32 bits where everything fits (a grid of fewer than 2^32
        // voxels): x86 CPUs take several times as long for a 64-bit
        // division, and training draws divide at every point.
        if let (Ok(x), Ok(d0), Ok(d1), Ok(pl)) = (u32::try_from(idx), u32::try_from(self.dims[0]), u32::try_from(self.dims[1]), u32::try_from(plane)) {
            if d0 > 0 && d1 > 0 {
                return [(x % d0) as usize, ((x / d0) % d1) as usize, (x / pl) as usize];
            }
        }
        let i = idx % self.dims[0];
        let j = (idx / self.dims[0]) % self.dims[1];
        let k = idx / plane;
        [i, j, k]
    }

    /// The centre of voxel `idx` in the index frame: its coordinates.
    #[inline]
    pub fn centre(&self, idx: usize) -> [f32; 3] {
        self.coords(idx).map(|c| c as f32)
    }

    /// The voxel below `u` (clamped to the domain) and `u`'s fractions
    /// past it, as [`Grid::trilinear`] weighs its corners.
    #[inline]
    pub fn corner(&self, u: [f32; 3]) -> ([usize; 3], [f32; 3]) {
        let mut i0 = [0usize; 3];
        let mut t = [0f32; 3];
        for a in 0..3 {
            let hi = (self.dims[a] - 1) as f32;
            let x = u[a].clamp(0.0, hi);
            let f = x.floor();
            let mut i = f as usize;
            let mut frac = x - f;
            if i + 1 >= self.dims[a] {
                // On the last plane (or a one-voxel axis): no neighbour above.
                i = self.dims[a] - 1;
                frac = 0.0;
            }
            i0[a] = i;
            t[a] = frac;
        }
        (i0, t)
    }

    /// Asks the cache for the values [`Grid::interpolate`] reads at the
    /// corner voxel `i0`: the lines of its row and of the rows above it in
    /// y and z (a row's neighbour in x is on the same line but at a line's
    /// end).
    #[inline]
    pub fn prefetch_corner(&self, i0: [usize; 3]) {
        let at = self.index(i0[0], i0[1], i0[2]);
        let (row, plane) = (self.dims[0], self.dims[0] * self.dims[1]);
        for off in [0, row, plane, row + plane] {
            super::prefetch(&self.values, at + off);
        }
    }

    /// Trilinear interpolation at an index-frame position, clamped to the domain.
    #[inline]
    pub fn trilinear(&self, u: [f32; 3]) -> f32 {
        let (i0, t) = self.corner(u);
        self.interpolate(i0, t)
    }

    /// [`Grid::trilinear`] at the corner voxel and fractions that
    /// [`Grid::corner`] found.
    #[inline]
    pub fn interpolate(&self, i0: [usize; 3], t: [f32; 3]) -> f32 {
        let step = |a: usize| if i0[a] + 1 < self.dims[a] { 1 } else { 0 };
        let (sx, sy, sz) = (step(0), step(1), step(2));
        let v = |di: usize, dj: usize, dk: usize| self.values[self.index(i0[0] + di, i0[1] + dj, i0[2] + dk)];
        let c00 = v(0, 0, 0) * (1.0 - t[0]) + v(sx, 0, 0) * t[0];
        let c10 = v(0, sy, 0) * (1.0 - t[0]) + v(sx, sy, 0) * t[0];
        let c01 = v(0, 0, sz) * (1.0 - t[0]) + v(sx, 0, sz) * t[0];
        let c11 = v(0, sy, sz) * (1.0 - t[0]) + v(sx, sy, sz) * t[0];
        let c0 = c00 * (1.0 - t[1]) + c10 * t[1];
        let c1 = c01 * (1.0 - t[1]) + c11 * t[1];
        c0 * (1.0 - t[2]) + c1 * t[2]
    }

    /// Mean over `k x k x k` blocks. Voxels beyond the last whole block on an
    /// axis (when `k` does not divide the dims) are dropped.
    pub fn downsample(&self, k: usize) -> Result<Grid> {
        if k == 0 {
            return Err(Error::arg("downsample factor must be at least 1"));
        }
        if k == 1 {
            return Ok(self.clone());
        }
        let nd = [self.dims[0] / k, self.dims[1] / k, self.dims[2] / k];
        if nd.contains(&0) {
            return Err(Error::arg(format!("downsample factor {k} is larger than the grid {:?}", self.dims)));
        }
        let inv = 1.0 / (k * k * k) as f64;
        let mut out = vec![0f32; nd[0] * nd[1] * nd[2]];
        out.par_chunks_mut(nd[0] * nd[1]).enumerate().for_each(|(z, slab)| {
            for y in 0..nd[1] {
                for x in 0..nd[0] {
                    let mut s = 0f64;
                    for dz in 0..k {
                        for dy in 0..k {
                            let row = self.index(x * k, y * k + dy, z * k + dz);
                            s += self.values[row..row + k].iter().map(|&v| v as f64).sum::<f64>();
                        }
                    }
                    slab[x + nd[0] * y] = (s * inv) as f32;
                }
            }
        });
        Grid::new(nd, out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Coordinates by 32-bit division are those by 64-bit division, also
    /// for indices and planes past 2^32 (which take the 64-bit path).
    #[test]
    fn coords_are_those_of_64_bit_division() {
        for dims in [[7usize, 5, 3], [1, 1, 1], [65_536, 65_536, 4], [100_000, 50_000, 3], [3, 1 << 31, 5]] {
            let g = Grid { dims, values: vec![] };
            let plane = dims[0] * dims[1];
            let n = plane * dims[2];
            for idx in [0, 1, dims[0] - 1, dims[0], plane - 1, plane, n / 2, n - 1, (1 << 32) - 1, 1 << 32].into_iter().filter(|&i| i < n) {
                let want = [idx % dims[0], (idx / dims[0]) % dims[1], idx / plane];
                assert_eq!(g.coords(idx), want, "{idx} in {dims:?}");
            }
        }
    }

    #[test]
    fn trilinear_reproduces_linear_fields() {
        let dims = [5, 4, 3];
        let f = |x: f32, y: f32, z: f32| 0.3 * x - 0.2 * y + 0.7 * z + 1.0;
        let mut vals = vec![];
        for k in 0..3 {
            for j in 0..4 {
                for i in 0..5 {
                    vals.push(f(i as f32, j as f32, k as f32));
                }
            }
        }
        let g = Grid::new(dims, vals).unwrap();
        for u in [[0.5, 1.25, 0.75], [3.9, 2.99, 1.999], [4.0, 3.0, 2.0], [0.0, 0.0, 0.0]] {
            assert!((g.trilinear(u) - f(u[0], u[1], u[2])).abs() < 1e-5, "{u:?}");
        }
        // Clamped outside the domain.
        assert!((g.trilinear([-3.0, 0.0, 0.0]) - f(0.0, 0.0, 0.0)).abs() < 1e-6);
    }

    #[test]
    #[allow(clippy::identity_op)] // indices written out, 0 among them
    fn downsample_is_block_mean() {
        let dims = [4, 4, 2];
        let vals: Vec<f32> = (0..32).map(|i| i as f32).collect();
        let g = Grid::new(dims, vals).unwrap();
        let d = g.downsample(2).unwrap();
        assert_eq!(d.dims, [2, 2, 1]);
        // Block (0,0,0) holds indices 0,1,4,5,16,17,20,21.
        assert_eq!(d.values[0], (0 + 1 + 4 + 5 + 16 + 17 + 20 + 21) as f32 / 8.0);
    }
}
