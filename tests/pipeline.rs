//! The one encode pipeline: the configuration follows the input's form and
//! the start, the model carries its labels, and the PSNR it records is that
//! of the file as written (checked by writing, reading and decoding it).

mod common;
use common::blobs;
use gsenc::backend::cpu::CpuBackend;
use gsenc::encode::pipeline::{self, config_for, Labels, Request, Start};
use gsenc::encode::{encode, EncodeConfig, Schedule, WarmStart};
use gsenc::field::{IndexFrame, Transform, ValueRange};
use gsenc::format::quantize::CentreCoding;
use gsenc::format::{read_model, write_model_as, Payload};
use gsenc::input::particles::Particles;
use gsenc::input::{prepare, Form, Input, Placement, RangeSpec};
use gsenc::math::rng::Rng;
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
fn particles_run_the_longer_full_schedule_and_a_warm_start_its_regime() {
    let mut rng = Rng::new(4);
    let n = 300;
    let positions: Vec<[f64; 3]> = (0..n).map(|_| [rng.range(0.0, 1.0), rng.range(0.0, 1.0), rng.range(0.0, 1.0)]).collect();
    let values: Vec<f32> = positions.iter().map(|p| (1.0 + (-(p[0] - 0.5).powi(2) / 0.05).exp()) as f32).collect();
    let (h, mass) = (vec![0.08; n], vec![1.0f32; n]);
    let particles = Particles { positions: &positions, smoothing_length: &h, mass: &mass, values: &values };
    let input = Input::Particles { particles: &particles, placement: Placement { dims: [8; 3], bounds: None } };
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
