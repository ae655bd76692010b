//! Time series: warm starts begin where the previous model ended, the value
//! range is the series', independent steps stay available, and steps that
//! do not fit the series are refused with clear errors.

mod common;
use common::blobs;
use gsenc::backend::cpu::CpuBackend;
use gsenc::encode::{encode, EncodeConfig, Schedule, Validation};
use gsenc::input::Target;
use gsenc::field::{Grid, IndexFrame, Transform, ValueRange};
use gsenc::math::loss::MASK_REF;
use gsenc::model::Outside;
use gsenc::encode::WarmStart;
use gsenc::input::Input;
use gsenc::series::{SeriesConfig, SeriesEncoder, SeriesRange};
use gsenc::Error;

const DIMS: [usize; 3] = [24, 20, 16];

fn frame(dims: [usize; 3]) -> IndexFrame {
    IndexFrame { dims, bmin: [0.0; 3], gamma: 1.0 }
}

/// Step `k` of a field in data units [2, 12]: blobs drifting with k.
fn step_grid(k: u64, dims: [usize; 3]) -> Grid {
    let g = blobs(dims, 40 + k, 4);
    Grid::new(dims, g.values.iter().map(|v| 2.0 + 10.0 * v).collect()).unwrap()
}

fn base() -> EncodeConfig {
    let mut c = EncodeConfig::new(150, Schedule::Short);
    c.iterations = Some(120);
    c.points = Some(1024);
    c
}

fn series(warm: WarmStart, range: SeriesRange) -> SeriesEncoder {
    let mut cfg = SeriesConfig::new(base(), warm, range);
    cfg.validation_points = 4096;
    cfg.validation_every = 20;
    SeriesEncoder::new(cfg).unwrap()
}

/// PSNR of `model` decoded on the reference lattice, at the series' fixed
/// validation points (the same draw as `SeriesConfig`'s seed). Validation
/// scores fit the support's outside on their own points (the lattice is
/// not at hand while training): with `refit`, so is the model's.
fn psnr_at_validation_points(model: &gsenc::model::Model, reference: &Grid, refit: bool) -> f64 {
    let seed = SeriesConfig::new(base(), WarmStart::Off, SeriesRange::FirstStep(Transform::Linear)).validation_seed;
    let v = Validation::from_reference(reference, 4096, seed, 20).unwrap();
    let mut model = model.clone();
    if let Some(support) = model.support.take_if(|_| refit) {
        let bare = model.decode(&mut CpuBackend::new(), None).unwrap();
        let at = |p: &[f32; 3]| p[0] as usize + DIMS[0] * (p[1] as usize + DIMS[1] * p[2] as usize);
        let at_points: Vec<f32> = v.points.iter().map(|p| bare.values[at(p)]).collect();
        let outside = Outside::choose(&at_points, &v.values, |i| v.values[i] <= MASK_REF);
        model.support = Some(support.with_outside(outside).unwrap());
    }
    let decoded = model.decode(&mut CpuBackend::new(), None).unwrap();
    let se: f64 = v
        .points
        .iter()
        .zip(&v.values)
        .map(|(p, &r)| {
            let i = p[0] as usize + DIMS[0] * (p[1] as usize + DIMS[1] * p[2] as usize);
            ((decoded.values[i] - r) as f64).powi(2)
        })
        .sum();
    gsenc::model::metrics::psnr_from_mse(se / v.points.len() as f64)
}

#[test]
fn a_warm_start_begins_at_the_previous_models_psnr() {
    let mut s = series(WarmStart::Coarse, SeriesRange::FirstStep(Transform::Linear));
    let g = step_grid(0, DIMS);
    let mut cpu = CpuBackend::new();
    let first = s.encode_step("rho", 0, None, Input::Grid { values: &g, frame: frame(DIMS) }, &mut cpu, &mut |_| {}).unwrap();
    assert!(!first.encoded.warm_started);
    // The same field again: a warm start scores, before its first update,
    // exactly what the previous model scores.
    let second = s.encode_step("rho", 1, Some(0.5), Input::Grid { values: &g, frame: frame(DIMS) }, &mut cpu, &mut |_| {}).unwrap();
    assert!(second.encoded.warm_started);
    assert_eq!(second.encoded.output.iterations, 1000, "coarse stride: 1000 iterations");
    assert!(second.encoded.output.relocations.is_empty(), "coarse stride: no relocation");
    assert!(second.encoded.output.seeding.is_none(), "a warm start does not seed");
    assert_eq!(second.encoded.model.len(), first.encoded.model.len());
    // Independently: decode the first model and score it on the same points.
    let range = s.range("rho").unwrap();
    let reference = Grid::new(DIMS, range.normalize(&g.values).unwrap().values).unwrap();
    let want = psnr_at_validation_points(&first.encoded.model, &reference, true);
    let (t0, p0) = second.encoded.output.validation[0];
    assert_eq!(t0, 0);
    assert!((p0 - want).abs() < 1e-3, "warm start begins at {p0} dB, the previous model scores {want} dB");
    // The outside fitted on the points is nearly the lattice's.
    let stored = psnr_at_validation_points(&first.encoded.model, &reference, false);
    assert!((stored - want).abs() < 0.05, "{stored} dB with the stored outside, {want} with the points'");
    assert!((first.encoded.output.validation.last().unwrap().1 - want).abs() < 1e-3);
    // A seeded start begins far lower.
    assert!(first.encoded.output.validation[0].1 < p0 - 3.0, "{:?}", first.encoded.output.validation);
    // And the log covers the run: 0, every 20, and the end.
    let its: Vec<usize> = second.encoded.output.validation.iter().map(|&(t, _)| t).collect();
    assert_eq!(its, (0..1000).step_by(20).chain([1000]).collect::<Vec<_>>());
}

