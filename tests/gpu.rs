//! The GPU backend against the CPU backend, on whatever adapter there is:
//! a hardware GPU, or Mesa's lavapipe (llvmpipe) on a machine without one.
//! Every test fills the device buffers with garbage before each call.
//!
//! Without an adapter the tests say so and pass, unless GSENC_REQUIRE_GPU=1
//! (CI sets it), which makes a missing adapter a failure.
#![cfg(feature = "gpu")]

mod common;
use common::*;
use gsenc::backend::gpu::device::{adapters, instances_made, DeviceRequest};
use gsenc::backend::gpu::GpuBackend;
use gsenc::backend::bricks::PointBricks;
use gsenc::backend::{cpu::CpuBackend, Backend, Lattice, PointBatch, PointLoss};
use gsenc::encode::config::EncodeConfig;
use gsenc::encode::relocate::relocate;
use gsenc::encode::{encode, encode_validated, Schedule, Validation, WarmStart};
use gsenc::field::{Grid, Transform, ValueRange};
use gsenc::input::Target;
use gsenc::io::raw::{read_raw, DType, Order};
use gsenc::math::kernel::{isotropic, Primitive};
use gsenc::math::loss::{regularizers, LossWeights, RegTerms};
use gsenc::math::optim::Adam;
use gsenc::math::rng::Rng;
use gsenc::model::metrics::voxel_psnr;

/// The GPU backend on the first hardware adapter, else on llvmpipe; `None`
/// (with a message) when wgpu sees no adapter at all and GSENC_REQUIRE_GPU
/// is not 1. An adapter that is there but fails (a kernel that does not
/// compile) always fails the test.
fn gpu() -> Option<GpuBackend> {
    let seen = adapters();
    if seen.is_empty() {
        assert!(
            std::env::var("GSENC_REQUIRE_GPU").as_deref() != Ok("1"),
            "GSENC_REQUIRE_GPU=1 and wgpu sees no adapter (install mesa-vulkan-drivers)"
        );
        eprintln!("NOT RUN: wgpu sees no adapter; install mesa-vulkan-drivers, or set GSENC_REQUIRE_GPU=1 to fail instead");
        return None;
    }
    let req = match std::env::var("GSENC_ADAPTER").ok().filter(|s| !s.is_empty()) {
        Some(name) => DeviceRequest { index: None, name: Some(name) },
        None if seen.iter().any(|a| !a.software()) => DeviceRequest::default(),
        None => DeviceRequest { index: None, name: Some(seen[0].name.clone()) },
    };
    let mut b = GpuBackend::new(&req).unwrap_or_else(|e| panic!("{e}"));
    b.garbage = true;
    Some(b)
}

/// Every enumeration and every device of the process go through one wgpu
/// instance: NVIDIA's driver stops listing its GPU in a process that has
/// made 30 (the H200, 2026-12-04), which a simulation opening an encoder
/// per output step reached after 15.
#[test]
fn devices_opened_and_dropped_share_one_instance() {
    let Some(g) = gpu() else { return };
    drop(g);
    for round in 0..40 {
        assert!(!adapters().is_empty(), "round {round}: the adapter is gone");
    }
    drop(gpu().expect("the adapter seen above"));
    assert_eq!(instances_made(), 1, "wgpu instances made by this process");
}

/// The same parameters bit for bit.
fn same_bits(a: &[Primitive], b: &[Primitive]) -> bool {
    a.len() == b.len() && a.iter().flatten().zip(b.iter().flatten()).all(|(x, y)| x.to_bits() == y.to_bits())
}

/// The `short` schedule at 250 primitives, cut to `iterations` of `points`.
fn short(iterations: usize, points: usize) -> EncodeConfig {
    let mut cfg = EncodeConfig::new(250, Schedule::Short);
    cfg.iterations = Some(iterations);
    cfg.points = Some(points);
    cfg
}

fn rel_close(a: f32, b: f32, tol: f32) -> bool {
    (a - b).abs() <= tol * a.abs().max(b.abs()).max(1e-3)
}

