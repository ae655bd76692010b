//! Analytic gradients of every loss term against central finite differences
//! of an independent dense f64 transcription of docs/METHOD.md.

mod common;
use common::*;
use gsenc::backend::{cpu::CpuBackend, Backend};
use gsenc::math::kernel::Primitive;
use gsenc::math::loss::{regularizers, LossWeights};
use gsenc::backend::PointBatch;
use gsenc::math::rng::Rng;

/// The objectives' shapes as METHOD.md "Objective" writes them (fidelity
/// weight `[constant, slope]`, anisotropy bound): the paper's and gsenc's.
const PAPER: ([f64; 2], f64) = ([0.5, 1.0], 4.0);
const GSENC: ([f64; 2], f64) = ([1.0, 0.0], 10.0);

/// A small random model whose primitives overlap a 12^3 box, with some scales
/// outside the penalty band and some strongly anisotropic, so that every
/// term is active.
fn random_model(rng: &mut Rng, n: usize) -> Vec<Primitive> {
    (0..n)
        .map(|i| {
            let mut p = [0f32; 12];
            for a in 0..3 {
                p[a] = rng.range(3.0, 9.0) as f32;
                p[3 + a] = rng.range(0.9f64.ln(), 2.5f64.ln()) as f32;
            }
            if i % 4 == 1 {
                p[3] = 9.5f32.ln(); // above 8: scale penalty, clamped sigma
                p[4] = 1.2f32.ln();
            }
            if i % 4 == 2 {
                p[5] = 0.25f32.ln(); // below 0.3: scale penalty; ratio > 4: anisotropy penalty
            }
            if i == 7 {
                p[4] = 3.0f32.ln(); // ratio 12: above gsenc's anisotropy bound too
                p[5] = 0.25f32.ln();
            }
            for q in 0..4 {
                p[6 + q] = rng.range(-1.0, 1.0) as f32;
            }
            p[6] += 1.5;
            p[10] = rng.range(-2.0, 2.0) as f32;
            p[11] = rng.range(-1.5, 1.5) as f32;
            p
        })
        .collect()
}

fn batch(rng: &mut Rng, count: usize) -> PointBatch {
    let mut b = PointBatch::default();
    for i in 0..count {
        b.pos.push([0, 1, 2].map(|_| rng.range(1.0, 11.0) as f32));
        // A few masked points, the rest spread over [0, 1].
        b.vref.push(if i % 7 == 0 { 0.001 } else { rng.range(0.02, 1.0) as f32 });
    }
    b
}

fn analytic(params: &[Primitive], b: &PointBatch, w: &LossWeights) -> (Vec<Primitive>, [f64; 4]) {
    let mut grad: Vec<Primitive> = vec![[0.0; 12]; params.len()];
    let pl = CpuBackend::new().point_loss_grad(params, b, w, &mut grad).unwrap();
    let reg = regularizers(params, w, &mut grad);
    (grad, [pl.val, pl.cov, reg.scale, reg.aniso])
}

