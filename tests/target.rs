//! A quality instead of a budget (METHOD.md "A quality instead of a
//! budget"): target-PSNR encodes of the repository's real data land within
//! 1 dB of their targets, measured by decoding the model they return; a
//! target out of reach ends at the cap and says so; bad targets are
//! refused; a series changes its budget only at a step that misses (and
//! not beyond its cap), and does so alike when resumed after a restart.

mod common;

use common::{blobs, repo_data};
use gsenc::backend::cpu::CpuBackend;
use gsenc::encode::pipeline::{encode, Encoded, Request};
use gsenc::encode::target::{TargetReport, Try, AIM_DB, DEFAULT_CURVE, LANDS_ABOVE_DB, LANDS_BELOW_DB, MIN_BUDGET, MIN_SLOPE_DB};
use gsenc::format::{read_model, write_model};
use gsenc::encode::{EncodeConfig, Schedule, TargetPsnr, WarmStart};
use gsenc::field::{Grid, IndexFrame, Transform};
use gsenc::input::cells::{CellSize, Cells};
use gsenc::input::{Input, Placement, Prepared, RangeSpec};
use gsenc::io::raw::{read_items, read_raw, DType, Order, Rows};
use gsenc::model::metrics::voxel_psnr;
use gsenc::series::{SeriesConfig, SeriesEncoder, SeriesRange};

/// `matched` cut to 600 iterations (probes of 150 and 300), targeting `db`,
/// with at most `cap` primitives (0: the default cap).
fn config(db: f64, cap: usize) -> EncodeConfig {
    let mut cfg = EncodeConfig::new(cap, Schedule::Matched);
    cfg.iterations = Some(600);
    cfg.target = Some(TargetPsnr::new(db).unwrap());
    cfg
}

fn encode_to(input: &Input, range: RangeSpec, cfg: EncodeConfig) -> (Prepared, Encoded) {
    encode(input, &range, &Request::new(cfg), &mut CpuBackend::new(), &mut |_| {}).unwrap()
}

/// The model's PSNR computed again: decoded on the reference lattice
/// (with its support), against the reference.
fn decoded_psnr(prepared: &Prepared, e: &Encoded) -> f64 {
    let decoded = e.model.decode(&mut CpuBackend::new(), None).unwrap();
    voxel_psnr(&decoded.values, &prepared.reference.values)
}

/// What every target-PSNR encode must show: the model is the chosen try,
/// its stored PSNR what a decode measures, within 1 dB of the target.
fn check(name: &str, prepared: &Prepared, e: &Encoded, db: f64) -> TargetReport {
    let r = e.target.clone().expect("a target's encode reports its search");
    let psnr = decoded_psnr(prepared, e);
    assert!((psnr - e.psnr).abs() < 1e-6, "{name}: stored {} dB, decoded {psnr} dB", e.psnr);
    assert_eq!(e.model.meta.encode_psnr, Some(e.psnr));
    assert_eq!((r.tries[r.chosen].budget, r.tries[r.chosen].psnr), (e.model.len(), e.psnr), "{name}: the model is the chosen try");
    assert!((psnr - db).abs() <= 1.0, "{name}: target {db} dB, reached {psnr:.2} dB with {} primitives ({r:?})", e.model.len());
    assert!(r.landed, "{name}: {r:?}");
    assert!(r.probes.len() == 4, "{name}: a seeded search probes two budgets twice");
    assert_eq!(r.tries[0].budget, predicted_budget(&r, 600), "{name}: the first try is not the probes' prediction ({r:?})");
    r
}

