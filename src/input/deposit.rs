//! Deposits: the reference grid that supervises particle and cell encodes
//! (METHOD.md "Reference grid").
//!
//! Every input item (a particle or a cell) is a *splat*: a box of voxels, and a
//! weight function over it. Each voxel gets `V = sum(w v) / sum(w)` over the
//! splats covering it, 0 where none does.
//!
//! Parallel and deterministic: the lattice is cut into slabs of z planes, each
//! slab lists the splats that reach it in input order, and each slab is filled
//! by one task with its own f64 accumulators. Every voxel therefore sums its
//! splats in input order whatever the number of threads or the slab thickness.

use crate::error::{Error, Result};
use crate::field::{Grid, IndexFrame};
use rayon::prelude::*;
use std::time::Instant;

/// How the splat spreads its weight over its voxel box.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum Shape {
    /// The M4 cubic spline of smoothing length `h` (index units), support `2h`,
    /// centred on `u`: weight `m W(|x - u|)`.
    Spline { u: [f64; 3], h: f64 },
    /// Constant weight `m` on every voxel of the box (a cell stamp, or a particle
    /// whose support covers no voxel centre, put into its nearest voxel).
    Box,
}

/// One input item ready to deposit: voxel box `lo..hi` (exclusive, clamped to
/// the lattice and non-empty), weight `m`, normalised value `v`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Splat {
    pub lo: [u32; 3],
    pub hi: [u32; 3],
    pub m: f64,
    pub v: f64,
    pub shape: Shape,
}

/// What a deposit cost and what it left out.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct DepositStats {
    /// Items (particles or cells) given.
    pub items: usize,
    /// Items whose centre lies outside the bounds. They are not samples (they
    /// seed nothing), but those whose support reaches the lattice are deposited,
    /// clipped to it: `outside - outside_dropped` of them.
    pub outside: usize,
    /// Items outside the bounds that reach no voxel, left out of the deposit.
    pub outside_dropped: usize,
    /// Items inside the bounds whose support covers no voxel centre; each is
    /// put into its nearest voxel with weight `m` (its whole kernel mass).
    pub nearest_voxel: usize,
    /// Voxels no item reached (value 0).
    pub empty_voxels: usize,
    /// Wall-clock seconds of the deposit (splat preparation included).
    pub seconds: f64,
    /// Peak heap bytes the deposit held at once: the output grid, the
    /// prepared splats, the slab lists and one slab of accumulators per thread.
    pub peak_bytes: usize,
}

/// The M4 cubic spline (Monaghan 1992) in 3D, normalised to integrate to 1:
/// `W(r, h) = 1/(pi h^3) f(r/h)`, `f(q) = 1 - 1.5q^2 + 0.75q^3` for `q < 1`,
/// `0.25(2 - q)^3` for `q < 2`, else 0.
#[inline]
pub fn m4_spline(r: f64, h: f64) -> f64 {
    let q = r / h;
    let f = if q < 1.0 {
        1.0 - 1.5 * q * q + 0.75 * q * q * q
    } else if q < 2.0 {
        let t = 2.0 - q;
        0.25 * t * t * t
    } else {
        0.0
    };
    f / (std::f64::consts::PI * h * h * h)
}

/// Checks the total voxel count before anything is allocated.
pub(crate) fn lattice_len(dims: [usize; 3]) -> Result<usize> {
    if dims.contains(&0) {
        return Err(Error::arg(format!("reference dims must be positive, got {dims:?}")));
    }
    dims.iter()
        .try_fold(1usize, |a, &d| a.checked_mul(d))
        .filter(|&n| n <= 1 << 34 && dims.iter().all(|&d| d <= u32::MAX as usize))
        .ok_or_else(|| Error::arg(format!("reference dims {dims:?} are too large")))
}

/// True when `u` lies inside the bounds the frame was built from, i.e. the
/// index box `[-0.5, D - 0.5]` on every axis.
pub(crate) fn inside_bounds(frame: &IndexFrame, u: [f64; 3]) -> bool {
    (0..3).all(|a| u[a] >= -0.5 && u[a] <= frame.dims[a] as f64 - 0.5)
}

/// The nearest voxel of `u`, clamped to the lattice, as a one-voxel box.
pub(crate) fn nearest_voxel_box(dims: [usize; 3], u: [f64; 3]) -> ([u32; 3], [u32; 3]) {
    let mut lo = [0u32; 3];
    let mut hi = [0u32; 3];
    for a in 0..3 {
        let i = u[a].round().clamp(0.0, (dims[a] - 1) as f64) as u32;
        lo[a] = i;
        hi[a] = i + 1;
    }
    (lo, hi)
}

