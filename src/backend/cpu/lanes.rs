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
    #[inline(always)]
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

/// Scaled local coordinates `y` of a block's lanes at `x` and their squared
/// norms `d2`, in local arrays only, so that the loop vectorises. A lane
/// with `d2 >= CUTOFF_D2` has a kernel of exactly zero there.
#[inline(always)]
fn block_coords(blk: &Block, x: [f32; 3]) -> (Lane, [Lane; 3]) {
    let mut d2 = [0.0f32; LANES];
    let mut y = [[0.0f32; LANES]; 3];
    let a = &blk.a;
    for l in 0..LANES {
        let dx = x[0] - blk.mu[0][l];
        let dy = x[1] - blk.mu[1][l];
        let dz = x[2] - blk.mu[2][l];
        let u0 = a[0][l] * dx + a[1][l] * dy + a[2][l] * dz;
        let u1 = a[3][l] * dx + a[4][l] * dy + a[5][l] * dz;
        let u2 = a[6][l] * dx + a[7][l] * dy + a[8][l] * dz;
        d2[l] = u0 * u0 + u1 * u1 + u2 * u2;
        y[0][l] = u0;
        y[1][l] = u1;
        y[2][l] = u2;
    }
    (d2, y)
}

/// The kernels of a block's lanes from their `d2` ([`block_coords`]); adds
/// `w K` to `rho` and `w K s` to `num` in the same loop (apart, the
/// compiler turned those sums into scalar code), with `w` the lanes'
/// weights: the block's own, or those times a 0-or-1 mask
/// (`PointPass::forward_pointwise`).
#[inline(always)]
fn block_kernels(blk: &Block, w: &Lane, d2: &Lane, rho: &mut Lane, num: &mut Lane) -> Lane {
    let mut k = [0.0f32; LANES];
    for l in 0..LANES {
        let e = crate::math::kernel::exp_neg_half(d2[l]);
        k[l] = if d2[l] < CUTOFF_D2 { e } else { 0.0 };
        let wk = w[l] * k[l];
        rho[l] += wk;
        num[l] += wk * blk.s[l];
    }
    k
}

/// Block `b`'s sums of `acc`, started at zero if `summed` says no point has
/// added to them yet (`PointPass::acc`).
#[inline(always)]
fn sums_mut<'a>(acc: &'a mut [[Lane; 12]], summed: &mut [bool], b: usize) -> &'a mut [Lane; 12] {
    let a = &mut acc[b];
    if !summed[b] {
        summed[b] = true;
        *a = [[0.0; LANES]; 12];
    }
    a
}

