//! The background queue: what each full-queue policy does, draining and
//! cancelling, a failed job that does not stop later steps, and models
//! equal to the ones the series encoder makes on the caller's thread.
//!
//! A gated sink holds every job in flight until the test opens the gate,
//! so "the encode is slower than the solver" is a fact, not a timing.

mod common;
use common::blobs;
use gsenc::backend::cpu::CpuBackend;
use gsenc::encode::{EncodeConfig, Schedule};
use gsenc::field::{Grid, IndexFrame, Transform, ValueRange};
use gsenc::model::Model;
use gsenc::input::StepData;
use gsenc::series::queue::{BackgroundEncoder, Job, JobState, ModelSink, Pushed, QueueConfig, WhenFull};
use gsenc::encode::WarmStart;
use gsenc::input::Input;
use gsenc::series::{SeriesConfig, SeriesEncoder, SeriesRange};
use gsenc::Error;
use std::sync::mpsc::{channel, Receiver, Sender};
use std::sync::{Arc, Mutex};

const DIMS: [usize; 3] = [12, 10, 8];

fn frame() -> IndexFrame {
    IndexFrame { dims: DIMS, bmin: [0.0; 3], gamma: 1.0 }
}

fn step_grid(k: u64) -> Grid {
    blobs(DIMS, 70 + k, 3)
}

fn series_config() -> SeriesConfig {
    let mut c = EncodeConfig::new(30, Schedule::Short);
    c.iterations = Some(40);
    c.points = Some(256);
    let range = SeriesRange::Fixed(ValueRange::new(0.0, 1.0, Transform::Linear).unwrap());
    let mut s = SeriesConfig::new(c, WarmStart::Coarse, range);
    s.warm_iterations = Some(30);
    s.validation_points = 256;
    s
}

fn queue_config(max_jobs: usize, when_full: WhenFull) -> QueueConfig {
    QueueConfig {
        series: series_config(),
        max_bytes: max_jobs * DIMS.iter().product::<usize>() * 4,
        when_full,
        threads: 1,
        backend: gsenc::backend::select::BackendChoice::cpu(),
        placement: Default::default(),
        kept_states: gsenc::series::queue::KEPT_STATES,
    }
}

fn job(field: &str, step: u64) -> Job {
    Job { field: field.into(), step, time: None, data: StepData::Grid { grid: step_grid(step), frame: frame() }, range: None }
}

/// Stores models in memory, each only once the test lets it through the
/// gate, and fails the steps in `fail`.
struct GatedSink {
    gate: Receiver<()>,
    fail: Vec<u64>,
    stored: Arc<Mutex<Vec<Model>>>,
}

impl ModelSink for GatedSink {
    fn store(&mut self, model: &Model) -> gsenc::Result<Option<String>> {
        let _ = self.gate.recv();
        if self.fail.contains(&model.meta.step) {
            return Err(Error::io("injected", std::io::Error::other("disk full (injected)")));
        }
        self.stored.lock().unwrap().push(model.clone());
        Ok(Some(format!("memory:{}", model.meta.step)))
    }
}

fn gated(cfg: QueueConfig, fail: Vec<u64>) -> (BackgroundEncoder, Sender<()>, Arc<Mutex<Vec<Model>>>) {
    let (open, gate) = channel();
    let stored = Arc::new(Mutex::new(Vec::new()));
    let q = BackgroundEncoder::new(cfg, Box::new(GatedSink { gate, fail, stored: stored.clone() })).unwrap();
    (q, open, stored)
}

fn steps_stored(stored: &Mutex<Vec<Model>>) -> Vec<u64> {
    stored.lock().unwrap().iter().map(|m| m.meta.step).collect()
}

/// The models the series encoder itself makes of the steps `0..steps` of
/// `job`'s field.
fn series_models(steps: u64) -> Vec<Model> {
    let mut direct = SeriesEncoder::new(series_config()).unwrap();
    let mut cpu = CpuBackend::new();
    (0..steps)
        .map(|k| {
            let g = step_grid(k);
            direct.encode_step("rho", k, None, Input::Grid { values: &g, frame: frame() }, &mut cpu, &mut |_| {}).unwrap().encoded.model
        })
        .collect()
}

