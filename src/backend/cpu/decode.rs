//! The decode (`Backend::decode_lattice`): primitives splatted brick by
//! brick of the lattice; each z-slab of bricks is one parallel task that
//! writes its own slice of the output, so no sum depends on the thread
//! count.

use super::CpuBackend;
use crate::backend::csr::{csr, Keyed};
use crate::backend::{check_len, Lattice};
use crate::error::Result;
use crate::math::kernel::{exp_neg_half, Frame, Primitive, CUTOFF_D2};
use crate::math::loss::v_eval;
use crate::math::simd::simd_dispatch;
use rayon::prelude::*;

/// Edge of a decode brick in lattice voxels.
const DECODE_BRICK: usize = 8;

impl CpuBackend {
    /// [`crate::backend::Backend::decode_lattice`].
    pub(super) fn splat_lattice(&mut self, params: &[Primitive], lattice: &Lattice, out: &mut [f32]) -> Result<()> {
        check_len("out", out.len(), lattice.len())?;
        self.prep.update(params);
        let frames = &self.prep.frames;
        let dims = lattice.dims;
        // Each primitive's box in lattice indices (inclusive), or None when outside.
        let boxes: Vec<Option<[u32; 6]>> = frames
            .par_iter()
            .map(|f| {
                let mut r = [0u32; 6];
                for a in 0..3 {
                    let l = ((f.mu[a] - f.ext[a] - lattice.origin[a]) / lattice.step[a]).ceil();
                    let h = ((f.mu[a] + f.ext[a] - lattice.origin[a]) / lattice.step[a]).floor();
                    if !(h >= 0.0 && l <= (dims[a] - 1) as f32) || h < l {
                        return None;
                    }
                    r[a] = l.max(0.0) as u32;
                    r[a + 3] = h.min((dims[a] - 1) as f32) as u32;
                }
                Some(r)
            })
            .collect();
        let bs = DECODE_BRICK;
        let nlayers = dims[2].div_ceil(bs);
        let mut layer_pairs = vec![];
        for (g, b) in boxes.iter().enumerate() {
            if let Some(b) = b {
                for layer in b[2] as usize / bs..=b[5] as usize / bs {
                    layer_pairs.push((layer as u32, g as u32));
                }
            }
        }
        let (lstart, lcand) = csr(nlayers, vec![Keyed::from_pairs(nlayers, layer_pairs)]);
        let slab_len = dims[0] * dims[1] * bs;
        out.par_chunks_mut(slab_len).enumerate().for_each(|(layer, slab)| {
            let cands = &lcand[lstart[layer] as usize..lstart[layer + 1] as usize];
            splat_slab_dispatch(Slab { frames, boxes: &boxes, lattice, cands, z0: layer * bs }, slab);
        });
        Ok(())
    }
}

/// What one z-slab of bricks splats: the primitives whose boxes reach it.
struct Slab<'a> {
    frames: &'a [Frame],
    /// Each primitive's box in lattice indices (inclusive), or None.
    boxes: &'a [Option<[u32; 6]>],
    lattice: &'a Lattice,
    cands: &'a [u32],
    /// The slab's first lattice plane.
    z0: usize,
}

simd_dispatch!(fn splat_slab_dispatch(job: Slab, slab: &mut [f32]) -> () => splat_slab);

/// The slab's bricks one after another: each candidate primitive adds its
/// terms to the brick's sums in candidate order, then each voxel's value is
/// `V_eval` of its sums.
#[inline(always)]
fn splat_slab(job: Slab, slab: &mut [f32]) {
    let bs = DECODE_BRICK;
    let Slab { frames, boxes, lattice, cands, z0 } = job;
    let dims = lattice.dims;
    let (nbx, nby) = (dims[0].div_ceil(bs), dims[1].div_ceil(bs));
    let nz = slab.len() / (dims[0] * dims[1]);
    let mut pairs = vec![];
    // Per candidate, the rows of each of the slab's planes its ellipsoid
    // reaches (`reached_rows`), found once for all the bricks of the slab.
    let mut reach = Vec::with_capacity(cands.len());
    for (i, &g) in cands.iter().enumerate() {
        let b = boxes[g as usize].unwrap();
        reach.push(reached_rows(&frames[g as usize], &b, lattice, z0, nz));
        for by in b[1] as usize / bs..=b[4] as usize / bs {
            for bx in b[0] as usize / bs..=b[3] as usize / bs {
                pairs.push(((bx + nbx * by) as u32, i as u32));
            }
        }
    }
    let (bstart, bcand) = csr(nbx * nby, vec![Keyed::from_pairs(nbx * nby, pairs)]);
    let mut rho = [0f32; DECODE_BRICK * DECODE_BRICK * DECODE_BRICK];
    let mut num = [0f32; DECODE_BRICK * DECODE_BRICK * DECODE_BRICK];
    for by in 0..nby {
        for bx in 0..nbx {
            let (x0, y0) = (bx * bs, by * bs);
            let (nx, ny) = (bs.min(dims[0] - x0), bs.min(dims[1] - y0));
            rho.fill(0.0);
            num.fill(0.0);
            let id = bx + nbx * by;
            for &i in &bcand[bstart[id] as usize..bstart[id + 1] as usize] {
                let g = cands[i as usize] as usize;
                let b = boxes[g].unwrap();
                let zr = (b[2] as usize).max(z0)..=(b[5] as usize).min(z0 + nz - 1);
                let yr = (b[1] as usize).max(y0)..=(b[4] as usize).min(y0 + ny - 1);
                let xr = (b[0] as usize).max(x0)..=(b[3] as usize).min(x0 + nx - 1);
                splat_box(&frames[g], lattice, [x0, y0, z0], [xr, yr, zr], &reach[i as usize], &mut rho, &mut num);
            }
            for k in 0..nz {
                for j in 0..ny {
                    let row = x0 + dims[0] * (y0 + j + dims[1] * k);
                    for i in 0..nx {
                        let l = i + j * bs + k * bs * bs;
                        slab[row + i] = v_eval(rho[l], num[l]);
                    }
                }
            }
        }
    }
}