/// Whether any lane is within the cutoff; branch-free, so it vectorises.
#[inline(always)]
fn any_within(d2: &Lane) -> bool {
    let mut m = 0u32;
    for &v in d2 {
        m |= (v < CUTOFF_D2) as u32;
    }
    m != 0
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

/// A point's `(rho, n)` from its lane partial sums, added in lane order.
#[inline(always)]
fn lane_total(rho: &Lane, num: &Lane) -> (f32, f32) {
    let (mut r, mut n) = (0.0f32, 0.0f32);
    for l in 0..LANES {
        r += rho[l];
        n += num[l];
    }
    (r, n)
}

/// Kernel values, squared norms and scaled local coordinates of one block
/// at the current point.
#[derive(Clone, Copy, Default)]
struct BlockEval {
    k: Lane,
    d2: Lane,
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
    /// Each block's lanes' own boxes (lo x, y, z, hi x, y, z; padding lanes
    /// hold none, so no point), for [`PointPass::forward_pointwise`]; empty
    /// after [`Self::load`].
    lane_boxes: Vec<[Lane; 6]>,
}

impl BrickCands {
    /// Candidate `j` of the list in block `j / LANES`, lane `j % LANES`.
    fn load(&mut self, hot: &[Hot], boxes: &[[f32; 6]], cands: &[u32]) {
        self.fill(hot, boxes, cands.len().div_ceil(LANES), cands.iter().enumerate().map(|(j, &g)| (j / LANES, j % LANES, g)), false);
    }

    /// Primitive `g` in lane `g % LANES`, in that lane's next free block:
    /// each lane holds its primitives in list order, whatever the others
    /// hold. Blocks: the most candidates any lane gets.
    fn load_pointwise(&mut self, hot: &[Hot], boxes: &[[f32; 6]], cands: &[u32]) {
        let mut next = [0usize; LANES];
        for &g in cands {
            next[g as usize % LANES] += 1;
        }
        let nb = next.iter().copied().max().unwrap_or(0);
        next = [0; LANES];
        let slots = cands.iter().map(|&g| {
            let l = g as usize % LANES;
            next[l] += 1;
            (next[l] - 1, l, g)
        });
        self.fill(hot, boxes, nb, slots, true);
    }

    /// `nb` blocks, primitive `g` in block `b`, lane `l` for each `(b, l, g)`
    /// of `slots`; the other lanes inert. The lanes' own boxes only when
    /// `lane_boxes` (training never reads them).
    fn fill(&mut self, hot: &[Hot], boxes: &[[f32; 6]], nb: usize, slots: impl Iterator<Item = (usize, usize, u32)>, lane_boxes: bool) {
        self.blocks.clear();
        self.blocks.resize(nb, EMPTY_BLOCK);
        for (c, v) in self.bounds.iter_mut().enumerate() {
            v.clear();
            v.resize(nb, if c < 3 { f32::INFINITY } else { f32::NEG_INFINITY });
        }
        self.lane_boxes.clear();
        if lane_boxes {
            self.lane_boxes.resize(nb, [[f32::INFINITY; LANES], [f32::INFINITY; LANES], [f32::INFINITY; LANES], [f32::NEG_INFINITY; LANES], [f32::NEG_INFINITY; LANES], [f32::NEG_INFINITY; LANES]]);
        }
        for (b, l, g) in slots {
            let h = &hot[g as usize];
            let bx = &boxes[g as usize];
            let blk = &mut self.blocks[b];
            for c in 0..3 {
                blk.mu[c][l] = h.mu[c];
                self.bounds[c][b] = self.bounds[c][b].min(bx[c]);
                self.bounds[c + 3][b] = self.bounds[c + 3][b].max(bx[c + 3]);
            }
            if lane_boxes {
                for (c, v) in self.lane_boxes[b].iter_mut().enumerate() {
                    v[l] = bx[c];
                }
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
    /// Each block's sums, valid where `summed` says so: a block's are
    /// zeroed when a point first adds to them, since most blocks of a
    /// brick meet none of a sparse batch's few points there (zeroing every
    /// block at every brick was 4.7 % of an RM 128³ `matched` encode).
    acc: Vec<[Lane; 12]>,
    /// Whether each block's sums were started in this pass.
    summed: Vec<bool>,
    /// The blocks whose box holds the current point, in block order:
    /// `inside[..n_inside]`.
    inside: Vec<u32>,
    n_inside: usize,
    /// Of those, the blocks with a lane within the cutoff at the current
    /// point, in block order: `live[..n_live]`. The others' kernels are all
    /// zero there, so their pair terms are zeros, which change no sum.
    live: Vec<u32>,
    n_live: usize,
    /// Whether each block's box holds the current point.
    holds: Vec<u8>,
}

impl PointPass {
    /// Ready for the `nb` blocks of a brick, with no sums started (room
    /// for them when `with_grad`).
    pub(super) fn reset(&mut self, nb: usize, with_grad: bool) {
        self.eval.resize(nb, BlockEval::default());
        self.inside.resize(nb, 0);
        self.live.resize(nb, 0);
        self.holds.resize(nb, 0);
        self.n_inside = 0;
        self.n_live = 0;
        self.summed.clear();
        self.summed.resize(nb, false);
        if with_grad && self.acc.len() < nb {
            self.acc.resize(nb, [[0.0; LANES]; 12]);
        }
    }

    /// Lists the blocks whose box holds `x` (`inside[..n_inside]`),
    /// without a branch: a branch per block would be mispredicted about a
    /// third of the time, and each miss would throw away the overlap of
    /// consecutive blocks' exp chains.
    #[inline(always)]
    fn list_inside(&mut self, cands: &BrickCands, x: [f32; 3]) {
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
    }

    /// Lists the blocks whose box holds `x` ([`Self::list_inside`]), then
    /// computes their lanes' coordinates and lists those with a lane within
    /// the cutoff (`live[..n_live]`, without a branch, as `list_inside`):
    /// the others' kernels are all zero at `x`, so their terms are zeros,
    /// and adding zeros changes no sum (an accumulator starts at +0, and
    /// `a + ±0` is `a`). Adds the lanes whose coordinates were computed
    /// (blocks not skipped by their box, times `LANES`) to `evals`.
    #[inline(always)]
    fn list_live(&mut self, cands: &BrickCands, x: [f32; 3], evals: &mut u64) {
        self.list_inside(cands, x);
        let mut n_live = 0;
        for &b in &self.inside[..self.n_inside] {
            let ev = &mut self.eval[b as usize];
            (ev.d2, ev.y) = block_coords(&cands.blocks[b as usize], x);
            self.live[n_live] = b;
            n_live += any_within(&ev.d2) as usize;
        }
        self.n_live = n_live;
        *evals += (self.n_inside * LANES) as u64;
    }

    /// Kernels of every candidate at `x`, computed for the live blocks
    /// ([`Self::list_live`]) in block order; returns `(rho, n)`. Lane
    /// partial sums are added in a fixed order, so the result depends only
    /// on the candidates.
    #[inline(always)]
    pub(super) fn forward(&mut self, cands: &BrickCands, x: [f32; 3], evals: &mut u64) -> (f32, f32) {
        self.list_live(cands, x, evals);
        let mut rho = [0.0f32; LANES];
        let mut num = [0.0f32; LANES];
        for &b in &self.live[..self.n_live] {
            let (blk, ev) = (&cands.blocks[b as usize], &mut self.eval[b as usize]);
            ev.k = block_kernels(blk, &blk.w, &ev.d2, &mut rho, &mut num);
        }
        lane_total(&rho, &num)
    }

    /// [`Self::forward`] over candidates loaded by
    /// [`BrickCands::load_pointwise`], each lane's term counted only where
    /// its own box holds `x`: the result depends on `x` and the primitives
    /// alone, not on the brick's other candidates
    /// (`Backend::evaluate_each`). Lane `l`'s sum is then the sum, in
    /// primitive order, over every primitive `g` with `g % LANES == l`
    /// whose box holds `x`: the brick lists every such primitive (the brick
    /// range of a box and the brick of a point come from the same monotone
    /// float operations), in primitive order; one it does not list adds
    /// nothing, and neither does a listed one whose box misses `x`, nor a
    /// skipped block. The lanes are then added in a fixed order.
    #[inline(always)]
    pub(super) fn forward_pointwise(&mut self, cands: &BrickCands, x: [f32; 3], evals: &mut u64) -> (f32, f32) {
        self.list_live(cands, x, evals);
        let mut rho = [0.0f32; LANES];
        let mut num = [0.0f32; LANES];
        for &b in &self.live[..self.n_live] {
            let (blk, bx, ev) = (&cands.blocks[b as usize], &cands.lane_boxes[b as usize], &self.eval[b as usize]);
            // Each lane's weight where its box holds `x`, else 0: a product
            // by 1 is exact, so a lane that counts adds `forward`'s bits.
            let mut w = [0.0f32; LANES];
            for l in 0..LANES {
                let holds = (x[0] >= bx[0][l]) & (x[1] >= bx[1][l]) & (x[2] >= bx[2][l]) & (x[0] <= bx[3][l]) & (x[1] <= bx[4][l]) & (x[2] <= bx[5][l]);
                w[l] = blk.w[l] * (holds as u32 as f32);
            }
            block_kernels(blk, &w, &ev.d2, &mut rho, &mut num);
        }
        lane_total(&rho, &num)
    }

    /// Adds the current point's pair terms to the pass's sums: those of the
    /// blocks with a lane within the cutoff (the others' terms are zeros,
    /// whose sums change no bit: an accumulator starts at +0 and `a + ±0`
    /// is `a`).
    #[inline(always)]
    pub(super) fn backward(&mut self, cands: &BrickCands, g_rho: f32, g_n: f32) {
        for &b in &self.live[..self.n_live] {
            let b = b as usize;
            let terms = block_pair_terms(&cands.blocks[b], &self.eval[b], g_rho, g_n);
            let acc = sums_mut(&mut self.acc, &mut self.summed, b);
            for t in 0..12 {
                for l in 0..LANES {
                    acc[t][l] += terms[t][l];
                }
            }
        }
    }

    /// Adds another pass's sums over the same blocks to this one's.
    pub(super) fn add(&mut self, other: &PointPass) {
        for (b, o) in other.acc.iter().enumerate().take(other.summed.len()) {
            if !other.summed[b] {
                continue;
            }
            let a = sums_mut(&mut self.acc, &mut self.summed, b);
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
        if !self.summed[b] {
            return None;
        }
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

    /// This brick's candidates for [`Self::forward_pointwise`]
    /// ([`BrickCands::load_pointwise`]); no gradient sums.
    pub(super) fn load_pointwise(&mut self, hot: &[Hot], boxes: &[[f32; 6]], cands: &[u32]) {
        self.cands.load_pointwise(hot, boxes, cands);
        self.pass.reset(self.cands.blocks.len(), false);
    }

    /// [`PointPass::forward_pointwise`] over this brick's candidates, loaded
    /// by [`Self::load_pointwise`].
    #[inline(always)]
    pub(super) fn forward_pointwise(&mut self, x: [f32; 3], evals: &mut u64) -> (f32, f32) {
        self.pass.forward_pointwise(&self.cands, x, evals)
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

    /// `forward_pointwise` depends on the point and the primitives alone:
    /// a brick that lists every primitive, one that lists only those whose
    /// box holds the point (in other blocks), and one that lists them after
    /// a few others that miss it, all in primitive order, give the same
    /// bits; and that is the mixture summed over every primitive by
    /// `Frame::kernel`, to within float rounding. The lane sums of
    /// `forward` do differ in their last bits between such lists for some
    /// point (what `forward_pointwise` exists to avoid).
    #[test]
    fn pointwise_a_point_gets_the_same_bits_from_any_list() {
        let mut rng = Rng::new(5);
        let n = 61;
        let params = random_prims(&mut rng, n);
        let mut prep = Prepared::default();
        prep.update(&params);
        let holds = |g: usize, x: [f32; 3]| (0..3).all(|a| x[a] >= prep.boxes[g][a] && x[a] <= prep.boxes[g][a + 3]);
        let mut lane_sums_differ = false;
        for _ in 0..200 {
            let x = [0, 1, 2].map(|_| rng.range(0.0, 6.0) as f32);
            let every: Vec<u32> = (0..n as u32).collect();
            let holding: Vec<u32> = every.iter().copied().filter(|&g| holds(g as usize, x)).collect();
            // Three far primitives first shift every holding one's lane.
            let far: Vec<u32> = every.iter().copied().filter(|&g| !holds(g as usize, x)).take(3).collect();
            let mut shifted: Vec<u32> = far.iter().chain(&holding).copied().collect();
            shifted.sort_unstable();
            let mut soa = BrickSoa::default();
            let mut run = |cands: &[u32], pointwise: bool| {
                let (r, n) = if pointwise {
                    soa.load_pointwise(&prep.hot, &prep.boxes, cands);
                    soa.forward_pointwise(x, &mut 0)
                } else {
                    soa.load(&prep.hot, &prep.boxes, cands, false);
                    soa.forward(x, &mut 0)
                };
                (r.to_bits(), n.to_bits())
            };
            let want = run(&every, true);
            assert_eq!(run(&holding, true), want, "at {x:?}: the holding primitives alone");
            assert_eq!(run(&shifted, true), want, "at {x:?}: after three that miss");
            lane_sums_differ |= run(&holding, false) != run(&every, false) || run(&shifted, false) != run(&every, false);
            let (mut r2, mut n2) = (0.0f32, 0.0f32);
            for f in &prep.frames {
                if let Some((k, _)) = f.kernel(x) {
                    r2 += f.w * k;
                    n2 += f.w * k * f.s;
                }
            }
            let (r, nn) = (f32::from_bits(want.0), f32::from_bits(want.1));
            assert!((r - r2).abs() <= 1e-5 * (1.0 + r2) && (nn - n2).abs() <= 1e-5 * (1.0 + n2.abs()), "{r} {r2} {nn} {n2}");
        }
        assert!(lane_sums_differ, "no point shows the lane sums' dependence on the list: the test proves nothing");

        // A primitive whose box misses the point adds nothing, even where
        // its kernel does not vanish (as at a box's edge, by rounding): a
        // box shrunk off the point's side counts as that primitive not
        // being there.
        let x = prep.frames[0].mu;
        let mut boxes = prep.boxes.clone();
        boxes[0][0] = x[0] + 1e-3;
        let every: Vec<u32> = (0..n as u32).collect();
        let mut soa = BrickSoa::default();
        soa.load_pointwise(&prep.hot, &boxes, &every);
        let (with, _) = soa.forward_pointwise(x, &mut 0);
        soa.load_pointwise(&prep.hot, &boxes, &every[1..]);
        let (without, _) = soa.forward_pointwise(x, &mut 0);
        soa.load_pointwise(&prep.hot, &prep.boxes, &every);
        let (whole, _) = soa.forward_pointwise(x, &mut 0);
        assert_eq!(with.to_bits(), without.to_bits());
        assert!(whole >= with + 0.5 * prep.frames[0].w, "the first primitive's own weight at its centre: {whole} vs {with}");
    }

    /// Skipping the blocks whose box misses a point, and then those with no
    /// lane within the cutoff, changes no bit: the forward's sums and every
    /// candidate's pair sums are those of a pass that evaluates every block
    /// at every point, with the same lane functions. Random primitives in a
    /// brick of several blocks, so that many blocks are skipped each way.
    #[test]
    fn skipped_blocks_change_no_bit() {
        let mut rng = Rng::new(11);
        let n = 45;
        let mut params = random_prims(&mut rng, n);
        // Small enough (sigma 0.14 to 0.61) that a block's box misses
        // many points.
        for p in &mut params {
            for a in 0..3 {
                p[crate::math::kernel::layout::LOG_SCALE + a] = rng.range(-2.0, -0.5) as f32;
            }
        }
        let mut prep = Prepared::default();
        prep.update(&params);
        let cands: Vec<u32> = (0..n as u32).collect();
        let mut soa = BrickSoa::default();
        soa.load(&prep.hot, &prep.boxes, &cands, true);
        // A block's sums start when a point first adds to them: garbage
        // left in the buffer by an earlier brick must not leak into them.
        soa.pass.acc.iter_mut().for_each(|a| *a = [[f32::NAN; LANES]; 12]);
        let blocks = &soa.cands.blocks;
        let mut every = vec![[[0.0f32; LANES]; 12]; blocks.len()];
        let (mut skipped_by_box, mut skipped_dead) = (0, 0);
        for _ in 0..400 {
            let x = [0, 1, 2].map(|_| rng.range(0.0, 6.0) as f32);
            let (g_rho, g_n) = (rng.range(-1.0, 1.0) as f32, rng.range(-1.0, 1.0) as f32);
            let (mut rho, mut num) = ([0.0f32; LANES], [0.0f32; LANES]);
            for (blk, acc) in blocks.iter().zip(&mut every) {
                let (d2, y) = block_coords(blk, x);
                let k = block_kernels(blk, &blk.w, &d2, &mut rho, &mut num);
                let terms = block_pair_terms(blk, &BlockEval { k, d2, y }, g_rho, g_n);
                for t in 0..12 {
                    for l in 0..LANES {
                        acc[t][l] += terms[t][l];
                    }
                }
            }
            let want = lane_total(&rho, &num);
            let got = soa.pass.forward(&soa.cands, x, &mut 0);
            assert_eq!((got.0.to_bits(), got.1.to_bits()), (want.0.to_bits(), want.1.to_bits()), "at {x:?}");
            soa.pass.backward(&soa.cands, g_rho, g_n);
            skipped_by_box += blocks.len() - soa.pass.n_inside;
            skipped_dead += soa.pass.n_inside - soa.pass.n_live;
        }
        assert!(skipped_by_box > 100 && skipped_dead > 100, "too few blocks skipped to test: {skipped_by_box} by box, {skipped_dead} dead");
        // The candidates' lanes; the padding lanes' sums (kernel 1, weight
        // 0) are never read.
        let mut untouched = 0;
        for j in 0..n {
            let want = &every[j / LANES];
            match soa.pass.take(j) {
                Some(got) => {
                    for t in 0..11 {
                        assert_eq!(got.0[t].to_bits(), want[t][j % LANES].to_bits(), "candidate {j} term {t}");
                    }
                }
                None => {
                    untouched += 1;
                    assert_eq!(want[11][j % LANES], 0.0, "candidate {j} met points but has no sums");
                }
            }
        }
        assert!(untouched < n, "no candidate met a point");
    }

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
