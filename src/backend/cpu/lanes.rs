//! The lane code of the CPU backend: a brick's candidates in blocks of
//! `LANES` (structure of arrays), the kernels of a block at a point, and a
//! block's pair terms; the loops over `[f32; LANES]` vectorise. The same
//! expressions as `kernel.rs` (`Frame::kernel`, `GradAcc::add_pair`), tested
//! against them below.

use crate::math::kernel::{Frame, GradAcc, CUTOFF_D2};

/// Lanes of the structure-of-arrays blocks; loops over `[f32; LANES]` vectorise.
pub(super) const LANES: usize = 8;
type Lane = [f32; LANES];

/// What the point passes read of one primitive, computed once per iteration.
#[derive(Clone, Copy, Default)]
pub(super) struct Hot {
    mu: [f32; 3],
    /// Rows of `diag(sigma)^-1 R^T`.
    a: [f32; 9],
    w: f32,
    s: f32,
}

impl Hot {
    pub(super) fn new(f: &Frame) -> Hot {
        let sa = f.scaled_axes();
        Hot { mu: f.mu, a: [sa[0][0], sa[0][1], sa[0][2], sa[1][0], sa[1][1], sa[1][2], sa[2][0], sa[2][1], sa[2][2]], w: f.w, s: f.s }
    }
}

/// `LANES` candidates of a brick in structure-of-arrays form. Padding lanes
/// are inert: `a = 0` and `w = 0`, so they add exactly zero everywhere.
#[derive(Clone, Copy)]
struct Block {
    mu: [Lane; 3],
    a: [Lane; 9],
    w: Lane,
    s: Lane,
}

const EMPTY_BLOCK: Block = Block {
    mu: [[0.0; LANES]; 3],
    a: [[0.0; LANES]; 9],
    w: [0.0; LANES],
    s: [0.0; LANES],
};

/// Kernels and scaled local coordinates of a block's lanes at `x`, computed
/// in local arrays only, so that the loop vectorises; adds `w K` to `rho`
/// and `w K s` to `num` in the same loop (apart, the compiler turned those
/// sums into scalar code).
#[inline(always)]
fn block_kernels(blk: &Block, x: [f32; 3], rho: &mut Lane, num: &mut Lane) -> (Lane, [Lane; 3]) {
    let mut k = [0.0f32; LANES];
    let mut y = [[0.0f32; LANES]; 3];
    let a = &blk.a;
    for l in 0..LANES {
        let dx = x[0] - blk.mu[0][l];
        let dy = x[1] - blk.mu[1][l];
        let dz = x[2] - blk.mu[2][l];
        let u0 = a[0][l] * dx + a[1][l] * dy + a[2][l] * dz;
        let u1 = a[3][l] * dx + a[4][l] * dy + a[5][l] * dz;
        let u2 = a[6][l] * dx + a[7][l] * dy + a[8][l] * dz;
        let d2 = u0 * u0 + u1 * u1 + u2 * u2;
        let e = crate::math::kernel::exp_neg_half(d2);
        k[l] = if d2 < CUTOFF_D2 { e } else { 0.0 };
        let wk = blk.w[l] * k[l];
        rho[l] += wk;
        num[l] += wk * blk.s[l];
        y[0][l] = u0;
        y[1][l] = u1;
        y[2][l] = u2;
    }
    (k, y)
}

/// The 11 `GradAcc` pair terms (and K) of a block's lanes for one point, in
/// local arrays; the same expressions as [`GradAcc::add_pair`].
#[inline(always)]
fn block_pair_terms(blk: &Block, ev: &BlockEval, g_rho: f32, g_n: f32) -> [Lane; 12] {
    let mut t = [[0.0f32; LANES]; 12];
    let (k, y) = (&ev.k, &ev.y);
    for l in 0..LANES {
        let c = -0.5 * k[l] * blk.w[l] * (g_rho + blk.s[l] * g_n);
        t[0][l] = k[l] * g_rho;
        t[1][l] = k[l] * g_n;
        t[2][l] = c * y[0][l];
        t[3][l] = c * y[1][l];
        t[4][l] = c * y[2][l];
        t[5][l] = c * y[0][l] * y[0][l];
        t[6][l] = c * y[1][l] * y[1][l];
        t[7][l] = c * y[2][l] * y[2][l];
        t[8][l] = c * y[0][l] * y[1][l];
        t[9][l] = c * y[0][l] * y[2][l];
        t[10][l] = c * y[1][l] * y[2][l];
        t[11][l] = k[l];
    }
    t
}

