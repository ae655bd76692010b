//! What a pass of parallel tasks costs beyond its work, on p threads
//! (`benches/fork_cost.sh`): an "iteration" of `PASSES` passes, each of 64
//! tasks of equal arithmetic, run by rayon as the CPU backend runs its passes
//! (`into_par_iter().with_max_len(1)` on a pool of p threads), and by a team of
//! threads that spin between passes instead of sleeping (an atomic task
//! counter and a spinning barrier, as an OpenMP runtime keeps its threads
//! awake between parallel regions). Both do the same work; what each takes
//! beyond the work's time on one thread alone (no pool) over p, per pass,
//! is what the pool's joins and wake-ups cost,
//! the number the scaling model (`benches/scaling_model.py --fork-join-us`)
//! takes on trust. Prints one JSON line per (scheduler, threads, pass size).
//! `cargo run --release --example fork_cost [-- THREADS... [--pass-us US...] [--seconds S]]`
use rayon::prelude::*;
use std::hint::black_box;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::Instant;

/// Tasks a pass: the CPU backend's `primitives_per_task` gives at most 64.
const TASKS: usize = 64;
/// Passes an iteration: about what an iteration of the CPU backend runs.
const PASSES: usize = 7;

/// `n` rounds of dependent arithmetic (about a nanosecond each).
#[inline(never)]
fn work(n: u64) -> f64 {
    let mut x = black_box(1.000_001f64);
    for _ in 0..n {
        x = x * 0.999_999_9 + 1e-9;
    }
    x
}

/// Rounds of `work` a microsecond on one thread.
fn rounds_per_us() -> f64 {
    let n = 2_000_000;
    work(n / 10);
    let t = Instant::now();
    black_box(work(n));
    n as f64 / (t.elapsed().as_secs_f64() * 1e6)
}

/// Seconds of the same tasks on the calling thread alone, no pool: the
/// work that p threads share.
fn serial_run(_threads: usize, rounds: u64, iterations: usize) -> f64 {
    let t = Instant::now();
    for _ in 0..iterations * PASSES * TASKS {
        black_box(work(rounds));
    }
    t.elapsed().as_secs_f64()
}

/// Seconds of `iterations` iterations on a rayon pool of `threads`.
fn rayon_run(threads: usize, rounds: u64, iterations: usize) -> f64 {
    let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("a pool");
    pool.install(|| {
        let t = Instant::now();
        for _ in 0..iterations {
            for _ in 0..PASSES {
                (0..TASKS).into_par_iter().with_max_len(1).for_each(|_| {
                    black_box(work(rounds));
                });
            }
        }
        t.elapsed().as_secs_f64()
    })
}

/// What the team shares: the pass being run (its number), the next task
/// of it, the tasks done, and the end.
struct Shared {
    pass: AtomicUsize,
    next: AtomicUsize,
    done: AtomicUsize,
    stop: AtomicBool,
}

/// Takes tasks of the current pass until none is left.
fn take_tasks(s: &Shared, rounds: u64) {
    loop {
        let i = s.next.fetch_add(1, Ordering::AcqRel);
        if i >= TASKS {
            return;
        }
        black_box(work(rounds));
        s.done.fetch_add(1, Ordering::AcqRel);
    }
}

/// Seconds of `iterations` iterations on a team of `threads` that spin
/// between passes: the caller starts each pass (resets the counters, then
/// bumps `pass`), all take its tasks, and the caller waits, spinning, until
/// every task is done. A measuring stick, not an executor: a thread still
/// in one pass's loop may take a task of the next, which is the same work
/// here (an executor would hand each pass's tasks out under its number).
fn team_run(threads: usize, rounds: u64, iterations: usize) -> f64 {
    let s = Arc::new(Shared { pass: AtomicUsize::new(0), next: AtomicUsize::new(TASKS), done: AtomicUsize::new(0), stop: AtomicBool::new(false) });
    let workers: Vec<_> = (1..threads)
        .map(|_| {
            let s = Arc::clone(&s);
            std::thread::spawn(move || {
                let mut seen = 0;
                loop {
                    let p = s.pass.load(Ordering::Acquire);
                    if p != seen {
                        seen = p;
                        take_tasks(&s, rounds);
                    } else if s.stop.load(Ordering::Acquire) {
                        return;
                    } else {
                        std::hint::spin_loop();
                    }
                }
            })
        })
        .collect();
    let t = Instant::now();
    for _ in 0..iterations * PASSES {
        s.done.store(0, Ordering::Release);
        s.next.store(0, Ordering::Release);
        s.pass.fetch_add(1, Ordering::AcqRel);
        take_tasks(&s, rounds);
        while s.done.load(Ordering::Acquire) < TASKS {
            std::hint::spin_loop();
        }
    }
    let seconds = t.elapsed().as_secs_f64();
    s.stop.store(true, Ordering::Release);
    for w in workers {
        w.join().expect("a team thread");
    }
    seconds
}

fn main() {
    let mut threads: Vec<usize> = vec![];
    let mut pass_us: Vec<f64> = vec![];
    let mut seconds = 0.5;
    let mut args = std::env::args().skip(1);
    let mut into_pass = false;
    while let Some(a) = args.next() {
        match a.as_str() {
            "--pass-us" => into_pass = true,
            "--seconds" => seconds = args.next().and_then(|s| s.parse().ok()).expect("--seconds S"),
            _ if into_pass => pass_us.push(a.parse().expect("a pass's microseconds of work")),
            _ => threads.push(a.parse().expect("a thread count")),
        }
    }
    if threads.is_empty() {
        let all = std::thread::available_parallelism().map_or(1, |n| n.get());
        threads = vec![1, all];
    }
    if pass_us.is_empty() {
        // A pass's work on one thread: RM 128³ `matched`'s passes take
        // 0.5–6 ms at one thread, hydrogen's 0.1–3 ms.
        pass_us = vec![200.0, 1000.0, 4000.0];
    }
    let per_us = rounds_per_us();
    // The median of three runs.
    let median = |run: fn(usize, u64, usize) -> f64, p: usize, rounds: u64, iterations: usize| {
        let mut runs: Vec<f64> = (0..3).map(|_| run(p, rounds, iterations)).collect();
        runs.sort_by(f64::total_cmp);
        runs[1]
    };
    for &us in &pass_us {
        let rounds = (us * per_us / TASKS as f64).max(1.0) as u64;
        // Enough iterations for about `seconds` of work.
        let iterations = ((seconds * 1e6 / (us * PASSES as f64)) as usize).max(3);
        let serial = median(serial_run, 1, rounds, iterations);
        for &p in &threads {
            for (name, run) in [("rayon", rayon_run as fn(usize, u64, usize) -> f64), ("spinning team", team_run)] {
                let wall = median(run, p, rounds, iterations);
                let ideal = serial / p as f64;
                let per_pass_us = (wall - ideal) / (iterations * PASSES) as f64 * 1e6;
                println!(
                    "{{\"scheduler\":\"{name}\",\"threads\":{p},\"pass_work_us\":{us},\"iterations\":{iterations},\"seconds\":{wall:.4},\"serial_seconds\":{serial:.4},\"beyond_work_per_pass_us\":{per_pass_us:.1},\"speedup\":{:.2}}}",
                    serial / wall
                );
            }
        }
    }
}