/// One primitive's terms on the voxels `xr x yr x zr` of the brick whose
/// first voxel is `origin`. A row is computed across the brick's full
/// width of `DECODE_BRICK` lanes, two rows to a vector of 16 where the box
/// has them (the row loop it replaced ran over `xr` alone, a few lanes with
/// a scalar tail: about 3.5x the CPU time, docs/BENCHMARKS.md "The decode's rows
/// as vectors"). A lane outside `xr` adds +0, which changes neither sum
/// (both start at +0 and only grow, as `w` and `s` are sigmoids); outside
/// the 5-sigma box `d2` exceeds the cut-off anyway, and the mask keeps the
/// voxels that rounding puts on the wrong side of the box's edge as the row
/// loop had them. A lane's `dx` is that loop's: from the first voxel of
/// `xr`, plus its offset from it times the step. So each voxel gets the
/// same bits as before.
#[inline(always)]
fn splat_box(f: &Frame, lattice: &Lattice, origin: [usize; 3], [xr, yr, zr]: [std::ops::RangeInclusive<usize>; 3], reach: &Rows, rho: &mut [f32], num: &mut [f32]) {
    const W: usize = DECODE_BRICK;
    let a = f.scaled_axes();
    let (i0, i1) = (*xr.start(), *xr.end());
    let dx0 = lattice.point(i0, 0, 0)[0] - f.mu[0];
    // Two rows' lanes: the second row's repeat the first's.
    let mut t = [0f32; 2 * W];
    let mut limit = [0f32; 2 * W];
    for q in 0..2 * W {
        let x = origin[0] + q % W;
        t[q] = (q % W) as f32 - (i0 - origin[0]) as f32;
        // d2 >= 0, so a lane outside the box never passes `d2 < -1`.
        limit[q] = if (i0..=i1).contains(&x) { CUTOFF_D2 } else { -1.0 };
    }
    let lanes = Lanes { a, w: f.w, s: f.s, dx0, step: lattice.step[0] };
    // `c[r]` of row j: the part of `u_r` that does not change along it.
    // Plain loops here and below, not `array::map`: that is a call to
    // `core`'s code unless LLVM inlines it, and in a build where it did not,
    // the call in this loop made the whole decode 2.3 times slower
    // (docs/BENCHMARKS.md "A decode written behind").
    let row_c = |j: usize, dz: f32| {
        let dy = lattice.point(0, j, 0)[1] - f.mu[1];
        let mut c = [0f32; 3];
        for r in 0..3 {
            c[r] = a[r][1] * dy + a[r][2] * dz;
        }
        c
    };
    for k in zr {
        let dz = lattice.point(0, 0, k)[2] - f.mu[2];
        let at = |j: usize| (j - origin[1]) * W + (k - origin[2]) * W * W;
        let [lo, hi] = reach[k - origin[2]];
        let mut rows = (*yr.start()).max(lo as usize)..=(*yr.end()).min(hi as usize);
        while let Some(j) = rows.next() {
            let cj = row_c(j, dz);
            match rows.next() {
                Some(j2) => {
                    let cj2 = row_c(j2, dz);
                    let mut c = [[0f32; 2 * W]; 3];
                    for r in 0..3 {
                        c[r][..W].fill(cj[r]);
                        c[r][W..].fill(cj2[r]);
                    }
                    let base = at(j);
                    lanes.add::<{ 2 * W }>(&c, &t, &limit, (&mut rho[base..base + 2 * W]).try_into().unwrap(), (&mut num[base..base + 2 * W]).try_into().unwrap());
                }
                None => {
                    let c = [[cj[0]; W], [cj[1]; W], [cj[2]; W]];
                    let base = at(j);
                    let (t, limit) = (t[..W].try_into().unwrap(), limit[..W].try_into().unwrap());
                    lanes.add::<W>(&c, t, limit, (&mut rho[base..base + W]).try_into().unwrap(), (&mut num[base..base + W]).try_into().unwrap());
                }
            }
        }
    }
}