#[test]
fn queued_models_equal_the_series_encoders() {
    let (q, open, stored) = gated(queue_config(8, WhenFull::Block), vec![]);
    for k in 0..3 {
        open.send(()).unwrap();
        assert_eq!(q.push(job("rho", k)).unwrap(), Pushed::Queued);
    }
    q.wait(None).unwrap();
    let queued = stored.lock().unwrap().clone();
    assert_eq!(queued.len(), 3);
    for (k, (m, direct)) in queued.iter().zip(series_models(3)).enumerate() {
        assert_eq!(m.params, direct.params, "step {k}: the queue's model differs from the series encoder's");
        assert_eq!(m.meta.schedule, direct.meta.schedule);
    }
    match q.poll("rho", 2) {
        Some(JobState::Written { psnr, location }) => {
            assert!(psnr > 10.0, "{psnr}");
            assert_eq!(location, "memory:2");
            assert_eq!(q.last("rho").unwrap().1, psnr);
        }
        other => panic!("step 2: {other:?}"),
    }
    assert!(q.poll("rho", 7).is_none());
}

#[test]
fn block_waits_for_room_and_loses_nothing() {
    let (q, open, stored) = gated(queue_config(1, WhenFull::Block), vec![]);
    let q = Arc::new(q);
    assert_eq!(q.push(job("rho", 0)).unwrap(), Pushed::Queued);
    // The queue holds one step, held at the gate: the next push blocks.
    let pusher = {
        let q = q.clone();
        std::thread::spawn(move || q.push(job("rho", 1)).unwrap())
    };
    std::thread::sleep(std::time::Duration::from_millis(300));
    assert!(!pusher.is_finished(), "a push into a full queue must block");
    assert!(q.poll("rho", 1).is_none(), "the blocked step is not queued yet");
    open.send(()).unwrap(); // step 0 stored: room for step 1
    assert_eq!(pusher.join().unwrap(), Pushed::Queued);
    assert!(q.queued_bytes() <= q.config().max_bytes);
    open.send(()).unwrap();
    q.wait(None).unwrap();
    assert_eq!(steps_stored(&stored), [0, 1]);
}

#[test]
fn skip_drops_the_step_and_the_series_goes_on() {
    let (q, open, stored) = gated(queue_config(1, WhenFull::Skip), vec![]);
    assert_eq!(q.push(job("rho", 0)).unwrap(), Pushed::Queued);
    assert_eq!(q.push(job("rho", 1)).unwrap(), Pushed::Skipped);
    assert!(matches!(q.poll("rho", 1), Some(JobState::Skipped)));
    // A skipped step still counts as pushed: steps must go on increasing.
    assert!(matches!(q.push(job("rho", 1)), Err(Error::InvalidArgument(_))));
    open.send(()).unwrap();
    q.wait(None).unwrap();
    open.send(()).unwrap();
    assert_eq!(q.push(job("rho", 2)).unwrap(), Pushed::Queued);
    q.wait(None).unwrap();
    assert_eq!(steps_stored(&stored), [0, 2]);
    // Step 2 warm-started from step 0, the last one encoded.
    assert_eq!(stored.lock().unwrap()[1].meta.schedule, "warm-coarse");
}

#[test]
fn busy_queues_nothing_and_the_step_can_be_pushed_again() {
    let (q, open, stored) = gated(queue_config(1, WhenFull::Busy), vec![]);
    assert_eq!(q.push(job("rho", 0)).unwrap(), Pushed::Queued);
    assert_eq!(q.push(job("rho", 1)).unwrap(), Pushed::Busy);
    assert!(q.poll("rho", 1).is_none(), "a busy push leaves no trace");
    open.send(()).unwrap();
    q.wait(None).unwrap();
    open.send(()).unwrap();
    assert_eq!(q.push(job("rho", 1)).unwrap(), Pushed::Queued);
    q.wait(None).unwrap();
    assert_eq!(steps_stored(&stored), [0, 1]);
}

