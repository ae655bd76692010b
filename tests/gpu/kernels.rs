//! The point passes against the CPU backend: forward values, evaluations,
//! every gradient, the bits run to run and however the work is split, each
//! brick's candidate lists, lists that overflow, and edge cases.

use super::*;

fn forward_matches(params: &[Primitive], pos: &[[f32; 3]], gpu: &mut GpuBackend) {
    let (mut r1, mut n1) = (vec![0.0; pos.len()], vec![0.0; pos.len()]);
    let (mut r2, mut n2) = (vec![0.0; pos.len()], vec![0.0; pos.len()]);
    CpuBackend::new().evaluate_points(params, pos, &mut r1, &mut n1).unwrap();
    gpu.evaluate_points(params, pos, &mut r2, &mut n2).unwrap();
    for i in 0..pos.len() {
        assert!(rel_close(r1[i], r2[i], 1e-5) && rel_close(n1[i], n2[i], 1e-5), "point {i}: cpu ({}, {}) gpu ({}, {})", r1[i], n1[i], r2[i], n2[i]);
    }
}

#[test]
fn forward_values_match_the_cpu_backend() {
    let Some(mut g) = gpu() else { return };
    let mut rng = Rng::new(11);
    let params = random_model(&mut rng, 300, 40.0);
    let b = random_batch(&mut rng, 3000, 40.0);
    forward_matches(&params, &b.pos, &mut g);
    // And against the dense f64 transcription of the method.
    let (mut rho, mut n) = (vec![0.0; b.len()], vec![0.0; b.len()]);
    g.evaluate_points(&params, &b.pos, &mut rho, &mut n).unwrap();
    let p64: Vec<[f64; 12]> = params.iter().map(|p| p.map(|v| v as f64)).collect();
    for i in (0..b.len()).step_by(37) {
        let (r, nn) = dense_rho_n(&p64, b.pos[i].map(|v| v as f64));
        assert!((rho[i] as f64 - r).abs() <= 1e-4 * (1.0 + r) && (n[i] as f64 - nn).abs() <= 1e-4 * (1.0 + nn));
    }
}

/// `evaluate_each` (what `Model::evaluate` asks) on the GPU backend gives
/// the CPU backend's bits, each point's own: the whole batch, and a point
/// alone, the same bits.
#[test]
fn evaluating_each_point_gives_the_cpu_backends_bits() {
    let Some(mut g) = gpu() else { return };
    let mut rng = Rng::new(21);
    let params = random_model(&mut rng, 300, 40.0);
    let b = random_batch(&mut rng, 2000, 40.0);
    let each = |be: &mut dyn Backend, pos: &[[f32; 3]]| {
        let (mut rho, mut n) = (vec![0.0f32; pos.len()], vec![0.0f32; pos.len()]);
        be.evaluate_each(&params, pos, &mut rho, &mut n).unwrap();
        rho.iter().chain(&n).map(|v| v.to_bits()).collect::<Vec<u32>>()
    };
    let cpu = each(&mut CpuBackend::new(), &b.pos);
    assert_eq!(each(&mut g, &b.pos), cpu);
    assert!(cpu.iter().any(|&v| f32::from_bits(v) > 0.0));
    for i in (0..b.len()).step_by(97) {
        assert_eq!(each(&mut g, &b.pos[i..=i]), [cpu[i], cpu[b.len() + i]], "point {i} alone");
    }
}

