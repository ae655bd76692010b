//! Training points (METHOD.md "Training points"): the paper's jittered
//! strata and gsenc's rule (voxel centres, and a stratum drawn where the
//! model is wrong), each checked against what it promises, and the rule's
//! effect on an encode measured against the paper's.

mod common;
use common::*;
use gsenc::backend::cpu::CpuBackend;
use gsenc::encode::points::{PointSampler, ERROR_MAP_VOXELS};
use gsenc::encode::{encode, EncodeConfig, PointRule, Schedule};
use gsenc::field::Grid;
use gsenc::input::Target;
use gsenc::model::metrics::voxel_psnr;
use gsenc::backend::{Backend, Lattice};

fn is_centre(p: [f32; 3]) -> bool {
    p.iter().all(|c| c.fract() == 0.0)
}

fn index(g: &Grid, p: [f32; 3]) -> usize {
    p[0] as usize + g.dims[0] * (p[1] as usize + g.dims[1] * p[2] as usize)
}

#[test]
fn gsenc_points_are_voxel_centres_with_their_own_values_and_the_papers_are_not() {
    let g = blobs([20, 16, 12], 4, 3);
    let mut gsenc = PointSampler::new(&g, 1, PointRule::GSENC);
    let b = gsenc.draw(4000, &g, &g);
    assert_eq!(b.pos.len(), 4000);
    for (p, &v) in b.pos.iter().zip(&b.vref) {
        assert!(is_centre(*p), "{p:?} is not a voxel centre");
        assert!((0..3).all(|a| p[a] >= 0.0 && p[a] <= (g.dims[a] - 1) as f32), "{p:?} outside");
        assert_eq!(v, g.values[index(&g, *p)], "reference value at {p:?}");
    }
    // Every stratum reaches the lattice's faces (the uniform one draws
    // whole voxels, so edge voxels are not halved).
    assert!(b.pos.iter().any(|p| p[0] == 0.0) && b.pos.iter().any(|p| p[0] == 19.0));
    // The paper's jitter leaves almost no point on a centre.
    let mut paper = PointSampler::new(&g, 1, PointRule::PAPER);
    let b = paper.draw(4000, &g, &g);
    let centred = b.pos.iter().filter(|p| is_centre(**p)).count();
    assert!(centred < 40, "{centred} of 4000 jittered points on voxel centres");
    // Without an error map gsenc's strata are the paper's.
    assert_eq!(gsenc.counts(4000, true), paper.counts(4000, true));
    assert_eq!(gsenc.counts(4000, true).error, 0);
}

/// A grid with a block of occupied voxels, and an evaluation that makes
/// the model exact there but at `wrong`, where it is off by the given error.
fn mapped(wrong: &[(usize, f32)]) -> (Grid, PointSampler) {
    let dims = [12, 10, 8];
    let mut v = vec![0f32; 12 * 10 * 8];
    for (i, x) in v.iter_mut().enumerate() {
        if i % 12 < 6 {
            *x = 0.3 + 0.001 * (i % 7) as f32;
        }
    }
    let g = Grid::new(dims, v).unwrap();
    let mut s = PointSampler::new(&g, 7, PointRule::GSENC);
    assert!(s.wants_errors());
    let values = g.values.clone();
    let mut seen = 0;
    s.map_errors(&g, |pos, rho, n| {
        seen += pos.len();
        for (k, p) in pos.iter().enumerate() {
            let i = p[0] as usize + 12 * (p[1] as usize + 10 * p[2] as usize);
            let e = wrong.iter().find(|w| w.0 == i).map_or(0.0, |w| w.1);
            rho[k] = 1.0;
            n[k] = values[i] + e;
        }
        Ok(())
    })
    .unwrap();
    // Only the occupied voxels are evaluated.
    assert_eq!(seen, g.values.iter().filter(|&&x| x > 0.005).count());
    (g, s)
}

#[test]
fn the_error_stratum_draws_in_proportion_to_the_models_error() {
    // Voxels 3 (x = 3) and 125 (x = 5, y = 0, z = 1) are occupied; 8 (x = 8)
    // is empty, and its error is never mapped.
    let (g, mut s) = mapped(&[(3, 0.1), (125, 0.3), (8, 0.5)]);
    let p = 20000;
    let c = s.counts(p, true);
    assert_eq!(c.error, 6000, "30 % of the batch");
    assert_eq!(c.high + c.mid + c.uniform + c.samples + c.error, p);
    let b = s.draw(p, &g, &g);
    let last = &b.pos[p - c.error..];
    let at = |i: usize| last.iter().filter(|q| index(&g, **q) == i).count();
    let (a, bb) = (at(3), at(125));
    assert_eq!(a + bb, c.error, "every error point on a voxel with error");
    let ratio = bb as f64 / a as f64;
    assert!((ratio - 3.0).abs() < 0.4, "errors 0.1 : 0.3 drew {a} : {bb}");
    assert!(b.pos[..p - c.error].iter().all(|q| is_centre(*q)));
}

