//! Writers of the HDF5 store stopped mid-append (cargo feature `hdf5`):
//! killed, where every step appended before the kill must read back
//! exactly (the last rounds' writers first append enough small steps that
//! their metadata cache evicts between appends); and on a disk that fills up and gets room again while the
//! writer keeps the store open, as an in-situ run's store does, where the
//! append that does not fit fails with the disk's error, the steps before
//! it stay readable, and once there is room the same open store takes that
//! step and the next (the small disk is `tests/common/disk.rs`'s). Its own
//! test binary, so that the writer processes it spawns inherit no HDF5 file
//! (and lock) that another test of the same process holds open.
#![cfg(feature = "hdf5")]

mod common;
use common::disk::{says_full, SmallDisk};
use common::store_model as model;
use common::tmpdir;
use gsenc::format::Payload;
use gsenc::io::store::{EntryKey, Store, CACHE_BYTES};
use std::io::{BufRead, BufReader, Write};
use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::time::Duration;

const CHILD_ENV: &str = "GSENC_STORE_CRASH_CHILD";
/// Small steps of field "warm" a child appends first: enough that its
/// metadata cache evicts between appends before it is killed.
const WARM_ENV: &str = "GSENC_STORE_CRASH_WARM";
const CRASH_PRIMS: usize = 40_000;
const WARM_PRIMS: usize = 20;

/// Run by `writers_killed_mid_append_leave_earlier_steps_readable` in a child
/// process: appends steps forever, saying when each append begins and when
/// it is flushed (with how long it took); first, if asked, small steps of
/// field "warm", then how many the store holds and the cache's bytes.
#[test]
#[ignore = "a child process of the crash test"]
fn crash_writer_child() {
    let _serial = common::hdf5_serial();
    let path = PathBuf::from(std::env::var(CHILD_ENV).expect("run by the crash test"));
    let warm: u64 = std::env::var(WARM_ENV).map_or(0, |w| w.parse().unwrap());
    let mut s = Store::open_append(&path).unwrap();
    let entries = s.entries().unwrap();
    let next = |field: &str| entries.iter().filter(|e| e.key.field == field).map(|e| e.key.step + 1).max().unwrap_or(0);
    let (first, first_warm) = (next("rho"), next("warm"));
    if warm > 0 {
        for step in first_warm..first_warm + warm {
            s.append(&model("warm", step, 0, WARM_PRIMS, 0.5), Payload::Float32).unwrap();
        }
        println!("\nwarm {} cache {}", first_warm + warm, s.cache_size().0);
    }
    for step in first.. {
        let payload = Payload::ALL[step as usize % 3];
        let m = model("rho", step, 0, CRASH_PRIMS, 0.5);
        println!("\nbegin {step}");
        let t = std::time::Instant::now();
        s.append(&m, payload).unwrap();
        println!("\nappended {step} {}", t.elapsed().as_micros());
    }
}

/// The step and microseconds of a child's "appended STEP US" line.
fn appended(line: &str) -> Option<(u64, u64)> {
    let mut words = line.strip_prefix("appended ")?.split(' ');
    Some((words.next()?.parse().ok()?, words.next()?.parse().ok()?))
}