/// The first try's budget computed again from the probes of a schedule of
/// `schedule` iterations, as METHOD.md "A quality instead of a budget"
/// says (its steps 1 and 2).
fn predicted_budget(r: &TargetReport, schedule: usize) -> usize {
    let [a0, a1, b0, b1] = &r.probes[..] else { panic!("four probes: {r:?}") };
    assert!(a0.budget == a1.budget && b0.budget == b1.budget && a0.iterations == schedule / 4 && a1.iterations == schedule / 2, "{r:?}");
    let full = |short: &Try, long: &Try| long.psnr + (long.psnr - short.psnr).max(0.0) * (schedule as f64 / long.iterations as f64).log2();
    let (pa, pb) = (full(a0, a1), full(b0, b1));
    let aim = r.target + AIM_DB;
    // Towards the aim: four times the first budget, or a quarter of it.
    assert_eq!(b0.budget, if pa < aim { 4 * a0.budget } else { a0.budget / 4 }, "{r:?}");
    let slope = ((pb - pa) / (b0.budget as f64 / a0.budget as f64).log2()).max(MIN_SLOPE_DB);
    let (n, p) = if (pb - aim).abs() < (pa - aim).abs() { (b0.budget, pb) } else { (a0.budget, pa) };
    ((n as f64 * 2f64.powf((aim - p) / slope)).round() as usize).clamp(MIN_BUDGET, r.cap)
}

#[test]
fn a_target_psnr_encode_of_the_hydrogen_atom_lands_within_a_db() {
    let grid = read_raw(repo_data("hydrogen_atom.float32.zst"), [64; 3], DType::F32, Order::XFastest).unwrap();
    let frame = IndexFrame::for_grid(grid.dims, [0.0; 3], 1.0).unwrap();
    let input = Input::Grid { values: &grid, frame };
    let mut budgets = vec![];
    for db in [40.0, 45.0] {
        let (prepared, e) = encode_to(&input, RangeSpec::FromData(Transform::Linear), config(db, 0));
        check(&format!("hydrogen 64^3 at {db} dB"), &prepared, &e, db);
        budgets.push(e.model.len());
    }
    assert!(budgets[1] > budgets[0], "a higher target takes more primitives: {budgets:?}");
}

#[test]
fn a_target_psnr_encode_of_the_enzo_cells_lands_within_a_db() {
    let items = |name: &str, comps| read_items(repo_data(name), DType::F32, comps, Rows { count: None, row: 0 }).unwrap();
    let triples = |v: Vec<f64>| v.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect::<Vec<_>>();
    let (centres, edges) = (triples(items("enzo_amr_cells.centers.float32.zst", 3)), triples(items("enzo_amr_cells.sizes.float32.zst", 3)));
    let rho: Vec<f32> = items("enzo_amr_cells.density.float32.zst", 1).into_iter().map(|v| v as f32).collect();
    let cells = Cells { centres: &centres, size: CellSize::Edges(&edges), values: &rho };
    let input = Input::Cells { cells: &cells, placement: Placement::new([32; 3], None) };
    let db = 42.0;
    let (prepared, e) = encode_to(&input, RangeSpec::FromData(Transform::Log10), config(db, 0));
    check("enzo cells 32^3 at 42 dB", &prepared, &e, db);
}

#[test]
fn a_target_beyond_reach_ends_at_the_cap_and_says_so() {
    let grid = blobs([20; 3], 3, 6);
    let frame = IndexFrame::for_grid(grid.dims, [0.0; 3], 1.0).unwrap();
    let (prepared, e) = encode_to(&Input::Grid { values: &grid, frame }, RangeSpec::FromData(Transform::Linear), config(110.0, 40));
    let r = e.target.clone().unwrap();
    assert!(!r.landed && r.cap == 40, "{r:?}");
    assert!(r.tries.iter().all(|t| t.budget <= 40) && r.probes.iter().all(|t| t.budget <= 40), "{r:?}");
    // The best of what it tried.
    assert!(r.tries.iter().all(|t| t.psnr <= e.psnr), "{r:?}");
    assert!(decoded_psnr(&prepared, &e) < 110.0 - LANDS_BELOW_DB);
}