#[test]
fn a_model_without_error_maps_nothing_and_the_papers_rule_never_maps() {
    let (g, mut s) = mapped(&[]);
    assert_eq!(s.counts(1000, true).error, 0, "an exact model leaves no error stratum");
    let b = s.draw(1000, &g, &g);
    assert_eq!(b.pos.len(), 1000);
    let mut paper = PointSampler::new(&g, 7, PointRule::PAPER);
    assert!(!paper.wants_errors());
    paper.map_errors(&g, |_, _, _| panic!("the paper's rule evaluates nothing")).unwrap();
    assert_eq!(paper.counts(1000, true).error, 0);
}

#[test]
fn a_large_occupied_set_is_mapped_on_a_fresh_draw_of_its_voxels() {
    let dims = [128, 96, 96]; // 1,179,648 occupied voxels, more than the map holds
    assert!(dims.iter().product::<usize>() > ERROR_MAP_VOXELS);
    let g = Grid::new(dims, vec![0.5; dims.iter().product()]).unwrap();
    let mut s = PointSampler::new(&g, 3, PointRule::GSENC);
    let mut firsts = vec![];
    for _ in 0..2 {
        let mut seen = 0;
        let mut first = None;
        s.map_errors(&g, |pos, rho, n| {
            seen += pos.len();
            first.get_or_insert(pos[0]);
            rho.fill(1.0);
            n.fill(0.6);
            Ok(())
        })
        .unwrap();
        assert_eq!(seen, ERROR_MAP_VOXELS);
        firsts.push(first.unwrap());
    }
    assert_ne!(firsts[0], firsts[1], "each map draws its voxels afresh");
}

#[test]
fn an_evaluation_error_is_returned_and_leaves_no_map() {
    let g = blobs([10, 10, 10], 2, 2);
    let mut s = PointSampler::new(&g, 1, PointRule::GSENC);
    let e = s.map_errors(&g, |_, _, _| Err(gsenc::error::Error::arg("device lost"))).unwrap_err();
    assert!(e.to_string().contains("device lost"), "{e}");
    assert_eq!(s.counts(1000, true).error, 0);
}

/// A sphere with a sharp edge: where the paper's jittered, trilinear
/// targets cost the most.
fn sphere(n: usize) -> Grid {
    let c = (n as f32 - 1.0) / 2.0;
    let v = (0..n * n * n)
        .map(|i| {
            let p = [i % n, i / n % n, i / (n * n)].map(|x| x as f32 - c);
            let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
            if r < 0.35 * n as f32 { 0.9 } else if r < 0.45 * n as f32 { 0.4 } else { 0.0 }
        })
        .collect();
    Grid::new([n, n, n], v).unwrap()
}

#[test]
fn gsenc_points_fit_a_sharp_field_better_than_the_papers_at_the_same_cost() {
    let g = sphere(24);
    let t = Target { reference: &g, samples: &g };
    let psnr = |rule: PointRule| {
        let mut cfg = EncodeConfig::new(300, Schedule::Tuned);
        cfg.iterations = Some(300);
        cfg.points = Some(2048);
        cfg.point_rule = rule;
        let out = encode(&t, &cfg, None, &mut CpuBackend::new(), &mut |_| {}).unwrap();
        let mut dec = vec![0f32; g.len()];
        CpuBackend::new().decode_lattice(&out.params, &Lattice::reference(g.dims), &mut dec).unwrap();
        // As the model decodes with its support stored (gsenc's default):
        // 0 where the data are empty.
        for (d, &v) in dec.iter_mut().zip(&g.values) {
            if v <= 0.005 {
                *d = 0.0;
            }
        }
        voxel_psnr(&dec, &g.values)
    };
    let (paper, ours) = (psnr(PointRule::PAPER), psnr(PointRule::GSENC));
    assert!(ours > paper + 3.0, "gsenc's points {ours:.2} dB, the paper's {paper:.2} dB");
}
