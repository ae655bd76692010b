//! Points sorted into cubic bricks: the spatial unit every backend's point
//! passes work on. One definition, so that the CPU and the GPU backends list
//! the same bricks and the same points in each.

use super::csr::{csr, Keyed};
use crate::profile;
use rayon::prelude::*;

/// Points per parallel task when sorting a batch into bricks.
const POINTS_PER_TASK: usize = 2048;

/// A dense grid of cubic bricks over a batch's points, and the points sorted
/// by brick (a stable counting sort: within a brick, in batch order).
#[derive(Clone, Debug, PartialEq)]
pub struct PointBricks {
    /// Corner of brick (0, 0, 0): the batch's lowest coordinates.
    pub lo: [f32; 3],
    /// `1 / brick edge`.
    pub inv_edge: f32,
    /// Bricks per axis of the dense grid.
    pub dims: [usize; 3],
    /// Point indices, grouped by brick, bricks in dense (x fastest) order.
    pub order: Vec<u32>,
    /// Per occupied brick, in dense order: its range into `order`.
    pub ranges: Vec<(u32, u32)>,
    /// Per occupied brick: its dense grid coordinates.
    pub coords: Vec<[u32; 3]>,
    /// Dense brick index -> occupied index, `u32::MAX` when empty.
    pub occupied: Vec<u32>,
}

impl PointBricks {
    /// Bricks of edge `edge` voxels, grown when needed so that the dense grid
    /// holds no more than a few bricks per point. Parallel over runs of
    /// points; the same bricks whatever the thread count (the bounds are
    /// minima and maxima, and the sort is stable).
    pub fn new(pos: &[[f32; 3]], edge: f32) -> PointBricks {
        type Bounds = ([f32; 3], [f32; 3]);
        let merge = |(lo, hi): Bounds, (l, h): Bounds| -> Bounds { (std::array::from_fn(|a| lo[a].min(l[a])), std::array::from_fn(|a| hi[a].max(h[a]))) };
        let empty = || ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
        let (lo, hi) = pos
            .par_chunks(POINTS_PER_TASK)
            .map(|run| profile::task("bricks: bounds", || run.iter().fold(empty(), |b, &p| merge(b, (p, p)))))
            .reduce(empty, merge);
        let vol: f64 = (0..3).map(|a| (hi[a] - lo[a]) as f64 + 1.0).product();
        let b = edge.max((vol / (4.0 * pos.len() as f64 + 64.0)).cbrt() as f32);
        let inv_edge = 1.0 / b;
        let mut dims = [0usize; 3];
        for a in 0..3 {
            dims[a] = ((hi[a] - lo[a]) * inv_edge) as usize + 1;
        }
        let brick_of = |x: [f32; 3]| -> usize {
            let c = |a: usize| (((x[a] - lo[a]) * inv_edge) as usize).min(dims[a] - 1);
            c(0) + dims[0] * (c(1) + dims[1] * c(2))
        };
        let nb = dims[0] * dims[1] * dims[2];
        // Each task counts its points' bricks as it keys them: a histogram
        // of every brick a task, so no fewer than an eighth of the grid's
        // bricks in points a task (a sparse batch over a large grid).
        let per_task = POINTS_PER_TASK.max(nb / 8);
        let keyed: Vec<Keyed> = pos
            .par_chunks(per_task)
            .enumerate()
            .map(|(t, run)| {
                profile::task("bricks: keys", || {
                    let mut k = Keyed::new(nb, run.len());
                    for (i, &x) in run.iter().enumerate() {
                        k.push(brick_of(x) as u32, (t * per_task + i) as u32);
                    }
                    k
                })
            })
            .collect();
        let (start, order) = profile::even("bricks: sort", keyed.len(), || csr(nb, keyed));
        profile::serial("bricks: list", || {
            let mut occupied = vec![u32::MAX; nb];
            let mut ranges = vec![];
            let mut coords = vec![];
            for id in 0..nb {
                if start[id + 1] > start[id] {
                    occupied[id] = ranges.len() as u32;
                    ranges.push((start[id], start[id + 1]));
                    coords.push([(id % dims[0]) as u32, (id / dims[0] % dims[1]) as u32, (id / (dims[0] * dims[1])) as u32]);
                }
            }
            PointBricks { lo, inv_edge, dims, order, ranges, coords, occupied }
        })
    }