/// Kernel values and scaled local coordinates of one block at the current point.
#[derive(Clone, Copy, Default)]
struct BlockEval {
    k: Lane,
    y: [Lane; 3],
}

/// The candidates of one brick in blocks of `LANES`, read by every point
/// of the brick (and by every run of a split brick's points at once).
#[derive(Default)]
pub(super) struct BrickCands {
    blocks: Vec<Block>,
    /// Each block's box, the union of its candidates' 5-sigma boxes (points
    /// outside it skip the block, whose kernels are all zero there), by
    /// coordinate (lo x, y, z, hi x, y, z), so that one loop tests a point
    /// against many blocks at once.
    bounds: [Vec<f32>; 6],
}

impl BrickCands {
    fn load(&mut self, hot: &[Hot], boxes: &[[f32; 6]], cands: &[u32]) {
        let nb = cands.len().div_ceil(LANES);
        self.blocks.clear();
        self.blocks.resize(nb, EMPTY_BLOCK);
        for (c, v) in self.bounds.iter_mut().enumerate() {
            v.clear();
            v.resize(nb, if c < 3 { f32::INFINITY } else { f32::NEG_INFINITY });
        }
        for (j, &g) in cands.iter().enumerate() {
            let (b, l) = (j / LANES, j % LANES);
            let h = &hot[g as usize];
            let bx = &boxes[g as usize];
            let blk = &mut self.blocks[b];
            for c in 0..3 {
                blk.mu[c][l] = h.mu[c];
                self.bounds[c][b] = self.bounds[c][b].min(bx[c]);
                self.bounds[c + 3][b] = self.bounds[c + 3][b].max(bx[c + 3]);
            }
            for r in 0..9 {
                blk.a[r][l] = h.a[r];
            }
            blk.w[l] = h.w;
            blk.s[l] = h.s;
        }
    }
}

/// One pass of points over a brick's candidates: the current point's
/// kernels and the pass's gradient sums (11 `GradAcc` terms and the sum of
/// K, per candidate).
#[derive(Default)]
pub(super) struct PointPass {
    eval: Vec<BlockEval>,
    acc: Vec<[Lane; 12]>,
    /// The blocks whose box holds the current point, in block order:
    /// `inside[..n_inside]`.
    inside: Vec<u32>,
    n_inside: usize,
    /// Whether each block's box holds the current point.
    holds: Vec<u8>,
}

impl PointPass {
    /// Ready for the `nb` blocks of a brick, with zero sums when `with_grad`.
    pub(super) fn reset(&mut self, nb: usize, with_grad: bool) {
        self.eval.resize(nb, BlockEval::default());
        self.inside.resize(nb, 0);
        self.holds.resize(nb, 0);
        self.n_inside = 0;
        if with_grad {
            self.acc.clear();
            self.acc.resize(nb, [[0.0; LANES]; 12]);
        }
    }

    /// Kernels of every candidate at `x`; returns `(rho, n)` and adds the
    /// number of lanes evaluated (blocks not skipped, times `LANES`) to
    /// `evals`. Lane partial sums are added in a fixed order, so the result
    /// depends only on the candidates.
    #[inline(always)]
    pub(super) fn forward(&mut self, cands: &BrickCands, x: [f32; 3], evals: &mut u64) -> (f32, f32) {
        // First the blocks whose box holds the point, listed without a
        // branch; then their kernels, in block order. A branch per block
        // would be mispredicted about a third of the time, and each miss
        // would throw away the overlap of consecutive blocks' exp chains.
        let [lx, ly, lz, hx, hy, hz] = &cands.bounds;
        let holds = &mut self.holds[..cands.blocks.len()];
        for (b, h) in holds.iter_mut().enumerate() {
            // `&`, not `&&`: six comparisons and no branch, vectorised.
            *h = ((x[0] >= lx[b]) & (x[1] >= ly[b]) & (x[2] >= lz[b]) & (x[0] <= hx[b]) & (x[1] <= hy[b]) & (x[2] <= hz[b])) as u8;
        }
        let mut n_in = 0;
        for (b, &h) in holds.iter().enumerate() {
            self.inside[n_in] = b as u32;
            n_in += h as usize;
        }
        self.n_inside = n_in;
        let mut rho = [0.0f32; LANES];
        let mut num = [0.0f32; LANES];
        for &b in &self.inside[..n_in] {
            let (blk, ev) = (&cands.blocks[b as usize], &mut self.eval[b as usize]);
            let (k, y) = block_kernels(blk, x, &mut rho, &mut num);
            ev.k = k;
            ev.y = y;
        }
        *evals += (n_in * LANES) as u64;
        let (mut r, mut n) = (0.0f32, 0.0f32);
        for l in 0..LANES {
            r += rho[l];
            n += num[l];
        }
        (r, n)
    }

