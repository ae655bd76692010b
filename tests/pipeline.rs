//! The one encode pipeline: the configuration follows the input's form and
//! the start, the model carries its labels, and the PSNR it records is that
//! of the file as written (checked by writing, reading and decoding it).

mod common;
use common::blobs;
use gsenc::backend::cpu::CpuBackend;
use gsenc::encode::pipeline::{self, config_for, Labels, Request, Start};
use gsenc::encode::{encode, EncodeConfig, PointRule, Schedule, WarmStart};
use gsenc::field::{IndexFrame, Transform, ValueRange};
use gsenc::format::quantize::CentreCoding;
use gsenc::format::packed::Precision;
use gsenc::format::{read_model, read_model_file, write_model_as, Payload};
use gsenc::input::particles::Particles;
use gsenc::input::{prepare, Form, Input, Placement, RangeSpec};
use gsenc::math::rng::Rng;
use gsenc::math::loss::LossWeights;
use gsenc::model::metrics::voxel_psnr;

#[test]
fn the_schedule_follows_the_form_and_the_start() {
    let base = EncodeConfig::new(100, Schedule::Full);
    let seeded = |form| config_for(&base, form, &Start::Seeded);
    assert_eq!(seeded(Form::Particles).iterations(), 4000);
    assert_eq!(seeded(Form::Grid).iterations(), 3000);
    assert_eq!(seeded(Form::Cells).iterations(), 3000);
    assert_eq!(seeded(Form::Particles).points(), 16384);
    let params = vec![[0.0f32; 12]; 100];
    let warm = |regime, iterations| config_for(&base, Form::Particles, &Start::Warm { params: &params, regime, iterations });
    assert_eq!((warm(WarmStart::Coarse, None).iterations(), warm(WarmStart::Coarse, None).relocation), (1000, false));
    assert_eq!((warm(WarmStart::Dense, None).iterations(), warm(WarmStart::Dense, None).relocation), (1500, true));
    assert_eq!(warm(WarmStart::Dense, Some(70)).iterations(), 70);
    // gsenc's `tuned`: matched's iterations and points at five times its learning rate.
    let tuned = config_for(&EncodeConfig::new(100, Schedule::Tuned), Form::Particles, &Start::Seeded);
    let matched = config_for(&EncodeConfig::new(100, Schedule::Matched), Form::Particles, &Start::Seeded);
    assert_eq!((tuned.iterations(), tuned.points()), (matched.iterations(), matched.points()));
    assert!((tuned.learning_rate - 5.0 * matched.learning_rate).abs() < 1e-7, "{}", tuned.learning_rate);
    assert_eq!(Schedule::from_name("tuned").unwrap(), Schedule::Tuned);
    // gsenc's `tuned-full`: full's iterations and points (longer for
    // particles) at tuned's learning rate.
    for form in [Form::Particles, Form::Grid] {
        let long = config_for(&EncodeConfig::new(100, Schedule::TunedFull), form, &Start::Seeded);
        let full = config_for(&base, form, &Start::Seeded);
        assert_eq!((long.iterations(), long.points()), (full.iterations(), full.points()));
        assert_eq!(long.learning_rate, tuned.learning_rate);
    }
    assert_eq!(Schedule::from_name("tuned-full").unwrap(), Schedule::TunedFull);
    // gsenc's two draw gsenc's training points under gsenc's objective;
    // the paper's, the paper's.
    for s in Schedule::ALL {
        let gsenc = matches!(s, Schedule::Tuned | Schedule::TunedFull);
        let cfg = EncodeConfig::new(100, s);
        assert_eq!(cfg.point_rule, if gsenc { PointRule::GSENC } else { PointRule::PAPER }, "{s:?}");
        assert_eq!(cfg.weights, if gsenc { LossWeights::GSENC } else { LossWeights::PAPER }, "{s:?}");
    }
    // A caller's overrides stand for a seeded encode.
    let mut short = base.clone();
    short.iterations = Some(12);
    assert_eq!(config_for(&short, Form::Particles, &Start::Seeded).iterations(), 12);
}