    /// The inclusive brick range `[r0, r1]` that the box `lo..hi` (index
    /// frame) overlaps, or `None` when it misses the grid or is NaN.
    pub fn range_of(&self, bx: &[f32; 6]) -> Option<([usize; 3], [usize; 3])> {
        let mut r0 = [0usize; 3];
        let mut r1 = [0usize; 3];
        for a in 0..3 {
            let l = (bx[a] - self.lo[a]) * self.inv_edge;
            let h = (bx[a + 3] - self.lo[a]) * self.inv_edge;
            if h < 0.0 || l >= self.dims[a] as f32 || l.is_nan() || h.is_nan() {
                return None;
            }
            r0[a] = l.max(0.0) as usize;
            r1[a] = (h as usize).min(self.dims[a] - 1);
        }
        Some((r0, r1))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::rng::Rng;

    #[test]
    fn every_point_once_in_its_brick_in_batch_order() {
        let mut rng = Rng::new(3);
        // More points than one task takes, the last run short; then a
        // sparse batch over a grid of more than 8 tasks' worth of bricks
        // (fewer, longer tasks).
        for (count, extent, edge) in [(2 * POINTS_PER_TASK + 500, 20.0, 4.0), (3 * POINTS_PER_TASK + 7, 1000.0, 1.0)] {
            let pos: Vec<[f32; 3]> = (0..count).map(|_| [0, 1, 2].map(|a| rng.range(-3.0, extent + 10.0 * a as f64) as f32)).collect();
            let b = PointBricks::new(&pos, edge);
            let nb = b.dims.iter().product::<usize>();
            assert_eq!(nb / 8 > POINTS_PER_TASK, extent > 100.0, "{nb} bricks");
            check(&pos, &b);
        }
    }

    /// A batch's sort made ahead is what the backends read for its edge,
    /// and only for its edge; a batch whose points were replaced after the
    /// sort (another count) is sorted again.
    #[test]
    fn a_batch_keeps_its_sort_for_that_edge_only() {
        use crate::backend::PointBatch;
        use std::borrow::Cow;
        let mut rng = Rng::new(5);
        let pos: Vec<[f32; 3]> = (0..3000).map(|_| [0, 1, 2].map(|_| rng.range(0.0, 64.0) as f32)).collect();
        let mut batch = PointBatch::new(pos.clone(), vec![0.5; pos.len()]);
        assert!(matches!(batch.bricks(16.0), Cow::Owned(_)), "nothing sorted ahead");
        batch.sort_into_bricks(16.0);
        let kept = batch.bricks(16.0);
        assert!(matches!(kept, Cow::Borrowed(_)));
        assert_eq!(*kept, PointBricks::new(&pos, 16.0));
        check(&pos, &kept);
        let other = batch.bricks(8.0);
        assert!(matches!(other, Cow::Owned(_)));
        assert_eq!(*other, PointBricks::new(&pos, 8.0));
        assert_ne!(*other, *kept);
        batch.pos.truncate(2000);
        batch.vref.truncate(2000);
        let again = batch.bricks(16.0);
        assert!(matches!(again, Cow::Owned(_)), "points replaced after the sort");
        check(&batch.pos, &again);
    }

    fn check(pos: &[[f32; 3]], b: &PointBricks) {
        let mut seen = vec![false; pos.len()];
        for (o, &(s, e)) in b.ranges.iter().enumerate() {
            let c = b.coords[o];
            let id = c[0] as usize + b.dims[0] * (c[1] as usize + b.dims[1] * c[2] as usize);
            assert_eq!(b.occupied[id], o as u32);
            let pts = &b.order[s as usize..e as usize];
            assert!(pts.windows(2).all(|w| w[0] < w[1]), "batch order inside a brick");
            for &i in pts {
                assert!(!seen[i as usize]);
                seen[i as usize] = true;
                let x = pos[i as usize];
                for a in 0..3 {
                    let cell = (((x[a] - b.lo[a]) * b.inv_edge) as usize).min(b.dims[a] - 1);
                    assert_eq!(cell, c[a] as usize);
                }
            }
        }
        assert!(seen.iter().all(|&s| s));
        assert_eq!(b.occupied.iter().filter(|&&o| o != u32::MAX).count(), b.ranges.len());
    }
}
