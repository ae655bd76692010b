//! Routing a decomposed domain's data to its pieces, without MPI: P "ranks"
//! in one process split their parts, each piece joins what it receives, and
//! its deposit must equal the serial deposit of all the data on the piece's
//! voxels; the step index round-trips and refuses what is not one.

use gsenc::field::{Grid, IndexFrame, Transform, ValueRange};
use gsenc::domain::halo::{data_bounds, exchange_bytes, fill, join, joined_bytes, plan, Kind};
use gsenc::field::IndexBox;
use gsenc::input::cells::{CellSize, Cells};
use gsenc::input::particles::Particles;
use gsenc::input::prepare::{prepare_cells, prepare_particles, Placement, RangeSpec};
use gsenc::input::StepData;

fn field(x: [f64; 3]) -> f32 {
    let r2: f64 = (0..3).map(|a| (x[a] - [0.45, 0.55, 0.5][a]).powi(2)).sum();
    (-r2 / 0.03).exp() as f32 + 0.1 * x[0] as f32
}

/// What `data` sends each piece: `plan` counts, `fill` writes one buffer,
/// cut here by the counts. The buffer starts as NaN and no input is NaN,
/// so a slot `fill` leaves unwritten (a count too large) shows.
fn split(data: &StepData, global: &IndexFrame, pieces: &[IndexBox]) -> gsenc::Result<Vec<Vec<f64>>> {
    let routing = plan(data, global, pieces)?;
    let flat = fill(data, global, pieces, &routing);
    assert_eq!(flat.len(), routing.total());
    assert!(flat.iter().all(|v| !v.is_nan()), "a value of the split was never written");
    let mut rest = &flat[..];
    Ok(routing.lens().iter().map(|&n| {
        let (piece, tail) = rest.split_at(n);
        rest = tail;
        piece.to_vec()
    }).collect())
}

/// The memory `exchange_bytes` predicts is what the buffers and the joined
/// data hold: the values sent and received as f64, and the join's own
/// `bytes()`, counted from its arrays.
fn check_exchange_bytes(kind: Kind, sent: &[Vec<Vec<f64>>], p: usize, piece: &IndexBox, joined: &StepData) {
    let out: usize = sent[p].iter().map(Vec::len).sum();
    let inn: usize = sent.iter().map(|s| s[p].len()).sum();
    assert_eq!(joined_bytes(kind, inn, piece), joined.bytes() as u64, "piece {p}");
    let want = 8 * inn as u64 + (joined.bytes() as u64).max(8 * out as u64);
    assert_eq!(exchange_bytes(kind, out, inn, piece), want, "piece {p}");
}

/// Pseudo-random points in the unit cube.
fn points(n: usize) -> Vec<[f64; 3]> {
    let mut s = 0x9e37_79b9_7f4a_7c15u64;
    let mut next = || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s >> 11) as f64 / (1u64 << 53) as f64
    };
    (0..n).map(|_| [next(), next(), next()]).collect()
}

/// The items of `all` at the indices `mine` (one rank's part).
fn pick<T: Copy>(all: &[T], mine: &[usize]) -> Vec<T> {
    mine.iter().map(|&j| all[j]).collect()
}

/// Rank r of 4 owns the quarter (x < 1/2 or not, y < 1/2 or not).
fn owner(x: &[f64; 3]) -> usize {
    (x[0] >= 0.5) as usize + 2 * (x[1] >= 0.5) as usize
}

