//! The HDF5 store on a disk that fills up and gets room again while one
//! writer keeps it open, as an in-situ run's store does (cargo feature
//! `hdf5`): the append that does not fit fails with the disk's error, the
//! steps before it stay readable, and once there is room the same open
//! store takes that step again and the next. Its own test binary: the
//! writer is a child process on a small disk (`tests/common/disk.rs`).
#![cfg(feature = "hdf5")]

mod common;
use common::disk::{says_full, SmallDisk};
use common::store_model as model;
use gsenc::format::Payload;
use gsenc::io::store::{EntryKey, Store};
use std::io::{BufRead, BufReader, Write};
use std::path::PathBuf;
use std::process::Stdio;

const CHILD_ENV: &str = "GSENC_STORE_FULL_CHILD";
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
    let path = PathBuf::from(std::env::var(CHILD_ENV).expect("run by the full-disk test"));
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
            .env(CHILD_ENV, path)
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
