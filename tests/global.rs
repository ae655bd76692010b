//! One global field from the models of a domain's pieces: the merged model
//! places each piece exactly, blends across the cut without a seam, and
//! (with an 8-voxel halo) scores within 1 dB of one model of the whole
//! domain with the same total budget. Pieces that do not share a lattice, a voxel
//! size or a range are refused.

mod common;
use common::blobs;
use gsenc::backend::cpu::CpuBackend;
use gsenc::encode::{encode, EncodeConfig, Schedule};
use gsenc::input::Target;
use gsenc::field::{Grid, IndexFrame, Transform, ValueRange};
use gsenc::domain::pieces::merge;
use gsenc::field::IndexBox;
use gsenc::model::metrics::voxel_psnr;
use gsenc::model::{Model, ModelMeta};
use gsenc::Error;

const DIMS: [usize; 3] = [40, 24, 20];
/// The cut along x, and the halo each piece keeps beyond it. The halo
/// decides the seam: 3 voxels scored 2.5 dB below one model of the whole,
/// 5 voxels 1.1 dB, 6 voxels 0.6 dB, 8 voxels 0.4 dB (docs/DESIGN.md).
const CUT: usize = 20;
const HALO: usize = 8;

fn range() -> ValueRange {
    ValueRange::new(0.0, 1.0, Transform::Linear).unwrap()
}

/// Cells `x0..x1` of `g` along x.
fn slab(g: &Grid, x0: usize, x1: usize) -> Grid {
    let [nx, ny, nz] = g.dims;
    let mut v = Vec::with_capacity((x1 - x0) * ny * nz);
    for k in 0..nz {
        for j in 0..ny {
            v.extend_from_slice(&g.values[(k * ny + j) * nx + x0..(k * ny + j) * nx + x1]);
        }
    }
    Grid::new([x1 - x0, ny, nz], v).unwrap()
}

fn encode_model(g: &Grid, x0: usize, budget: usize) -> Model {
    let mut cfg = EncodeConfig::new(budget, Schedule::Short);
    cfg.iterations = Some(400);
    cfg.points = Some(2048);
    let out = encode(&Target { reference: g, samples: g }, &cfg, None, &mut CpuBackend::new(), &mut |_| {}).unwrap();
    let frame = IndexFrame { dims: g.dims, bmin: [x0 as f64 * 0.5, -1.0, 2.0], gamma: 2.0 };
    let mut meta = ModelMeta::new(frame, range());
    meta.field = "rho".into();
    Model { meta, params: out.params, support: None }
}

/// `model` (of the lattice `global`) re-expressed in the frame of its box
/// `b`: the same primitives, their centres moved by the box's corner.
fn in_piece(model: &Model, global: &IndexFrame, b: &IndexBox) -> Model {
    let mut m = model.clone();
    m.meta.frame = global.sub_frame(b);
    for q in &mut m.params {
        (0..3).for_each(|a| q[a] -= b.lo[a] as f32);
    }
    m
}

fn mse(a: &[f32], b: &[f32]) -> f64 {
    a.iter().zip(b).map(|(x, y)| ((x - y) as f64).powi(2)).sum::<f64>() / a.len() as f64
}