#[test]
fn the_series_range_is_the_first_steps_and_later_values_are_clamped() {
    let mut s = series(WarmStart::Dense, SeriesRange::FirstStep(Transform::Linear));
    let mut cpu = CpuBackend::new();
    let g0 = step_grid(0, DIMS);
    let r0 = s.encode_step("rho", 0, None, Input::Grid { values: &g0, frame: frame(DIMS) }, &mut cpu, &mut |_| {}).unwrap();
    let want = ValueRange::from_data(&g0.values, Transform::Linear).unwrap();
    assert_eq!(r0.encoded.model.meta.range, want);
    assert_eq!(r0.prepared.clamped_values, 0);
    // Step 1 spans [0, 24]: outside the series' range on both sides.
    let g1 = Grid::new(DIMS, step_grid(1, DIMS).values.iter().map(|v| (v - 2.0) * 2.4).collect()).unwrap();
    let outside = g1.values.iter().filter(|&&v| (v as f64) < want.vmin || (v as f64) > want.vmax).count();
    assert!(outside > 0);
    let r1 = s.encode_step("rho", 5, None, Input::Grid { values: &g1, frame: frame(DIMS) }, &mut cpu, &mut |_| {}).unwrap();
    assert_eq!(r1.encoded.model.meta.range, want, "the range is the series', not the step's");
    assert_eq!(r1.prepared.clamped_values, outside);
    assert_eq!(r1.encoded.output.iterations, 1500, "dense stride: 1500 iterations");
    assert_eq!(r1.encoded.output.relocations.len(), 3, "dense stride: relocation on");
    assert_eq!(r1.encoded.model.meta.step, 5);
    // Validation scores each step against its own reference, on the first
    // step's points.
    let ref1 = Grid::new(DIMS, want.normalize(&g1.values).unwrap().values).unwrap();
    let p1 = psnr_at_validation_points(&r1.encoded.model, &ref1, true);
    assert!((r1.encoded.output.validation.last().unwrap().1 - p1).abs() < 1e-3, "{:?} vs {p1}", r1.encoded.output.validation.last());
    // A fixed range is used from the first step on.
    let fixed = ValueRange::new(0.0, 30.0, Transform::Linear).unwrap();
    let mut s = series(WarmStart::Dense, SeriesRange::Fixed(fixed));
    let r = s.encode_step("rho", 0, None, Input::Grid { values: &g0, frame: frame(DIMS) }, &mut cpu, &mut |_| {}).unwrap();
    assert_eq!(r.encoded.model.meta.range, fixed);
}

#[test]
fn independent_steps_equal_standalone_encodes() {
    let mut s = series(WarmStart::Off, SeriesRange::FirstStep(Transform::Linear));
    let mut cpu = CpuBackend::new();
    let g0 = step_grid(0, DIMS);
    let g1 = step_grid(1, DIMS);
    s.encode_step("rho", 0, None, Input::Grid { values: &g0, frame: frame(DIMS) }, &mut cpu, &mut |_| {}).unwrap();
    let r1 = s.encode_step("rho", 1, None, Input::Grid { values: &g1, frame: frame(DIMS) }, &mut cpu, &mut |_| {}).unwrap();
    assert!(!r1.encoded.warm_started);
    let range = s.range("rho").unwrap();
    let reference = Grid::new(DIMS, range.normalize(&g1.values).unwrap().values).unwrap();
    let alone = encode(&Target { reference: &reference, samples: &reference }, &base(), None, &mut cpu, &mut |_| {}).unwrap();
    assert_eq!(r1.encoded.model.params, alone.params, "validation scoring must not change the model");
}

