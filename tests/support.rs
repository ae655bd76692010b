//! The stored support (METHOD.md "Support"): a model decodes to zero where
//! its data are truly empty, to its fitted outside where they are a
//! background, leaves the decode inside untouched, and `--support none`
//! gives the paper's models byte for byte (the goldens of tests/golden,
//! written by gsenc before the support existed).

mod common;
use common::repo_data;
use gsenc::backend::cpu::CpuBackend;
use gsenc::encode::pipeline::{self, Encoded, Labels, Request};
use gsenc::encode::{EncodeConfig, Schedule, WarmStart};
use gsenc::field::{Bounds, Grid, IndexFrame, Transform};
use gsenc::format::quantize::CentreCoding;
use gsenc::format::{write_model_as, Payload};
use gsenc::input::cells::{CellSize, Cells};
use gsenc::input::particles::Particles;
use gsenc::input::{Input, Placement, Prepared, RangeSpec};
use gsenc::io::raw::{read_items, read_raw, DType, Order, Rows};
use gsenc::math::loss::MASK_REF;
use gsenc::math::rng::Rng;
use gsenc::model::metrics::voxel_psnr;
use gsenc::model::Model;
use gsenc::series::{SeriesConfig, SeriesEncoder, SeriesRange};

fn quick(budget: usize, iterations: usize) -> EncodeConfig {
    let mut c = EncodeConfig::new(budget, Schedule::Short);
    c.iterations = Some(iterations);
    c.points = Some(2048);
    c
}

/// Encodes `input` with and without its support.
fn both(input: &Input, range: RangeSpec, cfg: EncodeConfig) -> (Prepared, Encoded, Encoded) {
    let run = |store_support| {
        let request = Request { store_support, ..Request::new(cfg.clone()) };
        pipeline::encode(input, &range, &request, &mut CpuBackend::new(), &mut |_| {}).unwrap()
    };
    let (prepared, stored) = run(true);
    let (_, paper) = run(false);
    (prepared, stored, paper)
}

/// The stored model decodes to its outside's value of the paper's model
/// at every empty voxel of its reference (exactly 0 when the outside is
/// zero, as it must be where the reference is exactly 0 there), and
/// exactly like the paper's model everywhere else (the parameters are the
/// same: the support changes no training); the paper's model leaves tails
/// above `tail` somewhere in the empty space.
fn check_reference_lattice(prepared: &Prepared, stored: &Encoded, paper: &Encoded, tail: f32) {
    assert_eq!(stored.model.params, paper.model.params, "the support changed the training");
    assert!(stored.model.support.is_some() && paper.model.support.is_none());
    let outside = stored.model.support.as_ref().unwrap().outside();
    let empty = prepared.reference.values.iter().filter(|&&r| r <= MASK_REF);
    if empty.clone().all(|&r| r == 0.0) {
        assert!(outside.is_zero(), "an empty space of zeros fitted {outside:?}");
    }
    let (mut zeroed, mut worst_tail) = (0, 0f32);
    for (i, &r) in prepared.reference.values.iter().enumerate() {
        if r <= MASK_REF {
            let want = outside.value(paper.decoded[i]);
            assert_eq!(stored.decoded[i], want, "empty voxel {i} decodes to {}, not {want}", stored.decoded[i]);
            zeroed += 1;
            worst_tail = worst_tail.max(paper.decoded[i]);
        } else {
            assert_eq!(stored.decoded[i], paper.decoded[i], "occupied voxel {i} changed");
        }
    }
    assert!(zeroed > 0, "the test field has no empty voxel");
    assert!(worst_tail > tail, "the paper's model shows no tail above {tail} in empty space ({worst_tail}): no test");
    assert!(stored.psnr > paper.psnr, "{} dB with the support, {} dB without", stored.psnr, paper.psnr);
}

