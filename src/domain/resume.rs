//! A decomposed series resumed after a restart: each rank holds the model
//! of its own piece stored last, and the field's lattice and every rank's
//! piece are rebuilt from those models' frames, so that the resumed run's
//! pushes, step indexes and models continue the unbroken run's.
//!
//! A field's lattice is fixed at its first step (`mpi`'s layout): a grid's
//! is the union of the ranks' grids, which the pieces (each rank's grid
//! grown by the halo, clipped to the lattice) cover exactly; that of
//! particles and cells has the configured `dims` over the configured
//! `bounds`, or from the lowest corner of the ranks' data, where the piece
//! of the rank holding it starts. Every piece rebuilt here must give back
//! its model's frame bit for bit, or the restart is refused. Pure: the MPI
//! layer gathers the frames.

use crate::error::{Error, Result};
use crate::field::{ulps_apart, Bounds, IndexBox, IndexFrame, Transform, ValueRange};

/// What one rank sends the others about its resumed model: its piece's
/// frame and the series' range.
pub const WIRE_LEN: usize = 10;

/// `frame` and `range` as the words one rank sends the others.
pub fn to_wire(frame: &IndexFrame, range: &ValueRange) -> [f64; WIRE_LEN] {
    let [b0, b1, b2] = frame.bmin;
    let [d0, d1, d2] = frame.dims.map(|d| d as f64);
    [b0, b1, b2, frame.gamma, d0, d1, d2, range.vmin, range.vmax, range.transform as u8 as f64]
}

/// The frames and the one range of every rank's words (rank order), or
/// why they are not one series' pieces.
pub fn from_wire(all: &[f64]) -> Result<(Vec<IndexFrame>, ValueRange)> {
    let mut frames = Vec::with_capacity(all.len() / WIRE_LEN);
    let mut range: Option<ValueRange> = None;
    for (r, w) in all.chunks_exact(WIRE_LEN).enumerate() {
        let dims = [w[4], w[5], w[6]].map(|d| d as usize);
        frames.push(IndexFrame { dims, bmin: [w[0], w[1], w[2]], gamma: w[3] });
        let transform = Transform::from_code(w[9] as u32).ok_or_else(|| Error::Mpi(format!("rank {r} sent an unknown transform {}", w[9])))?;
        let mine = ValueRange { vmin: w[7], vmax: w[8], transform };
        match range {
            None => range = Some(mine),
            Some(first) if first != mine => {
                return Err(Error::Mpi(format!(
                    "rank {r}'s model has the value range [{}, {}] ({}), rank 0's [{}, {}] ({}): the models are not of one series",
                    mine.vmin,
                    mine.vmax,
                    mine.transform.name(),
                    first.vmin,
                    first.vmax,
                    first.transform.name()
                )))
            }
            Some(_) => {}
        }
    }
    let range = range.ok_or_else(|| Error::Mpi("no rank sent its model".into()))?;
    Ok((frames, range))
}

/// The frame a rank's model of `piece` of `global` has: a grid piece's
/// is the piece's own; particles and cells are deposited on the lattice
/// of the piece's dims over its world box (`halo::placement_of`), whose
/// voxel size, recomputed from that box, may differ from the global one
/// in its last bits.
pub fn piece_frame(global: &IndexFrame, piece: &IndexBox, grid: bool) -> IndexFrame {
    let f = global.sub_frame(piece);
    if grid {
        return f;
    }
    let w = f.world_box();
    IndexFrame::from_bounds(f.dims, w.min, w.max).unwrap_or(f)
}

/// Voxel sizes within this many units in the last place of a piece's are
/// tried for the global lattice's (see [`piece_frame`]).
const ULPS: usize = 4;

