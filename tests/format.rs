//! The file formats: round trips of the model file and rejection of
//! damaged or foreign files; the step index.

use gsenc::field::{Grid, IndexBox, IndexFrame, Transform, ValueRange};
use gsenc::format::StepIndex;
use gsenc::format::{read_model, read_model_file, write_model, write_model_as, Payload, BYTES_PER_PRIMITIVE};
use gsenc::format::packed::Precision;
use gsenc::format::support_coding;
use gsenc::format::quantize::CentreCoding;
use gsenc::model::{Curve, Model, ModelMeta, Outside, Support, WarmRecord, WarmTaken};
use gsenc::math::rng::Rng;
use gsenc::Error;

fn model(n: usize) -> Model {
    let mut rng = Rng::new(1);
    let mut m = model_without_extras(n, &mut rng);
    m.meta.time = Some(0.125);
    m.meta.rank = 3;
    m.meta.encode_psnr = Some(41.5);
    m
}

/// [`model`] with a support: a ball of data in the reference box, and a
/// background outside it (a fitted outside, stored behind its prefix).
fn model_with_support(n: usize) -> Model {
    let mut m = model(n);
    let dims = m.meta.frame.dims;
    let values = (0..dims.iter().product::<usize>())
        .map(|i| {
            let (x, y, z) = ((i % dims[0]) as f64 - 64.0, (i / dims[0] % dims[1]) as f64 - 32.0, (i / (dims[0] * dims[1])) as f64 - 16.0);
            if x * x + y * y + z * z < 400.0 { 0.5 } else { 0.0 }
        })
        .collect();
    let support = Support::from_reference(&Grid::new(dims, values).unwrap()).unwrap();
    m.support = Some(support.with_outside(Outside { offset: 0.0042, gain: -0.125 }).unwrap());
    m
}

fn model_without_extras(n: usize, rng: &mut Rng) -> Model {
    Model {
        meta: ModelMeta {
            frame: IndexFrame { dims: [128, 64, 32], bmin: [-1.5, 0.25, 3.0], gamma: 42.5 },
            range: ValueRange::new(-3.0, 7.5, Transform::Log10).unwrap(),
            field: "density".into(),
            step: 17,
            schedule: "full".into(),
            iterations: 3000,
            points: 16384,
            seed_init: 0,
            seed_sample: 1,
            time: None,
            rank: 0,
            encode_psnr: None,
            fell_back: None,
            warm: None,
            precision: None,
            curve: None,
        },
        // Centres inside the reference box, the rest spread like trained parameters.
        params: (0..n)
            .map(|_| std::array::from_fn(|k| if k < 3 { rng.range(-0.5, 127.5) } else { rng.range(-5.0, 5.0) } as f32))
            .collect(),
        support: None,
    }
}

#[test]
fn round_trip_is_exact_and_48_bytes_a_primitive() {
    let m = model(37);
    let a = write_model(&m).unwrap();
    let b = write_model(&model(38)).unwrap();
    assert_eq!(b.len() - a.len(), BYTES_PER_PRIMITIVE);
    assert_eq!(read_model(&a).unwrap(), m);
    let empty = model(0);
    assert_eq!(read_model(&write_model(&empty).unwrap()).unwrap(), empty);
}

#[test]
fn every_truncation_is_rejected() {
    for (payload, m) in Payload::ALL.into_iter().flat_map(|p| [(p, model(5)), (p, model_with_support(5))]) {
        let bytes = write_model_as(&m, payload).unwrap();
        for cut in 0..bytes.len() {
            let e = read_model(&bytes[..cut]).unwrap_err();
            assert!(matches!(e, Error::Format(_)), "{payload:?}, cut at {cut}: {e}");
        }
        let mut longer = bytes.clone();
        longer.push(0);
        assert!(read_model(&longer).is_err());
    }
}

#[test]
fn every_corrupted_byte_is_detected() {
    for (payload, m) in Payload::ALL.into_iter().flat_map(|p| [(p, model(3)), (p, model_with_support(3))]) {
        let bytes = write_model_as(&m, payload).unwrap();
        for i in 0..bytes.len() {
            for flip in [0x01u8, 0x80] {
                let mut b = bytes.clone();
                b[i] ^= flip;
                assert!(read_model(&b).is_err(), "{payload:?}: flipping bit {flip:#x} of byte {i} went unnoticed");
            }
        }
    }
}

/// The largest error the 8-bit export may make on each parameter, from its
/// definition: half a code step of the array's min/max map, and for float16
/// centres half a unit in the last place (11 significant bits).
fn allowed_error(params: &[[f32; 12]], k: usize, centres: CentreCoding) -> Box<dyn Fn(f32) -> f32> {
    let lo = params.iter().map(|p| p[k]).fold(f32::INFINITY, f32::min);
    let hi = params.iter().map(|p| p[k]).fold(f32::NEG_INFINITY, f32::max);
    let slack = 1e-6 * lo.abs().max(hi.abs());
    match (k < 3, centres) {
        (true, CentreCoding::Float16) => Box::new(move |v: f32| v.abs() * 2f32.powi(-11) + 1e-7),
        (true, CentreCoding::Fixed16) => Box::new(move |_| (hi - lo) / 65535.0 * 0.5 + slack),
        (false, _) => Box::new(move |_| (hi - lo) / 255.0 * 0.5 + slack),
    }
}