/// The budget is the most the queue holds, running and queued steps
/// together: a budget of two steps' bytes takes a second step beside a
/// running one, to the byte, and finds the third too many.
#[test]
fn the_budget_holds_exactly_its_bytes() {
    let (q, open, stored) = gated(queue_config(2, WhenFull::Busy), vec![]);
    assert_eq!(q.push(job("rho", 0)).unwrap(), Pushed::Queued);
    assert_eq!(q.push(job("rho", 1)).unwrap(), Pushed::Queued);
    assert_eq!(q.queued_bytes(), q.config().max_bytes);
    assert_eq!(q.push(job("rho", 2)).unwrap(), Pushed::Busy);
    for _ in 0..2 {
        open.send(()).unwrap();
    }
    q.wait(None).unwrap();
    assert_eq!(steps_stored(&stored), [0, 1]);
}

/// A step larger than the whole budget is still taken into an empty queue
/// (else it could never be encoded), and counts against the budget while
/// it is there: the next push finds the queue full.
#[test]
fn a_step_larger_than_the_budget_is_taken_into_an_empty_queue() {
    let cfg = QueueConfig { max_bytes: DIMS.iter().product::<usize>() * 4 / 2, ..queue_config(1, WhenFull::Busy) };
    let (q, open, stored) = gated(cfg, vec![]);
    assert_eq!(q.push(job("rho", 0)).unwrap(), Pushed::Queued);
    assert!(q.queued_bytes() > q.config().max_bytes);
    assert_eq!(q.push(job("rho", 1)).unwrap(), Pushed::Busy);
    open.send(()).unwrap();
    q.wait(None).unwrap();
    assert_eq!(q.queued_bytes(), 0);
    open.send(()).unwrap();
    assert_eq!(q.push(job("rho", 1)).unwrap(), Pushed::Queued);
    q.wait(None).unwrap();
    assert_eq!(steps_stored(&stored), [0, 1]);
}

#[test]
fn a_failed_job_is_reported_once_and_later_steps_are_written() {
    let (q, open, stored) = gated(queue_config(8, WhenFull::Block), vec![1]);
    for k in 0..4 {
        open.send(()).unwrap();
        q.push(job("rho", k)).unwrap();
    }
    let e = q.wait(Some("rho")).unwrap_err();
    assert!(matches!(e, Error::Io { .. }), "{e}");
    assert!(e.to_string().contains("field 'rho' step 1") && e.to_string().contains("injected"), "{e}");
    q.wait(None).unwrap(); // reported once
    assert!(matches!(q.poll("rho", 1), Some(JobState::Failed(_))));
    assert_eq!(steps_stored(&stored), [0, 2, 3]);
    // The failed store did not stop the series: step 2 warm-started from step 1's model.
    let last = q.last("rho").unwrap().0;
    assert_eq!(last.meta.step, 3);
}

/// A step whose store failed (a full disk) is the field's last model all
/// the same: the series goes on from it, and the caller can write it
/// elsewhere; it is the model the next step warm-starts from.
#[test]
fn a_step_whose_store_failed_is_the_fields_last_model() {
    let (q, open, stored) = gated(queue_config(8, WhenFull::Block), vec![1]);
    for k in 0..2 {
        open.send(()).unwrap();
        q.push(job("rho", k)).unwrap();
    }
    assert!(q.wait(None).is_err());
    let (last, psnr) = q.last("rho").unwrap();
    assert_eq!(last.meta.step, 1);
    assert!(psnr > 10.0 && last.meta.encode_psnr == Some(psnr), "{psnr}");
    // The series encoder, given the same steps, encodes step 1 to this model.
    assert_eq!(last.params, series_models(2)[1].params);
    assert_eq!(steps_stored(&stored), [0]);
}

/// `wait` for one field reports that field's failures only; another
/// field's stays for its own `wait` (or one for every field).
#[test]
fn a_wait_for_one_field_reports_only_its_failures() {
    let (q, open, stored) = gated(queue_config(8, WhenFull::Block), vec![1]);
    for (field, k) in [("rho", 0), ("rho", 1), ("u", 5), ("u", 6)] {
        open.send(()).unwrap();
        q.push(job(field, k)).unwrap();
    }
    q.wait(Some("u")).unwrap();
    let e = q.wait(Some("rho")).unwrap_err();
    assert!(e.to_string().contains("field 'rho' step 1"), "{e}");
    q.wait(None).unwrap();
    assert_eq!(steps_stored(&stored), [0, 5, 6]);
}

