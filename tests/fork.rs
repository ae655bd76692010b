//! `fork`: a child process has only the thread that forked. A host that
//! forks after gsenc started threads (Python's `multiprocessing` forks its
//! workers on Linux) must find its decodes working in the child, on a pool
//! of its own, and an encoder or a GPU device of its parent refusing work
//! there instead of waiting for ever on threads that are not there.
//!
//! Its own test binary, with one test: the child runs only what this test
//! gives it and leaves by `_exit`, whatever happens, so that it never goes
//! on with the harness. A hang in the child is its alarm's signal.

#![cfg(unix)]

mod common;
use common::blobs;
#[cfg(feature = "gpu")]
use common::gpu;
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

/// The GPU backend (a stand-in in a build without it, never opened).
#[cfg(feature = "gpu")]
type Gpu = gsenc::backend::gpu::GpuBackend;
#[cfg(not(feature = "gpu"))]
type Gpu = CpuBackend;

#[cfg(not(feature = "gpu"))]
fn gpu() -> Option<Gpu> {
    eprintln!("NOT RUN (the GPU part): built without the GPU backend");
    None
}

/// What the child checks of the GPU its parent opened: refused, by a
/// message that says why, where it waited for ever; a new device refused
/// too; `auto` on the CPU; the device dropped without waiting for the
/// driver's threads, which are the parent's.
#[cfg(feature = "gpu")]
fn gpu_in_the_child(mut g: Gpu, model: &Model, parents: &[f32]) -> Result<(), String> {
    use gsenc::backend::select::{BackendChoice, BackendKind};
    use gsenc::backend::Backend;
    match model.decode(&mut g, None) {
        Err(e) if e.to_string().contains("forked") => {}
        other => return Err(format!("the parent's GPU in the child: {:?}, not refused as forked", other.map(|_| ()))),
    }
    // Refused before anything reaches the device (a driver's state in the
    // child may be the parent's: nothing is uploaded).
    let (mut rho, mut n) = ([0.0f32; 2], [0.0f32; 2]);
    let uploads = g.uploads();
    match g.evaluate_points(&model.params, &[[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]], &mut rho, &mut n) {
        Err(e) if e.to_string().contains("forked") => {}
        other => return Err(format!("an evaluation on the parent's GPU in the child: {other:?}, not refused as forked")),
    }
    if g.uploads() != uploads {
        return Err(format!("the refused evaluation uploaded to the parent's device ({} uploads)", g.uploads() - uploads));
    }
    // The training steps too (the parent loaded the model for them).
    let r = g.resident().expect("the GPU backend keeps a model resident");
    let batch = gsenc::backend::PointBatch::new(vec![[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]], vec![0.5, 0.25]);
    for (what, refused) in [
        ("a resident step", r.submit(&batch, &Default::default(), 1e-3, true).err()),
        ("a resident finish", r.finish().err()),
    ] {
        if !refused.as_ref().is_some_and(|e| e.to_string().contains("forked")) {
            return Err(format!("{what} on the parent's GPU in the child: {refused:?}, not refused as forked"));
        }
    }
    if g.uploads() != uploads {
        return Err("the refused training step uploaded to the parent's device".into());
    }
    match Gpu::new(&Default::default()) {
        Err(e) if e.to_string().contains("forked") => {}
        other => return Err(format!("a new GPU in the child: {:?}, not refused as forked", other.map(|_| ()))),
    }
    let mut auto = BackendChoice { kind: BackendKind::Auto, ..Default::default() }.open().map_err(|e| e.to_string())?;
    let on_auto = with_threads(None, || model.decode(auto.as_mut(), None)).unwrap().map_err(|e| e.to_string())?.values;
    if on_auto != parents {
        return Err(format!("auto in the child ({}) decodes otherwise than the CPU", auto.name()));
    }
    drop(g);
    Ok(())
}

/// `model` loaded for resident training steps.
#[cfg(feature = "gpu")]
fn load(g: &mut Gpu, model: &Model) {
    use gsenc::backend::Backend;
    let adam = gsenc::math::optim::Adam::new(model.params.len());
    g.resident().expect("the GPU backend keeps a model resident").load(&model.params, &adam).unwrap();
}

#[cfg(not(feature = "gpu"))]
fn load(_: &mut Gpu, _: &Model) {}

#[cfg(not(feature = "gpu"))]
fn gpu_in_the_child(_: Gpu, _: &Model, _: &[f32]) -> Result<(), String> {
    Ok(())
}

/// What the child checks; `Err` says what failed.
fn in_the_child(q: BackgroundEncoder, model: &Model, parents: &[f32], g: Option<Gpu>) -> Result<(), String> {
    if decode(model) != parents {
        return Err("the child's decode differs from the parent's".into());
    }
    if let Some(g) = g {
        gpu_in_the_child(g, model, parents)?;
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
fn a_forked_child_decodes_on_its_own_pool_and_refuses_its_parents_encoder_and_gpu() {
    let q = queue();
    q.push(job(0)).unwrap();
    q.wait(None).unwrap();
    let (model, _) = q.last("rho").unwrap();
    // The default pool started here, in the parent, before the fork, and
    // the GPU used.
    let parents = decode(&model);
    let mut g = gpu();
    if let Some(g) = g.as_mut() {
        model.decode(g, None).unwrap();
        load(g, &model);
    }

    // SAFETY: the child only runs `in_the_child` and leaves by `_exit`.
    let child = unsafe { libc::fork() };
    assert!(child >= 0, "fork failed");
    if child == 0 {
        // SAFETY: plain calls in the child; `_exit` never returns.
        unsafe { libc::alarm(60) };
        let outcome = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| in_the_child(q, &model, &parents, g)));
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
