//! Task timings for the thread-scaling model (`benches/scaling_model.sh`)
//! and the timeline of the tasks as they ran (`benches/timeline.sh`).
//!
//! Built with the `task-profile` feature, an encode on one thread records
//! how long each task of each parallel pass takes and how long each serial
//! section takes, and writes them to the file that `GSENC_TASK_PROFILE`
//! names when its refinement loop ends. `benches/scaling_model.py` then
//! schedules those tasks on p workers to predict an iteration's time at p
//! threads: what keeps a pass from spreading over 16 cores (a serial
//! section, too few tasks, one long task) shows up on a 2-core machine.
//! Without the feature every function here is only the call it wraps (the
//! recording branch is compiled, and tested, but never taken).
//!
//! The file has one line per record, `pass<TAB>seconds`: a task of a
//! parallel pass (consecutive tasks of one pass are one run of it), a serial
//! section (negative seconds), or the end of an iteration (an empty pass).
//! A record made within [`beside`] (work that runs beside the iteration's
//! passes, as the next batch's draw does) has `beside: ` before its pass.
//! A task that forks ([`part`]: a head, then runs in parallel, then a tail
//! that waits for them) has a third field, `head`, `run` or `tail`, so that
//! the model starts the runs only after the head and the tail only after
//! the last run.
//!
//! With `GSENC_TASK_TIMELINE` set too (or alone), an encode on any number
//! of threads also writes when each record ran and on which thread, one line
//! a record, `pass<TAB>thread<TAB>start<TAB>end<TAB>kind` (seconds since
//! the earliest start; thread -1 off the pool; kind `task`, `serial`, or
//! `whole` for a pass timed whole), in the order the records were made,
//! after a first line `#threads<TAB>P`, the size of the pool that wrote it:
//! `benches/timeline.py` tells from it where a pass loses time on p
//! threads (the wait for the pool to join, the wait for its last task, the
//! gaps between passes).

use parking_lot::Mutex;
use std::cell::Cell;
use std::time::Instant;

const ON: bool = cfg!(feature = "task-profile");

static LOG: Recorder = Recorder::new();

thread_local! {
    /// Whether this thread runs within [`beside`] (the profile is taken on
    /// one thread, so every record of such work is made on it).
    static BESIDE: Cell<bool> = const { Cell::new(false) };
}

/// Runs `f`, work that runs beside the iteration's passes (the next
/// batch's draw beside the gradient), and marks its records so.
#[inline(always)]
pub fn beside<R>(f: impl FnOnce() -> R) -> R {
    if ON { marked_beside(f) } else { f() }
}

fn marked_beside<R>(f: impl FnOnce() -> R) -> R {
    let was = BESIDE.with(|b| b.replace(true));
    let r = f();
    BESIDE.with(|b| b.set(was));
    r
}

/// Runs one task of the parallel pass `pass` and records its time.
#[inline(always)]
pub fn task<R>(pass: &'static str, f: impl FnOnce() -> R) -> R {
    if ON { LOG.task(pass, f) } else { f() }
}

/// Where a record stands in a task that forks (see [`part`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Part {
    /// Before the runs; they start when it ends.
    Head,
    /// One of the runs, in parallel with the others.
    Run,
    /// After the runs; it starts when the last of them ends.
    Tail,
}

impl Part {
    fn label(self) -> &'static str {
        match self {
            Part::Head => "head",
            Part::Run => "run",
            Part::Tail => "tail",
        }
    }
}

/// Runs one part of a task of the parallel pass `pass` that forks into
/// runs, and records its time: each such task records one head, its runs,
/// then one tail, in that order (on the one thread of a profiled encode).
#[inline(always)]
pub fn part<R>(pass: &'static str, part: Part, f: impl FnOnce() -> R) -> R {
    if ON { LOG.part(pass, Some(part), f) } else { f() }
}

/// Runs a serial section and records its time.
#[inline(always)]
pub fn serial<R>(pass: &'static str, f: impl FnOnce() -> R) -> R {
    if ON { LOG.serial(pass, f) } else { f() }
}

/// Runs a whole parallel pass of `tasks` equal tasks (where timing each
/// would cost more than the task) and records its time split among them.
#[inline(always)]
pub fn even<R>(pass: &'static str, tasks: usize, f: impl FnOnce() -> R) -> R {
    if ON { LOG.even(pass, tasks, f) } else { f() }
}

/// Marks the end of a refinement iteration.
#[inline(always)]
pub fn iteration_end() {
    if ON {
        LOG.iteration_end();
    }
}