#[test]
fn merged_pieces_decode_one_seamless_field() {
    let whole = blobs(DIMS, 7, 5);
    let (a, b) = (slab(&whole, 0, CUT + HALO), slab(&whole, CUT - HALO, DIMS[0]));
    let budget = 600;
    let pa = encode_model(&a, 0, budget / 2);
    let pb = encode_model(&b, CUT - HALO, budget / 2);
    let single = encode_model(&whole, 0, budget);
    let global = merge(&[pa.clone(), pb.clone()]).unwrap();
    assert_eq!(global.meta.frame.dims, DIMS);
    assert_eq!(global.len(), budget);
    let mut cpu = CpuBackend::new();
    let decoded = global.decode(&mut cpu, None).unwrap();
    let single_decoded = single.decode(&mut cpu, None).unwrap();
    let (merged_psnr, single_psnr) = (voxel_psnr(&decoded.values, &whole.values), voxel_psnr(&single_decoded.values, &whole.values));
    // Within 1 dB of one model of the whole with the same budget.
    assert!(merged_psnr > single_psnr - 1.0, "merged pieces {merged_psnr:.2} dB, one model {single_psnr:.2} dB");

    // No seam: within two voxels of the cut, the merged pieces err no more
    // than the model of the whole domain does there (the cut runs through
    // the blobs, so that band is harder than the rest for both).
    let band = |values: &[f32]| {
        let (mut got, mut want) = (vec![], vec![]);
        let [nx, ny, nz] = DIMS;
        for k in 0..nz {
            for j in 0..ny {
                for i in CUT - 2..CUT + 2 {
                    got.push(values[(k * ny + j) * nx + i]);
                    want.push(whole.values[(k * ny + j) * nx + i]);
                }
            }
        }
        mse(&got, &want)
    };
    let (merged_cut, single_cut) = (band(&decoded.values), band(&single_decoded.values));
    assert!(merged_cut <= 1.25 * single_cut, "error at the cut: merged pieces {merged_cut:.3e}, one model {single_cut:.3e}");

    // One piece's region of the global lattice.
    let bb = global.meta.frame.box_of(&pb.meta.frame).unwrap();
    assert_eq!((bb.lo, bb.hi), ([CUT - HALO, 0, 0], DIMS));
}

#[test]
fn merging_moves_each_piece_into_the_global_frame_exactly() {
    // Two pieces far apart (beyond any kernel's reach): each piece's region
    // of the global decode is that piece's own decode.
    let (a, b) = (blobs([16, 12, 10], 11, 3), blobs([12, 12, 10], 12, 3));
    let pa = encode_model(&a, 0, 80);
    let pb = encode_model(&b, 70, 80); // 70 voxels along x from piece A's origin
    let global = merge(&[pa.clone(), pb.clone()]).unwrap();
    assert_eq!(global.meta.frame.dims, [82, 12, 10]);
    // In either order the same frame; the merged model is rank 0's and
    // keeps no piece's encode PSNR (it scored only its piece).
    let mut ranked = pb.clone();
    (ranked.meta.rank, ranked.meta.encode_psnr) = (1, Some(30.0));
    let swapped = merge(&[ranked, pa.clone()]).unwrap();
    assert_eq!((swapped.meta.frame, swapped.meta.rank, swapped.meta.encode_psnr), (global.meta.frame, 0, None));
    let mut cpu = CpuBackend::new();
    for p in [&pa, &pb] {
        let region = global.meta.frame.box_of(&p.meta.frame).unwrap();
        let part = global.decode_box(&mut cpu, global.meta.frame.dims, region).unwrap();
        let alone = p.decode(&mut cpu, None).unwrap();
        assert_eq!(part.dims, alone.dims);
        let worst = part.values.iter().zip(&alone.values).map(|(x, y)| (x - y).abs()).fold(0f32, f32::max);
        assert!(worst < 1e-5, "a piece moved into the global frame decodes {worst} away from itself");
    }
}

#[test]
fn pieces_off_one_lattice_are_refused() {
    let g = blobs([10, 8, 6], 3, 2);
    let p = encode_model(&g, 0, 40);
    let mut moved = p.clone();
    moved.meta.frame.bmin[1] += 0.25; // half a voxel (gamma 2)
    assert!(matches!(merge(&[p.clone(), moved]), Err(Error::InvalidArgument(m)) if m.contains("lattice")));
    let mut finer = p.clone();
    finer.meta.frame.gamma = 4.0;
    assert!(matches!(merge(&[p.clone(), finer]), Err(Error::InvalidArgument(m)) if m.contains("voxel size")));
    let mut other = p.clone();
    other.meta.range = ValueRange::new(0.0, 2.0, Transform::Linear).unwrap();
    assert!(matches!(merge(&[p.clone(), other]), Err(Error::InvalidArgument(m)) if m.contains("range")));
    let mut later = p.clone();
    later.meta.step = 4;
    assert!(matches!(merge(&[p.clone(), later]), Err(Error::InvalidArgument(_))));
    assert!(merge(&[]).is_err());
    assert_eq!(merge(std::slice::from_ref(&p)).unwrap().params, p.params);
}

