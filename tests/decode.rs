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

/// Evaluating at points runs in runs of `EVALUATE_RUN` points: over several
/// runs (and points outside the box), the values are the backend's one call
/// over all the points to within float rounding (the backend bins the
/// points it is given, and the sums of a point follow its bin), every point
/// written, and at voxel centres they are the decode's.
#[test]
fn evaluating_in_runs_gives_the_one_call_and_the_decode() {
    use gsenc::backend::Backend;
    use gsenc::model::EVALUATE_RUN;
    let m = model();
    let mut rng = Rng::new(3);
    let n = 2 * EVALUATE_RUN + 123;
    let points: Vec<[f64; 3]> = (0..n).map(|_| [rng.range(-3.0, 27.0), rng.range(-3.0, 23.0), rng.range(-3.0, 19.0)]).collect();
    let got = m.evaluate(&mut CpuBackend::new(), &points).unwrap();
    let f = &m.meta.frame;
    let index: Vec<[f32; 3]> = points.iter().map(|p| std::array::from_fn(|a| ((p[a] - f.bmin[a]) * f.gamma - 0.5) as f32)).collect();
    let (mut rho, mut num) = (vec![0.0; n], vec![0.0; n]);
    CpuBackend::new().evaluate_points(&m.params, &index, &mut rho, &mut num).unwrap();
    let once: Vec<f32> = (0..n).map(|i| m.value_at(index[i], rho[i], num[i])).collect();
    assert_close(&got, &once);
    let differ = got.iter().zip(&once).filter(|(a, b)| a.to_bits() != b.to_bits()).count();
    assert!(differ < n / 100, "{differ} of {n} points differ from one call in their last bits");

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