/// Writes the records to `GSENC_TASK_PROFILE` (when set) and forgets them.
pub fn write() -> std::io::Result<()> {
    if !ON {
        return Ok(());
    }
    let records = LOG.take();
    if let Some(path) = std::env::var_os("GSENC_TASK_PROFILE") {
        std::fs::write(path, text(&records))?;
    }
    if let Some(path) = std::env::var_os("GSENC_TASK_TIMELINE") {
        // The encode's pool: this runs on it (refine.rs), or on the calling
        // thread of a one-thread encode.
        std::fs::write(path, timeline(&records, rayon::current_num_threads()))?;
    }
    Ok(())
}

fn in_beside() -> bool {
    BESIDE.with(Cell::get)
}

/// One record: a pass, its seconds (negative for a serial section), whether
/// it was made beside the passes, the part of a task that forks, and when
/// and where it ran (its start, and the time it spanned, `None` for the
/// tasks of a pass timed whole but its first; the pool thread, -1 off the
/// pool).
#[derive(Clone, Copy, Debug)]
struct Record {
    pass: &'static str,
    seconds: f64,
    beside: bool,
    part: Option<Part>,
    start: Instant,
    wall: Option<f64>,
    /// One of the tasks of a pass timed whole ([`Recorder::even`]).
    whole: bool,
    thread: i64,
}

/// The records, in the order they were made.
struct Recorder(Mutex<Vec<Record>>);

impl Recorder {
    const fn new() -> Recorder {
        Recorder(Mutex::new(Vec::new()))
    }

    /// Runs `f` and records it as `pass` with `seconds` mapped from its time.
    fn record<R>(&self, pass: &'static str, part: Option<Part>, f: impl FnOnce() -> R, seconds: impl FnOnce(f64) -> f64) -> R {
        let t = Instant::now();
        let r = f();
        let s = t.elapsed().as_secs_f64();
        self.push(pass, seconds(s), part, t, Some(s), false);
        r
    }

    fn push(&self, pass: &'static str, seconds: f64, part: Option<Part>, start: Instant, wall: Option<f64>, whole: bool) {
        let thread = rayon::current_thread_index().map_or(-1, |i| i as i64);
        self.0.lock().push(Record { pass, seconds, beside: in_beside(), part, start, wall, whole, thread });
    }

    fn task<R>(&self, pass: &'static str, f: impl FnOnce() -> R) -> R {
        self.part(pass, None, f)
    }

    fn part<R>(&self, pass: &'static str, part: Option<Part>, f: impl FnOnce() -> R) -> R {
        self.record(pass, part, f, |s| s)
    }

    fn serial<R>(&self, pass: &'static str, f: impl FnOnce() -> R) -> R {
        self.record(pass, None, f, |s| -s)
    }

    /// A pass timed whole, recorded as `tasks` tasks of equal time (one
    /// line of the timeline, the whole pass on the calling thread).
    fn even<R>(&self, pass: &'static str, tasks: usize, f: impl FnOnce() -> R) -> R {
        let t = Instant::now();
        let r = f();
        let whole = t.elapsed().as_secs_f64();
        let n = tasks.max(1);
        for i in 0..n {
            self.push(pass, whole / n as f64, None, t, (i == 0).then_some(whole), true);
        }
        r
    }

    fn iteration_end(&self) {
        self.push("", 0.0, None, Instant::now(), Some(0.0), false);
    }

    /// The records so far, forgotten here.
    fn take(&self) -> Vec<Record> {
        std::mem::take(&mut *self.0.lock())
    }

    #[cfg(test)]
    fn take_text(&self) -> String {
        text(&self.take())
    }
}

/// The task profile's lines (the module's account).
fn text(records: &[Record]) -> String {
    records
        .iter()
        .map(|r| {
            let side = if r.beside { "beside: " } else { "" };
            match r.part {
                Some(p) => format!("{side}{}\t{:.9}\t{}\n", r.pass, r.seconds, p.label()),
                None => format!("{side}{}\t{:.9}\n", r.pass, r.seconds),
            }
        })
        .collect()
}