#[test]
fn every_gradient_matches_the_cpu_backend() {
    let Some(mut g) = gpu() else { return };
    let mut rng = Rng::new(12);
    let params = random_model(&mut rng, 200, 30.0);
    let b = random_batch(&mut rng, 4000, 30.0);
    for w in [
        LossWeights::default(),
        LossWeights::GSENC,
        LossWeights { val: 1.0, cov: 0.0, scale: 0.0, aniso: 0.0, ..LossWeights::PAPER },
        LossWeights { val: 0.0, cov: 1.0, scale: 0.0, aniso: 0.0, ..LossWeights::PAPER },
    ] {
        let mut gc = vec![[0.0; 12]; params.len()];
        let mut gg = vec![[0.0; 12]; params.len()];
        let lc = CpuBackend::new().point_loss_grad(&params, &b, &w, &mut gc).unwrap();
        let lg = g.point_loss_grad(&params, &b, &w, &mut gg).unwrap();
        assert!((lc.val - lg.val).abs() <= 1e-5 * lc.val.abs().max(1e-6), "L_val {} vs {}", lc.val, lg.val);
        assert!((lc.cov - lg.cov).abs() <= 1e-5 * lc.cov.abs().max(1e-6), "L_cov {} vs {}", lc.cov, lg.cov);
        // Each parameter group on its own, so that none hides behind another.
        for (name, r) in [("mu", 0..3), ("log scale", 3..6), ("quaternion", 6..10), ("alpha", 10..11), ("beta", 11..12)] {
            let pick = |v: &[Primitive]| -> Vec<Primitive> {
                v.iter()
                    .map(|p| {
                        let mut q = [0.0; 12];
                        q[r.clone()].copy_from_slice(&p[r.clone()]);
                        q
                    })
                    .collect()
            };
            let e = rel_l2(&pick(&gg), &pick(&gc));
            assert!(e <= 1e-4, "{name} gradient: relative L2 {e:e} with weights {w:?}");
        }
    }
}

#[test]
fn calls_are_bitwise_identical_run_to_run() {
    let Some(mut g) = gpu() else { return };
    let mut rng = Rng::new(13);
    let params = random_model(&mut rng, 500, 48.0);
    let b = random_batch(&mut rng, 6000, 48.0);
    let w = LossWeights::default();
    let mut first = vec![[0.0; 12]; params.len()];
    let l1 = g.point_loss_grad(&params, &b, &w, &mut first).unwrap();
    // A second backend (fresh buffers) and the first one again.
    let mut other = gpu().unwrap();
    for be in [&mut other, &mut g] {
        let mut again = vec![[0.0; 12]; params.len()];
        let l2 = be.point_loss_grad(&params, &b, &w, &mut again).unwrap();
        assert_eq!(l1, l2);
        assert!(same_bits(&first, &again));
    }
}

/// How the work is cut into workgroups does not change the bits:
/// gradients, evaluations, a resident step and a decode. The passes that
/// bin from every primitive split the primitives into chunks (4096: one
/// chunk here, 64 and 7: uneven, many per cell), and the brick level cuts
/// each coarse cell's list into chunks (1, 5, 256); the forward pass cuts a
/// brick's points into pieces (8 by default; 1, 3, 5, and 1000: one a
/// brick), the backward pass gives each brick slices of its candidates (8
/// by default; 1, 2 and 13, more than any brick has chunks of 128), and
/// the reduction gives each primitive a team of threads (8 by default; 1,
/// 2 and 128).
#[test]
fn how_the_work_is_split_does_not_change_the_bits() {
    let Some(mut whole) = gpu() else { return };
    let mut rng = Rng::new(29);
    let params = random_model(&mut rng, 450, 40.0);
    let b = random_batch(&mut rng, 4000, 40.0);
    let w = LossWeights::default();
    let lattice = Lattice { dims: [21, 18, 30], origin: [0.5, -1.0, 2.0], step: [2.0, 2.25, 1.5] };
    let run = |g: &mut GpuBackend| {
        let mut grad = vec![[0.0; 12]; params.len()];
        let loss = g.point_loss_grad(&params, &b, &w, &mut grad).unwrap();
        let (mut rho, mut n) = (vec![0.0; b.len()], vec![0.0; b.len()]);
        g.evaluate_points(&params, &b.pos, &mut rho, &mut n).unwrap();
        let mut decoded = vec![0.0; lattice.dims.iter().product()];
        g.decode_lattice(&params, &lattice, &mut decoded).unwrap();
        let r = g.resident().unwrap();
        r.load(&params, &Adam::new(params.len())).unwrap();
        r.step(&b, &w, 4e-3, false).unwrap();
        let (mut stepped, mut a) = (vec![[0.0; 12]; params.len()], Adam::new(0));
        r.store(&mut stepped, &mut a).unwrap();
        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        (loss, bits(grad.as_flattened()), bits(&rho), bits(&n), bits(&decoded), bits(stepped.as_flattened()))
    };
    let reference = run(&mut whole);
    assert!(reference.4.iter().any(|&x| f32::from_bits(x) > 0.0), "the decode must see primitives");
    for chunk in [64, 7] {
        let mut g = gpu().unwrap();
        g.set_bin_chunk(chunk);
        assert!(run(&mut g) == reference, "chunks of {chunk}");
    }
    for chunks in [1, 5, 256] {
        let mut g = gpu().unwrap();
        g.set_brick_chunks(chunks);
        assert!(run(&mut g) == reference, "coarse lists in {chunks} chunks at the brick level");
    }
    for (points, slices) in [(1000, 1), (1, 2), (3, 13), (5, 1)] {
        let mut g = gpu().unwrap();
        g.set_work_split(points, slices);
        // Buffers filled with garbage: the pieces must be written whole.
        g.garbage = points == 3;
        assert!(run(&mut g) == reference, "forward pieces of {points} points, {slices} backward slices");
    }
    // One thread a primitive (the reduction as it was before teams), and
    // teams of 2 and of a whole workgroup.
    for team in [1, 2, 128] {
        let mut g = gpu().unwrap();
        g.set_reduce_team(team);
        g.garbage = team == 2;
        assert!(run(&mut g) == reference, "reduction teams of {team}");
    }
}