#[test]
fn steps_that_do_not_fit_the_series_are_refused() {
    let mut s = series(WarmStart::Coarse, SeriesRange::FirstStep(Transform::Linear));
    let mut cpu = CpuBackend::new();
    let g0 = step_grid(0, DIMS);
    s.encode_step("rho", 3, None, Input::Grid { values: &g0, frame: frame(DIMS) }, &mut cpu, &mut |_| {}).unwrap();
    // Another lattice.
    let other = [20, 20, 16];
    let g = step_grid(1, other);
    let e = s.encode_step("rho", 4, None, Input::Grid { values: &g, frame: frame(other) }, &mut cpu, &mut |_| {});
    assert!(matches!(&e, Err(Error::InvalidArgument(m)) if m.contains("lattice")), "{:?}", e.err());
    // A step that does not follow the last one.
    let e = s.encode_step("rho", 3, None, Input::Grid { values: &g0, frame: frame(DIMS) }, &mut cpu, &mut |_| {});
    assert!(matches!(&e, Err(Error::InvalidArgument(m)) if m.contains("does not follow")), "{:?}", e.err());
    // Values and frame that disagree, a missing field name, NaN values.
    let e = s.encode_step("rho", 9, None, Input::Grid { values: &g0, frame: frame(other) }, &mut cpu, &mut |_| {});
    assert!(matches!(e, Err(Error::InvalidArgument(_))));
    let e = s.encode_step("", 9, None, Input::Grid { values: &g0, frame: frame(DIMS) }, &mut cpu, &mut |_| {});
    assert!(matches!(e, Err(Error::InvalidArgument(_))));
    let mut bad = g0.clone();
    bad.values[17] = f32::NAN;
    let e = s.encode_step("rho", 9, None, Input::Grid { values: &bad, frame: frame(DIMS) }, &mut cpu, &mut |_| {});
    assert!(matches!(e, Err(Error::InvalidData(_))));
    // None of these touched the series: step 4 on the series' lattice works
    // and warm-starts from step 3.
    let r = s.encode_step("rho", 4, None, Input::Grid { values: &g0, frame: frame(DIMS) }, &mut cpu, &mut |_| {}).unwrap();
    assert!(r.encoded.warm_started);
    // Another field starts its own series.
    let r = s.encode_step("temp", 0, None, Input::Grid { values: &g, frame: frame(other) }, &mut cpu, &mut |_| {}).unwrap();
    assert!(!r.encoded.warm_started);
}

#[test]
fn a_resumed_series_continues_exactly_as_an_unbroken_one() {
    let mut cpu = CpuBackend::new();
    let steps: Vec<Grid> = (0..3).map(|k| step_grid(k, DIMS)).collect();
    let mut unbroken = series(WarmStart::Coarse, SeriesRange::FirstStep(Transform::Linear));
    let mut models = Vec::new();
    for (k, g) in steps.iter().enumerate() {
        let r = unbroken.encode_step("rho", k as u64, None, Input::Grid { values: g, frame: frame(DIMS) }, &mut cpu, &mut |_| {}).unwrap();
        models.push(r);
    }
    // Stop after step 1 (its model stored and read back), start again.
    let stored = gsenc::format::read_model(&gsenc::format::write_model(&models[1].encoded.model).unwrap()).unwrap();
    let mut resumed = series(WarmStart::Coarse, SeriesRange::FirstStep(Transform::Linear));
    resumed.resume(stored.clone()).unwrap();
    assert_eq!(resumed.range("rho"), unbroken.range("rho"));
    let r = resumed.encode_step("rho", 2, None, Input::Grid { values: &steps[2], frame: frame(DIMS) }, &mut cpu, &mut |_| {}).unwrap();
    assert!(r.encoded.warm_started);
    assert_eq!(r.encoded.model.params, models[2].encoded.model.params, "the resumed step differs from the unbroken series'");
    assert_eq!(r.encoded.output.validation, models[2].encoded.output.validation, "the validation points differ");
    // A step on a shifted box is refused, as is resuming a field twice.
    let mut shifted = series(WarmStart::Coarse, SeriesRange::FirstStep(Transform::Linear));
    shifted.resume(stored.clone()).unwrap();
    let moved = IndexFrame { bmin: [0.5, 0.0, 0.0], ..frame(DIMS) };
    let e = shifted.encode_step("rho", 2, None, Input::Grid { values: &steps[2], frame: moved }, &mut cpu, &mut |_| {});
    assert!(matches!(&e, Err(Error::InvalidArgument(m)) if m.contains("box")), "{:?}", e.err());
    assert!(matches!(shifted.resume(stored.clone()), Err(Error::InvalidArgument(_))));
    // A series configured with another range, transform or rank does not
    // continue the model (it would encode on the model's range, not its own).
    let range = stored.meta.range;
    let other_range = ValueRange::new(range.vmin, range.vmax * 2.0, Transform::Linear).unwrap();
    let mut rank1 = SeriesConfig::new(base(), WarmStart::Coarse, SeriesRange::FirstStep(Transform::Linear));
    rank1.rank = 1;
    for (cfg, says) in [
        (SeriesConfig::new(base(), WarmStart::Coarse, SeriesRange::Fixed(other_range)), "keeps its range"),
        (SeriesConfig::new(base(), WarmStart::Coarse, SeriesRange::FirstStep(Transform::Log10)), "keeps its range"),
        (rank1, "rank 0's piece; this is rank 1"),
    ] {
        let e = SeriesEncoder::new(cfg).unwrap().resume(stored.clone());
        assert!(matches!(&e, Err(Error::InvalidArgument(m)) if m.contains(says)), "{:?}", e.err());
    }
    // The range it was encoded with, given, is its own.
    SeriesEncoder::new(SeriesConfig::new(base(), WarmStart::Coarse, SeriesRange::Fixed(range))).unwrap().resume(stored).unwrap();
}