/// One model re-expressed in two pieces' frames, overlapping (halo 4) or
/// abutting (halo 0): each piece decodes to the whole model there, so the
/// blend must reproduce the model's own decode exactly (weights sum to
/// one), at the reference dims and resampled (coarser; finer, whose voxels
/// within half a voxel of the domain's faces lie outside every piece's
/// voxel centres; odd, with a voxel centre on the abutting pieces' common
/// face), whole, in slabs and at the voxels' centres as points.
#[test]
fn blend_of_a_model_cut_into_pieces_is_the_model() {
    use gsenc::domain::pieces::{blend, blend_points};
    let whole = blobs(DIMS, 7, 5);
    let model = encode_model(&whole, 0, 200);
    let global = model.meta.frame;
    let cut = |halo: usize| [IndexBox { lo: [0, 0, 0], hi: [CUT + halo, DIMS[1], DIMS[2]] }, IndexBox { lo: [CUT - halo, 0, 0], hi: DIMS }];
    for (halo, dims) in [(4, DIMS), (4, [33, 17, 11]), (4, [81, 49, 41]), (0, DIMS), (0, [41, 24, 20]), (0, [81, 49, 41])] {
        let boxes = cut(halo);
        let pieces: Vec<Model> = boxes.iter().map(|b| in_piece(&model, &global, b)).collect();
        let direct = model.decode(&mut CpuBackend::new(), Some(dims)).unwrap();
        let blended = blend(&global, &pieces, &boxes, halo, dims, IndexBox::whole(dims), &mut CpuBackend::new()).unwrap();
        let worst = direct.values.iter().zip(&blended.values).map(|(a, b)| (a - b).abs()).fold(0f32, f32::max);
        assert!(worst < 1e-5, "halo {halo}, dims {dims:?}: blend differs from the model by {worst}");
        let step: [f64; 3] = std::array::from_fn(|a| DIMS[a] as f64 / dims[a] as f64 / global.gamma);
        let centres: Vec<[f64; 3]> = (0..direct.values.len()).map(|i| std::array::from_fn(|a| global.bmin[a] + (direct.coords(i)[a] as f64 + 0.5) * step[a])).collect();
        let at = blend_points(&global, &pieces, &boxes, halo, &centres, &mut CpuBackend::new()).unwrap();
        let worst = direct.values.iter().zip(&at).map(|(a, b)| (a - b).abs()).fold(0f32, f32::max);
        assert!(worst < 1e-5, "halo {halo}, dims {dims:?}: the blend at points differs from the model by {worst}");
        // A slab of z layers is the same voxels of the whole.
        let slab = IndexBox { lo: [3, 2, 4], hi: [dims[0] - 1, dims[1], 7] };
        let part = blend(&global, &pieces, &boxes, halo, dims, slab, &mut CpuBackend::new()).unwrap();
        for (i, &v) in part.values.iter().enumerate() {
            let [x, y, z] = part.coords(i);
            assert!((v - blended.values[blended.index(x + 3, y + 2, z + 4)]).abs() < 1e-6);
        }
    }
}