#[test]
fn writers_killed_mid_append_leave_earlier_steps_readable() {
    let _serial = common::hdf5_serial();
    let dir = tmpdir("crash");
    let path = dir.join("s.h5");
    let exe = std::env::current_exe().unwrap();
    let mut confirmed = std::collections::BTreeSet::new();
    let mut warm_steps = 0;
    let mut append_us = 5000u64;
    let mut unconfirmed_rounds = 0;
    // Each round lets the writer finish 0, 1 or 2 appends, then kills it at
    // a different fraction of the next one. In the last EVICTING rounds
    // the writer first appends WARM small steps, so that its metadata cache
    // has filled and evicts between appends (store.rs `unevicted`) when it
    // is killed.
    const ROUNDS: u64 = 30;
    const EVICTING: u64 = 5;
    const WARM: u64 = 400;
    for round in 0..ROUNDS + EVICTING {
        let warm = if round >= ROUNDS { WARM } else { 0 };
        let mut child = Command::new(&exe)
            .args(["--exact", "crash_writer_child", "--ignored", "--nocapture", "--test-threads=1"])
            .env(CHILD_ENV, &path)
            .env(WARM_ENV, warm.to_string())
            .stdout(Stdio::piped())
            .stderr(std::fs::File::create(dir.join("child.stderr")).unwrap())
            .spawn()
            .unwrap();
        let mut lines = BufReader::new(child.stdout.take().unwrap()).lines();
        let mut seen = 0;
        loop {
            let Some(Ok(line)) = lines.next() else {
                let why = std::fs::read_to_string(dir.join("child.stderr")).unwrap_or_default();
                panic!("round {round}: the writer died on its own: {why}");
            };
            if let Some((step, us)) = appended(&line) {
                confirmed.insert(step);
                append_us = us;
                seen += 1;
            } else if let Some(rest) = line.strip_prefix("warm ") {
                let (steps, cache) = rest.split_once(" cache ").unwrap();
                warm_steps = steps.parse().unwrap();
                let cache: usize = cache.parse().unwrap();
                // Without evictions between appends, 400 warm steps alone
                // hold about 3.7 MB.
                assert!(cache < CACHE_BYTES + CACHE_BYTES / 4, "round {round}: the writer's cache holds {cache} bytes");
            } else if line.starts_with("begin ") && seen == round % 3 {
                break;
            }
        }
        std::thread::sleep(Duration::from_micros(append_us * (round * 7 % ROUNDS) / ROUNDS));
        child.kill().unwrap();
        child.wait().unwrap();
        for line in lines.map_while(|l| l.ok()) {
            if let Some((step, _)) = appended(&line) {
                confirmed.insert(step);
            }
        }
        // Every confirmed step reads back exactly.
        let s = Store::open_read(&path).unwrap_or_else(|e| panic!("round {round}: store unreadable: {e}"));
        let entries = s.entries().unwrap();
        for &step in &confirmed {
            let want = model("rho", step, 0, CRASH_PRIMS, 0.5);
            let (got, payload) =
                s.read(&EntryKey::of(&want.meta)).unwrap_or_else(|e| panic!("round {round}: step {step} lost: {e}"));
            assert_eq!(got.params, payload.round_trip(&want).unwrap(), "round {round}: step {step}");
        }
        for step in 0..warm_steps {
            let want = model("warm", step, 0, WARM_PRIMS, 0.5);
            assert_eq!(s.read(&EntryKey::of(&want.meta)).unwrap_or_else(|e| panic!("round {round}: warm step {step} lost: {e}")).0, want);
        }
        // The append that was cut short is absent, whole, or listed as unreadable.
        for e in entries.iter().filter(|e| e.key.field == "rho" && !confirmed.contains(&e.key.step)) {
            unconfirmed_rounds += 1;
            if e.content.is_ok() {
                let want = model("rho", e.key.step, 0, CRASH_PRIMS, 0.5);
                let (got, payload) = s.read(&e.key).unwrap();
                assert_eq!(got.params, payload.round_trip(&want).unwrap(), "round {round}: partial step");
            }
        }
    }
    assert!(confirmed.len() >= ROUNDS as usize, "the writer appended too little to test anything ({confirmed:?})");
    assert_eq!(warm_steps, EVICTING * WARM);
    eprintln!("{} steps confirmed; {unconfirmed_rounds} kills left the cut-short step in the file", confirmed.len());
    let _ = std::fs::remove_dir_all(&dir);
}

const FULL_CHILD_ENV: &str = "GSENC_STORE_FULL_CHILD";
/// Primitives of the small steps (0 and 2) and of the large one (1): a store
/// holding step 0 (about 130 KB, its groups sized for many steps) fits on
/// the small disk, step 1 (about 480 KB) more does not, until it grows.
const SMALL: usize = 200;
const LARGE: usize = 10_000;
const DISK_KIB: u64 = 256;