/// The timeline's lines (the module's account) of a pool of `threads`, its
/// times counted from the earliest start.
fn timeline(records: &[Record], threads: usize) -> String {
    let Some(epoch) = records.iter().map(|r| r.start).min() else { return String::new() };
    let lines = records.iter().filter_map(|r| {
        let side = if r.beside { "beside: " } else { "" };
        let kind = match (r.seconds < 0.0, r.whole) {
            (true, _) => "serial",
            (false, false) => "task",
            (false, true) => "whole",
        };
        let start = (r.start - epoch).as_secs_f64();
        r.wall.map(|w| format!("{side}{}\t{}\t{start:.9}\t{:.9}\t{kind}\n", r.pass, r.thread, start + w))
    });
    std::iter::once(format!("#threads\t{threads}\n")).chain(lines).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_recorder_writes_tasks_serial_sections_and_iteration_ends_in_order() {
        let r = Recorder::new();
        assert_eq!(r.task("a", || 2 + 2), 4);
        r.serial("s", || std::thread::sleep(std::time::Duration::from_millis(2)));
        r.even("e", 4, || std::thread::sleep(std::time::Duration::from_millis(4)));
        r.iteration_end();
        let text = r.take_text();
        let lines: Vec<(&str, f64)> = text
            .lines()
            .map(|l| {
                let (p, s) = l.split_once('\t').expect("pass<TAB>seconds");
                (p, s.parse().expect("seconds"))
            })
            .collect();
        let names: Vec<&str> = lines.iter().map(|l| l.0).collect();
        assert_eq!(names, ["a", "s", "e", "e", "e", "e", ""]);
        assert!(lines[0].1 >= 0.0);
        assert!(lines[1].1 <= -0.002, "a serial section is negative: {}", lines[1].1);
        assert!(lines[2..6].iter().all(|l| l.1 == lines[2].1 && l.1 >= 0.001), "{lines:?}");
        assert_eq!(lines[6].1, 0.0);
        assert_eq!(r.take_text(), "", "taking the text forgets the records");
    }

    #[test]
    fn the_timeline_says_when_where_and_how_each_record_ran() {
        let r = Recorder::new();
        let ms = std::time::Duration::from_millis(2);
        let pool = rayon::ThreadPoolBuilder::new().num_threads(2).build().unwrap();
        pool.install(|| r.task("a", || std::thread::sleep(ms)));
        r.serial("s", || std::thread::sleep(ms));
        r.even("e", 3, || std::thread::sleep(ms));
        r.iteration_end();
        let records = r.take();
        assert_eq!(text(&records).lines().count(), 6, "the profile keeps one line a task");
        let text = timeline(&records, 3);
        let (head, rest) = text.split_once('\n').unwrap();
        assert_eq!(head, "#threads\t3", "the pool's size comes first");
        let lines: Vec<Vec<String>> = rest.lines().map(|l| l.split('\t').map(String::from).collect()).collect();
        let col = |i: usize| lines.iter().map(|l| l[i].as_str()).collect::<Vec<_>>();
        assert_eq!(col(0), ["a", "s", "e", ""], "a pass timed whole is one line");
        assert_eq!(col(4), ["task", "serial", "whole", "task"]);
        let thread: Vec<i64> = col(1).iter().map(|t| t.parse().unwrap()).collect();
        assert!((0..2).contains(&thread[0]) && thread[1..].iter().all(|&t| t == -1), "{thread:?}");
        let span: Vec<(f64, f64)> = lines.iter().map(|l| (l[2].parse().unwrap(), l[3].parse().unwrap())).collect();
        assert_eq!(span[0].0, 0.0, "times count from the earliest start");
        for (i, &(s, e)) in span.iter().enumerate().take(3) {
            assert!(e - s >= 0.002, "record {i} spans {s}..{e}");
        }
        assert!(span.windows(2).all(|w| w[1].0 >= w[0].1), "one after another: {span:?}");
    }

    #[test]
    fn the_parts_of_a_task_that_forks_carry_their_label() {
        let r = Recorder::new();
        r.task("p", || ());
        r.part("p", Some(Part::Head), || ());
        r.part("p", Some(Part::Run), || ());
        r.part("p", Some(Part::Run), || ());
        r.part("p", Some(Part::Tail), || ());
        let text = r.take_text();
        let labels: Vec<Option<&str>> = text.lines().map(|l| l.splitn(3, '\t').nth(2)).collect();
        assert_eq!(labels, [None, Some("head"), Some("run"), Some("run"), Some("tail")]);
        assert!(text.lines().all(|l| l.starts_with("p\t")), "{text}");
    }

    #[test]
    fn records_made_beside_the_passes_say_so_and_only_they() {
        let r = Recorder::new();
        r.task("a", || ());
        marked_beside(|| {
            r.task("draw", || ());
            marked_beside(|| r.serial("inner", || ()));
            r.even("sort", 2, || ());
        });
        r.task("b", || ());
        let text = r.take_text();
        let names: Vec<&str> = text.lines().map(|l| l.split_once('\t').expect("pass<TAB>seconds").0).collect();
        assert_eq!(names, ["a", "beside: draw", "beside: inner", "beside: sort", "beside: sort", "b"]);
    }
}