/// Splits each rank's part, joins per piece, and compares each piece's
/// deposit with the serial reference on its voxels.
/// `allowed` is the fraction of voxels that may differ: cell stamps whose
/// edge falls exactly on a voxel boundary can round to the other side in a
/// piece's frame (its corner is the global one moved by whole voxels, in
/// floating point).
/// A piece reaches past the half of the lattice by at most `reach` voxels
/// along x (its halo, and what its data's box overhangs the quarter).
fn check_pieces(parts: Vec<StepData>, global_ref: &Grid, global: &IndexFrame, halo: usize, reach: usize, allowed: f64, prepare: &dyn Fn(&StepData) -> Grid) {
    let pieces: Vec<IndexBox> = parts
        .iter()
        .map(|d| {
            let b = data_bounds(d);
            global.covering_box(b.min, b.max, halo)
        })
        .collect();
    let kind = Kind::of(&parts[0]);
    let sent: Vec<Vec<Vec<f64>>> = parts.iter().map(|d| split(d, global, &pieces).unwrap()).collect();
    for (p, piece) in pieces.iter().enumerate() {
        let received: Vec<&[f64]> = sent.iter().map(|s| s[p].as_slice()).collect();
        let joined = join(kind, &received, global, piece).unwrap();
        check_exchange_bytes(kind, &sent, p, piece, &joined);
        let reference = prepare(&joined);
        assert_eq!(reference.dims, piece.dims());
        let mut differing = 0;
        for (i, &v) in reference.values.iter().enumerate() {
            let [x, y, z] = reference.coords(i);
            let g = global_ref.values[global_ref.index(x + piece.lo[0], y + piece.lo[1], z + piece.lo[2])];
            differing += ((v - g).abs() > 1e-5) as usize;
        }
        let fraction = differing as f64 / reference.values.len() as f64;
        println!("piece {p}: {differing} voxels ({fraction:.4}) differ from the serial deposit");
        assert!(fraction <= allowed, "piece {p} ({:?}..{:?}): {differing} voxels differ from the serial deposit", piece.lo, piece.hi);
        // The halo reaches past the rank's own quarter, into its neighbours'.
        assert!(piece.dims()[0] > global.dims[0] / 2 && piece.dims()[0] <= global.dims[0] / 2 + reach, "piece {p}: {:?}", piece);
    }
}

#[test]
fn particle_pieces_deposit_the_serial_reference() {
    let pos = points(6000);
    // Wide kernels (5.8 voxels: the routing must send a particle as far as
    // its support reaches) and ones narrower than a voxel (put into their
    // nearest voxel: it must be sent where that voxel is).
    let h: Vec<f64> = (0..pos.len()).map(|j| if j % 2 == 0 { 0.12 } else { 0.015 }).collect();
    let mass: Vec<f32> = (0..pos.len()).map(|j| 0.5 + (j % 3) as f32 * 0.25).collect();
    let values: Vec<f32> = pos.iter().map(|&p| field(p)).collect();
    let range = ValueRange::from_data(&values, Transform::Linear).unwrap();
    let p = Particles { positions: &pos, smoothing_length: &h, mass: &mass, values: &values };
    let serial = prepare_particles(&p, &Placement::new([24; 3], None), &RangeSpec::Fixed(range)).unwrap();
    let parts: Vec<StepData> = (0..4)
        .map(|r| {
            let mine: Vec<usize> = (0..pos.len()).filter(|&j| owner(&pos[j]) == r).collect();
            StepData::Particles {
                positions: pick(&pos, &mine),
                smoothing_length: pick(&h, &mine),
                mass: pick(&mass, &mine),
                values: pick(&values, &mine),
                placement: Placement::new([24; 3], None),
            }
        })
        .collect();
    check_pieces(parts, &serial.reference, &serial.frame, 3, 4, 0.0, &|d| match d {
        StepData::Particles { positions, smoothing_length, mass, values, placement } => {
            let p = Particles { positions, smoothing_length, mass, values };
            prepare_particles(&p, placement, &RangeSpec::Fixed(range)).unwrap().reference
        }
        _ => unreachable!(),
    });
}

