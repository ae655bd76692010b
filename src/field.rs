//! Regular grids in the index frame, value normalisation, and the
//! world-to-index mapping of SPEC.md "Frames and units".

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
        if dims.iter().any(|&d| d == 0) {
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
        let i = idx % self.dims[0];
        let j = (idx / self.dims[0]) % self.dims[1];
        let k = idx / (self.dims[0] * self.dims[1]);
        [i, j, k]
    }

    /// Trilinear interpolation at an index-frame position, clamped to the domain.
    #[inline]
    pub fn trilinear(&self, u: [f32; 3]) -> f32 {
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
        if nd.iter().any(|&d| d == 0) {
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

/// Optional transform applied to raw values before normalisation.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Transform {
    Linear = 0,
    /// `log10(x)`, for fields spanning decades; requires positive values.
    Log10 = 1,
}

impl Transform {
    pub fn from_code(c: u32) -> Option<Transform> {
        match c {
            0 => Some(Transform::Linear),
            1 => Some(Transform::Log10),
            _ => None,
        }
    }
    pub fn name(self) -> &'static str {
        match self {
            Transform::Linear => "linear",
            Transform::Log10 => "log10",
        }
    }
    pub fn from_name(name: &str) -> Option<Transform> {
        [Transform::Linear, Transform::Log10].into_iter().find(|t| t.name() == name)
    }
}

/// The normalisation `v = (T(x) - vmin) / (vmax - vmin)` clamped to `[0, 1]`,
/// with `[vmin, vmax]` in transformed units. One per field and time series.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ValueRange {
    pub vmin: f64,
    pub vmax: f64,
    pub transform: Transform,
}

/// Normalised values and how many fell outside the range (and were clamped).
#[derive(Clone, Debug)]
pub struct Normalized {
    pub values: Vec<f32>,
    pub clamped: usize,
}

impl ValueRange {
    pub fn new(vmin: f64, vmax: f64, transform: Transform) -> Result<ValueRange> {
        if !(vmin.is_finite() && vmax.is_finite()) || vmax <= vmin {
            return Err(Error::arg(format!("value range [{vmin}, {vmax}] must be finite with max > min")));
        }
        Ok(ValueRange { vmin, vmax, transform })
    }

    fn apply(transform: Transform, x: f64) -> f64 {
        match transform {
            Transform::Linear => x,
            Transform::Log10 => x.log10(),
        }
    }

    /// The range of the (transformed) data itself. Fails on non-finite values,
    /// non-positive values under log10, empty or constant data.
    pub fn from_data(values: &[f32], transform: Transform) -> Result<ValueRange> {
        check_finite(values)?;
        if values.is_empty() {
            return Err(Error::data("no values"));
        }
        if transform == Transform::Log10 {
            if let Some(pos) = values.iter().position(|&v| v <= 0.0) {
                return Err(Error::data(format!(
                    "log10 transform needs positive values; value {} at index {pos}",
                    values[pos]
                )));
            }
        }
        let (lo, hi) = values
            .par_iter()
            .map(|&v| {
                let t = Self::apply(transform, v as f64);
                (t, t)
            })
            .reduce(|| (f64::INFINITY, f64::NEG_INFINITY), |a, b| (a.0.min(b.0), a.1.max(b.1)));
        if hi <= lo {
            return Err(Error::data(format!("field is constant ({lo}); give a value range explicitly")));
        }
        ValueRange::new(lo, hi, transform)
    }

    /// Normalises raw values, counting those clamped into `[0, 1]`.
    pub fn normalize(&self, values: &[f32]) -> Result<Normalized> {
        check_finite(values)?;
        let scale = 1.0 / (self.vmax - self.vmin);
        let (vmin, tr) = (self.vmin, self.transform);
        let out: Vec<(f32, bool)> = values
            .par_iter()
            .map(|&x| {
                let t = if tr == Transform::Log10 && x <= 0.0 { f64::NEG_INFINITY } else { Self::apply(tr, x as f64) };
                let v = (t - vmin) * scale;
                let c = v.clamp(0.0, 1.0);
                (c as f32, c != v)
            })
            .collect();
        let clamped = out.iter().filter(|x| x.1).count();
        Ok(Normalized { values: out.into_iter().map(|x| x.0).collect(), clamped })
    }

