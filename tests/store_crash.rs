//! Writers of the HDF5 store killed mid-append (cargo feature `hdf5`): every
//! step appended before the kill must read back exactly. Its own test binary,
//! so that the writer processes it spawns inherit no HDF5 file (and lock)
//! that another test of the same process holds open.
#![cfg(feature = "hdf5")]

mod common;
use common::store_model as model;
use common::tmpdir;
use gsenc::format::Payload;
use gsenc::io::store::{EntryKey, Store};
use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::time::Duration;

const CHILD_ENV: &str = "GSENC_STORE_CRASH_CHILD";
const CRASH_PRIMS: usize = 40_000;

/// Run by `writers_killed_mid_append_leave_earlier_steps_readable` in a child
/// process: appends steps forever, saying when each append begins and when
/// it is flushed (with how long it took).
#[test]
#[ignore = "a child process of the crash test"]
fn crash_writer_child() {
    let _serial = common::hdf5_serial();
    let path = PathBuf::from(std::env::var(CHILD_ENV).expect("run by the crash test"));
    let mut s = Store::open_append(&path).unwrap();
    let first = s.entries().unwrap().iter().map(|e| e.key.step + 1).max().unwrap_or(0);
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
    let mut append_us = 5000u64;
    let mut unconfirmed_rounds = 0;
    // Each round lets the writer finish 0, 1 or 2 appends, then kills it at
    // a different fraction of the next one.
    const ROUNDS: u64 = 30;
    for round in 0..ROUNDS {
        let mut child = Command::new(&exe)
            .args(["--exact", "crash_writer_child", "--ignored", "--nocapture", "--test-threads=1"])
            .env(CHILD_ENV, &path)
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
        // The append that was cut short is absent, whole, or listed as unreadable.
        for e in entries.iter().filter(|e| !confirmed.contains(&e.key.step)) {
            unconfirmed_rounds += 1;
            if e.content.is_ok() {
                let want = model("rho", e.key.step, 0, CRASH_PRIMS, 0.5);
                let (got, payload) = s.read(&e.key).unwrap();
                assert_eq!(got.params, payload.round_trip(&want).unwrap(), "round {round}: partial step");
            }
        }
    }
    assert!(confirmed.len() >= ROUNDS as usize, "the writer appended too little to test anything ({confirmed:?})");
    eprintln!("{} steps confirmed; {unconfirmed_rounds} kills left the cut-short step in the file", confirmed.len());
    let _ = std::fs::remove_dir_all(&dir);
}