/// Two different pieces: where only one has weight the blend is that
/// piece's own decode; across the overlap it is the two weighted by their
/// ramps (docs/METHOD.md), computed here from the formula.
#[test]
fn blend_uses_each_piece_only_inside_its_box() {
    use gsenc::domain::pieces::blend;
    let whole = blobs(DIMS, 7, 5);
    let a = encode_model(&slab(&whole, 0, CUT + 6), 0, 150);
    let b = encode_model(&slab(&whole, CUT - 6, DIMS[0]), CUT - 6, 150);
    let global = IndexFrame { dims: DIMS, bmin: a.meta.frame.bmin, gamma: 2.0 };
    let boxes = [IndexBox { lo: [0, 0, 0], hi: [CUT + 6, DIMS[1], DIMS[2]] }, IndexBox { lo: [CUT - 6, 0, 0], hi: DIMS }];
    let g = blend(&global, &[a.clone(), b.clone()], &boxes, 6, DIMS, IndexBox::whole(DIMS), &mut CpuBackend::new()).unwrap();
    let da = a.decode(&mut CpuBackend::new(), None).unwrap();
    let db = b.decode(&mut CpuBackend::new(), None).unwrap();
    for k in 0..DIMS[2] {
        for j in 0..DIMS[1] {
            // Only a's box: a alone.
            assert_eq!(g.values[g.index(5, j, k)], da.values[da.index(5, j, k)]);
            // Only b's box: b alone.
            assert_eq!(g.values[g.index(CUT + 10, j, k)], db.values[db.index(CUT + 10 - (CUT - 6), j, k)]);
            // In the overlap, the two by their ramps: a's falls from 1 to 0
            // across the 6 voxels before its box's end (the extent's edge
            // CUT + 5.5), b's rises from 0 after its box's start (CUT - 6.5).
            for x in CUT - 6..CUT + 6 {
                let (va, vb) = (da.values[da.index(x, j, k)] as f64, db.values[db.index(x - (CUT - 6), j, k)] as f64);
                let wa = ((CUT as f64 + 5.5 - x as f64) / 6.0).clamp(0.0, 1.0);
                let wb = ((x as f64 - (CUT as f64 - 6.5)) / 6.0).clamp(0.0, 1.0);
                let want = (wa * va + wb * vb) / (wa + wb);
                let v = g.values[g.index(x, j, k)] as f64;
                assert!((v - want).abs() < 1e-6, "x {x}: {v}, want {want} of {va} (weight {wa}) and {vb} (weight {wb})");
            }
        }
    }
}

/// Two different pieces without a halo only abut: each voxel is its own
/// piece's decode (none reaches a neighbour's voxel, where its model was
/// never fitted); a point on their common face is the mean of the two, and
/// a point on the domain's far face is the last piece's value, not 0.
#[test]
fn abutting_pieces_meet_at_their_face() {
    use gsenc::domain::pieces::{blend, blend_points};
    let whole = blobs(DIMS, 7, 5);
    let a = encode_model(&slab(&whole, 0, CUT), 0, 150);
    let b = encode_model(&slab(&whole, CUT, DIMS[0]), CUT, 150);
    let global = IndexFrame { dims: DIMS, bmin: a.meta.frame.bmin, gamma: 2.0 };
    let boxes = [IndexBox { lo: [0, 0, 0], hi: [CUT, DIMS[1], DIMS[2]] }, IndexBox { lo: [CUT, 0, 0], hi: DIMS }];
    let pieces = [a.clone(), b.clone()];
    let g = blend(&global, &pieces, &boxes, 0, DIMS, IndexBox::whole(DIMS), &mut CpuBackend::new()).unwrap();
    let da = a.decode(&mut CpuBackend::new(), None).unwrap();
    let db = b.decode(&mut CpuBackend::new(), None).unwrap();
    for k in 0..DIMS[2] {
        for j in 0..DIMS[1] {
            assert_eq!(g.values[g.index(CUT - 1, j, k)], da.values[da.index(CUT - 1, j, k)], "the last voxel of a, {j} {k}");
            assert_eq!(g.values[g.index(CUT, j, k)], db.values[db.index(0, j, k)], "the first voxel of b, {j} {k}");
        }
    }
    // World points at x = the common face and the domain's far face (exact
    // in binary: the corner's x is 0, two voxels a unit), y and z at voxel
    // centres.
    let (y, z) = (global.bmin[1] + 12.5 / 2.0, global.bmin[2] + 10.5 / 2.0);
    let face = [global.bmin[0] + CUT as f64 / 2.0, y, z];
    let end = [global.bmin[0] + DIMS[0] as f64 / 2.0, y, z];
    let at = blend_points(&global, &pieces, &boxes, 0, &[face, end], &mut CpuBackend::new()).unwrap();
    let va = a.evaluate(&mut CpuBackend::new(), &[face]).unwrap()[0];
    let vb = b.evaluate(&mut CpuBackend::new(), &[face, end]).unwrap();
    assert!((va - vb[0]).abs() > 1e-4, "the two pieces agree at the face ({va}, {}): the mean would not show", vb[0]);
    assert!((at[0] - (va + vb[0]) / 2.0).abs() < 1e-6, "at the common face: {}, want the mean of {va} and {}", at[0], vb[0]);
    assert!(vb[1].abs() > 1e-4, "b is 0 at the far face: a 0 from no piece would not show");
    assert_eq!(at[1], vb[1], "at the domain's far face");
}

