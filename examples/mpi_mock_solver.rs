//! A domain-decomposed mock solver on gsenc's MPI layer, and the test of it:
//! run under `mpirun -n N` (N = 1, 2, 4, 8).
//!
//! Every rank generates the same global fields (moving Gaussian blobs on a
//! grid, as SPH particles, and as AMR cells refined twice near the blobs)
//! and keeps its own part of the unit cube; each step every rank pushes its
//! part, collectively, and encodes `budget / N` Gaussians over its piece.
//! Rank 0 then reads the step index, decodes the global field from all
//! pieces (blended, `gsenc::domain::pieces::blend`; the additive decode of all
//! primitives together is printed beside it), and scores it against the
//! global reference (the serial deposit of all the data); it prints one JSON
//! line per form and step.
//!
//! With `--baseline FILE` (written by the `-n 1` run with
//! `--write-baseline`), rank 0 checks that the global PSNR is within
//! `--tolerance-db` (default 1) of the single-rank encode of the same total
//! budget, that the error near the cuts between ranks is no larger than
//! inside, and that every piece after the first step was warm-started.
//! Misuse is checked too: ranks that push different fields, or one rank's
//! bad data, give every rank an error, and the encoder goes on afterwards.
//!
//! ```text
//! mpirun -n 2 target/release/examples/mpi_mock_solver --out /tmp/m2 --baseline /tmp/m1/baseline.json
//! ```

use gsenc::backend::cpu::CpuBackend;
use gsenc::domain::mpi::{Decomposition, DecompositionConfig};
use gsenc::domain::pieces::blend;
use gsenc::encode::{EncodeConfig, Schedule, WarmStart};
use gsenc::field::{Grid, IndexBox, IndexFrame, Transform, ValueRange};
use gsenc::format::{model_file_name, step_index_file_name, Payload};
use gsenc::input::cells::{CellSize, Cells};
use gsenc::input::particles::Particles;
use gsenc::input::prepare::{prepare_cells, prepare_particles, Placement, RangeSpec};
use gsenc::input::StepData;
use gsenc::io::{read_step, write_atomic, ModelFolder};
use gsenc::model::metrics::voxel_psnr;
use gsenc::series::queue::{BackgroundEncoder, Job, QueueConfig, WhenFull, KEPT_STATES};
use gsenc::series::{SeriesConfig, SeriesRange};
use gsenc::Error;
use mpi::traits::*;
use std::path::PathBuf;
use std::time::Instant;

struct Args {
    out: PathBuf,
    baseline: Option<PathBuf>,
    write_baseline: bool,
    grid: usize,
    particles: usize,
    budget: usize,
    iterations: usize,
    steps: u64,
    halo: usize,
    tolerance_db: f64,
    forms: Vec<String>,
}

fn args() -> Args {
    let mut a = Args {
        out: PathBuf::from("mpi-out"),
        baseline: None,
        write_baseline: false,
        grid: 48,
        particles: 60_000,
        budget: 2400,
        iterations: 600,
        steps: 3,
        halo: 8,
        tolerance_db: 1.0,
        forms: vec!["grid".into(), "particles".into(), "cells".into()],
    };
    let mut it = std::env::args().skip(1);
    while let Some(k) = it.next() {
        let mut v = || it.next().unwrap_or_else(|| panic!("{k} needs a value"));
        match k.as_str() {
            "--out" => a.out = v().into(),
            "--baseline" => a.baseline = Some(v().into()),
            "--write-baseline" => a.write_baseline = true,
            "--grid" => a.grid = v().parse().unwrap(),
            "--particles" => a.particles = v().parse().unwrap(),
            "--budget" => a.budget = v().parse().unwrap(),
            "--iterations" => a.iterations = v().parse().unwrap(),
            "--steps" => a.steps = v().parse().unwrap(),
            "--halo" => a.halo = v().parse().unwrap(),
            "--tolerance-db" => a.tolerance_db = v().parse().unwrap(),
            "--forms" => a.forms = v().split(',').map(String::from).collect(),
            _ => panic!("unknown argument {k}"),
        }
    }
    a
}