#[test]
fn a_ball_of_particles_decodes_to_zero_outside_its_support_at_any_resolution() {
    let mut rng = Rng::new(11);
    let (centre, radius, hh) = ([0.5, 0.5, 0.5], 0.25, 0.03);
    let mut positions = Vec::new();
    while positions.len() < 3000 {
        let p: [f64; 3] = std::array::from_fn(|_| rng.range(0.0, 1.0));
        if (0..3).map(|a| (p[a] - centre[a]).powi(2)).sum::<f64>() < radius * radius {
            positions.push(p);
        }
    }
    let values: Vec<f32> = positions.iter().map(|p| (1.0 + 3.0 * p[0]) as f32).collect();
    let (h, mass) = (vec![hh; positions.len()], vec![1.0f32; positions.len()]);
    let particles = Particles { positions: &positions, smoothing_length: &h, mass: &mass, values: &values };
    let bounds = Bounds { min: [0.0; 3], max: [1.0; 3] };
    let input = Input::Particles { particles: &particles, placement: Placement::new([24; 3], Some(bounds)) };
    let (prepared, stored, paper) = both(&input, RangeSpec::FromData(Transform::Linear), quick(300, 120));
    check_reference_lattice(&prepared, &stored, &paper, 0.02);

    // At twice the resolution, every point more than the kernels' reach
    // (radius + 2 hh) plus one reference voxel from the ball's centre is
    // exactly 0 with the support.
    let fine = stored.model.decode(&mut CpuBackend::new(), Some([48; 3])).unwrap();
    let paper_fine = paper.model.decode(&mut CpuBackend::new(), Some([48; 3])).unwrap();
    let voxel = 1.0 / 24.0;
    let (mut outside, mut paper_tail) = (0, 0f32);
    for (i, &v) in fine.values.iter().enumerate() {
        let x = [i % 48, i / 48 % 48, i / (48 * 48)].map(|c| (c as f64 + 0.5) / 48.0);
        let d = (0..3).map(|a| (x[a] - centre[a]).powi(2)).sum::<f64>().sqrt();
        if d > radius + 2.0 * hh + voxel * 3f64.sqrt() {
            assert_eq!(v, 0.0, "a point {d:.3} from the centre decodes to {v}");
            outside += 1;
            paper_tail = paper_tail.max(paper_fine.values[i]);
        }
    }
    assert!(outside > 48 * 48 * 48 / 3 && paper_tail > 0.01, "{outside} points outside, paper tail {paper_tail}");
}

/// A blob on a grid, exactly 0 beyond three of its standard deviations.
fn blob(dims: [usize; 3], at: [f64; 3], sigma: f64) -> Grid {
    let values = (0..dims.iter().product::<usize>())
        .map(|i| {
            let x = [i % dims[0], i / dims[0] % dims[1], i / (dims[0] * dims[1])].map(|c| c as f64);
            let d2: f64 = (0..3).map(|a| (x[a] - at[a]).powi(2)).sum::<f64>() / (sigma * sigma);
            if d2 < 9.0 { (2.0 + 8.0 * (-0.5 * d2).exp()) as f32 } else { 0.0 }
        })
        .collect();
    Grid::new(dims, values).unwrap()
}

#[test]
fn a_blob_that_moves_away_leaves_no_ghost_in_a_warm_started_series() {
    let dims = [28, 16, 16];
    let frame = IndexFrame::for_grid(dims, [0.0; 3], 1.0).unwrap();
    let (first, second) = (blob(dims, [7.0, 8.0, 8.0], 2.0), blob(dims, [20.0, 8.0, 8.0], 2.0));
    let ghost = |store_support: bool| {
        let mut cfg = SeriesConfig::new(quick(150, 150), WarmStart::Dense, SeriesRange::FirstStep(Transform::Linear));
        cfg.validation_points = 0;
        cfg.warm_iterations = Some(60);
        cfg.store_support = store_support;
        let mut series = SeriesEncoder::new(cfg).unwrap();
        for (step, g) in [&first, &second].into_iter().enumerate() {
            let r = series.encode_step("rho", step as u64, None, Input::Grid { values: g, frame }, &mut CpuBackend::new(), &mut |_| {}).unwrap();
            assert_eq!(r.encoded.warm_started, step == 1);
        }
        // Where the first blob was, the second step's field is empty.
        let model = series.last_model("rho").unwrap();
        let decoded = model.decode(&mut CpuBackend::new(), None).unwrap();
        let old = [7usize, 8, 8];
        assert_eq!(second.values[second.index(old[0], old[1], old[2])], 0.0);
        (0..dims[0] * dims[1] * dims[2])
            .filter(|&i| {
                let c = [i % dims[0], i / dims[0] % dims[1], i / (dims[0] * dims[1])];
                (0..3).all(|a| c[a].abs_diff(old[a]) <= 3)
            })
            .map(|i| decoded.values[i])
            .fold(0f32, f32::max)
    };
    let (with, without) = (ghost(true), ghost(false));
    assert_eq!(with, 0.0, "the old blob's place decodes to {with}");
    assert!(without > 0.01, "without the support no ghost appears ({without}): the test shows nothing");
}