/// Deposits `splats` (in input order) on a lattice of `dims`. `stats` arrives
/// with the item counts filled in; the voxel, time and memory figures are added.
pub(crate) fn deposit(dims: [usize; 3], splats: &[Splat], mut stats: DepositStats, started: Instant) -> Result<(Grid, DepositStats)> {
    let n = lattice_len(dims)?;
    if splats.len() > u32::MAX as usize {
        return Err(Error::arg("more than 2^32 items in one deposit; split the input"));
    }
    let plane = dims[0] * dims[1];
    // Slab thickness only trades scheduling against overlap work; it does not
    // change the result (see the module comment).
    let slabs_wanted = (8 * rayon::current_num_threads()).max(1);
    let thickness = dims[2].div_ceil(slabs_wanted).max(1);
    let n_slabs = dims[2].div_ceil(thickness);
    // The grid, and two f64 accumulators of a slab on each thread at once.
    // Refused before any of it is allocated when the process cannot take
    // it: an allocation that fails aborts the process, a simulation that
    // links gsenc included (a lattice of [1, 2^32 - 1, 1] is one slab of 34
    // GB a thread).
    let scratch = 2 * 8 * (thickness * plane) as u64 * rayon::current_num_threads().min(n_slabs) as u64;
    crate::memory::check_large(&format!("depositing on a lattice of {dims:?} voxels"), 4 * n as u64 + scratch)?;

    // Counting sort of splat indices into the slabs they reach, input order kept.
    let slab_range = |s: &Splat| (s.lo[2] as usize / thickness, (s.hi[2] as usize - 1) / thickness);
    let mut offsets = vec![0usize; n_slabs + 1];
    for s in splats {
        let (a, b) = slab_range(s);
        for slab in a..=b {
            offsets[slab + 1] += 1;
        }
    }
    for i in 0..n_slabs {
        offsets[i + 1] += offsets[i];
    }
    let mut fill = offsets.clone();
    let mut lists = vec![0u32; offsets[n_slabs]];
    for (j, s) in splats.iter().enumerate() {
        let (a, b) = slab_range(s);
        for slab in a..=b {
            lists[fill[slab]] = j as u32;
            fill[slab] += 1;
        }
    }
    drop(fill);

    let mut out = Vec::new();
    out.try_reserve_exact(n).map_err(|_| Error::arg(format!("cannot allocate a reference grid of {n} voxels")))?;
    out.resize(n, 0f32);
    let empty: usize = out
        .par_chunks_mut(thickness * plane)
        .enumerate()
        .map(|(slab, values)| {
            let z0 = slab * thickness;
            let z1 = z0 + values.len() / plane;
            let mut num = vec![0f64; values.len()];
            let mut den = vec![0f64; values.len()];
            for &j in &lists[offsets[slab]..offsets[slab + 1]] {
                splat_into(&splats[j as usize], dims, z0, z1, &mut num, &mut den);
            }
            let mut empty = 0;
            for ((v, &a), &b) in values.iter_mut().zip(&num).zip(&den) {
                if b > 0.0 {
                    *v = (a / b) as f32;
                } else {
                    empty += 1;
                }
            }
            empty
        })
        .sum();

    stats.empty_voxels = empty;
    stats.peak_bytes = 4 * n
        + std::mem::size_of_val(splats)
        + 4 * lists.len()
        + std::mem::size_of_val(offsets.as_slice())
        + scratch as usize;
    stats.seconds = started.elapsed().as_secs_f64();
    Ok((Grid::new(dims, out)?, stats))
}

/// Adds one splat's share of planes `z0..z1` to a slab's accumulators.
fn splat_into(s: &Splat, dims: [usize; 3], z0: usize, z1: usize, num: &mut [f64], den: &mut [f64]) {
    let zs = (s.lo[2] as usize).max(z0);
    let ze = (s.hi[2] as usize).min(z1);
    let (nx, ny) = (dims[0], dims[1]);
    match s.shape {
        Shape::Box => {
            let (wv, w) = (s.m * s.v, s.m);
            for z in zs..ze {
                for y in s.lo[1] as usize..s.hi[1] as usize {
                    let row = (z - z0) * nx * ny + y * nx;
                    for x in s.lo[0] as usize..s.hi[0] as usize {
                        num[row + x] += wv;
                        den[row + x] += w;
                    }
                }
            }
        }
        Shape::Spline { u, h } => {
            let r2max = 4.0 * h * h;
            for z in zs..ze {
                let dz = z as f64 - u[2];
                for y in s.lo[1] as usize..s.hi[1] as usize {
                    let dy = y as f64 - u[1];
                    let dyz = dy * dy + dz * dz;
                    if dyz >= r2max {
                        continue;
                    }
                    let row = (z - z0) * nx * ny + y * nx;
                    for x in s.lo[0] as usize..s.hi[0] as usize {
                        let dx = x as f64 - u[0];
                        let r2 = dx * dx + dyz;
                        if r2 < r2max {
                            let w = s.m * m4_spline(r2.sqrt(), h);
                            num[row + x] += w * s.v;
                            den[row + x] += w;
                        }
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The spline integrates to 1 over space (midpoint rule on a fine lattice).
    #[test]
    fn m4_spline_is_normalised() {
        let h: f64 = 1.3;
        let step = 0.05;
        let n = (2.0 * h / step).ceil() as i64 + 1;
        let mut sum = 0.0;
        for i in -n..=n {
            for j in -n..=n {
                for k in -n..=n {
                    let r = ((i * i + j * j + k * k) as f64).sqrt() * step;
                    sum += m4_spline(r, h);
                }
            }
        }
        sum *= step * step * step;
        assert!((sum - 1.0).abs() < 1e-3, "{sum}");
        assert_eq!(m4_spline(2.0 * h, h), 0.0);
        // Continuous at q = 1.
        assert!((m4_spline(h * (1.0 - 1e-9), h) - m4_spline(h * (1.0 + 1e-9), h)).abs() < 1e-9);
    }

    /// A lattice within the dims' bounds whose deposit cannot fit (2^34
    /// voxels in one plane: 64 GiB of grid and 256 GiB of one slab's
    /// accumulators) is refused as such, before anything is allocated; it
    /// aborted the process (a failed allocation) when the C API's random
    /// walks first met it, on a lattice of [1, 2^32 - 1, 1].
    #[test]
    fn a_deposit_beyond_memory_is_refused_before_it_allocates() {
        let dims = [1 << 17, 1 << 17, 1];
        assert_eq!(lattice_len(dims).unwrap(), 1 << 34, "the lattice itself is allowed");
        let e = deposit(dims, &[], DepositStats::default(), Instant::now()).unwrap_err();
        assert!(matches!(&e, Error::InvalidArgument(m) if m.contains("depositing on a lattice of [131072, 131072, 1] voxels") && m.contains("more than")), "{e}");
    }
}