/// The device's candidate lists of training bricks are the CPU backend's,
/// entry for entry and in order: bin_rows.wgsl marks each coarse cell's
/// entries in per-brick bit rows and writes them back row by row, so an
/// entry dropped, listed twice or out of place shows here. Bricks of 16
/// (a 2^3 coarse grid, its cells' lists from bit rows too) and of 4 (a
/// 7^3 coarse grid, gathered by bin.wgsl; cells clipped at its edge), the
/// lists cut into 1 (tiles of 1,024 entries and more), 3 and 256 chunks
/// and the default, empty bricks in between, one large primitive alone
/// and among others, one outside, and lists that overflow and run again.
#[test]
fn each_bricks_candidates_are_the_cpu_backends_in_order() {
    let Some(_) = gpu() else { return };
    let mut rng = Rng::new(31);
    let spread = random_batch(&mut rng, 5000, 100.0).pos;
    let mut clustered = vec![];
    for i in 0..2000 {
        let c = if i % 2 == 0 { 5.0 } else { 90.0 };
        clustered.push([0, 1, 2].map(|_| (c + rng.range(-4.0, 4.0)) as f32));
    }
    let mut over_all = isotropic([50.0; 3], 9.0, 0.6, 0.9);
    over_all[6..10].copy_from_slice(&[0.9, 0.1, 0.3, -0.2]);
    let mut with_outside = random_model(&mut rng, 300, 100.0);
    with_outside.push(isotropic([500.0, 0.0, 0.0], 1.0, 0.5, 0.5));
    with_outside.insert(7, over_all);
    let many = random_model(&mut rng, 6000, 100.0);
    let cases: Vec<(&str, &[Primitive], &[[f32; 3]])> =
        vec![("6,000 primitives", &many, &spread), ("clustered points", &with_outside, &clustered), ("one large primitive", std::slice::from_ref(&over_all), &spread)];
    let (mut longest, mut total) = (0, 0);
    for (name, params, pos) in cases {
        for edge in [16.0, 4.0] {
            let mut cpu = CpuBackend::new();
            cpu.brick = edge;
            let want = cpu.candidate_lists(params, pos);
            for (chunks, capacity) in [(None, None), (Some(1), None), (Some(3), Some(7)), (Some(256), None)] {
                let mut g = gpu().unwrap();
                g.brick = edge;
                if let Some(k) = chunks {
                    g.set_brick_chunks(k);
                }
                if let Some(c) = capacity {
                    g.set_capacity(c);
                }
                let got = g.candidate_lists(params, pos).unwrap();
                assert_eq!(got.len(), want.len(), "{name}, bricks of {edge}: occupied bricks");
                for (b, (x, y)) in got.iter().zip(&want).enumerate() {
                    assert_eq!(x, y, "{name}, bricks of {edge}, {chunks:?} chunks: brick {b}");
                }
                assert!(capacity.is_none() || g.reruns >= 1, "a capacity of 7 must overflow");
            }
            // The longest coarse cell's list (4^3 bricks): the union of its
            // bricks' lists.
            let bricks = PointBricks::new(pos, edge);
            let mut cells = std::collections::HashMap::<[u32; 3], std::collections::BTreeSet<u32>>::new();
            for (c, list) in bricks.coords.iter().zip(&want) {
                cells.entry(c.map(|v| v / 4)).or_default().extend(list);
            }
            longest = longest.max(cells.values().map(|c| c.len()).max().unwrap_or(0));
            total += want.iter().map(Vec::len).sum::<usize>();
        }
    }
    // A coarse cell's list longer than a tile (in one chunk, several
    // tiles), and many entries in all.
    assert!(longest > 1024 && total > 100_000, "longest coarse list {longest}, {total} entries");
}