#[test]
fn a_grid_with_a_zero_region_decodes_to_zero_there() {
    let dims = [20, 16, 12];
    let g = common::blobs(dims, 21, 3);
    // The upper half in x holds no data at all.
    let values = (0..g.len()).map(|i| if i % dims[0] >= 10 { 0.0 } else { 1.0 + 4.0 * g.values[i] }).collect();
    let grid = Grid::new(dims, values).unwrap();
    let frame = IndexFrame::for_grid(dims, [0.0; 3], 0.5).unwrap();
    let (prepared, stored, paper) = both(&Input::Grid { values: &grid, frame }, RangeSpec::FromData(Transform::Linear), quick(200, 100));
    check_reference_lattice(&prepared, &stored, &paper, 0.01);
    // Written and read back, the support is still there.
    let back = gsenc::format::read_model(&write_model_as(&stored.model, Payload::Bits8(CentreCoding::Fixed16)).unwrap()).unwrap();
    assert_eq!(back.support, stored.model.support);
}

/// A flat background below the mask (Richtmyer-Meshkov's light fluid: 4
/// on a range of 3 to 230) is not empty space: the outside fitted to it
/// decodes it far better than zero, survives the model file, and the PSNR
/// the encode reports is the file's.
#[test]
fn a_background_below_the_mask_decodes_to_its_fitted_outside() {
    let dims = [20, 16, 12];
    let g = common::blobs(dims, 23, 3);
    let peak = g.values.iter().fold(0f32, |a, &b| a.max(b));
    let values: Vec<f32> =
        (0..g.len()).map(|i| if i == 0 { 3.0 } else if g.values[i] > 0.05 && i % dims[0] < 12 { 4.0 + 226.0 * g.values[i] / peak } else { 4.0 }).collect();
    let grid = Grid::new(dims, values).unwrap();
    let frame = IndexFrame::for_grid(dims, [0.0; 3], 0.5).unwrap();
    let input = Input::Grid { values: &grid, frame };
    let (prepared, stored, paper) = both(&input, RangeSpec::FromData(Transform::Linear), quick(200, 100));
    check_reference_lattice(&prepared, &stored, &paper, 0.0);
    let support = stored.model.support.clone().unwrap();
    let outside = support.outside();
    assert!((outside.value(0.0) - 1.0 / 227.0).abs() < 1e-3, "the background (1/227) decodes to {outside:?}");
    // Against the same support with a zero outside (the decode before
    // outsides were fitted): the background's error is gone.
    let zero = Model { support: Some(support.clone().with_outside(Default::default()).unwrap()), ..stored.model.clone() };
    let r = &prepared.reference.values;
    let zero_decoded = zero.decode(&mut CpuBackend::new(), None).unwrap().values;
    let zero_psnr = voxel_psnr(&zero_decoded, r);
    assert!(stored.psnr > zero_psnr, "{} dB with the outside, {zero_psnr} dB with zero", stored.psnr);
    let empty_se = |d: &[f32]| -> f64 { (0..r.len()).filter(|&i| r[i] <= MASK_REF).map(|i| ((d[i] - r[i]) as f64).powi(2)).sum() };
    let (fitted, zeroed) = (empty_se(&stored.decoded), empty_se(&zero_decoded));
    assert!(fitted < 0.05 * zeroed, "the background's squared error: {fitted} fitted, {zeroed} with zero");
    for payload in [Payload::Float32, Payload::Bits8(CentreCoding::Fixed16), Payload::Packed] {
        let mut m = stored.model.clone();
        m.meta.precision = Some(gsenc::format::packed::Precision::DEFAULT);
        let back = gsenc::format::read_model(&write_model_as(&m, payload).unwrap()).unwrap();
        assert_eq!(back.support.as_ref().map(|s| s.outside()), Some(outside), "{payload:?}");
    }
    let back = gsenc::format::read_model(&write_model_as(&stored.model, Payload::Float32).unwrap()).unwrap();
    let file_psnr = voxel_psnr(&back.decode(&mut CpuBackend::new(), None).unwrap().values, r);
    assert!((file_psnr - stored.psnr).abs() < 1e-9, "the file decodes to {file_psnr} dB, the encode said {}", stored.psnr);
}

