//! Steps resident on the device against the host's: one Adam step, batches
//! sorted ahead, steps in flight and batched, the buffers steady steps make
//! and the host phases they count.

use super::*;

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