    /// Maps a normalised value back to data units.
    pub fn denormalize(&self, v: f32) -> f64 {
        let t = self.vmin + v as f64 * (self.vmax - self.vmin);
        match self.transform {
            Transform::Linear => t,
            Transform::Log10 => 10f64.powf(t),
        }
    }
}

/// Fails with the position of the first NaN or infinite value.
/// [`check_finite`] on the calling thread alone, for the caller's side of
/// the background queue: a push must not wake a rayon pool (the host's, or
/// the global one the encoder's threads compete with).
pub fn check_finite_serial(values: &[f32]) -> Result<()> {
    // Whole chunks first: `all` over a chunk vectorises; the position is
    // looked up only on failure.
    if values.chunks(4096).all(|c| c.iter().all(|v| v.is_finite())) {
        return Ok(());
    }
    let pos = values.iter().position(|v| !v.is_finite()).expect("a non-finite value was seen");
    Err(not_finite(values, pos))
}

pub fn check_finite(values: &[f32]) -> Result<()> {
    if let Some(pos) = values.par_iter().position_first(|v| !v.is_finite()) {
        return Err(not_finite(values, pos));
    }
    Ok(())
}

fn not_finite(values: &[f32], pos: usize) -> Error {
    Error::data(format!("value {} at index {pos} is not finite", values[pos]))
}

/// Where the index frame sits in the world: `u = (x - bmin) * gamma - 0.5`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IndexFrame {
    pub dims: [usize; 3],
    pub bmin: [f64; 3],
    pub gamma: f64,
}

impl IndexFrame {
    /// SPEC.md: `gamma = min_a D_a / (bmax_a - bmin_a)`, isotropic voxels.
    pub fn from_bounds(dims: [usize; 3], bmin: [f64; 3], bmax: [f64; 3]) -> Result<IndexFrame> {
        let mut gamma = f64::INFINITY;
        for a in 0..3 {
            let ext = bmax[a] - bmin[a];
            if !(ext.is_finite() && ext > 0.0) {
                return Err(Error::arg(format!("bounds on axis {a} are empty or not finite: [{}, {}]", bmin[a], bmax[a])));
            }
            gamma = gamma.min(dims[a] as f64 / ext);
        }
        Ok(IndexFrame { dims, bmin, gamma })
    }

    /// A grid whose voxel centres are `origin + i * spacing` (isotropic spacing).
    pub fn for_grid(dims: [usize; 3], origin: [f64; 3], spacing: f64) -> Result<IndexFrame> {
        if !(spacing.is_finite() && spacing > 0.0) {
            return Err(Error::arg(format!("grid spacing must be positive, got {spacing}")));
        }
        Ok(IndexFrame {
            dims,
            bmin: [origin[0] - 0.5 * spacing, origin[1] - 0.5 * spacing, origin[2] - 0.5 * spacing],
            gamma: 1.0 / spacing,
        })
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
}

#[cfg(test)]
mod tests {
    use super::*;

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
    fn downsample_is_block_mean() {
        let dims = [4, 4, 2];
        let vals: Vec<f32> = (0..32).map(|i| i as f32).collect();
        let g = Grid::new(dims, vals).unwrap();
        let d = g.downsample(2).unwrap();
        assert_eq!(d.dims, [2, 2, 1]);
        // Block (0,0,0) holds indices 0,1,4,5,16,17,20,21.
        assert_eq!(d.values[0], (0 + 1 + 4 + 5 + 16 + 17 + 20 + 21) as f32 / 8.0);
    }

    #[test]
    fn normalize_clamps_and_counts() {
        let r = ValueRange::new(0.0, 10.0, Transform::Linear).unwrap();
        let n = r.normalize(&[-1.0, 0.0, 5.0, 10.0, 12.0]).unwrap();
        assert_eq!(n.values, vec![0.0, 0.0, 0.5, 1.0, 1.0]);
        assert_eq!(n.clamped, 2);
        assert!(r.normalize(&[f32::NAN]).is_err());
        assert!(ValueRange::from_data(&[1.0, 1.0], Transform::Linear).is_err());
        assert!(ValueRange::from_data(&[1.0, 0.0], Transform::Log10).is_err());
        let l = ValueRange::from_data(&[1.0, 1000.0], Transform::Log10).unwrap();
        assert_eq!((l.vmin, l.vmax), (0.0, 3.0));
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