/// The mock field: four blobs drifting with the step.
fn field(x: [f64; 3], step: u64) -> f32 {
    let t = step as f64 * 0.03;
    let blobs = [([0.3 + t, 0.35, 0.4], 0.12, 1.0), ([0.65, 0.6 - t, 0.55], 0.09, 0.8), ([0.5, 0.5, 0.5 + t], 0.2, 0.4), ([0.75, 0.3, 0.7], 0.06, 0.9)];
    blobs
        .iter()
        .map(|(c, s, a)| {
            let r2: f64 = (0..3).map(|i| (x[i] - c[i]).powi(2)).sum();
            a * (-r2 / (2.0 * s * s)).exp()
        })
        .sum::<f64>() as f32
}

/// How N ranks cut the unit cube: along x, then y, then z.
fn splits(n: usize) -> [usize; 3] {
    match n {
        1 => [1, 1, 1],
        2 => [2, 1, 1],
        4 => [2, 2, 1],
        8 => [2, 2, 2],
        n => [n, 1, 1],
    }
}

/// This rank's sub-box (half-open) of the unit cube.
fn sub_box(rank: usize, n: usize) -> ([f64; 3], [f64; 3]) {
    let s = splits(n);
    let idx = [rank % s[0], (rank / s[0]) % s[1], rank / (s[0] * s[1])];
    (std::array::from_fn(|a| idx[a] as f64 / s[a] as f64), std::array::from_fn(|a| (idx[a] + 1) as f64 / s[a] as f64))
}

fn owns(lo: &[f64; 3], hi: &[f64; 3], x: &[f64; 3]) -> bool {
    (0..3).all(|a| x[a] >= lo[a] && (x[a] < hi[a] || (hi[a] >= 1.0 && x[a] <= 1.0)))
}

/// Uniform pseudo-random particles, the same on every rank.
fn global_particles(n: usize, step: u64) -> (Vec<[f64; 3]>, Vec<f64>, Vec<f32>) {
    let mut state = 0x2545_f491_4f6c_dd1du64;
    let mut next = || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    let positions: Vec<[f64; 3]> = (0..n).map(|_| [next(), next(), next()]).collect();
    let h = 1.2 * (1.0 / n as f64).cbrt();
    let values = positions.iter().map(|&p| field(p, step)).collect();
    (positions, vec![h; n], values)
}

/// Cells of 1/16, refined into eighths twice where the field is strong.
fn global_cells(step: u64) -> (Vec<[f64; 3]>, Vec<[f64; 3]>, Vec<f32>) {
    let (mut centres, mut edges, mut values) = (vec![], vec![], vec![]);
    fn add(c: [f64; 3], e: f64, level: u32, step: u64, out: &mut (&mut Vec<[f64; 3]>, &mut Vec<[f64; 3]>, &mut Vec<f32>)) {
        let v = field(c, step);
        if level < 2 && v > 0.25 + 0.25 * level as f32 {
            for o in 0..8 {
                let d = [(o & 1) as f64, ((o >> 1) & 1) as f64, ((o >> 2) & 1) as f64];
                add(std::array::from_fn(|a| c[a] + (d[a] - 0.5) * e / 2.0), e / 2.0, level + 1, step, out);
            }
        } else {
            out.0.push(c);
            out.1.push([e; 3]);
            out.2.push(v);
        }
    }
    let m = 16;
    for k in 0..m {
        for j in 0..m {
            for i in 0..m {
                let c = [(i as f64 + 0.5) / m as f64, (j as f64 + 0.5) / m as f64, (k as f64 + 0.5) / m as f64];
                add(c, 1.0 / m as f64, 0, step, &mut (&mut centres, &mut edges, &mut values));
            }
        }
    }
    (centres, edges, values)
}