/// Term `term` of the objective `base` (its weights all zero but that
/// one's), against the dense transcription with the shape `shape`: the
/// fidelity weight's constant and slope, and the anisotropy bound.
fn check_term(term: usize, base: LossWeights, shape: ([f64; 2], f64)) {
    let mut rng = Rng::new(42 + term as u64);
    let params = random_model(&mut rng, 8);
    let b = batch(&mut rng, 400);
    let mut wv = [0.0f32; 4];
    wv[term] = 1.0;
    let w = LossWeights { val: wv[0], cov: wv[1], scale: wv[2], aniso: wv[3], ..base };
    let (grad, values) = analytic(&params, &b, &w);

    let p64 = to_f64(&params);
    let dense = dense_loss_terms(&p64, &b.pos, &b.vref, shape.0, shape.1);
    assert!(dense[term] > 1e-6, "term {term} is inactive in the test model ({dense:?})");
    let rel = (values[term] - dense[term]).abs() / dense[term].abs();
    assert!(rel < 1e-4, "term {term}: backend value {} vs dense {}", values[term], dense[term]);

    let h = 1e-4;
    let mut worst = 0.0f64;
    let mut scale = 0.0f64;
    let mut compared = 0;
    for i in 0..params.len() {
        for j in 0..12 {
            let mut plus = p64.clone();
            let mut minus = p64.clone();
            plus[i][j] += h;
            minus[i][j] -= h;
            let fd = (dense_loss_terms(&plus, &b.pos, &b.vref, shape.0, shape.1)[term] - dense_loss_terms(&minus, &b.pos, &b.vref, shape.0, shape.1)[term]) / (2.0 * h);
            let an = grad[i][j] as f64;
            worst = worst.max((fd - an).abs());
            scale = scale.max(fd.abs());
            if fd.abs() > 1e-6 {
                compared += 1;
            }
        }
    }
    // The point terms touch every parameter; the regularisers only log-scales.
    let needed = if term < 2 { 40 } else { 3 };
    assert!(compared >= needed, "term {term}: too few non-zero derivatives ({compared}) to be a test");
    assert!(worst <= 2e-3 * scale + 1e-7, "term {term}: max |analytic - fd| = {worst:e}, max |fd| = {scale:e}");
}

#[test]
fn value_term_gradient_matches_finite_differences() {
    check_term(0, LossWeights::PAPER, PAPER);
}

#[test]
fn coverage_term_gradient_matches_finite_differences() {
    check_term(1, LossWeights::PAPER, PAPER);
}

#[test]
fn scale_term_gradient_matches_finite_differences() {
    check_term(2, LossWeights::PAPER, PAPER);
}

#[test]
fn anisotropy_term_gradient_matches_finite_differences() {
    check_term(3, LossWeights::PAPER, PAPER);
}

/// gsenc's objective changes the value term's weights and the anisotropy
/// bound: both against the dense transcription of that shape.
#[test]
fn gsenc_objective_gradients_match_finite_differences() {
    check_term(0, LossWeights::GSENC, GSENC);
    check_term(3, LossWeights::GSENC, GSENC);
}

/// The two shapes differ where they should: the paper's weights favour high
/// values and its anisotropy bound is lower, so on the same model and points
/// the terms' values differ (a shape the backend ignored would not).
#[test]
fn the_objectives_differ_in_value_and_anisotropy_terms() {
    let mut rng = Rng::new(43);
    let params = random_model(&mut rng, 8);
    let b = batch(&mut rng, 400);
    let (_, paper) = analytic(&params, &b, &LossWeights::PAPER);
    let (_, gsenc) = analytic(&params, &b, &LossWeights::GSENC);
    assert!((paper[0] - gsenc[0]).abs() > 1e-3 * paper[0], "L_val {} vs {}", paper[0], gsenc[0]);
    assert!(paper[3] > gsenc[3] && gsenc[3] > 0.0, "L_aniso {} vs {}", paper[3], gsenc[3]);
    assert_eq!((paper[1], paper[2]), (gsenc[1], gsenc[2]));
}

#[test]
fn backend_density_matches_dense_reference() {
    let mut rng = Rng::new(5);
    let params = random_model(&mut rng, 40);
    let b = batch(&mut rng, 3000);
    let mut rho = vec![0f32; b.len()];
    let mut n = vec![0f32; b.len()];
    CpuBackend::new().evaluate_points(&params, &b.pos, &mut rho, &mut n).unwrap();
    let p64 = to_f64(&params);
    for (i, x) in b.pos.iter().enumerate() {
        let (r, nn) = dense_rho_n(&p64, [x[0] as f64, x[1] as f64, x[2] as f64]);
        assert!((rho[i] as f64 - r).abs() < 1e-5 * (1.0 + r), "rho at {x:?}: {} vs {r}", rho[i]);
        assert!((n[i] as f64 - nn).abs() < 1e-5 * (1.0 + nn), "n at {x:?}: {} vs {nn}", n[i]);
    }
}
