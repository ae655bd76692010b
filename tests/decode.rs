//! Decoding in slabs and sub-boxes against the one-shot decode of the whole lattice.

use gsenc::backend::cpu::CpuBackend;
use gsenc::field::{IndexFrame, Transform, ValueRange};
use gsenc::field::IndexBox;
use gsenc::model::{Model, ModelMeta};
use gsenc::math::rng::Rng;

fn model() -> Model {
    let mut rng = Rng::new(7);
    let dims = [24, 20, 16];
    Model {
        meta: ModelMeta::new(
            IndexFrame::for_grid(dims, [0.0; 3], 1.0).unwrap(),
            ValueRange::new(0.0, 1.0, Transform::Linear).unwrap(),
        ),
        params: (0..200)
            .map(|_| {
                let mut p = [0f32; 12];
                for a in 0..3 {
                    p[a] = rng.range(-1.0, dims[a] as f64) as f32;
                    p[3 + a] = rng.range(0.0, 1.5) as f32;
                }
                p[6] = 1.0;
                for k in 7..12 {
                    p[k] = rng.range(-1.0, 1.0) as f32;
                }
                p
            })
            .collect(),
        support: None,
    }
}

fn assert_close(a: &[f32], b: &[f32]) {
    assert_eq!(a.len(), b.len());
    let worst = a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0f32, f32::max);
    assert!(worst < 1e-5, "largest difference {worst}");
}

#[test]
fn slabs_of_any_size_give_the_whole_decode() {
    let m = model();
    let dims = [30, 25, 21];
    let whole = m.decode(&mut CpuBackend::new(), Some(dims)).unwrap();
    assert!(whole.values.iter().any(|&v| v > 0.1), "the test model must not decode to zero");
    for slab_voxels in [1, 30 * 25, 30 * 25 * 4 + 7, usize::MAX] {
        let mut got = Vec::new();
        let mut slabs = 0;
        m.decode_streaming(&mut CpuBackend::new(), dims, IndexBox::whole(dims), slab_voxels, &mut |s| {
            got.extend_from_slice(s);
            slabs += 1;
            Ok(())
        })
        .unwrap();
        assert_close(&got, &whole.values);
        assert_eq!(slabs, 21usize.div_ceil((slab_voxels / (30 * 25)).clamp(1, 21)));
    }
}

#[test]
fn a_sub_box_is_that_part_of_the_whole_decode() {
    let m = model();
    let dims = [48, 40, 32];
    let whole = m.decode(&mut CpuBackend::new(), Some(dims)).unwrap();
    let b = IndexBox { lo: [3, 17, 9], hi: [40, 18, 31] };
    let part = m.decode_box(&mut CpuBackend::new(), dims, b).unwrap();
    assert_eq!(part.dims, [37, 1, 22]);
    let mut expect = Vec::new();
    for z in 9..31 {
        for x in 3..40 {
            expect.push(whole.values[(z * 40 + 17) * 48 + x]);
        }
    }
    assert_close(&part.values, &expect);
    // Streaming the same box in one-layer slabs agrees too.
    let mut got = Vec::new();
    m.decode_streaming(&mut CpuBackend::new(), dims, b, 1, &mut |s| {
        got.extend_from_slice(s);
        Ok(())
    })
    .unwrap();
    assert_close(&got, &expect);
}