/// One form's global data at a step: this rank's part to push, and on rank 0
/// the global reference (normalised) and its frame.
fn step_data(form: &str, a: &Args, step: u64, rank: usize, n: usize, want_reference: bool) -> (StepData, Option<(Grid, IndexFrame)>) {
    let (lo, hi) = sub_box(rank, n);
    let g = a.grid;
    let dims = [g; 3];
    match form {
        "grid" => {
            let global: Vec<f32> = (0..g * g * g)
                .map(|i| field([(i % g) as f64 + 0.5, ((i / g) % g) as f64 + 0.5, (i / (g * g)) as f64 + 0.5].map(|c| c / g as f64), step))
                .collect();
            let cell = |x: f64| (x * g as f64).round() as usize;
            let (c0, c1) = (lo.map(cell), hi.map(cell));
            let mine_dims = [c1[0] - c0[0], c1[1] - c0[1], c1[2] - c0[2]];
            let mut values = Vec::with_capacity(mine_dims.iter().product());
            for k in c0[2]..c1[2] {
                for j in c0[1]..c1[1] {
                    values.extend_from_slice(&global[c0[0] + g * (j + g * k)..c1[0] + g * (j + g * k)]);
                }
            }
            let frame = IndexFrame { dims: mine_dims, bmin: c0.map(|c| c as f64 / g as f64), gamma: g as f64 };
            let data = StepData::Grid { grid: Grid::new(mine_dims, values).unwrap(), frame };
            let reference = want_reference.then(|| {
                let range = ValueRange::from_data(&global, Transform::Linear).unwrap();
                let norm = range.normalize(&global).unwrap().values;
                (Grid::new(dims, norm).unwrap(), IndexFrame { dims, bmin: [0.0; 3], gamma: g as f64 })
            });
            (data, reference)
        }
        "particles" => {
            let (pos, h, val) = global_particles(a.particles, step);
            let mass = vec![1.0f32; pos.len()];
            let reference = want_reference.then(|| {
                let p = Particles { positions: &pos, smoothing_length: &h, mass: &mass, values: &val };
                let prep = prepare_particles(&p, &Placement::new(dims, None), &RangeSpec::FromData(Transform::Linear)).unwrap();
                (prep.reference, prep.frame)
            });
            let mine: Vec<usize> = (0..pos.len()).filter(|&j| owns(&lo, &hi, &pos[j])).collect();
            let data = StepData::Particles {
                positions: mine.iter().map(|&j| pos[j]).collect(),
                smoothing_length: mine.iter().map(|&j| h[j]).collect(),
                mass: mine.iter().map(|&j| mass[j]).collect(),
                values: mine.iter().map(|&j| val[j]).collect(),
                placement: Placement::new(dims, None),
            };
            (data, reference)
        }
        _ => {
            let (centres, edges, values) = global_cells(step);
            let reference = want_reference.then(|| {
                let c = Cells { centres: &centres, size: CellSize::Edges(&edges), values: &values };
                let prep = prepare_cells(&c, &Placement::new(dims, None), &RangeSpec::FromData(Transform::Linear)).unwrap();
                (prep.reference, prep.frame)
            });
            let mine: Vec<usize> = (0..centres.len()).filter(|&j| owns(&lo, &hi, &centres[j])).collect();
            let data = StepData::Cells {
                centres: mine.iter().map(|&j| centres[j]).collect(),
                edges: mine.iter().map(|&j| edges[j]).collect(),
                volumes: Vec::new(),
                values: mine.iter().map(|&j| values[j]).collect(),
                placement: Placement::new(dims, None),
            };
            (data, reference)
        }
    }
}

/// Root-mean-square errors within 3 voxels of the cuts of a 4-rank run
/// (the planes x = 1/2 and y = 1/2) and elsewhere, over voxels where the
/// reference is not empty (> 1% of the range), on the same voxels whatever
/// the rank count.
fn cut_and_inside_rmse(decoded: &[f32], reference: &Grid, frame: &IndexFrame) -> (f64, f64) {
    let (mut cut, mut inside) = ((0.0, 0usize), (0.0, 0usize));
    for (i, (&d, &r)) in decoded.iter().zip(&reference.values).enumerate() {
        if r <= 0.01 {
            continue;
        }
        let [x, y, _] = reference.coords(i);
        let world = frame.index_to_world([x as f64, y as f64, 0.0]);
        let near = (world[0] - 0.5).abs() * frame.gamma < 3.0 || (world[1] - 0.5).abs() * frame.gamma < 3.0;
        let e = ((d - r) as f64).powi(2);
        let acc = if near { &mut cut } else { &mut inside };
        acc.0 += e;
        acc.1 += 1;
    }
    ((cut.0 / cut.1.max(1) as f64).sqrt(), (inside.0 / inside.1.max(1) as f64).sqrt())
}