/// Per plane of a slab, the first and last row a primitive's ellipsoid
/// reaches (first > last: none).
type Rows = [[u32; 2]; DECODE_BRICK];

/// The rows of each plane `z0..z0 + nz` of a primitive's box (`b`) that
/// may reach its cut-off ellipsoid. At every lane of a row whose line along
/// x misses it, `d2` exceeds the cut-off, so the row adds +0 to `rho` (and
/// +0 or -0 to `num`), which changes no sum: it is skipped with the same
/// bits. Such rows are at least a fifth of the box's (the corners of its y-z
/// face), more for a tilted or flat primitive.
///
/// Along a row, `u = a0 dx + c` with `c = a1 dy + a2 dz`, and the least
/// `d2` over the line is `|P c|^2`, P the projection across `a0`: a
/// quadratic in `dy` for each plane, solved in f64. The bound allows for
/// the rounding of a lane's f32 `d2` (a few ulp of the squared size of its
/// terms; 1e-5 of it, and 1 % of the cut-off), and a row more each side.
fn reached_rows(f: &Frame, b: &[u32; 6], lattice: &Lattice, z0: usize, nz: usize) -> Rows {
    let a = f.scaled_axes();
    let mut col = [[0f64; 3]; 3];
    for r in 0..3 {
        for c in 0..3 {
            col[c][r] = a[r][c] as f64;
        }
    }
    let dot = |x: &[f64; 3], y: &[f64; 3]| x[0] * y[0] + x[1] * y[1] + x[2] * y[2];
    let a0a0 = dot(&col[0], &col[0]);
    let across = |v: &[f64; 3]| {
        let k = if a0a0 > 0.0 { dot(v, &col[0]) / a0a0 } else { 0.0 };
        [v[0] - k * col[0][0], v[1] - k * col[0][1], v[2] - k * col[0][2]]
    };
    let (p1, p2) = (across(&col[1]), across(&col[2]));
    let (alpha, beta, gamma) = (dot(&p1, &p1), dot(&p1, &p2), dot(&p2, &p2));
    // The largest |d| of the box's points (a step beyond) on each axis.
    let mut far = [0f64; 3];
    for ax in 0..3 {
        let (step, origin, mu) = (lattice.step[ax] as f64, lattice.origin[ax] as f64, f.mu[ax] as f64);
        let d = |i: u32| (origin + i as f64 * step - mu).abs() + step.abs();
        far[ax] = d(b[ax]).max(d(b[ax + 3]));
    }
    let mut size = 0f64;
    for r in 0..3 {
        size += (col[0][r].abs() * far[0] + col[1][r].abs() * far[1] + col[2][r].abs() * far[2]).powi(2);
    }
    let bound = CUTOFF_D2 as f64 * 1.01 + 1e-5 * size;
    let (ystep, yorigin, ymu) = (lattice.step[1] as f64, lattice.origin[1] as f64, f.mu[1] as f64);
    let row_of = |dy: f64| (dy + ymu - yorigin) / ystep;
    let mut out = [[1, 0]; DECODE_BRICK];
    for (k, o) in out.iter_mut().enumerate().take(nz) {
        let dz = (lattice.point(0, 0, z0 + k)[2] - f.mu[2]) as f64;
        // least(dy) = alpha dy^2 + 2 beta dz dy + gamma dz^2 <= bound
        let c = gamma * dz * dz - bound;
        let (lo, hi) = if alpha > 0.0 {
            let disc = (beta * dz).powi(2) - alpha * c;
            if disc < 0.0 {
                continue;
            }
            let r = disc.sqrt();
            ((-beta * dz - r) / alpha, (-beta * dz + r) / alpha)
        } else if c <= 0.0 {
            (f64::NEG_INFINITY, f64::INFINITY)
        } else {
            continue;
        };
        let (ra, rb) = (row_of(lo), row_of(hi));
        let (jlo, jhi) = (ra.min(rb).floor() - 1.0, ra.max(rb).ceil() + 1.0);
        let (first, last) = (jlo.max(b[1] as f64), jhi.min(b[4] as f64));
        if first <= last {
            *o = [first as u32, last as u32];
        }
    }
    out
}

/// What every lane of a primitive's rows shares.
struct Lanes {
    a: [[f32; 3]; 3],
    w: f32,
    s: f32,
    dx0: f32,
    step: f32,
}

