//! Times a model's evaluation at points (docs/BENCHMARKS.md "Evaluating at
//! points: a point's own sum"): `Backend::evaluate_each`, the sum in
//! primitive order that `Model::evaluate` uses, against
//! `Backend::evaluate_points`, the lane sums of training, on the same points,
//! alternating, after one warm-up call of each:
//! `cargo run --release --example evaluate_timing -- MODEL.gsm [POINTS]`.
//! The points are uniform over the model's box (index frame), drawn with
//! seed 1. Prints the median of seven runs of each, in M points a second,
//! and their ratio.
use gsenc::backend::cpu::CpuBackend;
use gsenc::backend::Backend;
use gsenc::io::read_model_file;
use gsenc::math::rng::Rng;
use std::time::Instant;

fn main() {
    let a: Vec<String> = std::env::args().collect();
    let file = a.get(1).expect("usage: evaluate_timing MODEL.gsm [POINTS]");
    let points: usize = a.get(2).map_or(1 << 20, |p| p.parse().expect("points"));
    let m = read_model_file(std::path::Path::new(file)).expect("a model file").model;
    let dims = m.meta.frame.dims;
    let mut rng = Rng::new(1);
    let pos: Vec<[f32; 3]> = (0..points).map(|_| std::array::from_fn(|a| rng.range(-0.5, dims[a] as f64 - 0.5) as f32)).collect();
    let (mut rho, mut n) = (vec![0f32; points], vec![0f32; points]);
    let mut time = |each: bool| {
        let mut b = CpuBackend::new();
        let t = Instant::now();
        if each {
            b.evaluate_each(&m.params, &pos, &mut rho, &mut n).unwrap();
        } else {
            b.evaluate_points(&m.params, &pos, &mut rho, &mut n).unwrap();
        }
        std::hint::black_box((&rho, &n));
        let rate = points as f64 / t.elapsed().as_secs_f64() / 1e6;
        (rate, b.kernel_evaluations() as f64 / points as f64)
    };
    let (_, each_lanes) = time(true);
    let (_, lane_lanes) = time(false);
    let (mut each, mut lanes) = (vec![], vec![]);
    for _ in 0..7 {
        each.push(time(true).0);
        lanes.push(time(false).0);
    }
    let median = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let (e, l) = (median(&mut each), median(&mut lanes));
    println!(
        "{file}: {} primitives, {points} points: evaluate_each {e:.2} M points/s ({each_lanes:.0} lanes a point), evaluate_points {l:.2} M points/s ({lane_lanes:.0} lanes a point), each/lanes {:.2}",
        m.params.len(),
        e / l
    );
}