#[test]
fn cell_pieces_deposit_the_serial_reference() {
    // Cells of 1/12, the ones near the blob split in eight.
    let (mut centres, mut edges) = (vec![], vec![]);
    for c in (0..12 * 12 * 12).map(|i| [(i % 12) as f64, ((i / 12) % 12) as f64, (i / 144) as f64].map(|v| (v + 0.5) / 12.0)) {
        if field(c) > 0.5 {
            for o in 0..8 {
                centres.push(std::array::from_fn(|a| c[a] + (((o >> a) & 1) as f64 - 0.5) / 24.0));
                edges.push([1.0 / 24.0; 3]);
            }
        } else {
            centres.push(c);
            edges.push([1.0 / 12.0; 3]);
        }
    }
    let values: Vec<f32> = centres.iter().map(|&c| field(c)).collect();
    let range = ValueRange::from_data(&values, Transform::Linear).unwrap();
    // The same cubes given by their edges and by their volumes.
    let volumes: Vec<f64> = edges.iter().map(|e| e[0] * e[1] * e[2]).collect();
    for by_volume in [false, true] {
        fn size<'a>(by_volume: bool, edges: &'a [[f64; 3]], volumes: &'a [f64]) -> CellSize<'a> {
            if by_volume { CellSize::Volumes(volumes) } else { CellSize::Edges(edges) }
        }
        let cells = Cells { centres: &centres, size: size(by_volume, &edges, &volumes), values: &values };
        let serial = prepare_cells(&cells, &Placement::new([24; 3], None), &RangeSpec::Fixed(range)).unwrap();
        let parts: Vec<StepData> = (0..4)
            .map(|r| {
                let mine: Vec<usize> = (0..centres.len()).filter(|&j| owner(&centres[j]) == r).collect();
                StepData::Cells {
                    centres: pick(&centres, &mine),
                    edges: if by_volume { Vec::new() } else { pick(&edges, &mine) },
                    volumes: if by_volume { pick(&volumes, &mine) } else { Vec::new() },
                    values: pick(&values, &mine),
                    placement: Placement::new([24; 3], None),
                }
            })
            .collect();
        assert_eq!(Kind::of(&parts[0]), if by_volume { Kind::CellVolumes } else { Kind::CellBoxes });
        check_pieces(parts, &serial.reference, &serial.frame, 3, 4, 0.08, &|d| match d {
            StepData::Cells { centres, edges, volumes, values, placement } => {
                let c = Cells { centres, size: size(by_volume, edges, volumes), values };
                prepare_cells(&c, placement, &RangeSpec::Fixed(range)).unwrap().reference
            }
            _ => unreachable!(),
        });
    }
}

/// Cells of random sizes (0.16 voxel to three, most under one) at random places, so that no
/// stamp's edge falls on a voxel boundary: every piece's deposit is the
/// serial one on every voxel. A cell must be sent as far as its stamp
/// reaches: its edge and half a voxel of rounding. A cell under half a
/// voxel within half a voxel inside a piece's face towards another piece
/// can stamp only the voxel beyond the face: the piece must not put it
/// into its nearest voxel, as it would at the domain's edge.
#[test]
fn cell_pieces_off_the_lattice_deposit_the_serial_reference() {
    let centres = points(6000);
    let edges: Vec<[f64; 3]> = points(12000)[6000..].iter().map(|r| [0.008 + 0.15 * r[0].powi(3); 3]).collect();
    let values: Vec<f32> = centres.iter().map(|&c| field(c)).collect();
    let range = ValueRange::from_data(&values, Transform::Linear).unwrap();
    let cells = Cells { centres: &centres, size: CellSize::Edges(&edges), values: &values };
    let placement = Placement::new([24; 3], None);
    let serial = prepare_cells(&cells, &placement, &RangeSpec::Fixed(range)).unwrap();
    let parts: Vec<StepData> = (0..4)
        .map(|r| {
            let mine: Vec<usize> = (0..centres.len()).filter(|&j| owner(&centres[j]) == r).collect();
            StepData::Cells {
                centres: pick(&centres, &mine),
                edges: pick(&edges, &mine),
                volumes: Vec::new(),
                values: pick(&values, &mine),
                placement,
            }
        })
        .collect();
    check_pieces(parts, &serial.reference, &serial.frame, 1, 6, 0.0, &|d| match d {
        StepData::Cells { centres, edges, values, placement, .. } => {
            let c = Cells { centres, size: CellSize::Edges(edges), values };
            prepare_cells(&c, placement, &RangeSpec::Fixed(range)).unwrap().reference
        }
        _ => unreachable!(),
    });
}