impl Lanes {
    /// `L` lanes of consecutive rows: lane q at `dx0 + t[q] * step` along
    /// x, `c[r][q]` its row's share of `u_r`.
    #[inline(always)]
    fn add<const L: usize>(&self, c: &[[f32; L]; 3], t: &[f32; L], limit: &[f32; L], rho: &mut [f32; L], num: &mut [f32; L]) {
        let a = &self.a;
        for q in 0..L {
            let dx = self.dx0 + t[q] * self.step;
            let u0 = a[0][0] * dx + c[0][q];
            let u1 = a[1][0] * dx + c[1][q];
            let u2 = a[2][0] * dx + c[2][q];
            let d2 = u0 * u0 + u1 * u1 + u2 * u2;
            let e = exp_neg_half(d2);
            let wk = self.w * if d2 < limit[q] { e } else { 0.0 };
            rho[q] += wk;
            num[q] += wk * self.s;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::rng::Rng;

    /// The decode voxel by voxel, as the splat computed it before its rows
    /// became vectors: every primitive in index order whose box holds the
    /// voxel, `dx` from the first voxel of the box's row in the voxel's
    /// brick.
    fn voxel_by_voxel(params: &[Primitive], lattice: &Lattice) -> Vec<f32> {
        let dims = lattice.dims;
        let mut out = vec![0f32; lattice.len()];
        let frames: Vec<Frame> = params.iter().map(Frame::new).collect();
        for k in 0..dims[2] {
            for j in 0..dims[1] {
                for i in 0..dims[0] {
                    let (mut rho, mut num) = (0f32, 0f32);
                    for f in &frames {
                        let lo = [0, 1, 2].map(|a| ((f.mu[a] - f.ext[a] - lattice.origin[a]) / lattice.step[a]).ceil());
                        let hi = [0, 1, 2].map(|a| ((f.mu[a] + f.ext[a] - lattice.origin[a]) / lattice.step[a]).floor());
                        let inside = |a: usize, v: usize| lo[a] <= v as f32 && v as f32 <= hi[a];
                        if !(inside(0, i) && inside(1, j) && inside(2, k)) {
                            continue;
                        }
                        let i0 = (lo[0].max(0.0) as usize).max(i / DECODE_BRICK * DECODE_BRICK);
                        let a = f.scaled_axes();
                        let p = lattice.point(i0, j, k);
                        let (dy, dz) = (p[1] - f.mu[1], p[2] - f.mu[2]);
                        let c = [0, 1, 2].map(|r| a[r][1] * dy + a[r][2] * dz);
                        let dx = (p[0] - f.mu[0]) + (i - i0) as f32 * lattice.step[0];
                        let u = [0, 1, 2].map(|r| a[r][0] * dx + c[r]);
                        let d2 = u[0] * u[0] + u[1] * u[1] + u[2] * u[2];
                        let wk = f.w * if d2 < CUTOFF_D2 { exp_neg_half(d2) } else { 0.0 };
                        rho += wk;
                        num += wk * f.s;
                    }
                    out[i + dims[0] * (j + dims[1] * k)] = v_eval(rho, num);
                }
            }
        }
        out
    }

    /// Brick rows computed as vectors of two rows, lanes outside a box
    /// adding +0, give each voxel the bits of the plain loop: on lattices
    /// whose sides are no multiple of the brick, with steps that differ per
    /// axis, over a sub-box and beyond the primitives, where boxes start and
    /// end at every offset in a brick and hold odd and even numbers of rows.
    #[test]
    fn the_vectorised_splat_gives_each_voxel_the_plain_loops_bits() {
        let mut rng = Rng::new(21);
        let params = crate::backend::cpu::tests::random_prims(&mut rng, 150);
        let lattices = [
            Lattice::reference([6, 6, 6]),
            Lattice { dims: [21, 13, 10], origin: [-0.3, 0.1, 0.25], step: [0.31, 0.45, 0.6] },
            Lattice { dims: [9, 17, 8], origin: [1.5, 2.0, 0.5], step: [0.23, 0.17, 0.35] },
            Lattice { dims: [12, 5, 11], origin: [-2.0, -1.0, -3.0], step: [1.1, 2.3, 1.0] },
        ];
        for lattice in &lattices {
            let mut got = vec![f32::NAN; lattice.len()];
            CpuBackend::new().splat_lattice(&params, lattice, &mut got).unwrap();
            let want = voxel_by_voxel(&params, lattice);
            assert!(want.iter().any(|&v| v > 0.0), "{lattice:?}: nothing decoded");
            let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert!(bits(&got) == bits(&want), "{lattice:?}: {} voxels differ", got.iter().zip(&want).filter(|(a, b)| a.to_bits() != b.to_bits()).count());
        }
    }
}