#[test]
fn a_grid_encode_is_the_refinement_loops_model_labelled_and_scored_as_stored() {
    let g = blobs([20, 16, 12], 3, 4);
    let values: Vec<f32> = g.values.iter().map(|v| 10.0 + 90.0 * v).collect();
    let grid = gsenc::field::Grid::new(g.dims, values).unwrap();
    let frame = IndexFrame::for_grid(grid.dims, [-1.0, 2.0, 0.5], 0.25).unwrap();
    let mut cfg = EncodeConfig::new(120, Schedule::Short);
    cfg.iterations = Some(60);
    cfg.points = Some(1024);
    let payload = Payload::Bits8(CentreCoding::Float16);
    let labels = Labels { field: "rho".into(), step: 7, time: Some(-0.5), rank: 3 };
    let request = Request { config: cfg.clone(), start: Start::Seeded, payload, store_support: false, labels: labels.clone(), validation: None };
    let range = RangeSpec::FromData(Transform::Linear);
    let (prepared, encoded) =
        pipeline::encode(&Input::Grid { values: &grid, frame }, &range, &request, &mut CpuBackend::new(), &mut |_| {}).unwrap();

    // The parameters are the refinement loop's on the prepared target.
    let direct = encode(&prepared.target(), &cfg, None, &mut CpuBackend::new(), &mut |_| {}).unwrap();
    assert_eq!(encoded.model.params, direct.params);

    let m = &encoded.model.meta;
    assert_eq!((m.field.as_str(), m.step, m.time, m.rank), ("rho", 7, Some(-0.5), 3));
    assert_eq!((m.schedule.as_str(), m.iterations, m.points, m.seed_init, m.seed_sample), ("short", 60, 1024, 0, 1));
    assert_eq!(m.frame, frame);
    assert_eq!(m.range, ValueRange::from_data(&grid.values, Transform::Linear).unwrap());
    assert!(!encoded.warm_started);

    // The recorded PSNR is that of the 8-bit file: write it, read it back,
    // decode it, score it; the float32 parameters score differently.
    let stored = read_model(&write_model_as(&encoded.model, payload).unwrap()).unwrap();
    let decoded = stored.decode(&mut CpuBackend::new(), None).unwrap();
    let psnr = voxel_psnr(&decoded.values, &prepared.reference.values);
    assert!((psnr - encoded.psnr).abs() < 1e-9, "file {psnr} dB, recorded {} dB", encoded.psnr);
    assert_eq!(m.encode_psnr, Some(encoded.psnr));
    let float = encoded.model.decode(&mut CpuBackend::new(), None).unwrap();
    assert_ne!(voxel_psnr(&float.values, &prepared.reference.values), encoded.psnr, "the 8-bit round trip was not applied");
}

#[test]
fn a_grid_whose_frame_is_not_finite_is_refused_before_any_work() {
    let g = blobs([8, 8, 8], 3, 2);
    let range = RangeSpec::FromData(Transform::Linear);
    for (bmin, gamma) in [([f64::NAN, 0.0, 0.0], 1.0), ([0.0; 3], f64::INFINITY), ([0.0; 3], 0.0)] {
        let frame = IndexFrame { dims: g.dims, bmin, gamma };
        let Err(e) = prepare(&Input::Grid { values: &g, frame }, &range) else { panic!("a frame at {bmin:?}, gamma {gamma} was taken") };
        assert!(matches!(e, gsenc::Error::InvalidArgument(_)) && e.to_string().contains("finite"), "{e}");
    }
}

#[test]
fn particles_run_the_longer_full_schedule_and_a_warm_start_its_regime() {
    let mut rng = Rng::new(4);
    let n = 300;
    let positions: Vec<[f64; 3]> = (0..n).map(|_| [rng.range(0.0, 1.0), rng.range(0.0, 1.0), rng.range(0.0, 1.0)]).collect();
    let values: Vec<f32> = positions.iter().map(|p| (1.0 + (-(p[0] - 0.5).powi(2) / 0.05).exp()) as f32).collect();
    let (h, mass) = (vec![0.08; n], vec![1.0f32; n]);
    let particles = Particles { positions: &positions, smoothing_length: &h, mass: &mass, values: &values };
    let input = Input::Particles { particles: &particles, placement: Placement::new([8; 3], None) };
    let range = RangeSpec::FromData(Transform::Linear);
    let prepared = prepare(&input, &range).unwrap();
    assert_eq!(prepared.form, Form::Particles);
    let mut cfg = EncodeConfig::new(20, Schedule::Full);
    cfg.points = Some(64);
    let mut iterations_seen = 0;
    let first = pipeline::encode_prepared(&prepared, &Request::new(cfg.clone()), &mut CpuBackend::new(), &mut |p| {
        iterations_seen = p.iterations
    })
    .unwrap();
    assert_eq!((first.output.iterations, iterations_seen, first.model.meta.iterations), (4000, 4000, 4000));
    assert_eq!(first.model.meta.schedule, "full");

    let warm = Request { start: Start::Warm { params: &first.model.params, regime: WarmStart::Coarse, iterations: None }, ..Request::new(cfg) };
    let second = pipeline::encode_prepared(&prepared, &warm, &mut CpuBackend::new(), &mut |_| {}).unwrap();
    assert!(second.warm_started && second.output.seeding.is_none() && second.output.relocations.is_empty());
    assert_eq!((second.model.meta.schedule.as_str(), second.output.iterations), ("warm-coarse", 1000));
}