/// At world points the blend is the lattice blend: at every voxel centre
/// (of the reference lattice and of a finer one) the two agree to float
/// rounding, and a point outside every piece is 0.
#[test]
fn blend_at_points_is_the_lattice_blend() {
    use gsenc::domain::pieces::{blend, blend_points};
    let whole = blobs(DIMS, 7, 5);
    let a = encode_model(&slab(&whole, 0, CUT + 6), 0, 150);
    let b = encode_model(&slab(&whole, CUT - 6, DIMS[0]), CUT - 6, 150);
    let global = IndexFrame { dims: DIMS, bmin: a.meta.frame.bmin, gamma: 2.0 };
    let boxes = [IndexBox { lo: [0, 0, 0], hi: [CUT + 6, DIMS[1], DIMS[2]] }, IndexBox { lo: [CUT - 6, 0, 0], hi: DIMS }];
    let pieces = [a, b];
    for dims in [DIMS, [2 * DIMS[0], DIMS[1], DIMS[2]]] {
        let g = blend(&global, &pieces, &boxes, 6, dims, IndexBox::whole(dims), &mut CpuBackend::new()).unwrap();
        let step: [f64; 3] = std::array::from_fn(|a| DIMS[a] as f64 / dims[a] as f64 / global.gamma);
        let points: Vec<[f64; 3]> = (0..g.values.len())
            .map(|i| {
                let c = g.coords(i);
                std::array::from_fn(|a| global.bmin[a] + (c[a] as f64 + 0.5) * step[a])
            })
            .collect();
        let at = blend_points(&global, &pieces, &boxes, 6, &points, &mut CpuBackend::new()).unwrap();
        let worst = at.iter().zip(&g.values).map(|(p, l)| (p - l).abs()).fold(0f32, f32::max);
        assert!(worst < 1e-5, "dims {dims:?}: points differ from the lattice by {worst}");
        assert!(g.values.iter().any(|&v| v > 0.1), "the field is not empty");
    }
    let far = [[global.bmin[0] - 50.0, 0.0, 0.0]];
    assert_eq!(blend_points(&global, &pieces, &boxes, 6, &far, &mut CpuBackend::new()).unwrap(), vec![0.0]);
    let e = blend_points(&global, &pieces, &boxes, 6, &[[f64::NAN, 0.0, 0.0]], &mut CpuBackend::new()).unwrap_err();
    assert!(matches!(e, Error::InvalidData(_)), "{e}");
}

/// Pieces with supports: the merged model's support is each piece's own
/// on its box, and the blend decodes each piece with its support, so the
/// global field is 0 wherever the pieces' data are empty.
#[test]
fn merged_and_blended_pieces_keep_their_supports() {
    use gsenc::domain::pieces::blend;
    use gsenc::model::Support;
    let g = blobs(DIMS, 3, 4);
    // The data end at x = 30: the right piece has an empty part.
    let values: Vec<f32> = g.values.iter().enumerate().map(|(i, &v)| if i % DIMS[0] >= 30 { 0.0 } else { v }).collect();
    let whole = Grid::new(DIMS, values).unwrap();
    let (a, b) = (slab(&whole, 0, CUT + HALO), slab(&whole, CUT - HALO, DIMS[0]));
    let mut pieces = [encode_model(&a, 0, 150), encode_model(&b, CUT - HALO, 150)];
    pieces[0].support = Support::from_reference(&a);
    pieces[1].support = Support::from_reference(&b);
    assert!(pieces[1].support.is_some());

    let merged = merge(&pieces).unwrap();
    let s = merged.support.as_ref().expect("the merged model keeps a support");
    let want = Support::place(&[(pieces[0].support.as_ref(), IndexBox { lo: [0; 3], hi: a.dims }), (pieces[1].support.as_ref(), IndexBox { lo: [CUT - HALO, 0, 0], hi: DIMS })], DIMS);
    assert_eq!(s, &want);
    let decoded = merged.decode(&mut CpuBackend::new(), None).unwrap();
    let global = merged.meta.frame;
    let boxes = [IndexBox { lo: [0; 3], hi: a.dims }, IndexBox { lo: [CUT - HALO, 0, 0], hi: DIMS }];
    let mut pieces_in_global = pieces.clone();
    for (p, bx) in pieces_in_global.iter_mut().zip(&boxes) {
        p.meta.frame = global.sub_frame(bx);
    }
    let blended = blend(&global, &pieces_in_global, &boxes, HALO, DIMS, IndexBox::whole(DIMS), &mut CpuBackend::new()).unwrap();
    let mut empty = 0;
    for i in 0..whole.len() {
        if whole.values[i] <= 0.005 {
            assert_eq!((decoded.values[i], blended.values[i]), (0.0, 0.0), "voxel {i}");
            empty += 1;
        }
    }
    assert!(empty > 1000, "{empty} empty voxels");
}

