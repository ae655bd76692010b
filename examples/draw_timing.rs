//! Times the drawing of training points on one thread (docs/BENCHMARKS.md
//! "The host's share of a GPU encode"): batches of the paper's rule and of
//! gsenc's, the latter with an error map in place, on Richtmyer-Meshkov
//! 128³ (the 256³ uint8 file, 2x2x2 means):
//! `RAYON_NUM_THREADS=1 cargo run --release --example draw_timing -- $GSENC_DATA/richtmyer_meshkov_t20.uint8 16384 [paper|gsenc]`.
//! Prints the median of five runs of 200 batches, in ms a batch. Built with
//! `--features task-profile` and run with `GSENC_TASK_PROFILE=FILE`, it
//! writes the task profile of every draw (`src/profile.rs`): the records
//! `draw: stream` are the serial pass (the stream's words), `draw: points`
//! the tasks that place the runs (docs/BENCHMARKS.md "The draw's serial
//! words").
use gsenc::encode::config::PointRule;
use gsenc::encode::points::PointSampler;
use gsenc::field::{Grid, Transform, ValueRange};
use gsenc::io::raw::{read_raw, DType, Order};
use gsenc::math::rng::Rng;
use std::time::Instant;

fn main() {
    let a: Vec<String> = std::env::args().collect();
    let (file, points) = (&a[1], a.get(2).map_or(16384, |p| p.parse().expect("points")));
    let g = read_raw(file, [256; 3], DType::U8, Order::XFastest).expect("the Richtmyer-Meshkov file").downsample(2).unwrap();
    let r = ValueRange::from_data(&g.values, Transform::Linear).unwrap();
    let reference = Grid::new(g.dims, r.normalize(&g.values).unwrap().values).unwrap();
    let only = a.get(3).map(String::as_str);
    for (name, rule) in [("paper", PointRule::PAPER), ("gsenc", PointRule::GSENC)] {
        if only.is_some_and(|o| o != name) {
            continue;
        }
        let mut sampler = PointSampler::new(&reference, 1, rule);
        // An error map of made-up errors (uniform in [0, 1)) over every occupied voxel.
        let mut rng = Rng::new(2);
        sampler
            .map_errors(&reference, |pos, rho, n| {
                for k in 0..pos.len() {
                    (rho[k], n[k]) = (1.0, rng.uniform() as f32);
                }
                Ok(())
            })
            .unwrap();
        let reps = 200;
        let mut runs: Vec<f64> = (0..5)
            .map(|_| {
                let t = Instant::now();
                for _ in 0..reps {
                    std::hint::black_box(sampler.draw(points, &reference, &reference));
                }
                t.elapsed().as_secs_f64() * 1e3 / reps as f64
            })
            .collect();
        runs.sort_by(f64::total_cmp);
        println!("{name} rule: {points} points in {:.3} ms (median of 5 runs of {reps} batches)", runs[2]);
    }
    gsenc::profile::write().expect("writing the task profile");
}