/// Polls until `field`'s step `step` is final (which `wait` would report).
fn until_final(q: &BackgroundEncoder, field: &str, step: u64) {
    let t0 = std::time::Instant::now();
    while !q.poll(field, step).is_some_and(|s| s.is_final()) {
        assert!(t0.elapsed().as_secs() < 120, "the queue did not finish");
        std::thread::sleep(std::time::Duration::from_millis(10));
    }
}

/// Of the final jobs, only the last `kept_states` to finish keep their
/// states (of every field together), so a long run's memory does not grow
/// with its length; a failure `wait` has not reported is kept past its turn
/// until it has.
#[test]
fn only_the_last_final_states_are_kept() {
    let cfg = QueueConfig { kept_states: 3, ..queue_config(8, WhenFull::Block) };
    assert!(matches!(BackgroundEncoder::new(QueueConfig { kept_states: 0, ..cfg.clone() }, Box::new(gsenc::series::queue::CallerStores)), Err(Error::InvalidArgument(_))));
    let (q, open, stored) = gated(cfg, vec![2]);
    for k in 0..6 {
        open.send(()).unwrap();
        q.push(job("rho", k)).unwrap();
    }
    // Until every step is final, without reporting the failure.
    until_final(&q, "rho", 5);
    for k in [0, 1] {
        assert!(q.poll("rho", k).is_none() && q.dropped("rho", k), "step {k}: {:?}", q.poll("rho", k));
    }
    assert!(matches!(q.poll("rho", 2), Some(JobState::Failed(_))), "an unreported failure is kept: {:?}", q.poll("rho", 2));
    for k in 3..6 {
        assert!(matches!(q.poll("rho", k), Some(JobState::Written { .. })) && !q.dropped("rho", k), "step {k}: {:?}", q.poll("rho", k));
    }
    assert!(!q.dropped("rho", 6) && !q.dropped("T", 0), "never pushed");
    let e = q.wait(None).unwrap_err();
    assert!(e.to_string().contains("field 'rho' step 2"), "{e}");
    assert!(q.poll("rho", 2).is_none() && q.dropped("rho", 2), "reported, and past its turn");
    // Another field's steps take the oldest places.
    for k in 0..2 {
        open.send(()).unwrap();
        q.push(job("T", k)).unwrap();
    }
    q.wait(None).unwrap();
    assert!(q.poll("rho", 3).is_none() && q.poll("rho", 4).is_none());
    assert!(q.poll("rho", 5).is_some() && q.poll("T", 0).is_some() && q.poll("T", 1).is_some());
    assert_eq!(steps_stored(&stored), [0, 1, 3, 4, 5, 0, 1]);
    // Step 6 of rho still warm-starts from step 5, whose state was kept
    // only as long as its turn: the series' own record is apart.
    open.send(()).unwrap();
    q.push(job("rho", 6)).unwrap();
    q.wait(None).unwrap();
    assert_eq!(stored.lock().unwrap().last().unwrap().meta.schedule, "warm-coarse");
}

/// A failure reported after later steps' states were dropped leaves them
/// dropped: `dropped` goes by the latest step dropped, not the last.
#[test]
fn a_failure_reported_late_keeps_the_later_steps_dropped() {
    let cfg = QueueConfig { kept_states: 1, ..queue_config(8, WhenFull::Block) };
    let (q, open, _) = gated(cfg, vec![0]);
    for k in 0..3 {
        open.send(()).unwrap();
        q.push(job("rho", k)).unwrap();
    }
    until_final(&q, "rho", 2);
    assert!(q.poll("rho", 1).is_none() && q.dropped("rho", 1), "{:?}", q.poll("rho", 1));
    assert!(q.wait(None).unwrap_err().to_string().contains("field 'rho' step 0"));
    for k in [0, 1] {
        assert!(q.poll("rho", k).is_none() && q.dropped("rho", k), "step {k}: {:?}", q.poll("rho", k));
    }
    assert!(!q.dropped("rho", 2));
}

