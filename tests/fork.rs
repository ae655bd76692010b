//! `fork`: a child process has only the thread that forked. A host that
//! forks after gsenc started threads (Python's `multiprocessing` forks its
//! workers on Linux) must find its decodes working in the child, on a pool
//! of its own, and an encoder of its parent refusing work there instead of
//! waiting for ever on a thread that is not there.
//!
//! Its own test binary, with one test: the child runs only what this test
//! gives it and leaves by `_exit`, whatever happens, so that it never goes
//! on with the harness. A hang in the child is its alarm's signal.

#![cfg(unix)]

mod common;
use common::blobs;
use gsenc::backend::cpu::CpuBackend;
use gsenc::encode::{EncodeConfig, Schedule, WarmStart};
use gsenc::field::{IndexFrame, Transform, ValueRange};
use gsenc::input::StepData;
use gsenc::model::Model;
use gsenc::series::queue::{BackgroundEncoder, Job, ModelSink, QueueConfig, WhenFull, KEPT_STATES};
use gsenc::series::{SeriesConfig, SeriesRange};
use gsenc::threads::with_threads;

const DIMS: [usize; 3] = [12, 10, 8];

struct Keep;

impl ModelSink for Keep {
    fn store(&mut self, _: &Model) -> gsenc::Result<Option<String>> {
        Ok(Some(String::new()))
    }
}

fn job(step: u64) -> Job {
    let frame = IndexFrame { dims: DIMS, bmin: [0.0; 3], gamma: 1.0 };
    Job { field: "rho".into(), step, time: None, data: StepData::Grid { grid: blobs(DIMS, 70 + step, 3), frame }, range: None }
}

fn queue() -> BackgroundEncoder {
    let mut c = EncodeConfig::new(30, Schedule::Short);
    c.iterations = Some(40);
    c.points = Some(256);
    let range = SeriesRange::Fixed(ValueRange::new(0.0, 1.0, Transform::Linear).unwrap());
    let cfg = QueueConfig {
        series: SeriesConfig::new(c, WarmStart::Coarse, range),
        max_bytes: 1 << 20,
        when_full: WhenFull::Block,
        threads: 2,
        backend: gsenc::backend::select::BackendChoice::cpu(),
        placement: Default::default(),
        kept_states: KEPT_STATES,
    };
    BackgroundEncoder::new(cfg, Box::new(Keep)).unwrap()
}

/// The decode of `model` on the default pool (no thread count named).
fn decode(model: &Model) -> Vec<f32> {
    with_threads(None, || model.decode(&mut CpuBackend::new(), None)).unwrap().unwrap().values
}

/// What the child checks; `Err` says what failed.
fn in_the_child(q: BackgroundEncoder, model: &Model, parents: &[f32]) -> Result<(), String> {
    if decode(model) != parents {
        return Err("the child's decode differs from the parent's".into());
    }
    for (what, r) in [("push", q.push(job(1)).map(|_| ())), ("wait", q.wait(None)), ("cancel", q.cancel())] {
        match r {
            Err(e) if e.to_string().contains("forked") => {}
            other => return Err(format!("{what} in the child: {other:?}, not refused as forked")),
        }
    }
    drop(q); // must not wait for the parent's thread
    Ok(())
}

#[test]
fn a_forked_child_decodes_on_its_own_pool_and_refuses_the_parents_encoder() {
    let q = queue();
    q.push(job(0)).unwrap();
    q.wait(None).unwrap();
    let (model, _) = q.last("rho").unwrap();
    // The default pool started here, in the parent, before the fork.
    let parents = decode(&model);

    // SAFETY: the child only runs `in_the_child` and leaves by `_exit`.
    let child = unsafe { libc::fork() };
    assert!(child >= 0, "fork failed");
    if child == 0 {
        // SAFETY: plain calls in the child; `_exit` never returns.
        unsafe { libc::alarm(60) };
        let outcome = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| in_the_child(q, &model, &parents)));
        let code = match outcome {
            Ok(Ok(())) => 0,
            Ok(Err(why)) => {
                eprintln!("child: {why}");
                1
            }
            Err(_) => 2,
        };
        unsafe { libc::_exit(code) };
    }
    let mut status = 0;
    // SAFETY: waits for the child just forked.
    assert_eq!(unsafe { libc::waitpid(child, &mut status, 0) }, child);
    assert!(
        libc::WIFEXITED(status) && libc::WEXITSTATUS(status) == 0,
        "the child {}",
        if libc::WIFEXITED(status) { format!("exited with {}", libc::WEXITSTATUS(status)) } else { format!("was killed by signal {}", libc::WTERMSIG(status)) }
    );
    // The parent's encoder goes on.
    q.push(job(1)).unwrap();
    q.wait(None).unwrap();
    assert_eq!(q.last("rho").unwrap().0.meta.step, 1);
}