/// The goldens: 8-bit models of the repository's data written by gsenc
/// (commit cc82932) before supports existed, at these settings.
fn golden(name: &str, model: &Model) {
    let want = std::fs::read(std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/golden").join(name)).unwrap();
    let got = write_model_as(model, Payload::Bits8(CentreCoding::Float16)).unwrap();
    assert!(got == want, "{name}: the paper's model differs from the one gsenc wrote before ({} vs {} bytes)", got.len(), want.len());
}

/// The CPU backend as it was when the goldens were written: every brick's
/// points in one run (a dense brick's runs sum in another order).
fn whole_bricks() -> CpuBackend {
    let mut b = CpuBackend::new();
    b.split_shares = 0;
    b
}

fn paper_request(budget: usize) -> Request<'static> {
    Request {
        payload: Payload::Bits8(CentreCoding::Float16),
        store_support: false,
        labels: Labels { field: "golden".into(), ..Labels::default() },
        ..Request::new(EncodeConfig { iterations: Some(120), points: Some(1024), ..EncodeConfig::new(budget, Schedule::Short) })
    }
}

#[test]
fn without_the_support_the_models_are_the_papers_byte_for_byte() {
    let encode = |input: &Input, range: RangeSpec, budget| {
        pipeline::encode(input, &range, &paper_request(budget), &mut whole_bricks(), &mut |_| {}).unwrap().1.model
    };
    let items = |name: &str, comps| read_items(repo_data(name), DType::F32, comps, Rows { count: None, row: 0 }).unwrap();
    let triples = |v: Vec<f64>| v.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect::<Vec<_>>();
    let f32s = |v: Vec<f64>| v.into_iter().map(|x| x as f32).collect::<Vec<_>>();

    let g = read_raw(repo_data("hydrogen_atom.float32.zst"), [64; 3], DType::F32, Order::XFastest).unwrap().downsample(2).unwrap();
    let frame = IndexFrame::for_grid(g.dims, [0.5; 3], 2.0).unwrap();
    golden("hydrogen32.gsm", &encode(&Input::Grid { values: &g, frame }, RangeSpec::FromData(Transform::Linear), 400));

    let n = |a: &str| format!("dambreak3d_step10.{a}.float32.zst");
    let (pos, hh) = (triples(items(&n("positions"), 3)), items(&n("smoothing_length"), 1));
    let (mass, speed) = (f32s(items(&n("mass"), 1)), f32s(items(&n("speed"), 1)));
    let p = Particles { positions: &pos, smoothing_length: &hh, mass: &mass, values: &speed };
    let placement = Placement::new(p.bounds().fitted_dims(40).unwrap(), None);
    golden("dambreak40.gsm", &encode(&Input::Particles { particles: &p, placement }, RangeSpec::FromData(Transform::Linear), 300));

    let (c, edges) = (triples(items("enzo_amr_cells.centers.float32.zst", 3)), triples(items("enzo_amr_cells.sizes.float32.zst", 3)));
    let rho = f32s(items("enzo_amr_cells.density.float32.zst", 1));
    let cells = Cells { centres: &c, size: CellSize::Edges(&edges), values: &rho };
    let placement = Placement::new([24; 3], None);
    golden("enzo24.gsm", &encode(&Input::Cells { cells: &cells, placement }, RangeSpec::FromData(Transform::Log10), 300));

    // A dense warm start: hydrogen, then hydrogen shifted by three voxels.
    let request = paper_request(400);
    let mut cfg = SeriesConfig::new(request.config.clone(), WarmStart::Dense, SeriesRange::FirstStep(Transform::Linear));
    (cfg.validation_points, cfg.warm_iterations, cfg.payload, cfg.store_support) = (0, Some(90), request.payload, false);
    let mut series = SeriesEncoder::new(cfg).unwrap();
    let shifted = Grid::new(g.dims, (0..g.len()).map(|i| {
        let [x, y, z] = g.coords(i);
        g.values[g.index((x + 3).min(31), y, z)]
    }).collect()).unwrap();
    for (step, grid) in [&g, &shifted].into_iter().enumerate() {
        let r = series.encode_step("golden", step as u64, None, Input::Grid { values: grid, frame }, &mut whole_bricks(), &mut |_| {}).unwrap();
        if step == 1 {
            golden("hydrogen32_warm.gsm", &r.encoded.model);
        }
    }
}
