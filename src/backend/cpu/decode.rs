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
    // Per candidate and column of bricks its box overlaps, the rows of each
    // of the slab's planes its ellipsoid reaches within the column
    // (`reached_rows`, `Reach::rows_within`), found once for all the
    // bricks of the column; a brick none of whose rows it reaches does not
    // list it.
    let mut columns: Vec<Rows> = Vec::with_capacity(cands.len());
    let mut first_column = Vec::with_capacity(cands.len());
    for (i, &g) in cands.iter().enumerate() {
        let b = boxes[g as usize].unwrap();
        let reach = reached_rows(&frames[g as usize], &b, lattice, z0, nz);
        first_column.push(columns.len() as u32);
        for bx in b[0] as usize / bs..=b[3] as usize / bs {
            let xr = ((b[0] as usize).max(bx * bs), (b[3] as usize).min(bx * bs + bs - 1));
            let rows = reach.rows_within(lattice, &frames[g as usize].mu, &b, xr);
            columns.push(rows);
            if rows.iter().all(|&[first, last]| first > last) {
                continue;
            }
            for by in b[1] as usize / bs..=b[4] as usize / bs {
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
                let rows = &columns[first_column[i as usize] as usize + bx - b[0] as usize / bs];
                splat_box(&frames[g], lattice, [x0, y0, z0], [xr, yr, zr], rows, &mut rho, &mut num);
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
/// same bits as before. Of each plane's rows, only those `reached` lists
/// (`Reach::rows_within`) are computed.
#[inline(always)]
fn splat_box(f: &Frame, lattice: &Lattice, origin: [usize; 3], [xr, yr, zr]: [std::ops::RangeInclusive<usize>; 3], reached: &Rows, rho: &mut [f32], num: &mut [f32]) {
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
        let [lo, hi] = reached[k - origin[2]];
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

/// A primitive's reach in the planes of a slab (`reached_rows`): the rows
/// of each plane that its cut-off ellipsoid reaches, and where along x
/// each row's line meets it, so that each brick takes only the rows that
/// reach its own columns (`rows_within`).
struct Reach {
    rows: Rows,
    /// None where the coefficients are not finite: every brick then takes
    /// all of `rows`.
    chords: Option<Chords>,
}

/// Where the line along x of the row at `dy = t` in plane k meets the
/// ellipse `d2 <= bound`, in `dx`: centred on `-(g1 t + m0[k])`, of
/// half-width squared `w0[k] - w1[k] t - w2 t^2` (none where negative).
struct Chords {
    g1: f64,
    w2: f64,
    m0: [f64; DECODE_BRICK],
    w0: [f64; DECODE_BRICK],
    w1: [f64; DECODE_BRICK],
}

/// The rows of each plane `z0..z0 + nz` of a primitive's box (`b`) that
/// may reach its cut-off ellipsoid. At every lane of a row whose line along
/// x misses it, `d2` exceeds the cut-off, so the row adds +0 to `rho` (and
/// +0 or -0 to `num`), which changes no sum: it is skipped with the same
/// bits. Such rows are at least a fifth of the box's (the corners of its y-z
/// face), more for a tilted or flat primitive.
///
/// Along a row, `u = a0 dx + c` with `c = a1 dy + a2 dz`, and
/// `d2 = A (dx - m)^2 + least`, with `A = |a0|^2`, the chord's centre
/// `m = -a0.c / A` and `least = |P c|^2`, P the projection across `a0`: a
/// quadratic in `dy` for each plane, solved in f64. The bound allows for
/// the rounding of a lane's f32 `d2` (a few ulp of the squared size of its
/// terms; 1e-5 of it, and 1 % of the cut-off), and the rows for the
/// rounding of a lane's `dy` (`slack`).
fn reached_rows(f: &Frame, b: &[u32; 6], lattice: &Lattice, z0: usize, nz: usize) -> Reach {
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
    let mut rows = [[1, 0]; DECODE_BRICK];
    let (e1, e2) = (dot(&col[0], &col[1]), dot(&col[0], &col[2]));
    let mut chords = Chords { g1: e1 / a0a0, w2: alpha / a0a0, m0: [0.0; DECODE_BRICK], w0: [0.0; DECODE_BRICK], w1: [0.0; DECODE_BRICK] };
    for (k, o) in rows.iter_mut().enumerate().take(nz) {
        let dz = (lattice.point(0, 0, z0 + k)[2] - f.mu[2]) as f64;
        chords.m0[k] = e2 * dz / a0a0;
        chords.w0[k] = (bound - gamma * dz * dz) / a0a0;
        chords.w1[k] = 2.0 * beta * dz / a0a0;
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
        let (first, last) = rows_of(lattice, f.mu[1], lo, hi);
        let (first, last) = (first.max(b[1] as f64), last.min(b[4] as f64));
        if first <= last {
            *o = [first as u32, last as u32];
        }
    }
    let finite = |v: &[f64]| v.iter().all(|x| x.is_finite());
    let usable = a0a0 > 0.0 && chords.w2 + chords.g1 * chords.g1 > 0.0 && finite(&[chords.g1, chords.w2]) && finite(&chords.m0) && finite(&chords.w0) && finite(&chords.w1);
    Reach { rows, chords: usable.then_some(chords) }
}

/// The rows whose `dy`, as a lane computes it in f32, may lie in
/// `lo..=hi`: those within `slack` rows of it.
#[inline(always)]
fn rows_of(lattice: &Lattice, mu_y: f32, lo: f64, hi: f64) -> (f64, f64) {
    let (ystep, yorigin) = (lattice.step[1] as f64, lattice.origin[1] as f64);
    let row_of = |dy: f64| (dy + mu_y as f64 - yorigin) / ystep;
    let (ra, rb) = (row_of(lo), row_of(hi));
    let margin = slack(lattice, 1, mu_y);
    ((ra.min(rb) - margin).ceil(), (ra.max(rb) + margin).floor())
}

/// How far, in steps of `axis`, a lane's f32 offset from the centre `mu`
/// (`origin + i * step - mu`, and along x `t * step` added) may lie from
/// the exact one: each of its three or four roundings is within half an
/// f32 ulp of a term no larger than `|origin| + dims * |step| + |mu|`;
/// four ulp of that, and a twentieth of a step.
#[inline(always)]
fn slack(lattice: &Lattice, axis: usize, mu: f32) -> f64 {
    let (step, origin) = (lattice.step[axis].abs() as f64, lattice.origin[axis].abs() as f64);
    let size = origin + lattice.dims[axis] as f64 * step + mu.abs() as f64;
    0.05 + 4.0 * f32::EPSILON as f64 * size / step
}

impl Reach {
    /// Of `rows`, those whose line along x may meet the ellipse within the
    /// voxels `x.0..=x.1` along x of a column of bricks, where the box
    /// (`b`) goes on beyond them: the others add +0 at every lane of the
    /// column's bricks (the same argument as `reached_rows`'s, the voxels
    /// widened each side by what rounding may move a lane, `slack`).
    ///
    /// Where the box goes on to the left, a row must reach the voxels'
    /// left edge `e`: its chord's right end `m + sqrt(W)` is at least `e`.
    /// That holds where the centre `m >= e`, a half-line in `t = dy`, and
    /// else where `W >= (e - m)^2`, a quadratic in `t` whose roots bound
    /// an interval; the rows are those of both sets' hull. The same with
    /// the chord's left end on the right. In f64, once per primitive,
    /// slab and column of bricks, not per brick: per brick it cost more
    /// than the rows it saved (docs/BENCHMARKS.md "The CPU decode's rows
    /// within a column of bricks").
    #[inline(always)]
    fn rows_within(&self, lattice: &Lattice, mu: &[f32; 3], b: &[u32; 6], x: (usize, usize)) -> Rows {
        let Some(c) = &self.chords else { return self.rows };
        let (left, right) = (x.0 > b[0] as usize, x.1 < b[3] as usize);
        if !left && !right {
            return self.rows;
        }
        let sx = lattice.step[0] as f64;
        let dx = |i: usize| lattice.origin[0] as f64 + i as f64 * sx - mu[0] as f64;
        let widen = slack(lattice, 0, mu[0]) * sx.abs();
        let mut lo = [f64::NEG_INFINITY; DECODE_BRICK];
        let mut hi = [f64::INFINITY; DECODE_BRICK];
        if left {
            c.narrow(dx(x.0) - widen, true, &mut lo, &mut hi);
        }
        if right {
            c.narrow(dx(x.1) + widen, false, &mut lo, &mut hi);
        }
        let mut out = self.rows;
        for k in 0..DECODE_BRICK {
            let (first, last) = rows_of(lattice, mu[1], lo[k], hi[k]);
            let (first, last) = (first.max(out[k][0] as f64), last.min(out[k][1] as f64));
            out[k] = if lo[k] <= hi[k] && first <= last { [first as u32, last as u32] } else { [1, 0] };
        }
        out
    }
}

impl Chords {
    /// Narrows each plane's `lo..=hi` (in `dy`) to the rows whose chord
    /// ends at or beyond `e`: its right end at or right of `e`
    /// (`right_end`), or its left end at or left of it.
    #[inline(always)]
    fn narrow(&self, e: f64, right_end: bool, lo: &mut [f64; DECODE_BRICK], hi: &mut [f64; DECODE_BRICK]) {
        const INF: f64 = f64::INFINITY;
        let g1 = self.g1;
        let qa = self.w2 + g1 * g1;
        let half_over_qa = 0.5 / qa;
        // The centre is beyond `e` where `g1 t <= -s` (right end) or
        // `g1 t >= -s` (left end): which side of `t = -s / g1` depends on
        // the sign of g1; where g1 is 0, on the sign of s alone.
        let upper = (g1 > 0.0) == right_end;
        let flat = g1 == 0.0;
        let minus_over_g1 = if flat { 0.0 } else { -1.0 / g1 };
        for k in 0..DECODE_BRICK {
            let s = e + self.m0[k];
            let r = s * minus_over_g1;
            let (mut c_lo, mut c_hi) = if upper { (-INF, r) } else { (r, INF) };
            if flat {
                let all = if right_end { s <= 0.0 } else { s >= 0.0 };
                (c_lo, c_hi) = if all { (-INF, INF) } else { (INF, -INF) };
            }
            // W(t) - (s + g1 t)^2 >= 0, i.e. qa t^2 + qb t - qc <= 0.
            let qb = self.w1[k] + 2.0 * s * g1;
            let qc = self.w0[k] - s * s;
            let disc = qb * qb + 4.0 * qa * qc;
            let root = disc.max(0.0).sqrt();
            let (q_lo, q_hi) = if disc >= 0.0 { ((-qb - root) * half_over_qa, (-qb + root) * half_over_qa) } else { (INF, -INF) };
            lo[k] = lo[k].max(c_lo.min(q_lo));
            hi[k] = hi[k].min(c_hi.max(q_hi));
        }
    }
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
    /// adding +0, and only the rows that reach a brick's columns, give each
    /// voxel the bits of the plain loop: on lattices whose sides are no
    /// multiple of the brick, with steps that differ per axis, over a
    /// sub-box and beyond the primitives, where boxes start and end at every
    /// offset in a brick and hold odd and even numbers of rows; for tilted
    /// primitives, and for ones turned about x only or not at all, whose
    /// chords along x keep their centre from row to row (`Chords::g1` is 0).
    #[test]
    fn the_vectorised_splat_gives_each_voxel_the_plain_loops_bits() {
        use crate::math::kernel::layout::QUAT;
        let mut rng = Rng::new(21);
        let mut params = crate::backend::cpu::tests::random_prims(&mut rng, 150);
        for (i, mut p) in crate::backend::cpu::tests::random_prims(&mut rng, 60).into_iter().enumerate() {
            p[QUAT + 2] = 0.0;
            p[QUAT + 3] = 0.0;
            if i % 3 == 0 {
                p[QUAT + 1] = 0.0;
            }
            params.push(p);
        }
        let lattices = [
            Lattice::reference([6, 6, 6]),
            Lattice { dims: [21, 13, 10], origin: [-0.3, 0.1, 0.25], step: [0.31, 0.45, 0.6] },
            Lattice { dims: [9, 17, 8], origin: [1.5, 2.0, 0.5], step: [0.23, 0.17, 0.35] },
            Lattice { dims: [12, 5, 11], origin: [-2.0, -1.0, -3.0], step: [1.1, 2.3, 1.0] },
        ];
        // Far from the origin, where a lane's f32 offsets round by more
        // (`slack`): the primitives and a lattice moved there.
        let far = [3000.0f32, -2000.0, 1000.0];
        let mut moved = params.clone();
        for p in &mut moved {
            for a in 0..3 {
                p[a] += far[a];
            }
        }
        let far_lattice = Lattice { dims: [23, 15, 11], origin: [far[0] - 0.3, far[1] + 0.1, far[2] + 0.25], step: [0.29, 0.41, 0.53] };
        let cases = lattices.iter().map(|l| (l, &params)).chain([(&far_lattice, &moved)]);
        for (lattice, params) in cases {
            let mut got = vec![f32::NAN; lattice.len()];
            CpuBackend::new().splat_lattice(params, lattice, &mut got).unwrap();
            let want = voxel_by_voxel(params, lattice);
            assert!(want.iter().any(|&v| v > 0.0), "{lattice:?}: nothing decoded");
            let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert!(bits(&got) == bits(&want), "{lattice:?}: {} voxels differ", got.iter().zip(&want).filter(|(a, b)| a.to_bits() != b.to_bits()).count());
        }
    }
}