#[test]
fn eight_bit_payloads_keep_every_parameter_within_its_quantisation_step() {
    let m = model(500);
    for centres in [CentreCoding::Float16, CentreCoding::Fixed16] {
        let payload = Payload::Bits8(centres);
        let bytes = write_model_as(&m, payload).unwrap();
        let file = read_model_file(&bytes).unwrap();
        assert_eq!(file.payload, payload);
        assert_eq!(file.version, (1, 1));
        assert_eq!(file.model.meta, m.meta);
        assert_eq!(file.model.params, payload.round_trip(&m).unwrap());
        for k in 0..12 {
            let allowed = allowed_error(&m.params, k, centres);
            for (a, b) in m.params.iter().zip(&file.model.params) {
                assert!((a[k] - b[k]).abs() <= allowed(a[k]), "{centres:?} parameter {k}: {} vs {}", a[k], b[k]);
            }
        }
        // Storing what was read again does not drift (convert back and forth).
        let again = payload.round_trip(&file.model).unwrap();
        for (a, b) in again.iter().zip(&file.model.params) {
            for k in 0..12 {
                assert!((a[k] - b[k]).abs() <= 1e-6 * b[k].abs().max(1.0), "{centres:?} parameter {k} drifts: {} vs {}", a[k], b[k]);
            }
        }
        // About 12 bytes a primitive or less (the paper's figure), far below 48.
        let per = bytes.len() as f64 / 500.0;
        assert!(per < 16.0, "{centres:?}: {per} bytes a primitive");
    }
    // Converting back to float32 is exact.
    let eight = read_model(&write_model_as(&m, Payload::Bits8(CentreCoding::Float16)).unwrap()).unwrap();
    assert_eq!(read_model(&write_model(&eight).unwrap()).unwrap(), eight);
}

/// The stored primitive nearest to `p` by centre (the packed payload
/// stores primitives in Morton order).
fn stored_twin<'a>(p: &[f32; 12], stored: &'a [[f32; 12]]) -> &'a [f32; 12] {
    let d2 = |q: &[f32; 12]| (0..3).map(|a| (p[a] - q[a]).powi(2)).sum::<f32>();
    stored.iter().min_by(|a, b| d2(a).total_cmp(&d2(b))).unwrap()
}

fn sigmoid(x: f32) -> f64 {
    1.0 / (1.0 + (-(x as f64)).exp())
}

/// The rotation matrix of a quaternion (w, x, y, z), normalised.
fn rotation(q: &[f32]) -> [[f64; 3]; 3] {
    let n = q.iter().map(|v| (*v as f64).powi(2)).sum::<f64>().sqrt();
    let [w, x, y, z] = [0, 1, 2, 3].map(|i| q[i] as f64 / n);
    [
        [1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y)],
        [2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x)],
        [2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y)],
    ]
}

/// The 24 proper signed permutation matrices `(perm, signs)`: column `k`
/// is `signs[k]` times axis `perm[k]`. Turning a frame by one and giving
/// axis `k` the scale of axis `perm[k]` gives the same Gaussian.
fn axis_turns() -> Vec<([usize; 3], [f64; 3])> {
    let perms = [[0, 1, 2], [1, 2, 0], [2, 0, 1], [0, 2, 1], [2, 1, 0], [1, 0, 2]];
    let mut out = Vec::new();
    for (i, perm) in perms.into_iter().enumerate() {
        let parity = if i < 3 { 1.0 } else { -1.0 };
        for s in 0..8 {
            let signs = [0, 1, 2].map(|k| if s >> k & 1 == 1 { -1.0 } else { 1.0 });
            if parity * signs.iter().product::<f64>() > 0.0 {
                out.push((perm, signs));
            }
        }
    }
    assert_eq!(out.len(), 24);
    out
}

/// Asserts that each of `stored` (Morton order) is within the packed
/// payload's steps at `precision` of its twin in `params`, in one of the
/// 24 frames that give the twin's Gaussian (the payload stores a pose of
/// its choosing: scales and rotation are compared in the frame that fits).
fn assert_within_packed_steps(params: &[[f32; 12]], stored: &[[f32; 12]], precision: Precision) {
    let (lo, hi) = (0.4f64.ln(), 8f64.ln());
    let (beta_lo, beta_hi) = params.iter().fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), p| (a.min(p[11]), b.max(p[11])));
    let half = |bits: u8, span: f64| span / ((1u32 << bits) - 1) as f64 * 0.5 + 1e-5;
    for (i, p) in params.iter().enumerate() {
        let s = stored_twin(p, stored);
        // The centre's lattice is its class's: the octaves its smallest
        // stored scale lies above 0.4 voxel (both neighbours' on a border).
        let octaves = ((s[3].min(s[4]).min(s[5]) as f64).clamp(lo, hi) - lo) / std::f64::consts::LN_2;
        let class = |o: f64| (o.max(0.0).floor() as usize).min(3);
        let bits = [class(octaves - 1e-3), class(octaves + 1e-3)].map(|c| precision.centre[c]).into_iter().min().unwrap();
        for a in 0..3 {
            assert!((p[a] - s[a]).abs() as f64 <= 0.5f64.powi(bits as i32 + 1) + 1e-4, "{precision:?} centre {i}");
        }
        assert!((sigmoid(p[10]) - sigmoid(s[10])).abs() <= 0.5f64.powi(precision.value as i32 + 1) + 1e-6, "{precision:?} value {i}");
        assert!((p[11] - s[11]).abs() as f64 <= half(precision.weight, (beta_hi - beta_lo) as f64), "{precision:?} weight {i}");
        // Scales and rotation, in the frame of p that fits: the scales
        // within half a step; the rotation exactly none for a sphere, else
        // within the components' step, which may be coarser the rounder
        // the primitive.
        let sphere = s[3] == s[4] && s[4] == s[5];
        if sphere {
            assert_eq!(&s[6..10], &[1.0, 0.0, 0.0, 0.0], "{precision:?} sphere {i}");
        }
        let r = rotation(&p[6..10]);
        let t = rotation(&s[6..10]);
        let step = std::f64::consts::SQRT_2 / ((1u32 << precision.rotation) - 1) as f64;
        let spread = (s[3].max(s[4]).max(s[5]) - s[3].min(s[4]).min(s[5])) as f64 / (hi - lo);
        let allowed = (8.0 * step).max(8.0 * step / (3.0 * spread)).min(2.0);
        let fits = |(perm, signs): &([usize; 3], [f64; 3])| -> bool {
            let scales = (0..3).all(|k| ((p[3 + perm[k]] as f64).clamp(lo, hi) - s[3 + k] as f64).abs() <= half(precision.scale, hi - lo));
            // Column k of the turned frame: signs[k] times column perm[k] of r.
            let err = (0..9).map(|e| (signs[e % 3] * r[e / 3][perm[e % 3]] - t[e / 3][e % 3]).abs()).fold(0.0, f64::max);
            scales && (sphere || err <= allowed)
        };
        assert!(axis_turns().iter().any(fits), "{precision:?} primitive {i}: no frame of it within the steps of what is stored");
    }
}

