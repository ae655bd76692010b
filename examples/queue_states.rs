//! What a long series costs the background queue's memory
//! (docs/BENCHMARKS.md "A long series' job states"): STEPS steps of an
//! 8^3 grid (5 iterations each) through a queue that keeps KEPT final job
//! states, a `wait` after each push, as an in-situ code that waits for
//! each step. Prints the live heap (every allocation counted) and the
//! bytes it gained a step since the first quarter of the run:
//! `cargo run --release --example queue_states -- [STEPS [KEPT]]`
//! (defaults 8,000 and `gsenc::series::queue::KEPT_STATES`).
use gsenc::encode::{EncodeConfig, Schedule, WarmStart};
use gsenc::field::{Grid, IndexFrame, Transform, ValueRange};
use gsenc::input::StepData;
use gsenc::series::queue::{BackgroundEncoder, CallerStores, Job, QueueConfig, WhenFull, KEPT_STATES};
use gsenc::series::{SeriesConfig, SeriesRange};
use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicIsize, Ordering};

/// The system allocator, counting the bytes allocated and not yet freed.
struct Counting;
static LIVE: AtomicIsize = AtomicIsize::new(0);
// SAFETY: every call goes to the system allocator with the caller's arguments.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        LIVE.fetch_add(l.size() as isize, Ordering::Relaxed);
        // SAFETY: as the caller's.
        unsafe { System.alloc(l) }
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        LIVE.fetch_sub(l.size() as isize, Ordering::Relaxed);
        // SAFETY: as the caller's.
        unsafe { System.dealloc(p, l) }
    }
    unsafe fn realloc(&self, p: *mut u8, l: Layout, n: usize) -> *mut u8 {
        LIVE.fetch_add(n as isize - l.size() as isize, Ordering::Relaxed);
        // SAFETY: as the caller's.
        unsafe { System.realloc(p, l, n) }
    }
}
#[global_allocator]
static A: Counting = Counting;

fn main() {
    let a: Vec<String> = std::env::args().collect();
    let steps: u64 = a.get(1).map_or(8000, |s| s.parse().expect("steps"));
    let kept: usize = a.get(2).map_or(KEPT_STATES, |s| s.parse().expect("kept states"));
    let dims = [8, 8, 8];
    let mut c = EncodeConfig::new(20, Schedule::Short);
    c.iterations = Some(5);
    c.points = Some(64);
    let range = SeriesRange::Fixed(ValueRange::new(0.0, 1.0, Transform::Linear).unwrap());
    let mut s = SeriesConfig::new(c, WarmStart::Coarse, range);
    s.validation_points = 64;
    s.warm_iterations = Some(5);
    let cfg = QueueConfig {
        series: s,
        max_bytes: 1 << 20,
        when_full: WhenFull::Block,
        threads: 1,
        backend: gsenc::backend::select::BackendChoice::cpu(),
        placement: Default::default(),
        kept_states: kept,
    };
    let q = BackgroundEncoder::new(cfg, Box::new(CallerStores)).unwrap();
    let frame = IndexFrame { dims, bmin: [0.0; 3], gamma: 1.0 };
    let quarter = (steps / 4).max(1);
    let mut base = 0;
    for k in 0..steps {
        let grid = Grid::new(dims, (0..512).map(|i| ((i + k as usize) % 7) as f32 / 7.0).collect()).unwrap();
        q.push(Job { field: "density".into(), step: k, time: None, data: StepData::Grid { grid, frame }, range: None }).unwrap();
        q.wait(None).unwrap();
        for m in q.take_finished() {
            q.set_stored("density", m.meta.step, Ok(format!("memory:/density/{}", m.meta.step)));
        }
        if k + 1 == quarter {
            base = LIVE.load(Ordering::Relaxed);
        } else if (k + 1) % quarter == 0 {
            let live = LIVE.load(Ordering::Relaxed);
            println!("{} steps, {kept} states kept: live heap {} KB, {:.0} bytes a step since step {quarter}", k + 1, live / 1024, (live - base) as f64 / (k + 1 - quarter) as f64);
        }
    }
}