/// Relative L2 distance of two gradients over all parameters.
fn rel_l2(a: &[Primitive], b: &[Primitive]) -> f64 {
    let (mut d, mut s) = (0.0f64, 0.0f64);
    for (x, y) in a.iter().flatten().zip(b.iter().flatten()) {
        d += ((x - y) as f64).powi(2);
        s += (*y as f64).powi(2);
    }
    (d / s.max(1e-30)).sqrt()
}

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
fn decode_matches_the_cpu_decode() {
    let Some(mut g) = gpu() else { return };
    let mut rng = Rng::new(15);
    let params = random_model(&mut rng, 250, 20.0);
    // The reference lattice, a finer resampling with sizes not a multiple of
    // the decode brick, a shifted window, and slabs of more than a megabyte
    // (copied out of the mapped buffer in runs of one: the last run short).
    for lat in [
        Lattice::reference([20, 20, 20]),
        Lattice::resampled([20, 20, 20], [37, 29, 19]),
        Lattice { dims: [9, 17, 25], origin: [3.5, -2.0, 1.25], step: [0.75, 1.0, 0.5] },
        Lattice::resampled([20, 20, 20], [181, 190, 11]),
    ] {
        let mut a = vec![0.0; lat.len()];
        let mut b = vec![f32::NAN; lat.len()];
        CpuBackend::new().decode_lattice(&params, &lat, &mut a).unwrap();
        g.decode_lattice(&params, &lat, &mut b).unwrap();
        for i in 0..a.len() {
            assert!((a[i] - b[i]).abs() <= 2e-5, "{lat:?} voxel {i}: cpu {} gpu {}", a[i], b[i]);
        }
    }
}

#[test]
fn decode_slabs_that_overflow_run_again() {
    let Some(mut g) = gpu() else { return };
    let mut rng = Rng::new(16);
    let params = random_model(&mut rng, 300, 24.0);
    let lat = Lattice::reference([24, 24, 24]);
    let mut a = vec![0.0; lat.len()];
    g.decode_lattice(&params, &lat, &mut a).unwrap();
    let mut tight = gpu().unwrap();
    tight.set_capacity(3);
    let mut b = vec![0.0; lat.len()];
    tight.decode_lattice(&params, &lat, &mut b).unwrap();
    assert!(tight.reruns >= 1);
    assert!(a.iter().zip(&b).all(|(x, y)| x.to_bits() == y.to_bits()));
}

