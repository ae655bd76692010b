//! `auto` warm starts (METHOD.md "Warm start"): a step that moved far starts
//! from a repaired model or a fresh seeding and ends near an independent
//! encode; a step that did not change keeps its model and stops early; the
//! choice is the same run after run; bad input in the middle of a series
//! leaves it usable; the model records the start it took.

use gsenc::backend::cpu::CpuBackend;
use gsenc::encode::{EncodeConfig, Schedule, WarmStart};
use gsenc::field::{Grid, IndexFrame, Transform};
use gsenc::format::{read_model_file, write_model};
use gsenc::input::Input;
use gsenc::model::{WarmRecord, WarmTaken};
use gsenc::series::{SeriesConfig, SeriesEncoder, SeriesRange, StepResult};
use gsenc::Error;

const DIMS: [usize; 3] = [32, 16, 16];
const CAP: usize = 300;

/// Two blobs on a grid, exactly 0 beyond three standard deviations.
fn blobs_at(centres: &[[f64; 3]]) -> Grid {
    let values = (0..DIMS.iter().product::<usize>())
        .map(|i| {
            let x = [i % DIMS[0], i / DIMS[0] % DIMS[1], i / (DIMS[0] * DIMS[1])].map(|c| c as f64);
            centres
                .iter()
                .map(|c| {
                    let d2: f64 = (0..3).map(|a| (x[a] - c[a]).powi(2)).sum::<f64>() / 4.0;
                    if d2 < 9.0 { (1.0 + 9.0 * (-0.5 * d2).exp()) as f32 } else { 0.0 }
                })
                .fold(0.0, f32::max)
        })
        .collect();
    Grid::new(DIMS, values).unwrap()
}

fn config() -> EncodeConfig {
    let mut c = EncodeConfig::new(120, Schedule::Short);
    c.iterations = Some(CAP);
    c.points = Some(1024);
    c.relocation = false;
    c
}

fn series(warm: WarmStart, validation_points: usize) -> SeriesEncoder {
    SeriesEncoder::new(series_config(warm, validation_points)).unwrap()
}

fn series_config(warm: WarmStart, validation_points: usize) -> SeriesConfig {
    let mut cfg = SeriesConfig::new(config(), warm, SeriesRange::FirstStep(Transform::Linear));
    cfg.validation_points = validation_points;
    cfg.validation_every = 10;
    cfg
}

fn step(s: &mut SeriesEncoder, k: u64, g: &Grid) -> Result<StepResult, Error> {
    let frame = IndexFrame::for_grid(DIMS, [0.0; 3], 1.0).unwrap();
    s.encode_step("rho", k, None, Input::Grid { values: g, frame }, &mut CpuBackend::new(), &mut |_| {})
}

fn first() -> Grid {
    blobs_at(&[[6.0, 8.0, 8.0], [9.0, 5.0, 9.0]])
}

/// The blobs moved across the box: nothing of the first step is left.
fn moved() -> Grid {
    blobs_at(&[[25.0, 8.0, 8.0], [22.0, 11.0, 7.0]])
}

#[test]
fn a_field_that_jumps_starts_repaired_or_fresh_and_ends_near_an_independent_encode() {
    let mut auto = series(WarmStart::Auto, 4096);
    step(&mut auto, 0, &first()).unwrap();
    let warm = step(&mut auto, 1, &moved()).unwrap();
    let record = warm.encoded.model.meta.warm.expect("an auto step records its start");
    assert_ne!(record.taken, WarmTaken::Kept, "a model of blobs that left cannot be kept");
    assert!(record.moved > 0, "every primitive sat where the field vanished: {record:?}");
    // The same step encoded on its own with the cap's iterations.
    let mut off = series(WarmStart::Off, 4096);
    step(&mut off, 0, &first()).unwrap();
    let independent = step(&mut off, 1, &moved()).unwrap();
    assert!(independent.encoded.model.meta.warm.is_none());
    let (a, i) = (warm.encoded.psnr, independent.encoded.psnr);
    assert!(a > i - 0.5, "auto ends at {a:.2} dB, an independent encode at {i:.2} dB");
    assert!(warm.encoded.output.iterations <= CAP);
}