#[test]
fn the_packed_payload_keeps_every_group_within_its_step_and_records_its_precision() {
    let mut m = model(400);
    // A few spheres: equal log scales, whose rotation is not stored.
    for p in m.params.iter_mut().take(40) {
        (p[4], p[5]) = (p[3], p[3]);
    }
    for precision in [Precision::DEFAULT, Precision { centre: [2, 0, 5, 3], scale: 4, rotation: 3, value: 5, weight: 3 }, Precision::FINEST] {
        m.meta.precision = Some(precision);
        let bytes = write_model_as(&m, Payload::Packed).unwrap();
        let file = read_model_file(&bytes).unwrap();
        assert_eq!(file.payload, Payload::Packed);
        assert_eq!(file.version, (1, 1), "no new header field: the payload code tells");
        assert_eq!(file.model.meta, m.meta, "the precision is read back from the payload");
        assert_eq!(file.model.params, Payload::Packed.round_trip(&m).unwrap(), "what an encoder scores is what is read");
        assert_within_packed_steps(&m.params, &file.model.params, precision);
        // Storing what was read again stays within the steps of it.
        let again = read_model(&write_model_as(&file.model, Payload::Packed).unwrap()).unwrap();
        assert_within_packed_steps(&file.model.params, &again.params, precision);
    }
    // The default is well below the 8-bit payloads.
    m.meta.precision = None;
    let packed = write_model_as(&m, Payload::Packed).unwrap().len();
    let eight = write_model_as(&m, Payload::Bits8(CentreCoding::Fixed16)).unwrap().len();
    assert!(packed < eight, "packed {packed} bytes, 8bit-u16 {eight}");
}

#[test]
fn constant_arrays_and_empty_models_survive_the_8_bit_payload() {
    let mut m = model(7);
    for p in &mut m.params {
        p[5] = 1.25;
        p[11] = -2.0;
    }
    for payload in Payload::ALL {
        let back = read_model(&write_model_as(&m, payload).unwrap()).unwrap();
        assert!(back.params.iter().all(|p| p[11] == -2.0), "{payload:?}");
        // The packed payload quantises log scales over the kernel's fixed band, not their own range.
        assert!(back.params.iter().all(|p| p[5] == 1.25 || payload == Payload::Packed), "{payload:?}");
        let mut empty = model(0);
        let back = read_model(&write_model_as(&empty, payload).unwrap()).unwrap();
        // A packed file tells the precision it was written at.
        empty.meta.precision = (payload == Payload::Packed).then_some(Precision::DEFAULT);
        assert_eq!(back, empty);
    }
}

#[test]
fn unstorable_parameters_are_refused_on_write() {
    let mut m = model(3);
    m.params[1][7] = f32::NAN;
    for payload in Payload::ALL {
        let e = write_model_as(&m, payload).unwrap_err();
        assert!(matches!(e, Error::InvalidData(_)) && e.to_string().contains("non-finite"), "{e}");
    }
    let mut far = model(3);
    far.params[2][0] = 70000.0;
    let e = write_model_as(&far, Payload::Bits8(CentreCoding::Float16)).unwrap_err();
    assert!(e.to_string().contains("8bit-u16"), "{e}");
    // The packed payload's default lattice coarsens to fit a wide domain
    // (70,000 voxels: 1/16 voxel, within 2^21 steps)...
    let packed = read_model_file(&write_model_as(&far, Payload::Packed).unwrap()).unwrap();
    assert_eq!(packed.model.meta.precision, Some(Precision::DEFAULT.with_centres(4)));
    let twin = stored_twin(&far.params[2], &packed.model.params);
    assert!((twin[0] - 70000.0).abs() <= 1.0 / 32.0 + 0.004, "{}", twin[0]);
    let back = read_model(&write_model_as(&far, Payload::Bits8(CentreCoding::Fixed16)).unwrap()).unwrap();
    assert!((back.params[2][0] - 70000.0).abs() < 1.0);
    // A centre whose code would be exactly 2^21 (131,072 voxels from the
    // origin at 1/16 voxel) needs the next coarser lattice.
    let origin = far.params.iter().enumerate().filter(|&(i, _)| i != 2).map(|(_, p)| p[0]).fold(f32::INFINITY, f32::min).floor();
    far.params[2][0] = origin + 131072.0;
    let packed = read_model_file(&write_model_as(&far, Payload::Packed).unwrap()).unwrap();
    assert_eq!(packed.model.meta.precision, Some(Precision::DEFAULT.with_centres(3)));
    // ...down to whole voxels; beyond 2^21 voxels it is refused.
    far.params[2][0] = 3.0e6;
    let e = write_model_as(&far, Payload::Packed).unwrap_err();
    assert!(e.to_string().contains("8bit-u16"), "{e}");
}