#[test]
fn grid_pieces_are_the_global_grid_with_halo_and_must_tile_it() {
    let n = 20;
    let global = IndexFrame { dims: [n; 3], bmin: [0.0; 3], gamma: n as f64 };
    let values: Vec<f32> = (0..n * n * n).map(|i| i as f32).collect();
    let whole = Grid::new([n; 3], values).unwrap();
    // Two ranks, cut at x = 8 (uneven).
    let part = |x0: usize, x1: usize| {
        let mut v = vec![];
        for k in 0..n {
            for j in 0..n {
                v.extend((x0..x1).map(|i| whole.values[whole.index(i, j, k)]));
            }
        }
        let dims = [x1 - x0, n, n];
        StepData::Grid { grid: Grid::new(dims, v).unwrap(), frame: IndexFrame { dims, bmin: [x0 as f64 / n as f64, 0.0, 0.0], gamma: n as f64 } }
    };
    let parts = [part(0, 8), part(8, n)];
    let pieces = [IndexBox { lo: [0, 0, 0], hi: [11, n, n] }, IndexBox { lo: [5, 0, 0], hi: [n, n, n] }];
    let sent: Vec<Vec<Vec<f64>>> = parts.iter().map(|d| split(d, &global, &pieces).unwrap()).collect();
    for (p, piece) in pieces.iter().enumerate() {
        let received: Vec<&[f64]> = sent.iter().map(|s| s[p].as_slice()).collect();
        let joined = join(Kind::Grid, &received, &global, piece).unwrap();
        check_exchange_bytes(Kind::Grid, &sent, p, piece, &joined);
        let StepData::Grid { grid, frame } = joined else { panic!() };
        assert_eq!(frame, global.sub_frame(piece));
        for (i, &v) in grid.values.iter().enumerate() {
            let [x, y, z] = grid.coords(i);
            assert_eq!(v, whole.values[whole.index(x + piece.lo[0], y, z)], "piece {p} voxel {x},{y},{z}");
        }
    }
    // Without a halo each rank's grid is its piece: a grid that only abuts
    // a piece sends it nothing (not even an empty block).
    let own = [IndexBox { lo: [0, 0, 0], hi: [8, n, n] }, IndexBox { lo: [8, 0, 0], hi: [n, n, n] }];
    for (r, d) in parts.iter().enumerate() {
        let out = split(d, &global, &own).unwrap();
        assert_eq!(out[r].len(), 6 + d.bytes() / 4, "rank {r} sends its own piece its grid and one header");
        assert!(out[1 - r].is_empty(), "rank {r} sent {} values to a piece it only abuts", out[1 - r].len());
    }
    // Rank 1's grid alone does not cover piece 0: refused, with the count.
    let lone: Vec<&[f64]> = vec![&sent[1][0]];
    let Err(err) = join(Kind::Grid, &lone, &global, &pieces[0]) else { panic!("an uncovered piece was joined") };
    let err = err.to_string();
    assert!(err.contains(&format!("{} voxels", 8 * n * n)) && err.contains("tile"), "{err}");
    // A block that reaches outside the piece it was sent to, or is shorter
    // than its box, is refused (not written out of bounds).
    // Piece 1 is voxels 5.. along x: voxels 0..12 of a row start before
    // it; voxels 5..6 of two rows are two values, not one.
    let outside = [[0.0, 0.0, 0.0, 12.0, 1.0, 1.0].as_slice(), &[1.0; 12]].concat();
    let short = [5.0, 0.0, 0.0, 6.0, 2.0, 1.0, 1.0];
    for buf in [outside.as_slice(), &short] {
        let Err(err) = join(Kind::Grid, &[buf], &global, &pieces[1]) else { panic!("a malformed block {buf:?} was joined") };
        assert!(err.to_string().contains("malformed"), "{err}");
    }
    // A grid off the lattice is refused when split.
    let StepData::Grid { grid, mut frame } = part(0, 8) else { panic!() };
    frame.bmin[1] += 0.3 / n as f64;
    let Err(err) = split(&StepData::Grid { grid, frame }, &global, &pieces) else { panic!("a grid off the lattice was split") };
    assert!(err.to_string().contains("lattice"), "{err}");
}