#[test]
fn overflowing_candidate_lists_run_again_with_the_same_result() {
    let Some(mut g) = gpu() else { return };
    let mut rng = Rng::new(14);
    let params = random_model(&mut rng, 400, 32.0);
    let b = random_batch(&mut rng, 3000, 32.0);
    let w = LossWeights::default();
    let mut roomy = vec![[0.0; 12]; params.len()];
    g.point_loss_grad(&params, &b, &w, &mut roomy).unwrap();
    let mut tight = gpu().unwrap();
    tight.set_capacity(7);
    let mut grad = vec![[0.0; 12]; params.len()];
    tight.point_loss_grad(&params, &b, &w, &mut grad).unwrap();
    assert!(tight.reruns >= 1, "a capacity of 7 candidates must overflow");
    assert!(same_bits(&roomy, &grad));
}

#[test]
fn edge_cases_match_the_cpu_backend() {
    let Some(mut g) = gpu() else { return };
    let mut rng = Rng::new(17);
    let w = LossWeights::default();
    // Points in two far clusters: most bricks between them are empty.
    let mut b = PointBatch::default();
    for i in 0..2000 {
        let c = if i % 2 == 0 { 2.0 } else { 90.0 };
        b.pos.push([0, 1, 2].map(|_| (c + rng.range(-2.0, 2.0)) as f32));
        b.vref.push(rng.range(0.0, 1.0) as f32);
    }
    let cases: Vec<(&str, Vec<Primitive>)> = vec![
        ("clustered points, primitives between", random_model(&mut rng, 100, 96.0)),
        // One primitive whose box covers every brick.
        ("one primitive over everything", {
            let mut p = isotropic([46.0; 3], 8.0, 0.6, 0.9);
            p[6..10].copy_from_slice(&[0.9, 0.1, 0.3, -0.2]);
            vec![p]
        }),
        // Zero weights: sigmoid(-200) is 0 in f32.
        ("zero weights", random_model(&mut rng, 50, 96.0).into_iter().map(|mut p| {
            p[11] = -200.0;
            p
        }).collect()),
        // Faint primitives: rho below the training floor 1e-3 everywhere.
        ("density under the floor", random_model(&mut rng, 50, 96.0).into_iter().map(|mut p| {
            p[11] = -9.0;
            p
        }).collect()),
        // Primitives all outside the points' grid.
        ("primitives outside", vec![isotropic([500.0, 0.0, 0.0], 1.0, 0.5, 0.5), isotropic([-300.0, 40.0, 40.0], 2.0, 0.5, 0.5)]),
    ];
    for (name, params) in cases {
        forward_matches(&params, &b.pos, &mut g);
        let mut gc = vec![[0.0; 12]; params.len()];
        let mut gg = vec![[1.0; 12]; params.len()];
        let lc = CpuBackend::new().point_loss_grad(&params, &b, &w, &mut gc).unwrap();
        let lg = g.point_loss_grad(&params, &b, &w, &mut gg).unwrap();
        assert!((lc.val - lg.val).abs() <= 1e-5 * lc.val.abs().max(1e-6) && (lc.cov - lg.cov).abs() <= 1e-5 * lc.cov.abs().max(1e-6), "{name}: loss {lc:?} vs {lg:?}");
        let all_zero = gc.iter().flatten().all(|&v| v == 0.0);
        if all_zero {
            assert!(gg.iter().flatten().all(|&v| v == 0.0), "{name}: the CPU gradient is zero, the GPU's is not");
        } else {
            let e = rel_l2(&gg, &gc);
            assert!(e <= 1e-4, "{name}: gradient relative L2 {e:e}");
        }
    }
}