#[test]
fn a_version_1_0_file_is_read_with_unknown_extras() {
    // A 1.0 header is the 1.1 header without its last 20 bytes (time, rank, PSNR).
    let m = model(4);
    let b = write_model(&m).unwrap();
    let header_len = header_len(&b);
    let mut out = b[..16 + header_len - 20].to_vec();
    out[10..12].copy_from_slice(&0u16.to_le_bytes());
    out[12..16].copy_from_slice(&((header_len - 20) as u32).to_le_bytes());
    out.extend_from_slice(&b[16 + header_len..b.len() - 4]);
    let crc = crc32fast::hash(&out);
    out.extend_from_slice(&crc.to_le_bytes());
    let file = read_model_file(&out).unwrap();
    assert_eq!(file.version, (1, 0));
    assert_eq!(file.payload, Payload::Float32);
    assert_eq!((file.model.meta.time, file.model.meta.rank, file.model.meta.encode_psnr), (None, 0, None));
    assert_eq!(file.model.params, m.params);
}

#[test]
fn payload_names_round_trip_and_unknown_names_are_refused() {
    for p in Payload::ALL {
        assert_eq!(Payload::from_name(p.name()).unwrap(), p);
        assert_eq!(Payload::from_code(p.code()), Some(p));
    }
    assert!(Payload::from_name("float8").unwrap_err().to_string().contains("8bit-u16"));
    assert_eq!(Payload::from_code(9), None);
}

#[test]
fn foreign_and_newer_files_are_rejected_with_clear_errors() {
    let e = read_model(b"\x89HDF\r\n\x1a\n and more bytes of another format").unwrap_err().to_string();
    assert!(e.contains("not a gsenc model"), "{e}");
    let mut b = write_model(&model(2)).unwrap();
    b[8..10].copy_from_slice(&2u16.to_le_bytes());
    fix_checksum(&mut b);
    let e = read_model(&b).unwrap_err();
    assert!(matches!(e, Error::Version(_)) && e.to_string().contains("version 2.1 is newer"), "{e}");
}

#[test]
fn a_newer_minor_version_with_extra_header_fields_is_read() {
    // A minor version past 1.5 carries the 1.5 fields (the support, the
    // fall-back, the warm record, the curve), then its own.
    let mut m = model_with_support(4);
    m.meta.fell_back = Some("device lost".into());
    m.meta.warm = Some(WarmRecord { taken: WarmTaken::Fresh, moved: 3 });
    m.meta.curve = Some(Curve { per_budget_doubling: 2.25, per_iteration_doubling: 0.5 });
    let b = write_model(&m).unwrap();
    let header_len = header_len(&b);
    let mut out = b[..16 + header_len].to_vec();
    out[10..12].copy_from_slice(&6u16.to_le_bytes());
    out.extend_from_slice(b"future fields");
    out[12..16].copy_from_slice(&((header_len + 13) as u32).to_le_bytes());
    out.extend_from_slice(&b[16 + header_len..b.len() - 4]);
    let crc = crc32fast::hash(&out);
    out.extend_from_slice(&crc.to_le_bytes());
    assert_eq!(read_model(&out).unwrap(), m);
}

#[test]
fn a_huge_count_behind_a_valid_checksum_is_refused_before_allocating() {
    // The count sits after the payload code: bytes 20..28.
    for (count, why) in [(1u64 << 31, "cannot hold"), (1 << 40, "claims")] {
        let mut b = write_model_as(&model(3), Payload::Bits8(CentreCoding::Float16)).unwrap();
        b[20..28].copy_from_slice(&count.to_le_bytes());
        fix_checksum(&mut b);
        let e = read_model(&b).unwrap_err();
        assert!(matches!(e, Error::Format(_)) && e.to_string().contains(why), "{e}");
    }
}

#[test]
fn an_invalid_index_frame_behind_a_valid_checksum_is_refused() {
    // dims (3 x u32) at bytes 28..40, bmin (3 x f64) at 40..64, gamma at 64..72.
    let changes: [(usize, Vec<u8>); 5] = [
        (64, 0f64.to_le_bytes().to_vec()),
        (64, (-2f64).to_le_bytes().to_vec()),
        (64, f64::NAN.to_le_bytes().to_vec()),
        (32, 0u32.to_le_bytes().to_vec()),
        (56, f64::INFINITY.to_le_bytes().to_vec()),
    ];
    for (at, value) in changes {
        let mut b = write_model(&model(3)).unwrap();
        b[at..at + value.len()].copy_from_slice(&value);
        fix_checksum(&mut b);
        let e = read_model(&b).unwrap_err();
        assert!(matches!(e, Error::Format(_)) && e.to_string().contains("invalid index frame"), "bytes {at}: {e}");
    }
}

#[test]
fn non_finite_parameters_behind_a_valid_checksum_are_refused() {
    let mut b = write_model(&model(2)).unwrap();
    let header_len = header_len(&b);
    let at = 16 + header_len + 4 * 7; // the first primitive's q[1]
    b[at..at + 4].copy_from_slice(&f32::NAN.to_le_bytes());
    fix_checksum(&mut b);
    let e = read_model(&b).unwrap_err();
    assert!(matches!(e, Error::Format(_)) && e.to_string().contains("non-finite"), "{e}");
}