/// The writer: opens the store for appending and runs the commands of its
/// standard input, `append STEP PRIMITIVES` (answering `appended STEP` or
/// `refused STEP: ERROR` on a line) until `exit` or the end.
#[test]
#[ignore = "a child process of the full-disk test"]
fn full_disk_writer_child() {
    let path = PathBuf::from(std::env::var(FULL_CHILD_ENV).expect("run by the full-disk test"));
    let mut s = Store::open_append(&path).unwrap();
    for line in std::io::stdin().lines() {
        let line = line.unwrap();
        let words: Vec<&str> = line.split_whitespace().collect();
        let (step, n) = match words[..] {
            ["append", step, n] => (step.parse().unwrap(), n.parse().unwrap()),
            _ => break,
        };
        match s.append(&model("rho", step, 0, n, 0.5), Payload::Float32) {
            Ok(()) => println!("\nappended {step}"),
            Err(e) => println!("\nrefused {step}: {}", e.to_string().replace('\n', " ")),
        }
        std::io::stdout().flush().unwrap();
    }
}

/// A writer of the store at `path` on `disk`, driven line by line.
struct Writer {
    child: std::process::Child,
    to: std::process::ChildStdin,
    from: Box<dyn Iterator<Item = String>>,
}

impl Writer {
    fn start(disk: &SmallDisk, path: &std::path::Path) -> Writer {
        let mut child = disk
            .command(std::env::current_exe().unwrap())
            .args(["--exact", "full_disk_writer_child", "--ignored", "--nocapture", "--test-threads=1"])
            .env(FULL_CHILD_ENV, path)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .spawn()
            .unwrap();
        let to = child.stdin.take().unwrap();
        let lines = BufReader::new(child.stdout.take().unwrap()).lines().map_while(|l| l.ok());
        let from = Box::new(lines.filter(|l| l.starts_with("appended") || l.starts_with("refused")));
        Writer { child, to, from }
    }

    /// Appends step `step` of `n` primitives: the writer's answer.
    fn append(&mut self, step: u64, n: usize) -> String {
        writeln!(self.to, "append {step} {n}").unwrap();
        self.from.next().unwrap_or_else(|| panic!("the writer died appending step {step}"))
    }

    /// Closes the store and waits for the writer.
    fn exit(mut self) {
        writeln!(self.to, "exit").unwrap();
        assert!(self.child.wait().unwrap().success(), "the writer failed");
    }
}

/// The steps the store at `path` lists, each checked to read back as written.
fn check_steps(path: &std::path::Path, steps: &[(u64, usize)]) {
    let s = Store::open_read(path).unwrap();
    let listed: Vec<u64> = s.entries().unwrap().iter().map(|e| e.key.step).collect();
    assert_eq!(listed, steps.iter().map(|s| s.0).collect::<Vec<_>>());
    for &(step, n) in steps {
        let want = model("rho", step, 0, n, 0.5);
        let (got, _) = s.read(&EntryKey::of(&want.meta)).unwrap_or_else(|e| panic!("step {step}: {e}"));
        assert_eq!(got.params, want.params, "step {step}");
    }
}

#[test]
fn a_store_on_a_full_disk_keeps_its_steps_and_goes_on_when_there_is_room() {
    let _serial = common::hdf5_serial();
    let disk = SmallDisk::new("store-full", DISK_KIB);
    let path = disk.path("s.h5");

    // A step that does not fit fails with the disk's error; the writer
    // closes the store on the full disk, and the step before reads back.
    let mut w = Writer::start(&disk, &path);
    assert_eq!(w.append(0, SMALL), "appended 0");
    let refused = w.append(1, LARGE);
    assert!(refused.starts_with("refused 1: ") && says_full(&refused), "{refused}");
    w.exit();
    check_steps(&path, &[(0, SMALL)]);

    // Opened again on the still full disk: refused again; then, with room,
    // the same open store takes that step and the next.
    let mut w = Writer::start(&disk, &path);
    let refused = w.append(1, LARGE);
    assert!(refused.starts_with("refused 1: ") && says_full(&refused), "{refused}");
    disk.grow(16 * 1024, w.child.id());
    assert_eq!(w.append(1, LARGE), "appended 1");
    assert_eq!(w.append(2, SMALL), "appended 2");
    w.exit();
    check_steps(&path, &[(0, SMALL), (1, LARGE), (2, SMALL)]);
    assert_eq!(disk.names(), ["s.h5"], "a temporary file was left behind");
}