/// Peak resident memory of this process (kB), from /proc.
fn peak_rss_kb() -> u64 {
    gsenc::memory::process_status("VmHWM:").unwrap_or(0) / 1024
}

fn main() {
    let a = args();
    let (universe, threading) = mpi::initialize_with_threading(mpi::Threading::Funneled).expect("MPI initialises");
    assert!(threading != mpi::Threading::Single, "MPI gave MPI_THREAD_SINGLE");
    let world = universe.world();
    let (rank, n) = (world.rank() as usize, world.size() as usize);
    std::fs::create_dir_all(&a.out).unwrap();
    let mut failures = Vec::new();

    let mut encode = EncodeConfig::new(a.budget / n, Schedule::Short);
    encode.iterations = Some(a.iterations);
    let mut series = SeriesConfig::new(encode, WarmStart::Dense, SeriesRange::FirstStep(Transform::Linear));
    series.validation_points = 0;
    series.warm_iterations = Some(a.iterations / 2);
    series.rank = rank as u32;
    let cfg = DecompositionConfig { dims: [a.grid; 3], bounds: None, halo: a.halo, range: SeriesRange::FirstStep(Transform::Linear) };
    let mut ranks = Decomposition::new(&world, cfg).unwrap();
    // Each rank of a node takes its own GPU when there are several.
    let backend = gsenc::backend::select::BackendChoice::default().for_node_rank(ranks.node_rank());
    let queue_cfg = QueueConfig { series, max_bytes: 1 << 30, when_full: WhenFull::Block, threads: 1, backend, placement: Default::default(), kept_states: KEPT_STATES };
    let queue = BackgroundEncoder::new(queue_cfg, Box::new(ModelFolder { dir: a.out.clone(), payload: Payload::Float32 })).unwrap();

    // Misuse, before the series: every rank must get an error, and go on.
    if n > 1 {
        let (data, _) = step_data("grid", &a, 0, rank, n, false);
        let job = Job { field: format!("misuse{rank}"), step: 0, time: None, data, range: None };
        match ranks.push(&queue, job, &|r| model_file_name("misuse", 0, r)) {
            Err(Error::Mpi(m)) if m.contains("different") => {}
            other => failures.push(format!("rank {rank}: different fields gave {:?}", other.map(|d| d.pushed))),
        }
        let (mut data, _) = step_data("grid", &a, 0, rank, n, false);
        if let (1, StepData::Grid { grid, .. }) = (rank, &mut data) {
            grid.values[7] = f32::NAN;
        }
        let job = Job { field: "misuse".into(), step: 0, time: None, data, range: None };
        match (rank, ranks.push(&queue, job, &|r| model_file_name("misuse", 0, r))) {
            (1, Err(Error::InvalidData(_))) => {}
            (r, Err(Error::Mpi(m))) if r != 1 && m.contains("rank 1") => {}
            (_, other) => failures.push(format!("rank {rank}: NaN on rank 1 gave {:?}", other.map(|d| d.pushed))),
        }
    }

    let baseline: Option<serde_json::Value> = a.baseline.as_ref().map(|p| serde_json::from_str(&std::fs::read_to_string(p).unwrap()).unwrap());
    let mut results = serde_json::Map::new();
    for form in a.forms.iter().map(String::as_str) {
        for step in 1..=a.steps {
            let (data, reference) = step_data(form, &a, step, rank, n, rank == 0);
            world.barrier();
            let t = Instant::now();
            let job = Job { field: form.into(), step, time: Some(step as f64), data, range: None };
            let done = ranks.push(&queue, job, &|r| model_file_name(form, step, r)).unwrap_or_else(|e| panic!("rank {rank}: {e}"));
            if let Some(index) = done.index {
                write_atomic(a.out.join(step_index_file_name(form, step)), index.to_json().as_bytes()).unwrap();
            }
            let push_seconds = t.elapsed().as_secs_f64();
            queue.wait(None).unwrap_or_else(|e| panic!("rank {rank}: {e}"));
            let local = [t.elapsed().as_secs_f64()];
            let mut slowest = [0f64];
            world.all_reduce_into(&local[..], &mut slowest[..], mpi::collective::SystemOperation::max());
            let rss = [peak_rss_kb()];
            let mut max_rss = [0u64];
            world.all_reduce_into(&rss[..], &mut max_rss[..], mpi::collective::SystemOperation::max());
            let Some((reference, frame)) = reference else { continue };
            // Rank 0: the global field from every piece.
            let t_decode = Instant::now();
            let (index, pieces) = read_step(&a.out.join(step_index_file_name(form, step))).unwrap();
            let (global, boxes) = index.layout();
            assert_eq!(global.dims, frame.dims);
            assert!((0..3).all(|i| (global.bmin[i] - frame.bmin[i]).abs() < 1e-9), "global frame {global:?} vs {frame:?}");
            let decoded = blend(&global, &pieces, &boxes, index.halo, frame.dims, IndexBox::whole(frame.dims), &mut CpuBackend::new()).unwrap();
            let decode_seconds = t_decode.elapsed().as_secs_f64();
            let psnr = voxel_psnr(&decoded.values, &reference.values);
            // The additive decode of every piece's primitives together, for comparison.
            let additive = gsenc::domain::pieces::merge(&pieces).unwrap().decode(&mut CpuBackend::new(), Some(frame.dims)).unwrap();
            let additive_psnr = voxel_psnr(&additive.values, &reference.values);
            let (cut, inside) = cut_and_inside_rmse(&decoded.values, &reference, &frame);
            let warm = pieces.iter().all(|p| p.meta.schedule.starts_with("warm"));
            let line = serde_json::json!({
                "form": form, "step": step, "ranks": n, "budget_per_rank": a.budget / n, "halo": a.halo,
                "global_psnr": psnr, "additive_psnr": additive_psnr, "cut_rmse": cut, "inside_rmse": inside, "all_warm": warm,
                "seconds_per_step": slowest[0], "push_seconds_rank0": push_seconds, "decode_seconds": decode_seconds,
                "peak_rss_mb_max_rank": max_rss[0] as f64 / 1024.0,
                "pieces_primitives": pieces.iter().map(|p| p.params.len()).collect::<Vec<_>>(),
            });
            println!("{line}");
            results.insert(format!("{form}/{step}"), line.clone());
            if step > 1 && !warm {
                failures.push(format!("{form} step {step}: not every piece was warm-started"));
            }
            if let Some(b) = &baseline {
                let one = &b[format!("{form}/{step}")];
                let single = one["global_psnr"].as_f64().expect("baseline has this form and step");
                // The cuts' voxels hold a different part of the field than the
                // rest, so each is compared with the single-rank model on the
                // same voxels: the error near the cuts may grow no more than
                // the error inside (10 % slack for the encode's noise).
                let (cut_growth, inside_growth) = (cut / one["cut_rmse"].as_f64().unwrap(), inside / one["inside_rmse"].as_f64().unwrap());
                if n > 1 && cut_growth > 1.1 * inside_growth {
                    failures.push(format!(
                        "{form} step {step}: near the cuts the RMSE grew {cut_growth:.2}x over one rank's, inside only {inside_growth:.2}x"
                    ));
                }
                if psnr < single - a.tolerance_db {
                    failures.push(format!("{form} step {step}: global PSNR {psnr:.2} dB is more than {} dB below one rank's {single:.2} dB", a.tolerance_db));
                }
            }
        }
    }
    if rank == 0 && a.write_baseline {
        std::fs::write(a.out.join("baseline.json"), serde_json::Value::Object(results).to_string()).unwrap();
    }
    drop(ranks);
    drop(queue);
    let mine = [failures.len() as u64];
    let mut total = [0u64];
    world.all_reduce_into(&mine[..], &mut total[..], mpi::collective::SystemOperation::sum());
    for f in &failures {
        eprintln!("FAIL {f}");
    }
    if rank == 0 {
        eprintln!("mpi mock solver, {n} ranks: {} failures", total[0]);
    }
    drop(universe);
    std::process::exit(if total[0] == 0 { 0 } else { 1 });
}