/// The step-index fuzzing seeds (`fuzz/gsi-seeds`, written by Python's json,
/// not by gsenc) read as the indexes gsenc makes of the same layouts, so that
/// the fuzzer starts from indexes that reach the decode.
#[test]
fn step_index_fuzz_seeds_read_as_made() {
    let seed = |name: &str| StepIndex::from_json(&std::fs::read_to_string(format!("{}/fuzz/gsi-seeds/{name}", env!("CARGO_MANIFEST_DIR"))).unwrap()).unwrap();
    let names = |field: &str, step: u64, ranks: usize| (0..ranks).map(|r| gsenc::format::model_file_name(field, step, r as u32)).collect::<Vec<_>>();
    let b = |lo: [usize; 3], hi: [usize; 3]| IndexBox { lo, hi };
    let linear = |vmin, vmax| ValueRange::new(vmin, vmax, Transform::Linear).unwrap();
    let two = IndexFrame { dims: [8, 4, 4], bmin: [0.0; 3], gamma: 4.0 };
    let two_boxes = [b([0, 0, 0], [5, 4, 4]), b([3, 0, 0], [8, 4, 4])];
    assert_eq!(seed("two-ranks.gsi"), StepIndex::new("rho", 3, Some(0.25), &linear(0.0, 2.0), &two, &two_boxes, 1, names("rho", 3, 2)));
    let four = IndexFrame { dims: [6, 6, 3], bmin: [-1.5, -1.5, -0.75], gamma: 2.0 };
    let four_boxes = [b([0, 0, 0], [5, 5, 3]), b([1, 0, 0], [6, 5, 3]), b([0, 1, 0], [5, 6, 3]), b([1, 1, 0], [6, 6, 3])];
    let log = ValueRange::new(-3.0, 1.5, Transform::Log10).unwrap();
    assert_eq!(seed("four-ranks-log10.gsi"), StepIndex::new("density", 12, None, &log, &four, &four_boxes, 2, names("density", 12, 4)));
    let one = IndexFrame { dims: [3, 2, 2], bmin: [0.0; 3], gamma: 1.0 };
    assert_eq!(seed("one-rank.gsi"), StepIndex::new("v", 0, None, &linear(-1.0, 1.0), &one, &[b([0; 3], [3, 2, 2])], 0, names("v", 0, 1)));
    assert_eq!(std::fs::read_dir(format!("{}/fuzz/gsi-seeds", env!("CARGO_MANIFEST_DIR"))).unwrap().count(), 3);
}

#[test]
fn step_index_round_trips_and_refuses_other_json() {
    let global = IndexFrame { dims: [32, 16, 16], bmin: [-1.0, 0.0, 0.5], gamma: 16.0 };
    let boxes = [IndexBox { lo: [0, 0, 0], hi: [20, 16, 16] }, IndexBox { lo: [12, 0, 0], hi: [32, 16, 16] }];
    let range = ValueRange::new(0.1, 7.5, Transform::Log10).unwrap();
    let index = StepIndex::new("rho", 4, Some(0.25), &range, &global, &boxes, 4, vec!["rho_000004.gsm".into(), "rho_000004_r1.gsm".into()]);
    let text = index.to_json();
    assert_eq!(StepIndex::from_json(&text).unwrap(), index);
    assert_eq!(index.pieces[1].world_min[0], -1.0 + 12.0 / 16.0);
    assert_eq!(index.pieces[1].world_max[0], 1.0);
    assert!(matches!(StepIndex::from_json("{\"format\": \"other\"}"), Err(gsenc::Error::Format(_))));
    assert!(matches!(StepIndex::from_json("not json"), Err(gsenc::Error::Format(_))));
    // The next version is already one this reader does not know.
    let newer = text.replace("\"version\": 1", "\"version\": 2");
    assert!(matches!(StepIndex::from_json(&newer), Err(gsenc::Error::Version(_))));
    let missing_rank = text.replace("\"ranks\": 2", "\"ranks\": 3");
    assert!(StepIndex::from_json(&missing_rank).unwrap_err().to_string().contains("ranks"));
    // Pieces out of rank order (rank 1 listed first) would pair each model
    // with the other's box.
    let swapped = text.replace("\"rank\": 0", "\"rank\": 9").replace("\"rank\": 1", "\"rank\": 0").replace("\"rank\": 9", "\"rank\": 1");
    assert_ne!(swapped, text);
    assert!(matches!(StepIndex::from_json(&swapped), Err(gsenc::Error::Format(m)) if m.contains("ranks 0..ranks once each")));

    // A layout the decode cannot trust is refused by what is wrong with it.
    let with = |edit: &dyn Fn(&mut serde_json::Value)| {
        let mut v: serde_json::Value = serde_json::from_str(&text).unwrap();
        edit(&mut v);
        StepIndex::from_json(&v.to_string())
    };
    let bad: [(&dyn Fn(&mut serde_json::Value), &str); 9] = [
        (&|v| v["gamma"] = 0.0.into(), "voxels a world unit"),
        (&|v| v["gamma"] = (-16.0).into(), "voxels a world unit"),
        (&|v| v["dims"][2] = 0.into(), "empty or too large"),
        (&|v| v["dims"] = serde_json::json!([1u64 << 32, 1u64 << 32, 1u64 << 32]), "empty or too large"),
        (&|v| v["range"]["transform"] = "sqrt".into(), "unknown transform 'sqrt'"),
        (&|v| v["range"]["vmax"] = 0.1.into(), "max > min"),
        (&|v| v["pieces"][1]["hi"][0] = 33.into(), "rank 1's voxels"),
        (&|v| v["pieces"][0]["lo"][1] = 16.into(), "rank 0's voxels"),
        (&|v| {
            v["ranks"] = 0.into();
            v["pieces"] = serde_json::json!([]);
        }, "no pieces"),
    ];
    for (edit, says) in bad {
        let e = with(edit).unwrap_err();
        assert!(matches!(&e, gsenc::Error::Format(m) if m.contains(says)), "{says}: {e}");
    }
    // The edits are what made them fail: the same path to an edit that keeps
    // the index as it was reads.
    assert_eq!(with(&|v| v["halo"] = 4.into()).unwrap(), index);
    // A halo wider than the lattice is a run's choice (its ramp is only
    // wider), and reads.
    assert_eq!(with(&|v| v["halo"] = 1000.into()).unwrap().halo, 1000);
}