/// Pieces are fixed at a field's first step; at a later one a rank may hold
/// no particle (rank 3 here: its quarter emptied), so its piece holds no
/// particle's centre, only what its neighbours' wide kernels reach of it,
/// and with narrow kernels nothing at all. Its deposit is still the serial
/// deposit of all the particles on its voxels (zero where nothing reaches),
/// seeded from its voxels (no samples). It failed before ("none of the
/// items lies inside the bounds"), and the rank's empty part was refused.
#[test]
fn a_piece_that_holds_no_particle_deposits_what_reaches_it() {
    let first = points(6000);
    let part = |pos: &[[f64; 3]], h: f64, r: usize| {
        let mine: Vec<usize> = (0..pos.len()).filter(|&j| owner(&pos[j]) == r).collect();
        let positions = pick(pos, &mine);
        let n = positions.len();
        let values = positions.iter().map(|&p| field(p)).collect();
        StepData::Particles { positions, smoothing_length: vec![h; n], mass: vec![1.0; n], values, placement: Placement::new([24; 3], None) }
    };
    let global = IndexFrame::from_bounds([24; 3], [0.0; 3], [1.0; 3]).unwrap();
    let pieces: Vec<IndexBox> = (0..4)
        .map(|r| {
            // No halo: piece 3 is rank 3's quarter alone.
            let b = data_bounds(&part(&first, 0.05, r));
            global.covering_box(b.min, b.max, 0)
        })
        .collect();
    let range = ValueRange::new(0.0, 1.2, Transform::Linear).unwrap();
    for (h, reaches) in [(0.12, true), (0.004, false)] {
        // Narrow kernels a few voxels away from the piece, which the routing
        // (sending an item to every piece its support box may touch) leaves out.
        let margin = if reaches { 0.5 } else { 0.4 };
        let later: Vec<[f64; 3]> = first.iter().copied().filter(|p| p[0] < margin || p[1] < margin).collect();
        let parts: Vec<StepData> = (0..4).map(|r| part(&later, h, r)).collect();
        let StepData::Particles { positions, .. } = &parts[3] else { unreachable!() };
        assert!(positions.is_empty());
        let values: Vec<f32> = later.iter().map(|&p| field(p)).collect();
        let (hs, masses) = (vec![h; later.len()], vec![1.0; later.len()]);
        let all = Particles { positions: &later, smoothing_length: &hs, mass: &masses, values: &values };
        let serial = prepare_particles(&all, &Placement::new([24; 3], Some(global.world_box())), &RangeSpec::Fixed(range)).unwrap();
        let sent: Vec<Vec<Vec<f64>>> = parts.iter().map(|d| split(d, &global, &pieces).unwrap()).collect();
        let received: Vec<&[f64]> = sent.iter().map(|s| s[3].as_slice()).collect();
        let StepData::Particles { positions, smoothing_length, mass, values, placement } = join(Kind::Particles, &received, &global, &pieces[3]).unwrap() else {
            unreachable!()
        };
        assert_eq!(positions.is_empty(), !reaches, "h {h}: {} particles reach the empty piece", positions.len());
        let p = Particles { positions: &positions, smoothing_length: &smoothing_length, mass: &mass, values: &values };
        let prepared = prepare_particles(&p, &placement, &RangeSpec::Fixed(range)).unwrap();
        assert!(prepared.samples.is_none(), "h {h}: no particle's centre lies in the piece");
        let piece = pieces[3];
        let mut reached = 0;
        for (i, &v) in prepared.reference.values.iter().enumerate() {
            let [x, y, z] = prepared.reference.coords(i);
            let g = serial.reference.values[serial.reference.index(x + piece.lo[0], y + piece.lo[1], z + piece.lo[2])];
            assert!((v - g).abs() <= 1e-5, "h {h}: voxel {:?} of the piece is {v}, the serial deposit {g}", [x, y, z]);
            reached += (v != 0.0) as usize;
        }
        assert_eq!(reached > 0, reaches, "h {h}: {reached} voxels reached");
    }
}