/// Particles without configured bounds: the unbroken series deposits every
/// step in its first step's data box, which the stored model no longer
/// holds; the resumed series deposits on the model's lattice all the same
/// (though the lattice's own box gives another voxel size here), so its
/// steps equal the unbroken series'.
#[test]
fn a_resumed_particle_series_keeps_its_first_steps_box() {
    use gsenc::input::particles::Particles;
    use gsenc::input::Placement;
    let mut cpu = CpuBackend::new();
    let n = 600;
    let dims = [20, 14, 9];
    // The first draw whose lattice's own box gives another voxel size.
    let draw = |seed: u64| -> Vec<[f64; 3]> {
        let mut rng = gsenc::math::rng::Rng::new(seed);
        (0..n).map(|_| [rng.range(0.013, 0.977), rng.range(0.021, 0.69), rng.range(0.05, 0.5)]).collect()
    };
    let box_differs = |pos: &[[f64; 3]]| {
        let lo: [f64; 3] = std::array::from_fn(|a| pos.iter().map(|p| p[a]).fold(f64::INFINITY, f64::min));
        let hi: [f64; 3] = std::array::from_fn(|a| pos.iter().map(|p| p[a]).fold(f64::NEG_INFINITY, f64::max));
        let f = IndexFrame::from_bounds(dims, lo, hi).unwrap();
        let w = f.world_box();
        IndexFrame::from_bounds(dims, w.min, w.max).unwrap() != f
    };
    let base = (1..100).map(draw).find(|b| box_differs(b)).expect("a draw whose lattice's box gives another voxel size");
    // Step k: drifted by 0.01 k along x, values of a bump that moves.
    let step = |k: usize| -> (Vec<[f64; 3]>, Vec<f32>) {
        let pos: Vec<[f64; 3]> = base.iter().map(|p| [p[0] + 0.01 * k as f64, p[1], p[2]]).collect();
        let values = pos.iter().map(|p| (1.0 + (-(p[0] - 0.3 - 0.05 * k as f64).powi(2) / 0.02).exp()) as f32).collect();
        (pos, values)
    };
    let (h, mass) = (vec![0.06; n], vec![1.0f32; n]);
    let placement = Placement::new(dims, None);
    let mut unbroken = series(WarmStart::Coarse, SeriesRange::FirstStep(Transform::Linear));
    let mut models = Vec::new();
    for k in 0..3 {
        let (pos, values) = step(k);
        let particles = Particles { positions: &pos, smoothing_length: &h, mass: &mass, values: &values };
        let r = unbroken.encode_step("gas", k as u64, None, Input::Particles { particles: &particles, placement }, &mut cpu, &mut |_| {}).unwrap();
        models.push(r.encoded.model);
    }
    let stored = gsenc::format::read_model(&gsenc::format::write_model(&models[1]).unwrap()).unwrap();
    let mut resumed = series(WarmStart::Coarse, SeriesRange::FirstStep(Transform::Linear));
    resumed.resume(stored).unwrap();
    let (pos, values) = step(2);
    let particles = Particles { positions: &pos, smoothing_length: &h, mass: &mass, values: &values };
    let r = resumed.encode_step("gas", 2, None, Input::Particles { particles: &particles, placement }, &mut cpu, &mut |_| {}).unwrap();
    assert_eq!(r.encoded.model.meta.frame, models[2].meta.frame);
    assert_eq!(r.encoded.model.params, models[2].params, "the resumed step differs from the unbroken series'");
}