/// A model the caller stores after its state was dropped: a failure is
/// still reported by `wait` (then dropped), a success leaves no state.
#[test]
fn a_caller_store_after_the_state_was_dropped() {
    let cfg = QueueConfig { kept_states: 1, ..queue_config(8, WhenFull::Block) };
    let q = BackgroundEncoder::new(cfg, Box::new(gsenc::series::queue::CallerStores)).unwrap();
    for k in 0..3 {
        q.push(job("rho", k)).unwrap();
    }
    q.wait(None).unwrap();
    assert_eq!(q.take_finished().len(), 3);
    assert!(q.poll("rho", 0).is_none() && q.poll("rho", 1).is_none() && q.dropped("rho", 1));
    q.set_stored("rho", 0, Ok("store:/rho/0".into()));
    assert!(q.poll("rho", 0).is_none(), "a success past its turn leaves no state");
    q.set_stored("rho", 1, Err(Error::io("store.h5", std::io::Error::other("no space left"))));
    assert!(matches!(q.poll("rho", 1), Some(JobState::Failed(_))));
    q.set_stored("rho", 2, Ok("store:/rho/2".into()));
    assert!(matches!(q.poll("rho", 2), Some(JobState::Written { location, .. }) if location == "store:/rho/2"));
    let e = q.wait(None).unwrap_err();
    assert!(e.to_string().contains("step 1") && e.to_string().contains("no space"), "{e}");
    assert!(q.poll("rho", 1).is_none(), "dropped once reported");
    assert!(matches!(q.poll("rho", 2), Some(JobState::Written { .. })), "the last to finish is kept");
    q.wait(None).unwrap();
}

#[test]
fn dropping_the_queue_drains_it() {
    let (q, open, stored) = gated(queue_config(8, WhenFull::Block), vec![]);
    for k in 0..3 {
        q.push(job("rho", k)).unwrap();
    }
    for _ in 0..3 {
        open.send(()).unwrap();
    }
    drop(q);
    assert_eq!(steps_stored(&stored), [0, 1, 2]);
}

#[test]
fn cancel_drops_queued_steps_and_the_encoder_stays_usable() {
    let (q, open, stored) = gated(queue_config(8, WhenFull::Block), vec![]);
    for k in 0..4 {
        q.push(job("rho", k)).unwrap();
    }
    // Once step 0's loop is over (nothing can cancel it now), the worker
    // waits at the gate with steps 1..3 queued; open it after cancel began.
    while !matches!(q.poll("rho", 0), Some(JobState::Running { iteration, iterations }) if iterations > 0 && iteration == iterations) {
        std::thread::yield_now();
    }
    let canceller = {
        let open = open.clone();
        std::thread::spawn(move || {
            std::thread::sleep(std::time::Duration::from_millis(200));
            open.send(()).unwrap();
        })
    };
    q.cancel().unwrap();
    canceller.join().unwrap();
    for k in 1..4 {
        assert!(matches!(q.poll("rho", k), Some(JobState::Cancelled)), "step {k}: {:?}", q.poll("rho", k));
    }
    assert_eq!(q.queued_bytes(), 0);
    open.send(()).unwrap();
    q.push(job("rho", 4)).unwrap();
    q.wait(None).unwrap();
    assert_eq!(steps_stored(&stored), [0, 4]);
}

#[test]
fn a_running_encode_stops_at_cancel() {
    // A long encode, no gate: cancel must stop it between iterations.
    let mut cfg = queue_config(8, WhenFull::Block);
    cfg.series.encode.iterations = Some(1_000_000);
    let (q, _open, stored) = gated(cfg, vec![]);
    q.push(job("rho", 0)).unwrap();
    while !matches!(q.poll("rho", 0), Some(JobState::Running { iteration, .. }) if iteration > 0) {
        std::thread::yield_now();
    }
    q.cancel().unwrap();
    assert!(matches!(q.poll("rho", 0), Some(JobState::Cancelled)), "{:?}", q.poll("rho", 0));
    assert!(steps_stored(&stored).is_empty());
    assert!(q.last("rho").is_none(), "a cancelled step leaves no model");
}

