//! The pool's threads stay awake between the passes of an iteration: the
//! workspace builds rayon-core with `ROUNDS_UNTIL_SLEEPY` at 1,000 instead of
//! 32 (vendor/rayon-core/GSENC.md), so that a thread that runs out of work
//! keeps looking for about a millisecond before it sleeps. Counted in
//! sleeps (voluntary context switches: a thread that only yields its CPU
//! makes none), not in time, so that a loaded machine cannot fail it.

/// This thread's voluntary context switches so far.
#[cfg(target_os = "linux")]
fn voluntary_switches() -> u64 {
    let status = std::fs::read_to_string("/proc/thread-self/status").expect("/proc/thread-self/status");
    let line = status.lines().find(|l| l.starts_with("voluntary_ctxt_switches:")).expect("voluntary_ctxt_switches");
    line.split_whitespace().nth(1).and_then(|n| n.parse().ok()).expect("a count")
}

/// Busy for `us` microseconds.
#[cfg(target_os = "linux")]
fn busy(us: u64) {
    let t = std::time::Instant::now();
    while t.elapsed() < std::time::Duration::from_micros(us) {
        std::hint::spin_loop();
    }
}

/// 300 passes of two tasks, one of them 100 µs of work: the other thread
/// idles about 100 µs each pass. Upstream's 32 rounds last a few tens of
/// microseconds, so the idle thread slept nearly every pass (about 300
/// sleeps); with 1,000 rounds it sleeps in few of them.
#[cfg(target_os = "linux")]
#[test]
fn a_thread_out_of_work_stays_awake_through_a_short_gap() {
    const PASSES: u64 = 300;
    let pool = rayon::ThreadPoolBuilder::new().num_threads(2).build().unwrap();
    let sleeps = || -> u64 { pool.broadcast(|_| voluntary_switches()).iter().sum() };
    let before = sleeps();
    pool.install(|| {
        for _ in 0..PASSES {
            rayon::join(|| busy(100), || busy(1));
        }
    });
    let slept = sleeps() - before;
    assert!(slept < PASSES / 4, "the pool's threads slept {slept} times in {PASSES} passes");
}