#[test]
fn a_packed_encode_measures_its_precision_and_loses_at_most_a_tenth_of_a_db() {
    let g = blobs([28, 24, 20], 5, 6);
    // Empty corners (a support) and a field without one.
    let holed: Vec<f32> = g.values.iter().map(|&v| if v < 0.05 { 0.0 } else { v }).collect();
    for (values, store_support) in [(holed, true), (g.values.clone(), false)] {
        let grid = gsenc::field::Grid::new(g.dims, values).unwrap();
        let frame = IndexFrame::for_grid(grid.dims, [0.0; 3], 1.0).unwrap();
        let mut cfg = EncodeConfig::new(300, Schedule::Short);
        cfg.iterations = Some(200);
        let request = Request { payload: Payload::Packed, store_support, ..Request::new(cfg) };
        let range = RangeSpec::FromData(Transform::Linear);
        let input = Input::Grid { values: &grid, frame };
        let (prepared, encoded) = pipeline::encode(&input, &range, &request, &mut CpuBackend::new(), &mut |_| {}).unwrap();
        let precision = encoded.model.meta.precision.expect("a packed encode measures its precision");
        assert_ne!(precision, Precision::FINEST, "the search gave up no bit");
        assert_eq!(encoded.model.support.is_some(), store_support);

        // Independently: the file as written, decoded on the whole lattice,
        // against the float32 model's decode.
        let bytes = write_model_as(&encoded.model, Payload::Packed).unwrap();
        let file = read_model_file(&bytes).unwrap();
        assert_eq!(file.model.meta.precision, Some(precision));
        let reference = &prepared.reference.values;
        let stored = voxel_psnr(&file.model.decode(&mut CpuBackend::new(), None).unwrap().values, reference);
        let float = voxel_psnr(&encoded.model.decode(&mut CpuBackend::new(), None).unwrap().values, reference);
        assert!((stored - encoded.psnr).abs() < 1e-9, "file {stored} dB, recorded {} dB", encoded.psnr);
        assert_eq!(encoded.float32_psnr, Some(float));
        assert!(float - stored <= 0.1, "support {store_support}: the packed payload lost {} dB", float - stored);
        assert!(float - stored > 0.0, "support {store_support}: nothing was lost: the precision was not lowered");

        // Smaller than the 8-bit payload of the same model.
        let eight = read_model_file(&write_model_as(&encoded.model, Payload::Bits8(CentreCoding::Fixed16)).unwrap()).unwrap();
        assert!(file.payload_bytes * 10 < eight.payload_bytes * 8, "packed {} bytes, 8bit-u16 {}", file.payload_bytes, eight.payload_bytes);

        // The same input gives the same file.
        let (_, again) = pipeline::encode(&input, &range, &request, &mut CpuBackend::new(), &mut |_| {}).unwrap();
        assert_eq!(write_model_as(&again.model, Payload::Packed).unwrap(), bytes);
    }
}

#[test]
fn the_tuned_schedule_trains_at_its_own_rate_and_says_so() {
    let g = blobs([20, 16, 12], 3, 4);
    let frame = IndexFrame::for_grid(g.dims, [0.0; 3], 1.0).unwrap();
    let run = |schedule| {
        let mut cfg = EncodeConfig::new(120, schedule);
        cfg.iterations = Some(80);
        cfg.points = Some(1024);
        cfg.relocation = false; // Adam's steps alone, which scale with the rate
        cfg.point_rule = PointRule::PAPER; // the same points for both
        encode_grid(&g, frame, &Request::new(cfg))
    };
    let (tuned, matched) = (run(Schedule::Tuned), run(Schedule::Matched));
    assert_eq!(tuned.model.meta.schedule, "tuned");
    // The same seeding and points: only the learning rate differs, and it is
    // used: Adam's steps are about the rate each, so the centres travel further.
    assert_ne!(tuned.model.params, matched.model.params);
    let moved = |e: &pipeline::Encoded, seeded: &[[f32; 12]]| e.model.params.iter().zip(seeded).map(|(a, b)| (a[0] - b[0]).abs() as f64).sum::<f64>();
    let mut cfg = EncodeConfig::new(120, Schedule::Matched);
    cfg.iterations = Some(0);
    let seeded = encode_grid(&g, frame, &Request::new(cfg)).model.params;
    assert!(moved(&tuned, &seeded) > 1.3 * moved(&matched, &seeded), "centres moved {} (tuned) vs {} (matched)", moved(&tuned, &seeded), moved(&matched, &seeded));
}

#[test]
fn voxel_centre_points_need_the_stored_support() {
    let g = blobs([16, 14, 12], 5, 3);
    let frame = IndexFrame::for_grid(g.dims, [0.0; 3], 1.0).unwrap();
    let run = |store_support| {
        let mut cfg = EncodeConfig::new(60, Schedule::Tuned);
        cfg.iterations = Some(30);
        cfg.points = Some(512);
        encode_grid(&g, frame, &Request { store_support, ..Request::new(cfg) })
    };
    let (with, without) = (run(true), run(false));
    assert_eq!(with.config.point_rule, PointRule::GSENC);
    // Without a support nothing would teach the empty voxels beside the
    // data: the paper's jittered points, and still the error stratum.
    assert_eq!(without.config.point_rule, PointRule { on_lattice: false, ..PointRule::GSENC });
    assert_ne!(with.model.params, without.model.params);
}

/// `g` (its own range) encoded through the pipeline on the CPU.
fn encode_grid(g: &gsenc::field::Grid, frame: IndexFrame, request: &Request) -> pipeline::Encoded {
    let range = RangeSpec::FromData(Transform::Linear);
    pipeline::encode(&Input::Grid { values: g, frame }, &range, request, &mut CpuBackend::new(), &mut |_| {}).unwrap().1
}