#[test]
fn bad_boxes_and_sink_errors_are_reported() {
    let m = model();
    let dims = [8, 8, 8];
    for b in [IndexBox { lo: [0, 0, 0], hi: [9, 8, 8] }, IndexBox { lo: [4, 0, 0], hi: [4, 8, 8] }] {
        let e = m.decode_box(&mut CpuBackend::new(), dims, b).unwrap_err();
        assert!(e.to_string().contains("sub-box"), "{e}");
    }
    let e = m.decode(&mut CpuBackend::new(), Some([1 << 20, 1 << 20, 1 << 20])).unwrap_err();
    assert!(e.to_string().contains("too large"), "{e}");
    // A lattice within the bounds whose one z layer (a slab's least) cannot
    // be held: refused before it is reserved (Linux would promise the
    // memory and kill the process as the decode wrote it). 2^34 voxels, 192
    // GiB with a consumer's two copies. A whole decode of it too.
    let flat = [1 << 17, 1 << 17, 1];
    let e = m.decode_streaming(&mut CpuBackend::new(), flat, IndexBox::whole(flat), 1 << 24, &mut |_| panic!("no slab")).unwrap_err();
    assert!(matches!(&e, gsenc::Error::InvalidArgument(t) if t.contains("decoding slabs of 17179869184 voxels") && t.contains("more than")), "{e}");
    let e = m.decode(&mut CpuBackend::new(), Some(flat)).unwrap_err();
    assert!(matches!(&e, gsenc::Error::InvalidArgument(t) if t.contains("a decode of 17179869184 voxels") && t.contains("more than")), "{e}");
    // A failing sink (a full disk, say) stops the decode with its error.
    let mut calls = 0;
    let e = m
        .decode_streaming(&mut CpuBackend::new(), dims, IndexBox::whole(dims), 64, &mut |_| {
            calls += 1;
            Err(gsenc::Error::arg("disk full"))
        })
        .unwrap_err();
    assert_eq!(calls, 1);
    assert!(e.to_string().contains("disk full"));
}

/// A point's value is its own, to the bit: evaluated over several runs of
/// `EVALUATE_RUN` points (and points outside the box), alone, in reverse
/// order, and on one thread or three, each point gets the same bits. The
/// values are the mixture summed directly over every primitive
/// (`Frame::kernel`, an independent computation) to within float rounding,
/// and at voxel centres they are the decode's.
#[test]
fn a_point_evaluates_to_the_same_bits_whatever_is_asked_beside_it() {
    use gsenc::math::kernel::Frame;
    use gsenc::model::EVALUATE_RUN;
    let m = model();
    let mut rng = Rng::new(3);
    let n = 2 * EVALUATE_RUN + 123;
    let points: Vec<[f64; 3]> = (0..n).map(|_| [rng.range(-3.0, 27.0), rng.range(-3.0, 23.0), rng.range(-3.0, 19.0)]).collect();
    let on = |threads: usize, points: &[[f64; 3]]| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        pool.install(|| m.evaluate(&mut CpuBackend::new(), points).unwrap())
    };
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<u32>>();
    let got = on(3, &points);
    assert_eq!(bits(&on(1, &points)), bits(&got), "one thread and three differ");
    let reversed: Vec<[f64; 3]> = points.iter().rev().copied().collect();
    let mut back = on(2, &reversed);
    back.reverse();
    assert_eq!(bits(&back), bits(&got), "the points in reverse order differ");
    // Each alone (every 257th point: a few hundred calls of one point).
    for i in (0..n).step_by(257) {
        let alone = m.evaluate(&mut CpuBackend::new(), &points[i..=i]).unwrap();
        assert_eq!(alone[0].to_bits(), got[i].to_bits(), "point {i} alone: {} among the others: {}", alone[0], got[i]);
    }
    // The mixture summed directly over every primitive.
    let f = &m.meta.frame;
    let frames: Vec<Frame> = m.params.iter().map(Frame::new).collect();
    let direct: Vec<f32> = points
        .iter()
        .map(|p| {
            let u: [f32; 3] = std::array::from_fn(|a| ((p[a] - f.bmin[a]) * f.gamma - 0.5) as f32);
            let (mut rho, mut num) = (0f32, 0f32);
            for fr in &frames {
                if let Some((k, _)) = fr.kernel(u) {
                    rho += fr.w * k;
                    num += fr.w * k * fr.s;
                }
            }
            m.value_at(u, rho, num)
        })
        .collect();
    assert_close(&got, &direct);
    assert!(got.iter().filter(|&&v| v > 0.1).count() > n / 10, "the test model must not evaluate to zero");

    let dims = m.meta.frame.dims;
    let decoded = m.decode(&mut CpuBackend::new(), Some(dims)).unwrap().values;
    let centres: Vec<[f64; 3]> = (0..dims[0] * dims[1] * dims[2])
        .map(|i| [i % dims[0], (i / dims[0]) % dims[1], i / (dims[0] * dims[1])].map(|c| c as f64))
        .collect();
    assert_close(&m.evaluate(&mut CpuBackend::new(), &centres).unwrap(), &decoded);
    // Room for another count of values is refused.
    let mut short = vec![0.0; 5];
    assert!(m.evaluate_into(&mut CpuBackend::new(), &centres, &mut short).is_err());
}