#[test]
fn bad_pushes_are_refused_at_once() {
    let (q, _open, _) = gated(queue_config(8, WhenFull::Block), vec![]);
    let mut g = step_grid(0);
    g.values[5] = f32::NAN;
    let bad = Job { field: "rho".into(), step: 0, time: None, data: StepData::Grid { grid: g, frame: frame() }, range: None };
    assert!(matches!(q.push(bad), Err(Error::InvalidData(_))));
    assert!(matches!(q.push(job("a/b", 0)), Err(Error::InvalidArgument(_))));
    // A particle or cell the encode would refuse is refused at the push
    // (it was the step's failure, at the wait); none at all is the encode's
    // to refuse (a rank of a decomposed field may hold none).
    let particles = |h: f64, mass: f32| StepData::Particles {
        positions: vec![[0.5; 3], [0.25; 3]],
        smoothing_length: vec![0.1, h],
        mass: vec![1.0, mass],
        values: vec![1.0, 2.0],
        placement: gsenc::input::Placement::new([8; 3], None),
    };
    let cells = |edge: f64| StepData::Cells {
        centres: vec![[0.5; 3]],
        edges: vec![[0.1, edge, 0.1]],
        volumes: vec![],
        values: vec![1.0],
        placement: gsenc::input::Placement::new([8; 3], None),
    };
    for (data, says) in [
        (particles(-0.5, 1.0), "particle 1 has smoothing length -0.5"),
        (particles(0.1, -2.0), "particle 1 has mass -2"),
        (cells(0.0), "cell 0 has edges [0.1, 0.0, 0.1]"),
    ] {
        let e = q.push(Job { field: "rho".into(), step: 0, time: None, data, range: None }).expect_err("refused");
        assert!(matches!(&e, Error::InvalidData(m) if m.contains(says)), "{e}");
    }
    assert!(q.poll("rho", 0).is_none());
    let mut cfg = queue_config(8, WhenFull::Block);
    cfg.threads = 100_000;
    let e = BackgroundEncoder::new(cfg, Box::new(gsenc::series::queue::CallerStores)).err().expect("100,000 threads refused");
    assert!(matches!(&e, Error::InvalidArgument(m) if m.contains("threads 100000")), "{e}");
}

#[test]
fn a_caller_stored_model_waits_for_the_caller() {
    let q = BackgroundEncoder::new(queue_config(8, WhenFull::Block), Box::new(gsenc::series::queue::CallerStores)).unwrap();
    q.push(job("rho", 0)).unwrap();
    q.push(job("rho", 1)).unwrap();
    q.wait(None).unwrap();
    // Encoded, not stored: the models are the caller's to write, in order.
    assert!(matches!(q.poll("rho", 1), Some(JobState::Encoded { .. })));
    let models = q.take_finished();
    assert_eq!(models.iter().map(|m| m.meta.step).collect::<Vec<_>>(), [0, 1]);
    assert!(q.take_finished().is_empty());
    q.set_stored("rho", 0, Ok("store:/rho/0".into()));
    q.set_stored("rho", 1, Err(Error::io("store.h5", std::io::Error::other("no space left"))));
    assert!(matches!(q.poll("rho", 0), Some(JobState::Written { location, .. }) if location == "store:/rho/0"));
    let e = q.wait(None).unwrap_err();
    assert!(e.to_string().contains("step 1") && e.to_string().contains("no space"), "{e}");
}