/// A series' step at the cap that falls short stops there: one try, no
/// growth beyond the cap and none of zero primitives.
#[test]
fn a_series_step_at_the_cap_does_not_grow() {
    let grid = blobs([20; 3], 3, 6);
    let frame = IndexFrame::for_grid(grid.dims, [0.0; 3], 1.0).unwrap();
    let mut cfg = SeriesConfig::new(config(110.0, 40), WarmStart::Dense, SeriesRange::FirstStep(Transform::Linear));
    cfg.validation_points = 0;
    cfg.warm_iterations = Some(300);
    let mut series = SeriesEncoder::new(cfg).unwrap();
    let mut reports = Vec::new();
    for step in 0..2u64 {
        let r = series.encode_step("f", step, None, Input::Grid { values: &grid, frame }, &mut CpuBackend::new(), &mut |_| {}).unwrap();
        assert_eq!(r.encoded.model.len(), 40, "step {step}");
        reports.push(r.encoded.target.unwrap());
    }
    assert!(!reports[0].landed && reports[0].tries.iter().any(|t| t.budget == 40), "{:?}", reports[0]);
    assert!(!reports[1].landed && reports[1].tries.len() == 1 && reports[1].tries[0].budget == 40, "{:?}", reports[1]);
}

/// A series' step whose model is larger than the step's own cap (the
/// default cap follows the occupied voxels, which a later step can have
/// far fewer of) and that falls short keeps its model: it neither grows
/// nor is cut (before, the growth of "the cap minus the model" overflowed).
#[test]
fn a_series_step_past_its_own_cap_keeps_its_budget() {
    let dims = [20; 3];
    let frame = IndexFrame::for_grid(dims, [0.0; 3], 1.0).unwrap();
    let wide = blobs(dims, 3, 12);
    // A bump on 5^3 voxels: a default cap of MIN_BUDGET.
    let mut small = Grid::new(dims, vec![0.0; 8000]).unwrap();
    for (k, j, i) in (0..5).flat_map(|k| (0..5).flat_map(move |j| (0..5).map(move |i| (k, j, i)))) {
        small.values[(8 + i) + 20 * ((8 + j) + 20 * (8 + k))] = 0.3 + 0.1 * (i + j + k) as f32 / 4.0;
    }
    let mut cfg = SeriesConfig::new(config(110.0, 0), WarmStart::Dense, SeriesRange::FirstStep(Transform::Linear));
    cfg.validation_points = 0;
    cfg.warm_iterations = Some(200);
    let mut series = SeriesEncoder::new(cfg).unwrap();
    let mut step = |n: u64, g: &Grid| series.encode_step("f", n, None, Input::Grid { values: g, frame }, &mut CpuBackend::new(), &mut |_| {}).unwrap().encoded;
    let first = step(0, &wide);
    let r = first.target.clone().unwrap();
    assert!(!r.landed && first.model.len() > MIN_BUDGET, "{r:?}");
    let second = step(1, &small);
    let r = second.target.unwrap();
    assert_eq!(r.cap, MIN_BUDGET, "{r:?}");
    assert!(!r.landed && r.tries.len() == 1 && second.model.len() == first.model.len(), "{r:?}");
}

#[test]
fn bad_targets_are_refused() {
    for db in [0.0, -3.0, f64::NAN, f64::INFINITY, 121.0] {
        let e = TargetPsnr::new(db).unwrap_err().to_string();
        assert!(e.contains("target PSNR"), "{db}: {e}");
    }
    assert!(TargetPsnr::new(120.0).is_ok());
}