#[test]
fn a_support_is_stored_in_version_1_2_and_a_model_without_one_stays_1_1() {
    for payload in Payload::ALL {
        let with = model_with_support(6);
        let file = read_model_file(&write_model_as(&with, payload).unwrap()).unwrap();
        assert_eq!(file.version, (1, 2));
        assert_eq!(file.model.support, with.support);
        assert_eq!(file.model.support.as_ref().unwrap().count(), with.support.as_ref().unwrap().count());
        let without = read_model_file(&write_model_as(&model(6), payload).unwrap()).unwrap();
        assert_eq!((without.version, without.model.support), ((1, 1), None));
    }
    // A support on another lattice than the model's is refused on write.
    let mut m = model(2);
    m.support = Support::from_reference(&Grid::new([4, 4, 4], vec![0.0; 64]).unwrap());
    assert!(matches!(write_model(&m), Err(Error::InvalidArgument(_))));
}

#[test]
fn a_fall_back_is_stored_in_version_1_3_with_or_without_a_support() {
    let why = "GPU 'NVIDIA H200': device lost";
    for payload in Payload::ALL {
        for mut m in [model(5), model_with_support(5)] {
            m.meta.fell_back = Some(why.into());
            let file = read_model_file(&write_model_as(&m, payload).unwrap()).unwrap();
            assert_eq!(file.version, (1, 3));
            assert_eq!(file.model.meta.fell_back.as_deref(), Some(why));
            assert_eq!(file.model.support, m.support);
        }
    }
    // A reason longer than a header string holds is cut at a character
    // boundary, not refused: the model matters more than its note.
    let mut m = model(2);
    m.meta.fell_back = Some("é".repeat(40_000));
    let back = read_model(&write_model(&m).unwrap()).unwrap().meta.fell_back.unwrap();
    assert_eq!(back.len(), 65_534);
    assert!(back.chars().all(|c| c == 'é'));
}

#[test]
fn a_warm_record_is_stored_in_version_1_4_and_a_foreign_one_refused() {
    for payload in Payload::ALL {
        for fell_back in [None, Some("device lost".to_owned())] {
            for mut m in [model(5), model_with_support(5)] {
                m.meta.fell_back = fell_back.clone();
                m.meta.warm = Some(WarmRecord { taken: WarmTaken::Repaired, moved: 4 });
                let file = read_model_file(&write_model_as(&m, payload).unwrap()).unwrap();
                assert_eq!(file.version, (1, 4));
                assert_eq!(file.model.meta.warm, m.meta.warm);
                assert_eq!(file.model.meta.fell_back, fell_back, "1.4 reads an empty fall-back as none");
                assert_eq!(file.model.support, m.support);
            }
        }
    }
    // The record is the header's last 5 bytes: a start code past `fresh`
    // is refused (with a valid checksum, so the check is the code's).
    let mut m = model(3);
    m.meta.warm = Some(WarmRecord { taken: WarmTaken::Kept, moved: 0 });
    let e = read_model(&with_header_tail(write_model(&m).unwrap(), 5, &[3])).unwrap_err();
    assert!(matches!(e, Error::Format(_)) && e.to_string().contains("unknown warm start 3"), "{e}");
}

/// The header's length, as a file's prefix says.
fn header_len(bytes: &[u8]) -> usize {
    u32::from_le_bytes(bytes[12..16].try_into().unwrap()) as usize
}

/// Makes the checksum of a changed file valid again.
fn fix_checksum(bytes: &mut [u8]) {
    let n = bytes.len();
    let crc = crc32fast::hash(&bytes[..n - 4]);
    bytes[n - 4..].copy_from_slice(&crc.to_le_bytes());
}

/// `bytes` with the header's bytes from `from_end` before its end on
/// replaced by `with`, and the checksum made valid again.
fn with_header_tail(mut bytes: Vec<u8>, from_end: usize, with: &[u8]) -> Vec<u8> {
    let header_len = header_len(&bytes);
    let at = 16 + header_len - from_end;
    bytes[at..at + with.len()].copy_from_slice(with);
    fix_checksum(&mut bytes);
    bytes
}