/// A series resumed from a stored model (a restart from a checkpoint)
/// continues bit for bit as the unbroken series, and what cannot be
/// resumed is refused at once.
#[test]
fn a_resumed_series_continues_as_the_unbroken_one() {
    let caller = || BackgroundEncoder::new(queue_config(8, WhenFull::Block), Box::new(gsenc::series::queue::CallerStores)).unwrap();
    let unbroken = caller();
    for k in 0..3 {
        unbroken.push(job("rho", k)).unwrap();
    }
    unbroken.wait(None).unwrap();
    let models = unbroken.take_finished();
    assert_eq!(models.len(), 3);
    // Through the file format, as a restart reads it.
    let stored = gsenc::format::read_model(&gsenc::format::write_model(&models[0]).unwrap()).unwrap();

    let resumed = caller();
    resumed.resume(stored.clone()).unwrap();
    assert_eq!(resumed.last("rho").map(|(m, _)| m.meta.step), Some(0), "the resumed model is the field's last");
    let e = resumed.push(job("rho", 0)).unwrap_err();
    assert!(e.to_string().contains("does not follow step 0"), "{e}");
    for k in 1..3 {
        resumed.push(job("rho", k)).unwrap();
    }
    resumed.wait(None).unwrap();
    let again = resumed.take_finished();
    assert_eq!(again.len(), 2);
    for (m, want) in again.iter().zip(&models[1..]) {
        assert_eq!(m.meta.step, want.meta.step);
        assert_eq!(m.params, want.params, "step {}: the resumed series differs from the unbroken one", m.meta.step);
    }
    // Refused: a field with steps pushed, another rank's model, another
    // range, no primitives. Nothing of the encoder changes.
    let e = resumed.resume(stored.clone()).unwrap_err();
    assert!(e.to_string().contains("has begun on this encoder already (its last step 2)"), "{e}");
    let fresh = caller();
    let mut other = stored.clone();
    other.meta.rank = 3;
    assert!(fresh.resume(other).unwrap_err().to_string().contains("rank 3's piece"));
    let mut other = stored.clone();
    other.meta.range = ValueRange::new(0.0, 2.0, Transform::Linear).unwrap();
    assert!(fresh.resume(other).unwrap_err().to_string().contains("not the configured [0, 1]"));
    let mut other = stored.clone();
    other.params.clear();
    assert!(matches!(fresh.resume(other), Err(Error::InvalidData(_))));
    assert!(fresh.last("rho").is_none());
    fresh.push(job("rho", 0)).unwrap();
    fresh.wait(None).unwrap();
    assert_eq!(fresh.take_finished()[0].params, models[0].params, "a refused resume leaves the field as it was");
}

/// The ranks of an MPI run decide a full queue together: another rank's
/// full queue makes this one skip or report busy although it has room, and
/// under `Block` it queues (it waits only for its own room).
#[test]
fn another_ranks_full_queue_counts_as_full() {
    for (policy, want) in [(WhenFull::Skip, Pushed::Skipped), (WhenFull::Busy, Pushed::Busy), (WhenFull::Block, Pushed::Queued)] {
        let (q, open, stored) = gated(queue_config(4, policy), vec![]);
        let j = job("rho", 0);
        q.check(&j).unwrap();
        assert!(q.has_room(j.data.bytes()));
        assert_eq!(q.push_checked(j, false).unwrap(), want, "{policy:?}");
        assert_eq!(q.push_checked(job("rho", 1), true).unwrap(), Pushed::Queued, "{policy:?}: with room everywhere");
        for _ in 0..2 {
            let _ = open.send(());
        }
        q.wait(None).unwrap();
        let expect: &[u64] = if want == Pushed::Queued { &[0, 1] } else { &[1] };
        assert_eq!(steps_stored(&stored), expect, "{policy:?}");
    }
}

/// A model, the CPUs and the scheduling policy of the thread that stored
/// it, and the threads of its pool.
#[cfg(target_os = "linux")]
type Seen = (Model, Option<Vec<usize>>, i32, usize);

/// Stores models in memory with where they were stored (on one of the
/// pool's threads).
#[cfg(target_os = "linux")]
struct WhereSink {
    seen: Arc<Mutex<Vec<Seen>>>,
}

#[cfg(target_os = "linux")]
impl ModelSink for WhereSink {
    fn store(&mut self, model: &Model) -> gsenc::Result<Option<String>> {
        // SAFETY: a plain query of the calling thread.
        let policy = unsafe { libc::sched_getscheduler(0) };
        self.seen.lock().unwrap().push((model.clone(), gsenc::series::placement::allowed_cpus(), policy, rayon::current_num_threads()));
        Ok(None)
    }
}