/// Slabs go to the device two at a time, so a slab's lists are found to
/// have overflowed while the next slab is already on the queue: that one is
/// kept if its lists fitted and runs again with the first if not. Here the
/// slabs along z hold 16, 4, 64, 8 and 256 primitives, none reaching past
/// its own, so the lists overflow
/// on the first slab with the second behind it overflowing too, on the third
/// with the fourth fitting behind it, and on the last with none behind it.
#[test]
fn a_later_slab_that_overflows_runs_again_with_the_one_behind_it() {
    let Some(mut g) = gpu() else { return };
    let mut rng = Rng::new(17);
    let mut params = vec![];
    for (slab, count) in [16, 4, 64, 8, 256].into_iter().enumerate() {
        for mut p in random_model(&mut rng, count, 16.0) {
            p[2] = (8 * slab) as f32 + rng.range(3.0, 5.0) as f32;
            for a in 3..6 {
                p[a] = rng.range(0.3f64.ln(), 0.5f64.ln()) as f32;
            }
            params.push(p);
        }
    }
    let lat = Lattice::reference([16, 16, 40]);
    let mut cpu = vec![0.0; lat.len()];
    CpuBackend::new().decode_lattice(&params, &lat, &mut cpu).unwrap();
    let mut roomy = vec![f32::NAN; lat.len()];
    g.decode_lattice(&params, &lat, &mut roomy).unwrap();
    let mut tight = gpu().unwrap();
    tight.set_capacity(3);
    let mut b = vec![f32::NAN; lat.len()];
    tight.decode_lattice(&params, &lat, &mut b).unwrap();
    assert!(tight.reruns >= 3, "the lists overflowed {} times, not slab after slab", tight.reruns);
    for i in 0..b.len() {
        assert!(b[i].to_bits() == roomy[i].to_bits(), "voxel {i}: {} with reruns, {} without", b[i], roomy[i]);
        assert!((cpu[i] - b[i]).abs() <= 2e-5, "voxel {i}: cpu {} gpu {}", cpu[i], b[i]);
    }
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

#[test]
fn relocation_moves_the_same_primitives() {
    let Some(mut g) = gpu() else { return };
    let mut rng = Rng::new(18);
    let params = random_model(&mut rng, 120, 30.0);
    let b = random_batch(&mut rng, 2000, 30.0);
    let (mut pc, mut pg) = (params.clone(), params.clone());
    let (mut ac, mut ag) = (Adam::new(params.len()), Adam::new(params.len()));
    let rc = relocate(&mut CpuBackend::new(), &mut pc, &mut ac, &b).unwrap();
    let rg = relocate(&mut g, &mut pg, &mut ag, &b).unwrap();
    assert!(!rc.moved.is_empty());
    assert_eq!(rc.moved, rg.moved);
    assert_eq!(rc.targets, rg.targets);
    assert_eq!(pc, pg);
}

/// The repository's hydrogen_atom at 32^3, normalised by its own range.
fn hydrogen32() -> Grid {
    let raw = read_raw(repo_data("hydrogen_atom.float32.zst"), [64; 3], DType::F32, Order::XFastest).unwrap().downsample(2).unwrap();
    let r = ValueRange::from_data(&raw.values, Transform::Linear).unwrap();
    Grid::new(raw.dims, r.normalize(&raw.values).unwrap().values).unwrap()
}

/// Real data, so that the comparison measures the backends, not the chaos
/// of a toy problem: on a tiny synthetic field (300 primitives on 24^3) a
/// different float summation order alone moves the PSNR by up to 2 dB on
/// either backend (relocation picks other primitives), while on hydrogen
/// the CPU backend with 8- and 16-voxel bricks (another summation order)
/// and the GPU backend agree within 0.1 dB (docs/BENCHMARKS.md).
#[test]
fn a_short_encode_lands_within_a_third_of_a_db_of_the_cpu_backend() {
    let Some(mut g) = gpu() else { return };
    let field = hydrogen32();
    let t = Target { reference: &field, samples: &field };
    let cfg = short(300, 4096);
    let score = |params: &[Primitive]| {
        let mut out = vec![0.0; field.len()];
        CpuBackend::new().decode_lattice(params, &Lattice::reference(field.dims), &mut out).unwrap();
        voxel_psnr(&out, &field.values)
    };
    let cpu = encode(&t, &cfg, None, &mut CpuBackend::new(), &mut |_| {}).unwrap();
    let on_gpu = encode(&t, &cfg, None, &mut g, &mut |_| {}).unwrap();
    let (a, b) = (score(&cpu.params), score(&on_gpu.params));
    assert!(a > 33.0, "the CPU encode itself is poor: {a:.2} dB");
    assert!((a - b).abs() <= 0.3, "cpu {a:.3} dB, gpu {b:.3} dB");
    assert!(on_gpu.backend.starts_with("wgpu:"), "{}", on_gpu.backend);
    // Where the loop's host threads went: the CPU backend neither submits
    // nor waits; a resident step does both, one after the other (drawing
    // may run beside them).
    for (out, resident) in [(&cpu, false), (&on_gpu, true)] {
        let p = out.phases;
        assert!(p.draw > 0.0 && p.draw <= out.loop_seconds && p.submit + p.wait <= out.loop_seconds, "{p:?} of {} s", out.loop_seconds);
        assert_eq!((p.submit > 0.0, p.wait > 0.0), (resident, resident), "{p:?}");
    }
    // And the same bits when run again.
    let again = encode(&t, &cfg, None, &mut g, &mut |_| {}).unwrap();
    assert!(same_bits(&on_gpu.params, &again.params));
}

/// Resident training: one step on the device (point terms, regularisers,
/// Adam) against the same step on the host from the device's own gradient;
/// then a step whose candidate lists overflow (the update is held back and
/// the step runs again) gives the same bits as one that fits. Under the
/// paper's objective and gsenc's.
#[test]
fn one_resident_adam_step_matches_the_host() {
    resident_step_matches_the_host(LossWeights::PAPER);
}

#[test]
fn one_resident_adam_step_of_gsenc_objective_matches_the_host() {
    resident_step_matches_the_host(LossWeights::GSENC);
}

fn resident_step_matches_the_host(w: LossWeights) {
    let Some(mut g) = gpu() else { return };
    let mut rng = Rng::new(19);
    let mut params = random_model(&mut rng, 300, 32.0);
    params[7][3] = 9.5f32.ln(); // the scale penalty
    params[8][3] = 3.0f32.ln(); // and the anisotropy penalty (ratio 15)
    params[8][5] = 0.2f32.ln();
    let b = random_batch(&mut rng, 4000, 32.0);
    let mut adam = Adam::new(params.len());
    // Some history in the moments, so that the step is not the first.
    for (i, (m, v)) in adam.m.iter_mut().zip(adam.v.iter_mut()).enumerate() {
        for k in 0..12 {
            m[k] = 1e-3 * ((i + k) % 7) as f32 - 3e-3;
            v[k] = 1e-6 * (1 + (i * k) % 5) as f32;
        }
    }
    adam.t = 4;
    let lr = 8e-3;
    // The host's step, from the device's gradient of the point terms.
    let mut grad = vec![[0.0; 12]; params.len()];
    g.point_loss_grad(&params, &b, &w, &mut grad).unwrap();
    let reg = regularizers(&params, &w, &mut grad);
    let (mut host_p, mut host_a) = (params.clone(), adam.clone());
    host_a.step(&mut host_p, &grad, lr);
    // The device's.
    let r = g.resident().unwrap();
    r.load(&params, &adam).unwrap();
    let (pl, rg) = r.step(&b, &w, lr, true).unwrap().unwrap();
    let (mut dev_p, mut dev_a) = (vec![[0.0; 12]; params.len()], Adam::new(0));
    r.store(&mut dev_p, &mut dev_a).unwrap();
    assert_eq!(dev_a.t, 5);
    assert!((rg.scale - reg.scale).abs() <= 1e-5 * reg.scale.abs().max(1e-9) && rg.scale > 0.0, "{rg:?} vs {reg:?}");
    assert!((rg.aniso - reg.aniso).abs() <= 1e-5 * reg.aniso.abs().max(1e-9) && rg.aniso > 0.0, "{rg:?} vs {reg:?}");
    assert!(pl.val > 0.0 && pl.cov > 0.0);
    for i in 0..params.len() {
        for k in 0..12 {
            let (d, h) = (dev_p[i][k], host_p[i][k]);
            assert!((d - h).abs() <= 1e-6 + 1e-5 * h.abs(), "primitive {i} parameter {k}: device {d}, host {h}");
            assert!((dev_a.m[i][k] - host_a.m[i][k]).abs() <= 1e-9 + 1e-5 * host_a.m[i][k].abs(), "m {i} {k}: {} {} grad {}", dev_a.m[i][k], host_a.m[i][k], grad[i][k]);
            assert!((dev_a.v[i][k] - host_a.v[i][k]).abs() <= 1e-12 + 1e-5 * host_a.v[i][k].abs());
        }
    }
    // The same step with lists that overflow: held back, run again, same bits.
    let mut tight = gpu().unwrap();
    tight.set_capacity(5);
    let r = tight.resident().unwrap();
    r.load(&params, &adam).unwrap();
    r.step(&b, &w, lr, false).unwrap();
    let (mut again, mut again_a) = (vec![[0.0; 12]; params.len()], Adam::new(0));
    r.store(&mut again, &mut again_a).unwrap();
    assert!(tight.reruns >= 1);
    assert!(same_bits(&again, &dev_p));
    assert_eq!(again_a.t, 5);
}

/// The GPU backend reads a batch's sort into bricks made ahead, and only
/// one of its own edge: the gradient (`common::check_sorted_ahead`) and a
/// resident step, bit for bit.
#[test]
fn a_batch_sorted_ahead_gives_the_step_of_one_sorted_in_the_call() {
    let Some(mut g) = gpu() else { return };
    let mut rng = Rng::new(37);
    let params = random_model(&mut rng, 300, 40.0);
    let plain = random_batch(&mut rng, 4000, 40.0);
    check_sorted_ahead(&mut g, &params, &plain);
    let edge = g.brick_edge().unwrap();
    let w = LossWeights::default();
    let mut step = |b: &PointBatch| {
        let r = g.resident().unwrap();
        r.load(&params, &Adam::new(params.len())).unwrap();
        let terms = r.step(b, &w, 4e-3, true).unwrap().unwrap();
        let (mut p, mut a) = (vec![[0.0; 12]; params.len()], Adam::new(0));
        r.store(&mut p, &mut a).unwrap();
        (terms, p)
    };
    let (terms, reference) = step(&plain);
    assert!(!same_bits(&reference, &params), "the step must move the parameters");
    for e in [edge, edge / 4.0] {
        let mut b = plain.clone();
        b.sort_into_bricks(e);
        let (t, p) = step(&b);
        assert!(t.0 == terms.0 && (t.1.scale, t.1.aniso) == (terms.1.scale, terms.1.aniso) && same_bits(&p, &reference), "sorted ahead into bricks of {e}");
    }
}

/// Submitted resident steps hold the device until `finish`: up to two may
/// be in flight, every other call in between is an error that leaves them
/// intact, and the steps finished late are the steps run one at a time,
/// bit for bit.
#[test]
fn submitted_steps_hold_the_device_until_they_finish() {
    let Some(mut g) = gpu() else { return };
    let mut rng = Rng::new(23);
    let params = random_model(&mut rng, 120, 24.0);
    let batches = [random_batch(&mut rng, 1500, 24.0), random_batch(&mut rng, 1200, 24.0)];
    let w = LossWeights::default();
    let adam = Adam::new(params.len());
    let lr = 5e-3;
    let r = g.resident().unwrap();
    assert_eq!(r.depth(), 2);
    assert!(r.finish().is_err(), "finish without a submit");
    r.load(&params, &adam).unwrap();
    let at_once: Vec<_> = batches.iter().map(|b| r.step(b, &w, lr, true).unwrap().unwrap()).collect();
    let (mut at_once_p, mut a) = (vec![[0.0; 12]; params.len()], Adam::new(0));
    r.store(&mut at_once_p, &mut a).unwrap();

    r.load(&params, &adam).unwrap();
    r.submit(&batches[0], &w, lr, true).unwrap();
    r.submit(&batches[1], &w, lr, true).unwrap();
    let b = &batches[0];
    assert!(r.submit(b, &w, lr, true).is_err(), "a third submit");
    let mut scratch = (vec![[0.0; 12]; params.len()], Adam::new(0));
    assert!(r.store(&mut scratch.0, &mut scratch.1).is_err(), "a store");
    assert!(r.load(&params, &adam).is_err(), "a load");
    let (mut rho, mut n) = (vec![0.0; b.pos.len()], vec![0.0; b.pos.len()]);
    assert!(g.evaluate_points(&params, &b.pos, &mut rho, &mut n).is_err(), "an evaluation");
    let mut grad = vec![[0.0; 12]; params.len()];
    assert!(g.point_loss_grad(&params, b, &w, &mut grad).is_err(), "a gradient");
    let lattice = Lattice { dims: [4, 4, 4], origin: [0.0; 3], step: [2.0; 3] };
    assert!(g.decode_lattice(&params, &lattice, &mut vec![0.0; 64]).is_err(), "a decode");
    let r = g.resident().unwrap();
    for (k, once) in at_once.iter().enumerate() {
        let late = r.finish().unwrap().unwrap();
        assert_eq!((late.0.val.to_bits(), late.1.scale.to_bits()), (once.0.val.to_bits(), once.1.scale.to_bits()), "step {k}");
    }
    assert!(r.finish().is_err(), "a finish with nothing in flight");
    let (mut late_p, mut late_a) = (vec![[0.0; 12]; params.len()], Adam::new(0));
    r.store(&mut late_p, &mut late_a).unwrap();
    assert_eq!(late_a.t, 2);
    assert!(same_bits(&late_p, &at_once_p));
}

/// A step whose lists overflow while the next is already queued: the next
/// ran on parameters the first did not update, so it must change nothing
/// (adam.wgsl `mark`), even where its own lists fit, and run again after
/// the first. A large batch then a small one (a corner of the box), with
/// room for the small one's lists only, against the same steps in turn
/// with room for both: the same bits. Then three steps, two in flight at a
/// time, with lists that start far too small.
#[test]
fn a_step_that_overflows_holds_back_the_step_queued_after_it() {
    let Some(mut g) = gpu() else { return };
    let mut rng = Rng::new(29);
    let params = random_model(&mut rng, 200, 24.0);
    let mut batches: Vec<_> = (0..3).map(|_| random_batch(&mut rng, 1000, 24.0)).collect();
    batches[1] = random_batch(&mut rng, 12, 4.0);
    let w = LossWeights::default();
    let adam = Adam::new(params.len());
    let lr = 5e-3;
    let in_turn = |g: &mut GpuBackend, batches: &[PointBatch]| {
        let r = g.resident().unwrap();
        r.load(&params, &adam).unwrap();
        let losses: Vec<_> = batches.iter().map(|b| r.step(b, &w, lr, true).unwrap().unwrap()).collect();
        let (mut p, mut a) = (vec![[0.0; 12]; params.len()], Adam::new(0));
        r.store(&mut p, &mut a).unwrap();
        (losses, p)
    };
    // Two in flight from the start; the third submitted after the first finishes.
    let piped = |g: &mut GpuBackend, batches: &[PointBatch]| {
        let r = g.resident().unwrap();
        r.load(&params, &adam).unwrap();
        let mut losses = vec![];
        for (k, b) in batches.iter().enumerate() {
            r.submit(b, &w, lr, true).unwrap();
            if k >= 1 {
                losses.push(r.finish().unwrap().unwrap());
            }
        }
        losses.push(r.finish().unwrap().unwrap());
        let (mut p, mut a) = (vec![[0.0; 12]; params.len()], Adam::new(0));
        r.store(&mut p, &mut a).unwrap();
        assert_eq!(a.t, batches.len() as u32);
        (losses, p)
    };
    let same = |(la, pa): &(Vec<(PointLoss, RegTerms)>, Vec<Primitive>), (lb, pb): &(Vec<(PointLoss, RegTerms)>, Vec<Primitive>)| {
        la.iter().zip(lb).all(|(a, b)| (a.0.val.to_bits(), a.1.aniso.to_bits()) == (b.0.val.to_bits(), b.1.aniso.to_bits()))
            && same_bits(pa, pb)
    };
    // Each in a submission of its own, then two to a submission (the step
    // that overflows and the one it holds back in one command buffer),
    // then three (a submission read back before it is full).
    let want = in_turn(&mut g, &batches[..2]);
    for batch in [1, 2] {
        // Room for the small batch's lists and not the large one's: the
        // first step alone overflows (one rerun), and the second, queued
        // behind it with lists that fit, must wait for it.
        let mut found = false;
        for cap in (3..16).map(|k| 1usize << k) {
            let mut tight = gpu().unwrap();
            tight.batch = batch;
            tight.set_capacity(cap);
            let got = piped(&mut tight, &batches[..2]);
            if tight.reruns == 1 {
                assert!(same(&got, &want), "batch {batch}, capacity {cap}: the queued step did not wait for the one that overflowed");
                found = true;
            }
        }
        assert!(found, "batch {batch}: no capacity made the large batch overflow and the small one fit");
    }
    let want = in_turn(&mut g, &batches);
    for batch in [1, 2, 3] {
        let mut tight = gpu().unwrap();
        tight.batch = batch;
        tight.set_capacity(5);
        let got = piped(&mut tight, &batches);
        assert!(tight.reruns >= 1, "batch {batch}: the lists never overflowed");
        assert!(same(&got, &want), "batch {batch}");
    }
}

/// An encode with two submissions of resident steps in flight, each of one
/// step or of several (`GpuBackend::batch`), gives the model of the same
/// encode one step at a time, bit for bit, also when the candidate lists
/// start too small and overflow along the way.
#[test]
fn an_encode_with_steps_in_flight_or_batched_gives_the_model_of_one_at_a_time() {
    let Some(mut g) = gpu() else { return };
    let field = hydrogen32();
    let t = Target { reference: &field, samples: &field };
    let cfg = short(60, 2048);
    g.depth = 1;
    let one = encode(&t, &cfg, None, &mut g, &mut |_| {}).unwrap();
    assert_eq!(one.relocations.len(), 3);
    for batch in [1, 2, 3] {
        let mut piped = gpu().unwrap();
        piped.set_capacity(64);
        piped.batch = batch;
        assert_eq!(piped.resident().unwrap().depth(), 2 * batch);
        let out = encode(&t, &cfg, None, &mut piped, &mut |_| {}).unwrap();
        assert!(piped.reruns > 0, "batch {batch}: the lists never overflowed");
        assert_eq!(one.last_loss.total.to_bits(), out.last_loss.total.to_bits(), "batch {batch}");
        assert!(same_bits(&one.params, &out.params), "batch {batch}");
    }
}

/// Steps batched three to a submission: up to six in flight, each step
/// arranged, written and recorded on its own, but submitted once a batch
/// (and a batch that is not full once one of its steps is read back); the
/// bits of one step a submission. Uploads written buffer by buffer take
/// one step a submission, whatever the batch.
#[test]
fn batched_steps_share_a_submission() {
    let Some(mut g) = gpu() else { return };
    let mut rng = Rng::new(41);
    let params = random_model(&mut rng, 140, 24.0);
    let batches: Vec<PointBatch> = (0..7).map(|k| random_batch(&mut rng, 700 + 50 * k, 24.0)).collect();
    let w = LossWeights::default();
    let adam = Adam::new(params.len());
    let run = |g: &mut GpuBackend| {
        let r = g.resident().unwrap();
        r.load(&params, &adam).unwrap();
        let (depth, mut pending, mut losses) = (r.depth(), 0, vec![]);
        for b in &batches {
            r.submit(b, &w, 5e-3, true).unwrap();
            pending += 1;
            while pending >= depth {
                losses.push(r.finish().unwrap().unwrap().0.val.to_bits());
                pending -= 1;
            }
        }
        for _ in 0..pending {
            losses.push(r.finish().unwrap().unwrap().0.val.to_bits());
        }
        let (mut p, mut a) = (vec![[0.0; 12]; params.len()], Adam::new(0));
        r.store(&mut p, &mut a).unwrap();
        assert_eq!(a.t, batches.len() as u32);
        let times = |phase: &str| g.host_seconds().iter().find(|(n, _, _)| n == phase).map_or(0, |p| p.1);
        (p, losses, times("record"), times("submit"))
    };
    let (one_p, one_losses, recorded, submitted) = run(&mut g);
    assert_eq!((recorded, submitted), (7, 7));
    let mut three = gpu().unwrap();
    three.batch = 3;
    assert_eq!(three.resident().unwrap().depth(), 6);
    let (p, losses, recorded, submitted) = run(&mut three);
    // (0, 1, 2) and (3, 4, 5) full; 6 submitted when the end reads it.
    assert_eq!((recorded, submitted), (7, 3));
    assert_eq!(losses, one_losses);
    assert!(same_bits(&p, &one_p));
    let mut per_buffer = gpu().unwrap();
    (per_buffer.batch, per_buffer.upload_per_buffer) = (3, true);
    assert_eq!(per_buffer.resident().unwrap().depth(), 2);
    let (p, losses, _, submitted) = run(&mut per_buffer);
    assert_eq!(submitted, 7);
    assert_eq!(losses, one_losses);
    assert!(same_bits(&p, &one_p));
}

/// An `auto` warm step on the device (its start chosen and its end decided
/// by validation scores taken there, resident training, the best parameters
/// kept) lands within a third of a dB of the same step on the CPU, and gives
/// the same bits when run again.
#[test]
fn an_auto_warm_step_matches_the_cpu_backend() {
    let Some(mut g) = gpu() else { return };
    let field = hydrogen32();
    let t = Target { reference: &field, samples: &field };
    let cfg = short(100, 2048);
    let prev = encode(&t, &cfg, None, &mut CpuBackend::new(), &mut |_| {}).unwrap().params;
    // The next step: the field moved 5 voxels along x.
    let dx = field.dims[0];
    let moved = Grid::new(field.dims, (0..field.len()).map(|i| if i % dx >= 5 { field.values[i - 5] } else { 0.0 }).collect()).unwrap();
    let t = Target { reference: &moved, samples: &moved };
    let auto = WarmStart::Auto.step_config(&cfg);
    let v = Validation::from_reference(&moved, 2048, 3, 10).unwrap();
    let run = |b: &mut dyn Backend| encode_validated(&t, &auto, Some(&prev), Some(&v), b, &mut |_| {}).unwrap();
    let (cpu, on_gpu) = (run(&mut CpuBackend::new()), run(&mut g));
    assert!(on_gpu.warm.is_some() && on_gpu.iterations <= 100, "{:?} {}", on_gpu.warm, on_gpu.iterations);
    let (a, b) = (cpu.validation.last().unwrap().1, on_gpu.validation.last().unwrap().1);
    assert!((a - b).abs() <= 0.3, "cpu {a:.3} dB ({:?}), gpu {b:.3} dB ({:?})", cpu.warm, on_gpu.warm);
    let again = run(&mut g);
    assert_eq!((again.warm, again.iterations), (on_gpu.warm, on_gpu.iterations));
    assert!(same_bits(&on_gpu.params, &again.params));
}

/// Steady training makes no device objects: once a run's buffers have
/// grown to its batches, a resident step (two in flight, so both read-back
/// slots) rewrites the buffers of the steps before it and binds them
/// through the bind groups it kept, instead of making a uniform buffer and
/// a bind group per dispatch, each a driver allocation. Its uploads fill
/// one staging buffer that is mapped again after each step (staged.rs
/// `Staged`), where a queue write per buffer takes staging memory of its
/// own each. And the steps give the bits of a backend that made
/// everything afresh.
#[test]
fn steady_resident_steps_make_no_buffers_or_bind_groups() {
    let Some(mut g) = gpu() else { return };
    let mut rng = Rng::new(31);
    let params = random_model(&mut rng, 150, 24.0);
    let batches: Vec<PointBatch> = (0..3).map(|k| random_batch(&mut rng, 1400 - 200 * k, 24.0)).collect();
    let w = LossWeights::default();
    let adam = Adam::new(params.len());
    let run = |g: &mut GpuBackend, steps: usize| -> (Vec<Primitive>, Vec<(u64, u64, u64)>) {
        let mut made = vec![];
        g.resident().unwrap().load(&params, &adam).unwrap();
        for t in 0..steps {
            let r = g.resident().unwrap();
            r.submit(&batches[t % 3], &w, 5e-3, true).unwrap();
            if t > 0 {
                r.finish().unwrap();
            }
            let (buffers, binds) = g.objects_made();
            made.push((buffers, binds, g.uploads()));
        }
        let r = g.resident().unwrap();
        r.finish().unwrap();
        let (mut p, mut a) = (vec![[0.0; 12]; params.len()], Adam::new(0));
        r.store(&mut p, &mut a).unwrap();
        (p, made)
    };
    let (first, _) = run(&mut g, 9);
    let (again, made) = run(&mut g, 9);
    // Two steps to a submission: the same.
    let mut batched = gpu().unwrap();
    batched.batch = 2;
    run(&mut batched, 9);
    let (batched_p, batched_made) = run(&mut batched, 9);
    assert!(batched_made.windows(2).all(|m| m[0] == (m[1].0, m[1].1, m[1].2 - 1)), "batched, step by step: {batched_made:?}");
    assert!(same_bits(&first, &batched_p));
    let objects = |m: &(u64, u64, u64)| (m.0, m.1);
    assert!(made.windows(2).all(|m| objects(&m[0]) == objects(&m[1])), "objects made (buffers, bind groups, writes) step by step: {made:?}");
    assert!(made[0].1 > 0, "no bind group counted: {made:?}");
    assert!(made.windows(2).all(|m| m[1].2 == m[0].2 + 1), "uploads step by step (one each): {made:?}");
    let mut fresh = gpu().unwrap();
    let (fresh_p, _) = run(&mut fresh, 9);
    assert!(same_bits(&first, &again) && same_bits(&first, &fresh_p));
    // Written buffer by buffer (`GSENC_GPU_UPLOAD=writes`): the same bits,
    // a write for each of the call's nine regions.
    let mut per_buffer = gpu().unwrap();
    per_buffer.upload_per_buffer = true;
    run(&mut per_buffer, 9);
    let (per_buffer_p, made) = run(&mut per_buffer, 9);
    assert!(made.windows(2).all(|m| m[1].2 == m[0].2 + 9), "uploads step by step, buffer by buffer: {made:?}");
    assert!(same_bits(&first, &per_buffer_p));
}

/// The host's phases of the point calls (`host_seconds`): each of a
/// resident step's six phases counted once a step, and their seconds
/// within the time the calls took. A phase timed twice, or one never
/// timed, fails.
#[test]
fn host_phases_count_each_step_once_within_its_time() {
    let Some(mut g) = gpu() else { return };
    let mut rng = Rng::new(37);
    let params = random_model(&mut rng, 120, 24.0);
    let batch = random_batch(&mut rng, 900, 24.0);
    let w = LossWeights::default();
    g.resident().unwrap().load(&params, &Adam::new(params.len())).unwrap();
    assert!(g.host_seconds().is_empty(), "phases timed before any point call: {:?}", g.host_seconds());
    let steps = 5;
    let started = std::time::Instant::now();
    for _ in 0..steps {
        let r = g.resident().unwrap();
        r.submit(&batch, &w, 5e-3, false).unwrap();
        r.finish().unwrap();
    }
    let took = started.elapsed().as_secs_f64();
    let phases = g.host_seconds();
    let names: Vec<&str> = phases.iter().map(|(n, _, _)| n.as_str()).collect();
    let mut want = ["arrange", "write", "record", "submit", "wait", "read"];
    want.sort();
    assert_eq!(names, want, "{phases:?}");
    for (name, times, _) in &phases {
        assert_eq!(*times, steps as u64, "{name}: {phases:?}");
    }
    let sum: f64 = phases.iter().map(|p| p.2).sum();
    assert!(sum > 0.0 && sum <= took, "phases sum to {sum} s of the calls' {took} s: {phases:?}");
}