#[test]
fn a_field_that_does_not_change_keeps_its_model_and_stops_early() {
    // No validation set from the series (in situ): auto scores its own. A
    // first step long enough to converge; warm steps of at most CAP.
    let mut cfg = series_config(WarmStart::Auto, 0);
    cfg.encode.iterations = Some(4 * CAP);
    cfg.warm_iterations = Some(CAP);
    let mut auto = SeriesEncoder::new(cfg).unwrap();
    let g = first();
    let before = step(&mut auto, 0, &g).unwrap();
    let after = step(&mut auto, 1, &g).unwrap();
    let record = after.encoded.model.meta.warm.expect("recorded");
    assert_eq!(record, WarmRecord { taken: WarmTaken::Kept, moved: 0 });
    let its = after.encoded.output.iterations;
    assert!(its < CAP / 2, "a calm step ran {its} of {CAP} iterations");
    // It never ends below where it started.
    assert!(after.encoded.psnr >= before.encoded.psnr - 0.05, "{} -> {}", before.encoded.psnr, after.encoded.psnr);
    assert_eq!(after.encoded.model.meta.iterations as usize, its);
}

#[test]
fn the_choice_and_the_model_are_the_same_run_after_run() {
    let run = || {
        let mut s = series(WarmStart::Auto, 2048);
        step(&mut s, 0, &first()).unwrap();
        let mid = blobs_at(&[[14.0, 8.0, 8.0], [9.0, 5.0, 9.0]]);
        let a = step(&mut s, 1, &mid).unwrap().encoded;
        let b = step(&mut s, 2, &moved()).unwrap().encoded;
        (a.model, b.model, a.output.iterations, b.output.iterations)
    };
    let (x, y) = (run(), run());
    assert_eq!(x.0.params, y.0.params);
    assert_eq!(x.1.params, y.1.params);
    assert_eq!((x.0.meta.warm, x.1.meta.warm, x.2, x.3), (y.0.meta.warm, y.1.meta.warm, y.2, y.3));
}

#[test]
fn bad_input_in_the_middle_leaves_the_series_usable() {
    let mut s = series(WarmStart::Auto, 2048);
    let good = step(&mut s, 0, &first()).unwrap().encoded.model;
    let mut bad = moved();
    bad.values[100] = f32::NAN;
    assert!(step(&mut s, 1, &bad).is_err());
    assert_eq!(s.last_model("rho").unwrap().params, good.params, "a failed step changes nothing");
    let next = step(&mut s, 2, &moved()).unwrap();
    assert!(next.encoded.model.meta.warm.is_some());
    assert!(next.encoded.psnr > 25.0, "{}", next.encoded.psnr);
}

#[test]
fn the_record_survives_the_model_file() {
    let mut s = series(WarmStart::Auto, 2048);
    step(&mut s, 0, &first()).unwrap();
    let m = step(&mut s, 1, &moved()).unwrap().encoded.model;
    let back = read_model_file(&write_model(&m).unwrap()).unwrap();
    assert_eq!(back.model.meta.warm, m.meta.warm);
    assert_eq!(back.version, (1, 4));
    assert_eq!(back.model.meta.fell_back, None);
}

#[test]
fn an_adaptive_encode_without_validation_points_is_refused() {
    // The pipeline always gives one; a caller of the encoder directly must.
    let g = first();
    let range = gsenc::field::ValueRange::from_data(&g.values, Transform::Linear).unwrap();
    let reference = Grid::new(DIMS, range.normalize(&g.values).unwrap().values).unwrap();
    let t = gsenc::input::Target { reference: &reference, samples: &reference };
    let cfg = WarmStart::Auto.step_config(&config());
    let prev = gsenc::encode::encode(&t, &config(), None, &mut CpuBackend::new(), &mut |_| {}).unwrap().params;
    let e = gsenc::encode::encode_validated(&t, &cfg, Some(&prev), None, &mut CpuBackend::new(), &mut |_| {}).err().unwrap();
    assert!(matches!(e, Error::InvalidArgument(_)) && e.to_string().contains("needs a validation set"), "{e}");
}