/// An encoder placed on one CPU at idle priority runs its pool's threads
/// there and so (read back from the kernel by the thread that stores each
/// model), one thread for its one CPU when asked for 0 (one per CPU), and
/// encodes the same models as one placed by default; CPUs the process may
/// not use are refused before any thread starts.
#[cfg(target_os = "linux")]
#[test]
fn the_encoders_threads_run_where_and_as_placed() {
    use gsenc::series::placement::{allowed_cpus, Priority, ThreadPlacement};
    let allowed = allowed_cpus().unwrap();
    let one = *allowed.last().unwrap();
    let run = |placement: ThreadPlacement, threads: usize| {
        let seen = Arc::new(Mutex::new(vec![]));
        let q = BackgroundEncoder::new(QueueConfig { placement, threads, ..queue_config(4, WhenFull::Block) }, Box::new(WhereSink { seen: seen.clone() })).unwrap();
        for k in 0..2 {
            q.push(job("rho", k)).unwrap();
        }
        q.wait(None).unwrap();
        drop(q);
        Arc::try_unwrap(seen).ok().unwrap().into_inner().unwrap()
    };
    let placed = run(ThreadPlacement { cpus: Some(vec![one]), priority: Priority::Idle }, 0);
    let plain = run(ThreadPlacement::default(), 0);
    assert_eq!(placed.len(), 2);
    for ((pm, pcpus, ppolicy, pthreads), (m, cpus, policy, threads)) in placed.iter().zip(&plain) {
        assert_eq!((pcpus.as_deref(), *ppolicy, *pthreads), (Some(&[one][..]), libc::SCHED_IDLE, 1));
        assert_eq!((cpus.as_deref(), *policy, *threads), (Some(&allowed[..]), libc::SCHED_OTHER, allowed.len()));
        assert_eq!(pm.params, m.params, "step {}: the placement changed the model", m.meta.step);
    }
    let outside = ThreadPlacement { cpus: Some(vec![allowed.last().unwrap() + 1]), priority: Priority::Normal };
    let e = BackgroundEncoder::new(QueueConfig { placement: outside, ..queue_config(4, WhenFull::Block) }, Box::new(gsenc::series::queue::CallerStores)).err().unwrap();
    assert!(matches!(e, Error::InvalidArgument(_)) && e.to_string().contains("may not run on"), "{e}");
}

/// `reserve` readies a buffer for the next grid push before any step has
/// run: the push takes it (`recycled_buffer`) instead of allocating. A
/// reserve a kept buffer covers adds none; a larger one replaces a kept
/// buffer once the queue keeps as many as it may, so that the buffers kept
/// stay bounded; 0 does nothing; a size beyond any memory is refused.
#[test]
fn a_reserved_buffer_serves_the_first_grid_push() {
    let q = BackgroundEncoder::new(queue_config(8, WhenFull::Block), Box::new(gsenc::series::queue::CallerStores)).unwrap();
    let n = DIMS.iter().product::<usize>();
    assert!(q.recycled_buffer(1).is_none(), "a buffer kept before any reserve or step");
    q.reserve(0).unwrap();
    assert!(q.recycled_buffer(1).is_none(), "reserve(0) kept a buffer");
    q.reserve(n).unwrap();
    let b = q.recycled_buffer(n).expect("the reserved buffer");
    assert!(b.capacity() >= n && b.is_empty(), "capacity {} len {}", b.capacity(), b.len());
    assert!(q.recycled_buffer(1).is_none(), "more than one buffer kept");
    // Covered: a smaller reserve after a larger keeps one buffer.
    q.reserve(n).unwrap();
    q.reserve(n / 2).unwrap();
    assert!(q.recycled_buffer(1).is_some() && q.recycled_buffer(1).is_none(), "a covered reserve kept another buffer");
    // Growing reserves keep at most two buffers, the largest ones.
    for k in 1..=4 {
        q.reserve(k * 1000).unwrap();
    }
    let kept: Vec<usize> = std::iter::from_fn(|| q.recycled_buffer(1).map(|b| b.capacity())).collect();
    assert_eq!(kept.len(), 2, "{kept:?}");
    assert!(kept.iter().all(|&c| c >= 3000), "{kept:?}");
    let e = q.reserve(usize::MAX / 2).unwrap_err();
    assert!(e.to_string().contains("reserving a grid push's copy"), "{e}");
    // Pushes still work after all of it.
    q.reserve(n).unwrap();
    q.push(job("rho", 0)).unwrap();
    q.wait(None).unwrap();
}