#[test]
fn a_target_curve_is_stored_in_version_1_5_and_a_foreign_one_refused() {
    let curve = Curve { per_budget_doubling: 1.8125, per_iteration_doubling: 0.75 };
    for payload in Payload::ALL {
        for warm in [None, Some(WarmRecord { taken: WarmTaken::Kept, moved: 0 })] {
            for mut m in [model(5), model_with_support(5)] {
                m.meta.warm = warm;
                m.meta.curve = Some(curve);
                let file = read_model_file(&write_model_as(&m, payload).unwrap()).unwrap();
                assert_eq!(file.version, (1, 5));
                assert_eq!((file.model.meta.curve, file.model.meta.warm, file.model.meta.fell_back.as_deref()), (Some(curve), warm, None));
                assert_eq!(file.model.support, m.support);
            }
        }
    }
    // Without a curve, what 1.4 (or before) wrote.
    let mut m = model(3);
    m.meta.warm = Some(WarmRecord { taken: WarmTaken::Kept, moved: 0 });
    assert_eq!(read_model_file(&write_model(&m).unwrap()).unwrap().version, (1, 4));
    // The header ends with the warm record (5 bytes) and the curve (16).
    m.meta.warm = None;
    m.meta.curve = Some(curve);
    let b = write_model(&m).unwrap();
    let nan = [f64::NAN.to_le_bytes(), f64::NAN.to_le_bytes()].concat();
    assert_eq!(read_model(&with_header_tail(b.clone(), 16, &nan)).unwrap().meta.curve, None, "NaN, NaN: none");
    for bad in [[f64::NAN, 0.5], [1.5, f64::INFINITY], [0.0, 0.5], [1.5, -0.25]] {
        let e = read_model(&with_header_tail(b.clone(), 16, &[bad[0].to_le_bytes(), bad[1].to_le_bytes()].concat())).unwrap_err();
        assert!(matches!(e, Error::Format(_)) && e.to_string().contains("target curve"), "{bad:?}: {e}");
        m.meta.curve = Some(Curve { per_budget_doubling: bad[0], per_iteration_doubling: bad[1] });
        assert!(matches!(write_model(&m), Err(Error::InvalidArgument(_))), "{bad:?} is not written");
    }
    // "No warm start" is a 1.5 code: a 1.4 header holding it is refused.
    let mut m = model(3);
    m.meta.warm = Some(WarmRecord { taken: WarmTaken::Kept, moved: 0 });
    let e = read_model(&with_header_tail(write_model(&m).unwrap(), 5, &[0xff])).unwrap_err();
    assert!(matches!(e, Error::Format(_)) && e.to_string().contains("unknown warm start 255"), "{e}");
}

/// The header of a 1.2 file with its support frame replaced by `frame`,
/// with a valid checksum.
fn with_support_frame(frame: &[u8]) -> Vec<u8> {
    let b = write_model(&model_with_support(2)).unwrap();
    let header_len = header_len(&b);
    let old_len = u32::from_le_bytes(b[16 + header_len - 4 - support_bytes(&b)..][..4].try_into().unwrap()) as usize;
    let cut = 16 + header_len - old_len - 4;
    let mut out = b[..cut].to_vec();
    out.extend_from_slice(&(frame.len() as u32).to_le_bytes());
    out.extend_from_slice(frame);
    out[12..16].copy_from_slice(&((header_len - old_len + frame.len()) as u32).to_le_bytes());
    out.extend_from_slice(&b[16 + header_len..b.len() - 4]);
    let crc = crc32fast::hash(&out);
    out.extend_from_slice(&crc.to_le_bytes());
    out
}

/// Bytes of the stored support of a file written by [`write_model`].
fn support_bytes(b: &[u8]) -> usize {
    let packed = support_coding::encode(&model_with_support(2).support.unwrap(), 19).unwrap();
    assert!(b.windows(packed.len()).any(|w| w == packed.as_slice()), "the file holds the stored support");
    packed.len()
}

#[test]
fn a_corrupted_support_behind_a_valid_checksum_is_refused() {
    let bits = model_with_support(2).support.unwrap().bits().to_vec();
    // The frame rebuilt as written reads back (the helper is sound).
    assert!(read_model(&with_support_frame(&zstd::bulk::compress(&bits, 19).unwrap())).unwrap().support.is_some());
    let short = zstd::bulk::compress(&bits[..bits.len() - 1], 19).unwrap();
    let mut stray = bits.clone();
    *stray.last_mut().unwrap() = 0xff;
    stray.push(0);
    let long = zstd::bulk::compress(&stray, 19).unwrap();
    for (frame, why) in [(&b"not zstd"[..], "support"), (&short[..], "support"), (&long[..], "support"), (&[0u8; 3][..], "support")] {
        let e = read_model(&with_support_frame(frame)).unwrap_err();
        assert!(matches!(&e, Error::Format(m) if m.contains(why)), "{e}");
    }
    // An empty frame is no support.
    assert_eq!(read_model(&with_support_frame(&[])).unwrap().support, None);
    // Both codings read back to the same support, whichever the writer took
    // (the bits alone: a zero outside).
    let with_outside = model_with_support(2).support.unwrap();
    let support = with_outside.clone().with_outside(Outside::ZERO).unwrap();
    let stored = support_coding::encode(&support, 19).unwrap();
    let zstd_frame = zstd::bulk::compress(&bits, 19).unwrap();
    for frame in [&stored, &zstd_frame] {
        assert_eq!(read_model(&with_support_frame(frame)).unwrap().support.as_ref(), Some(&support));
    }
    // Behind its outside, the same bits.
    let outside_frame = support_coding::encode(&with_outside, 19).unwrap();
    assert_eq!((outside_frame[0], &outside_frame[9..]), (support_coding::OUTSIDE_TAG, &stored[..]));
    assert_eq!(read_model(&with_support_frame(&outside_frame)).unwrap().support, Some(with_outside));
    // A range coding (the smaller here) cut short, or with a stray byte, is refused.
    assert_eq!(stored[0], 1, "the support is range-coded");
    for frame in [&stored[..stored.len() - 1], &[stored.as_slice(), &[0]].concat()[..]] {
        let e = read_model(&with_support_frame(frame)).unwrap_err();
        assert!(matches!(&e, Error::Format(m) if m.contains("support is corrupted")), "{e}");
    }
}