/// A step whose lattice reaches past its pieces (particles in configured
/// bounds wider than they fill): the field is on the index's lattice. Its
/// frame is the index's (what a decode's default dims and a `.vti`'s
/// placement come from), each piece's box is the index's, and the decode
/// is the model's own wherever a piece reaches and 0 beyond, additive or
/// blended. A piece off the index's lattice is refused.
#[test]
fn a_step_whose_lattice_reaches_past_its_pieces_is_on_the_index_lattice() {
    use gsenc::domain::global::GlobalField;
    use gsenc::format::StepIndex;
    let whole = blobs(DIMS, 7, 5);
    let model = encode_model(&whole, 0, 200);
    let global = model.meta.frame;
    let boxes = [IndexBox { lo: [4, 2, 0], hi: [24, 20, 16] }, IndexBox { lo: [16, 2, 0], hi: [30, 20, 16] }];
    let pieces: Vec<Model> = boxes.iter().map(|b| in_piece(&model, &global, b)).collect();
    let index = StepIndex::new("rho", 0, None, &range(), &global, &boxes, 4, vec!["a.gsm".into(), "b.gsm".into()]);
    let field = GlobalField::of_step(index.clone(), pieces.clone()).unwrap();
    assert_eq!(field.merged().meta.frame, global);
    for (i, b) in boxes.iter().enumerate() {
        assert_eq!(field.piece_box(i).unwrap(), *b);
    }
    let direct = model.decode(&mut CpuBackend::new(), None).unwrap();
    for additive in [false, true] {
        let decoded = field.decode(&mut CpuBackend::new(), DIMS, IndexBox::whole(DIMS), additive).unwrap();
        for (i, (&got, &want)) in decoded.iter().zip(&direct.values).enumerate() {
            let c = direct.coords(i);
            let covered = boxes.iter().any(|b| (0..3).all(|a| c[a] >= b.lo[a] && c[a] < b.hi[a]));
            if !additive || covered {
                let want = if covered { want } else { 0.0 };
                assert!((got - want).abs() < 1e-5, "additive {additive}, voxel {c:?}: {got}, want {want}");
            }
        }
    }
    // A blended decode whose one z layer (2^34 voxels: 448 GiB of sums,
    // values and a consumer's copies) cannot be held is refused before its
    // sums are reserved; a whole decode of it too.
    let flat = [1 << 17, 1 << 17, 1];
    let e = field.decode_streaming(&mut CpuBackend::new(), flat, IndexBox::whole(flat), false, 1 << 24, &mut |_| panic!("no slab")).unwrap_err();
    assert!(matches!(&e, Error::InvalidArgument(m) if m.contains("decoding slabs of 17179869184 voxels") && m.contains("more than")), "{e}");
    let e = field.decode(&mut CpuBackend::new(), flat, IndexBox::whole(flat), false).unwrap_err();
    assert!(matches!(&e, Error::InvalidArgument(m) if m.contains("a decode of 17179869184 voxels") && m.contains("more than")), "{e}");
    let mut off = pieces.clone();
    off[1].meta.frame.bmin[0] += 0.25; // half a voxel
    assert!(matches!(GlobalField::of_step(index, off).map(|_| ()), Err(Error::InvalidArgument(m)) if m.contains("piece 1")));
}
