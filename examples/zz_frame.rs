use gsenc::math::kernel::{Frame, Primitive};
use std::time::Instant;
fn main() {
    let n = 32000;
    let params: Vec<Primitive> = (0..n).map(|i| { let f = i as f32 * 1e-4; [f, f*2.0, f*3.0, 1.0, 0.1*f, 0.2, 0.3, 0.5-f*1e-3, 0.7, -0.2, 0.1, 0.3] }).collect();
    let mut frames = vec![Frame::default(); n];
    for _ in 0..3 {
        let t = Instant::now();
        for _ in 0..50 { for (f, p) in frames.iter_mut().zip(&params) { *f = Frame::new(p); } }
        println!("frame::new {:.1} ns/prim", t.elapsed().as_secs_f64() * 1e9 / (50 * n) as f64);
        let t = Instant::now();
        let mut s = 0.0f32;
        for _ in 0..50 { for p in &params { s += p[6].exp() + p[7].exp() + p[8].exp() + p[9].exp() + p[10].exp(); } }
        println!("5 exp {:.1} ns/prim {s}", t.elapsed().as_secs_f64() * 1e9 / (50 * n) as f64);
    }
}