#[test]
fn in_a_series_the_budget_changes_only_at_a_step_that_misses() {
    let dims = [24; 3];
    let frame = IndexFrame::for_grid(dims, [0.0; 3], 1.0).unwrap();
    // Steps 1 and 2: the same three blobs (step 2 lands where step 1 did);
    // step 3: twelve, which the budget of three does not reach.
    let steps: [Grid; 3] = [blobs(dims, 5, 3), blobs(dims, 5, 3), blobs(dims, 9, 12)];
    let db = 40.0;
    let mut cfg = SeriesConfig::new(config(db, 2000), WarmStart::Dense, SeriesRange::FirstStep(Transform::Linear));
    cfg.validation_points = 0;
    cfg.warm_iterations = Some(300);
    let mut series = SeriesEncoder::new(cfg.clone()).unwrap();
    let (mut out, mut models) = (vec![], vec![]);
    for (step, g) in steps.iter().enumerate() {
        let r = series.encode_step("f", step as u64, None, Input::Grid { values: g, frame }, &mut CpuBackend::new(), &mut |_| {}).unwrap();
        out.push((r.encoded.model.len(), r.encoded.psnr, r.encoded.target.clone().unwrap()));
        models.push(r.encoded.model);
    }
    let [(n1, p1, r1), (n2, p2, r2), (n3, p3, r3)] = &out[..] else { unreachable!() };
    assert!(!r1.probes.is_empty() && r2.probes.is_empty() && r3.probes.is_empty(), "only the first step probes");
    assert!(r1.landed && (p1 - db).abs() <= 1.0, "step 1: {p1:.2} dB ({r1:?})");
    // Step 2 starts from step 1's budget and does not fall short: it keeps it.
    assert_eq!((r2.tries[0].budget, r2.tries.len(), *n2), (*n1, 1, *n1), "step 2: {r2:?}");
    assert!(*p2 >= db - LANDS_BELOW_DB, "step 2: {p2:.2} dB ({r2:?})");
    // Step 3 starts from it too, misses below, and grows.
    assert_eq!(r3.tries[0].budget, *n2, "step 3: {r3:?}");
    assert!(r3.tries[0].psnr < db - LANDS_BELOW_DB, "step 3 is meant to miss: {r3:?}");
    assert!(*n3 > *n2 && r3.landed && *p3 <= db + LANDS_ABOVE_DB, "step 3: {n3} primitives, {p3:.2} dB ({r3:?})");
    // With the series' own slopes, not the defaults, which every model keeps.
    assert_eq!(r3.curve, r1.curve);
    assert_ne!(r1.curve, DEFAULT_CURVE);
    assert!(models.iter().all(|m| m.meta.curve == Some(r1.curve)));

    // Stopped after step 2 and resumed from its model file, the series
    // corrects step 3 with the same slopes: the unbroken series' model, bit
    // for bit. Without them (a model that lost its curve) the correction
    // goes by the defaults and gives another budget.
    let stored = read_model(&write_model(&models[1]).unwrap()).unwrap();
    let mut lost = stored.clone();
    lost.meta.curve = None;
    // The resume logs a warning when the model has no curve.
    let resumed = |model| {
        let mut series = SeriesEncoder::new(cfg.clone()).unwrap();
        let log = warnings(|| series.resume(model).unwrap());
        let r = series.encode_step("f", 2, None, Input::Grid { values: &steps[2], frame }, &mut CpuBackend::new(), &mut |_| {}).unwrap();
        (r.encoded.target.unwrap().curve, r.encoded.model, log)
    };
    let (curve, model, log) = resumed(stored);
    assert_eq!((curve, &model), (r1.curve, &models[2]), "the resumed step 3 differs from the unbroken series'");
    assert_eq!(log, "");
    let (curve, model, log) = resumed(lost);
    assert_eq!(curve, DEFAULT_CURVE);
    assert_ne!(model.params, models[2].params);
    assert!(log.contains("WARN") && log.contains("holds no target curve"), "{log}");
}

/// What `f` logs at warning level and above, as text.
fn warnings(f: impl FnOnce()) -> String {
    use std::sync::{Arc, Mutex};
    #[derive(Clone, Default)]
    struct Buffer(Arc<Mutex<Vec<u8>>>);
    impl std::io::Write for Buffer {
        fn write(&mut self, b: &[u8]) -> std::io::Result<usize> {
            self.0.lock().unwrap().extend_from_slice(b);
            Ok(b.len())
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }
    let buffer = Buffer::default();
    let out = buffer.clone();
    let subscriber = tracing_subscriber::fmt().with_max_level(tracing::Level::WARN).with_ansi(false).with_writer(move || out.clone()).finish();
    tracing::subscriber::with_default(subscriber, f);
    let bytes = buffer.0.lock().unwrap().clone();
    String::from_utf8(bytes).unwrap()
}