/// A packed payload damaged behind a valid checksum: the payload's own
/// checks answer, with format errors that say what is wrong.
#[test]
fn a_corrupted_packed_payload_behind_a_valid_checksum_is_refused() {
    let bytes = write_model_as(&model(50), Payload::Packed).unwrap();
    let header_len = header_len(&bytes);
    let start = 16 + header_len;
    let resealed = |edit: &dyn Fn(&mut Vec<u8>)| {
        let mut b = bytes[..bytes.len() - 4].to_vec();
        edit(&mut b);
        let crc = crc32fast::hash(&b);
        b.extend_from_slice(&crc.to_le_bytes());
        b
    };
    // Resealed unchanged, it reads (the helper is sound).
    assert!(read_model(&resealed(&|_| {})).is_ok());
    // The first stream's body follows the layout byte, the precision (four
    // centre lattices, four groups), origin, weight map and its length.
    assert_eq!(bytes[start], 0x82, "the layout of per-class centre lattices");
    let first_stream = start + 1 + 8 + 24 + 8 + 4;
    let cases: [(&dyn Fn(&mut Vec<u8>), &str); 7] = [
        (&|b| b[start + 5] = 0, "scale group"),             // scale bits out of range
        (&|b| b[start + 2] = 9, "centre (class 1) group"),  // centre bits out of range
        (&|b| b[start] = 9, "unknown layout"),              // neither layout's first byte
        (&|b| b.truncate(start + 4), "truncated"),          // cut inside the precision
        (&|b| b[first_stream] = 9, "neither a zstd frame"), // a stream of no known coding
        (&|b| b.push(0xff), "left after the centres"),      // stray bytes after the gap bits
        (&|b| b.truncate(b.len() - 3), "ends early"),       // the gap bits cut short
    ];
    for (edit, why) in cases {
        let e = read_model(&resealed(edit)).unwrap_err();
        assert!(matches!(&e, Error::Format(m) if m.contains(why)), "{why}: {e}");
    }
}

/// Packed models of the payload's first layout (one centre lattice) still
/// read: one written before the range coding (every stream a zstd frame:
/// `fuzz/seeds/packed.gsm`, committed then) and one after
/// (`packed-range.gsm`), each to the primitives its rewrite in the current
/// layout holds (all centre classes on its lattice); the zstd one in
/// fewer bytes.
#[test]
fn packed_models_of_the_first_layout_still_read() {
    for (old, zstd_streams) in [(&include_bytes!("../fuzz/seeds/packed.gsm")[..], true), (&include_bytes!("../fuzz/seeds/packed-range.gsm")[..], false)] {
        let file = read_model_file(old).unwrap();
        assert_eq!(file.payload, Payload::Packed);
        let start = 16 + header_len(old);
        assert!(old[start] <= 8, "the first layout opens with its centre bits");
        let precision = file.model.meta.precision.unwrap();
        assert_eq!(precision, precision.with_centres(old[start]), "every class on the one lattice");
        let first_stream = start + 5 + 24 + 8 + 4;
        assert_eq!(old[first_stream..first_stream + 4] == [0x28, 0xB5, 0x2F, 0xFD], zstd_streams, "the seed's first stream");
        let new = write_model_as(&file.model, Payload::Packed).unwrap();
        assert_eq!(new[start], 0x82, "rewritten in the current layout");
        // The range-coded seed grows by the four more precision bytes and
        // the gap classes' contexts warming up on its few primitives.
        let allowed = if zstd_streams { old.len() - 1 } else { old.len() + 8 };
        assert!(new.len() <= allowed, "{} bytes rewritten, {} before", new.len(), old.len());
        let again = read_model_file(&new).unwrap();
        assert_eq!(again.model.params, file.model.params);
        assert_eq!(again.model.meta.precision, file.model.meta.precision);
    }
}

/// Packed models of the repository's data written by gsenc at commit
/// `c8e6ed6` (tests/golden/README.md), read as that commit read them:
/// every parameter, the support's bits and its outside exactly as its
/// `*.expected.zst` holds them. Their streams and supports are
/// range-coded or zstd frames, whichever was smaller: the range coder's
/// model (its probabilities' rates, each stream's and the support's
/// contexts) is part of the format, and a change to it reads these files
/// otherwise, or not at all.
#[test]
fn packed_goldens_read_as_they_were_written() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/golden");
    for (name, outside) in [("hydrogen32_packed", true), ("dambreak40_packed", false)] {
        let bytes = std::fs::read(dir.join(format!("{name}.gsm"))).unwrap();
        let file = read_model_file(&bytes).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!((file.payload, file.version), (Payload::Packed, (1, 2)), "{name}");
        // u32 count n, n x 12 float32 parameters, the outside's offset and
        // gain (float32), then the support's bits as Support::bits holds them.
        let want = zstd::stream::decode_all(&std::fs::read(dir.join(format!("{name}.expected.zst"))).unwrap()[..]).unwrap();
        let n = u32::from_le_bytes(want[..4].try_into().unwrap()) as usize;
        let (numbers, bits) = want[4..].split_at(4 * (12 * n + 2));
        let numbers: Vec<f32> = numbers.chunks_exact(4).map(|b| f32::from_le_bytes(b.try_into().unwrap())).collect();
        let params: Vec<[f32; 12]> = numbers[..12 * n].chunks_exact(12).map(|c| c.try_into().unwrap()).collect();
        assert!(file.model.params == params, "{name}: the parameters read otherwise");
        let support = file.model.support.as_ref().unwrap_or_else(|| panic!("{name}: no support"));
        assert_eq!(support.outside(), Outside { offset: numbers[12 * n], gain: numbers[12 * n + 1] }, "{name}");
        assert_eq!(!support.outside().is_zero(), outside, "{name}");
        assert!(support.bits() == bits, "{name}: the support reads otherwise");
    }
}