    /// Adds the current point's pair terms to the pass's sums.
    #[inline(always)]
    pub(super) fn backward(&mut self, cands: &BrickCands, g_rho: f32, g_n: f32) {
        for &b in &self.inside[..self.n_inside] {
            let b = b as usize;
            let terms = block_pair_terms(&cands.blocks[b], &self.eval[b], g_rho, g_n);
            let acc = &mut self.acc[b];
            for t in 0..12 {
                for l in 0..LANES {
                    acc[t][l] += terms[t][l];
                }
            }
        }
    }

    /// Adds another pass's sums over the same blocks to this one's.
    pub(super) fn add(&mut self, other: &PointPass) {
        for (a, o) in self.acc.iter_mut().zip(&other.acc) {
            for t in 0..12 {
                for l in 0..LANES {
                    a[t][l] += o[t][l];
                }
            }
        }
    }

    /// The pass's sums of candidate `j`, or `None` when it touched no point.
    pub(super) fn take(&self, j: usize) -> Option<GradAcc> {
        let (b, l) = (j / LANES, j % LANES);
        let acc = &self.acc[b];
        if acc[11][l] == 0.0 {
            return None;
        }
        let mut g = GradAcc::default();
        for t in 0..11 {
            g.0[t] = acc[t][l];
        }
        Some(g)
    }
}

/// A brick's candidates and one pass of its points over them.
#[derive(Default)]
pub(super) struct BrickSoa {
    pub(super) cands: BrickCands,
    pub(super) pass: PointPass,
}

impl BrickSoa {
    pub(super) fn load(&mut self, hot: &[Hot], boxes: &[[f32; 6]], cands: &[u32], with_grad: bool) {
        self.cands.load(hot, boxes, cands);
        self.pass.reset(self.cands.blocks.len(), with_grad);
    }

    /// [`PointPass::forward`] over this brick's candidates.
    #[inline(always)]
    pub(super) fn forward(&mut self, x: [f32; 3], evals: &mut u64) -> (f32, f32) {
        self.pass.forward(&self.cands, x, evals)
    }

    /// [`PointPass::backward`] over this brick's candidates.
    #[inline(always)]
    pub(super) fn backward(&mut self, g_rho: f32, g_n: f32) {
        self.pass.backward(&self.cands, g_rho, g_n)
    }

    /// Blocks of candidates loaded.
    pub(super) fn blocks(&self) -> usize {
        self.cands.blocks.len()
    }
}

#[cfg(test)]
mod tests {
    use super::super::tests::random_prims;
    use super::super::Prepared;
    use super::*;
    use crate::math::rng::Rng;

    /// The lane code is a transcription of `Frame::kernel` and
    /// `GradAcc::add_pair`; it must agree with them.
    #[test]
    fn lane_code_matches_the_scalar_definitions() {
        let mut rng = Rng::new(4);
        let params = random_prims(&mut rng, 13); // not a multiple of LANES: padding is exercised
        let mut prep = Prepared::default();
        prep.update(&params);
        let cands: Vec<u32> = (0..13).collect();
        let mut soa = BrickSoa::default();
        soa.load(&prep.hot, &prep.boxes, &cands, true);
        let mut expect = vec![GradAcc::default(); 13];
        for _ in 0..20 {
            let x = [0, 1, 2].map(|_| rng.range(0.0, 6.0) as f32);
            let (g_rho, g_n) = (rng.range(-1.0, 1.0) as f32, rng.range(-1.0, 1.0) as f32);
            let (rho, n) = soa.forward(x, &mut 0);
            soa.backward(g_rho, g_n);
            let (mut r2, mut n2) = (0.0f32, 0.0f32);
            for (g, f) in prep.frames.iter().enumerate() {
                if let Some((k, y)) = f.kernel(x) {
                    r2 += f.w * k;
                    n2 += f.w * k * f.s;
                    expect[g].add_pair(f, k, y, g_rho, g_n);
                }
            }
            assert!((rho - r2).abs() <= 1e-5 * (1.0 + r2) && (n - n2).abs() <= 1e-5 * (1.0 + n2), "{rho} {r2} {n} {n2}");
        }
        for (g, e) in expect.iter().enumerate() {
            let got = soa.pass.take(g).unwrap_or_default();
            for t in 0..11 {
                assert!((got.0[t] - e.0[t]).abs() <= 1e-4 * (1.0 + e.0[t].abs()), "candidate {g} term {t}: {} vs {}", got.0[t], e.0[t]);
            }
        }
    }
}
