//! Times the phases of one training iteration on a real grid, for profiling:
//! `cargo run --release --example phase_timing -- FILE X Y Z DTYPE BUDGET POINTS`.
use gsenc::backend::{cpu::CpuBackend, Backend};
use gsenc::field::{Grid, Transform, ValueRange};
use gsenc::io::raw::{read_raw, DType, Order};
use gsenc::math::kernel::Primitive;
use gsenc::math::loss::LossWeights;
use gsenc::encode::points::PointSampler;
use std::time::Instant;

fn main() {
    let a: Vec<String> = std::env::args().collect();
    let dims = [a[2].parse().unwrap(), a[3].parse().unwrap(), a[4].parse().unwrap()];
    let g = read_raw(&a[1], dims, DType::from_name(&a[5]).unwrap(), Order::XFastest).unwrap();
    let budget: usize = a[6].parse().unwrap();
    let points: usize = a[7].parse().unwrap();
    let r = ValueRange::from_data(&g.values, Transform::Linear).unwrap();
    let reference = Grid::new(dims, r.normalize(&g.values).unwrap().values).unwrap();
    let seeded = gsenc::encode::seeding::seed(&reference, dims, budget, 0).unwrap();
    // The order the encoder trains in.
    let order = gsenc::encode::spatial_order(&seeded.params);
    let params: Vec<Primitive> = order.iter().map(|&i| seeded.params[i]).collect();
    let mut sampler = PointSampler::new(&reference, 1, gsenc::encode::config::PointRule::PAPER);
    let mut be = CpuBackend::new();
    let mut grad: Vec<Primitive> = vec![[0.0; 12]; budget];
    if let Ok(b) = std::env::var("BRICK") { be.brick = b.parse().unwrap(); }
    let w = LossWeights::default();
    let reps = 50;
    let t = Instant::now();
    let batches: Vec<_> = (0..reps).map(|_| sampler.draw(points, &reference, &reference)).collect();
    println!("draw      {:8.3} ms", t.elapsed().as_secs_f64() * 1e3 / reps as f64);
    let t = Instant::now();
    let mut st = (0, 0);
    for b in &batches {
        st = be.profile_bin(&params, &b.pos);
    }
    println!("bin       {:8.3} ms  bricks {} pairs {}", t.elapsed().as_secs_f64() * 1e3 / reps as f64, st.0, st.1);
    let t = Instant::now();
    for b in &batches {
        let mut rho = vec![0.0; b.len()];
        let mut n = vec![0.0; b.len()];
        be.evaluate_points(&params, &b.pos, &mut rho, &mut n).unwrap();
    }
    println!("forward   {:8.3} ms", t.elapsed().as_secs_f64() * 1e3 / reps as f64);
    let e0 = be.kernel_evaluations();
    let t = Instant::now();
    for b in &batches {
        be.point_loss_grad(&params, b, &w, &mut grad).unwrap();
    }
    let dt = t.elapsed().as_secs_f64() / reps as f64;
    println!("loss+grad {:8.3} ms  evals/point {:.1}", dt * 1e3, (be.kernel_evaluations() - e0) as f64 / (reps * points) as f64);
}