/// The lattice of a field whose ranks' models have the frames `frames`
/// (rank order), and each rank's piece as a box of it: the lattice whose
/// pieces give every model's frame bit for bit ([`piece_frame`]). `grid`:
/// the field came as grids (its lattice is the pieces' union, exactly the
/// one the series had); otherwise it has `dims` voxels, over `bounds` when
/// given (exactly the series' lattice), else from the lowest corner of the
/// pieces, with the first voxel size tried that gives every piece: where
/// several do, it may differ from the series' own in its last bits (the
/// pieces are the same; only a particle within a rounding error of a
/// piece's face could be routed otherwise). An `Mpi` error
/// names a rank whose model is not a piece of such a lattice.
pub fn lattice_of_pieces(frames: &[IndexFrame], grid: bool, dims: [usize; 3], bounds: Option<Bounds>) -> Result<(IndexFrame, Vec<IndexBox>)> {
    if frames.is_empty() {
        return Err(Error::Mpi("no piece to rebuild a lattice from".into()));
    }
    let lowest: [f64; 3] = std::array::from_fn(|a| frames.iter().map(|f| f.bmin[a]).fold(f64::INFINITY, f64::min));
    let lattice = |gamma: f64| -> Result<IndexFrame> {
        Ok(match (grid, bounds) {
            (true, _) => {
                let dims = std::array::from_fn(|a| {
                    let ends = frames.iter().map(|f| ((f.bmin[a] - lowest[a]) * gamma).round().max(0.0) as usize + f.dims[a]);
                    ends.max().unwrap_or(1)
                });
                IndexFrame { dims, bmin: lowest, gamma }
            }
            (false, Some(b)) => IndexFrame::from_bounds(dims, b.min, b.max)?,
            (false, None) => IndexFrame { dims, bmin: lowest, gamma },
        })
    };
    // Each rank's piece of `global`, when its model is that piece's.
    let pieces_of = |global: &IndexFrame| -> std::result::Result<Vec<IndexBox>, usize> {
        let mut pieces = Vec::with_capacity(frames.len());
        for (r, f) in frames.iter().enumerate() {
            let lo = std::array::from_fn(|a| ((f.bmin[a] - global.bmin[a]) * global.gamma).round());
            let fits = (0..3).all(|a| lo[a] >= 0.0 && lo[a] as usize + f.dims[a] <= global.dims[a]);
            let piece = IndexBox { lo: lo.map(|l| l.max(0.0) as usize), hi: std::array::from_fn(|a| lo[a].max(0.0) as usize + f.dims[a]) };
            if !fits || piece_frame(global, &piece, grid) != *f {
                return Err(r);
            }
            pieces.push(piece);
        }
        Ok(pieces)
    };
    // The global voxel size: one of the ranks' own (a few distinct
    // values), or a few units in the last place from one (particles' and
    // cells' models recompute it).
    let mut bases: Vec<f64> = Vec::new();
    for f in frames {
        if !bases.contains(&f.gamma) {
            bases.push(f.gamma);
        }
    }
    let mut tried = Vec::new();
    let mut first_failure = None;
    for k in 0..=ULPS {
        for &base in &bases {
            for gamma in ulps_apart(base, k) {
                if tried.contains(&gamma) {
                    continue;
                }
                tried.push(gamma);
                let global = lattice(gamma)?;
                match pieces_of(&global) {
                    Ok(pieces) => return Ok((global, pieces)),
                    Err(r) => {
                        first_failure.get_or_insert(r);
                    }
                }
            }
        }
    }
    let rank = first_failure.unwrap_or(0);
    let f = &frames[rank];
    let global = lattice(frames[0].gamma)?;
    Err(Error::Mpi(format!(
        "rank {rank}'s model (corner {:?}, {:?} voxels of {}) is not a piece of the lattice of {:?} voxels from {:?} that the models and the configuration give; resume on the ranks, dims, bounds and halo of the run that stored them",
        f.bmin,
        f.dims,
        1.0 / f.gamma,
        global.dims,
        global.bmin
    )))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Pieces cut from `global` come back as the same boxes of `global`,
    /// or, for particles and cells, of a lattice whose voxel size differs
    /// from its in the last bits only and gives every model the same frame.
    fn round_trip(global: IndexFrame, boxes: &[IndexBox], grid: bool, dims: [usize; 3], bounds: Option<Bounds>) {
        let frames: Vec<IndexFrame> = boxes.iter().map(|b| piece_frame(&global, b, grid)).collect();
        let (again, pieces) = lattice_of_pieces(&frames, grid, dims, bounds).unwrap();
        assert_eq!(pieces, boxes);
        assert_eq!((again.dims, again.bmin), (global.dims, global.bmin));
        if grid || bounds.is_some() {
            assert_eq!(again.gamma, global.gamma);
        }
        assert!((again.gamma - global.gamma).abs() <= 4.0 * f64::EPSILON * global.gamma, "{} for {}", again.gamma, global.gamma);
        for (b, f) in boxes.iter().zip(&frames) {
            assert_eq!(piece_frame(&again, b, grid), *f);
        }
    }

    fn boxed(lo: [usize; 3], hi: [usize; 3]) -> IndexBox {
        IndexBox { lo, hi }
    }

    #[test]
    fn a_grids_lattice_is_its_pieces_union() {
        let global = IndexFrame { dims: [24, 20, 9], bmin: [-0.3, 0.1, 7.0], gamma: 1.0 / 0.037 };
        // Two slabs along x with a halo of 2, and a third rank's corner.
        let boxes = [boxed([0, 0, 0], [14, 20, 9]), boxed([10, 0, 0], [24, 20, 9]), boxed([10, 12, 3], [24, 20, 9])];
        round_trip(global, &boxes, true, [1, 1, 1], None);
    }

    #[test]
    fn particles_keep_the_configured_dims_and_bounds() {
        let bounds = Bounds { min: [0.0, -1.0, 2.0], max: [1.0, 1.0, 2.5] };
        let global = IndexFrame::from_bounds([32, 40, 16], bounds.min, bounds.max).unwrap();
        // Pieces of the data that reach no face of the box but the lowest corner.
        let boxes = [boxed([3, 0, 1], [20, 30, 9]), boxed([15, 22, 5], [28, 40, 10])];
        round_trip(global, &boxes, false, [32, 40, 16], Some(bounds));
        // Models whose voxel size differs from the lattice's in its last
        // bits (recomputed from their boxes), and the lattice found all the same.
        let (boxes, mut lattices) = two_pieces_of_lattices();
        let differs = |g: &IndexFrame| boxes.iter().filter(|b| piece_frame(g, b, false).gamma != g.gamma).count();
        let global = lattices
            .find(|g| differs(g) == boxes.len())
            .expect("a lattice none of whose pieces has its voxel size");
        round_trip(global, &boxes, false, [24, 24, 24], None);
        // Without bounds the lattice starts at the lowest piece's corner.
        let global = IndexFrame::from_bounds([32, 40, 16], [0.25, -0.5, 1.0], [1.25, 1.5, 1.75]).unwrap();
        let boxes = [boxed([0, 0, 0], [18, 25, 10]), boxed([12, 20, 6], [32, 40, 16])];
        round_trip(global, &boxes, false, [32, 40, 16], None);
    }

    /// Two pieces (particles' or cells') of 24^3 lattices whose x extent
    /// steps by 1e-4: lattices whose voxel size the pieces, recomputed
    /// from their boxes, may miss in the last bits.
    fn two_pieces_of_lattices() -> ([IndexBox; 2], impl Iterator<Item = IndexFrame>) {
        let boxes = [boxed([0, 0, 0], [13, 24, 24]), boxed([9, 0, 0], [24, 24, 24])];
        let lattices = (1..2000).map(|i| IndexFrame::from_bounds([24, 24, 24], [0.03, 0.031, 0.031], [0.99 + i as f64 * 1e-4, 0.969, 0.969]).unwrap());
        (boxes, lattices)
    }

    /// Where no piece's own voxel size gives every piece back (each was
    /// recomputed from its box, and none is the lattice's), the search
    /// goes on a few units in the last place from them and finds one that
    /// does. Such lattices exist (the test finds some).
    #[test]
    fn a_voxel_size_none_of_the_pieces_has_is_searched_for() {
        let (boxes, lattices) = two_pieces_of_lattices();
        // Whether the lattice of voxel size `gamma` from g's corner gives every frame of `frames`.
        let gives = |g: &IndexFrame, frames: &[IndexFrame], gamma: f64| {
            let l = IndexFrame { gamma, ..*g };
            boxes.iter().zip(frames).all(|(b, f)| piece_frame(&l, b, false) == *f)
        };
        let hard: Vec<IndexFrame> = lattices
            .filter(|g| {
                let frames: Vec<IndexFrame> = boxes.iter().map(|b| piece_frame(g, b, false)).collect();
                frames.iter().all(|f| !gives(g, &frames, f.gamma))
            })
            .take(3)
            .collect();
        assert!(!hard.is_empty(), "no lattice where every piece's own voxel size fails");
        for g in hard {
            round_trip(g, &boxes, false, [24, 24, 24], None);
        }
    }

    #[test]
    fn pieces_of_another_lattice_are_refused() {
        let global = IndexFrame { dims: [16, 16, 16], bmin: [0.0; 3], gamma: 8.0 };
        let mut frames = vec![global.sub_frame(&boxed([0, 0, 0], [10, 16, 16])), global.sub_frame(&boxed([6, 0, 0], [16, 16, 16]))];
        // Moved by a third of a voxel: not on the lattice.
        frames[1].bmin[1] += 1.0 / 24.0;
        let e = lattice_of_pieces(&frames, true, [1; 3], None).unwrap_err();
        assert!(e.to_string().contains("rank 1's model"), "{e}");
        // Another voxel size.
        frames[1] = IndexFrame { gamma: 4.0, ..global.sub_frame(&boxed([6, 0, 0], [16, 16, 16])) };
        assert!(lattice_of_pieces(&frames, true, [1; 3], None).unwrap_err().to_string().contains("voxels of 0.25"));
        // Particles' pieces outside the configured box.
        frames[1] = global.sub_frame(&boxed([6, 0, 0], [16, 16, 16]));
        let small = Bounds { min: [0.0; 3], max: [1.5, 2.0, 2.0] };
        let e = lattice_of_pieces(&frames, false, [12, 16, 16], Some(small)).unwrap_err();
        assert!(e.to_string().contains("rank 1's model") && e.to_string().contains("resume on the ranks"), "{e}");
    }

    #[test]
    fn the_wire_carries_frames_and_one_range() {
        let range = ValueRange::new(-2.0, 3.5, Transform::Log10).unwrap();
        let frames = [IndexFrame { dims: [3, 4, 5], bmin: [0.5, -1.0, 2.0], gamma: 3.0 }, IndexFrame { dims: [7, 1, 2], bmin: [0.0; 3], gamma: 3.0 }];
        let all: Vec<f64> = frames.iter().flat_map(|f| to_wire(f, &range)).collect();
        let (got, r) = from_wire(&all).unwrap();
        assert_eq!(got, frames);
        assert_eq!(r, range);
        let other = ValueRange::new(-2.0, 3.0, Transform::Log10).unwrap();
        let mixed: Vec<f64> = to_wire(&frames[0], &range).into_iter().chain(to_wire(&frames[1], &other)).collect();
        assert!(from_wire(&mixed).unwrap_err().to_string().contains("rank 1's model has the value range [-2, 3]"));
    }
}
