//! The HDF5 store across processes: the command-line tool writes what
//! this process reads, and reads what this process writes (feature `hdf5`).
#![cfg(feature = "hdf5")]

#[path = "../../tests/common/mod.rs"]
mod common;
use common::store_model as model;
use common::tmpdir;
use gsenc::format::quantize::CentreCoding;
use gsenc::format::{write_model_as, Payload};
use gsenc::io::store::{EntryKey, Store};
use gsenc::model::{WarmRecord, WarmTaken};
use std::process::Command;

fn gsenc_bin() -> &'static str {
    env!("CARGO_BIN_EXE_gsenc")
}

#[test]
fn one_process_writes_another_reads() {
    let _serial = common::hdf5_serial();
    let dir = tmpdir("procs");
    let path = dir.join("s.h5");
    // The command-line tool, another process, writes two steps...
    let mut files = Vec::new();
    for step in [5u64, 6] {
        let mut m = model("rho", step, 1, 300, 0.5);
        if step == 6 {
            m.meta.fell_back = Some("GPU 'x': device lost (test)".into());
            m.meta.warm = Some(WarmRecord { taken: WarmTaken::Repaired, moved: 17 });
        }
        let f = dir.join(format!("m{step}.gsm"));
        std::fs::write(&f, write_model_as(&m, Payload::Float32).unwrap()).unwrap();
        files.push((f, m));
    }
    let out = Command::new(gsenc_bin())
        .args(["store", "add", "--payload", "8bit-u16"])
        .arg(&path)
        .args(files.iter().map(|(f, _)| f))
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    // ...which this process reads.
    let s = Store::open_read(&path).unwrap();
    for (_, m) in &files {
        let (back, payload) = s.read(&EntryKey::of(&m.meta)).unwrap();
        assert_eq!(payload, Payload::Bits8(CentreCoding::Fixed16));
        assert_eq!(back.params, payload.round_trip(&m).unwrap());
        assert_eq!(back.meta.encode_psnr, None, "a lossy payload cannot keep the float32 PSNR");
        assert_eq!(back.meta.fell_back, m.meta.fell_back);
        assert_eq!(back.meta.warm, m.meta.warm);
    }
    drop(s);
    // This process appends; the tool reads it back in another process.
    let m = model("rho", 7, 1, 100, 0.5);
    Store::open_append(&path).unwrap().append(&m, Payload::Float32).unwrap();
    let out = Command::new(gsenc_bin()).args(["info", "--json"]).arg(&path).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let entries = v["entries"].as_array().unwrap();
    let names: Vec<&str> = entries.iter().map(|e| e["entry"].as_str().unwrap()).collect();
    assert_eq!(names, ["/rho/5/rank_1", "/rho/6/rank_1", "/rho/7/rank_1"]);
    assert_eq!(entries[2]["primitives"], 100);
    assert_eq!(entries[2]["time"], 1.75);
    assert_eq!(entries[0]["payload"], "8bit-u16");
    assert!(entries[0]["fell_back"].is_null());
    assert_eq!(entries[1]["fell_back"], "GPU 'x': device lost (test)");
    assert!(entries[0]["warm_start"].is_null());
    assert_eq!((&entries[1]["warm_start"], &entries[1]["warm_moved"]), (&serde_json::json!("repaired"), &serde_json::json!(17)));
    // And extracts a model that equals what this process stored.
    let got = dir.join("got.gsm");
    let out = Command::new(gsenc_bin()).args(["store", "extract"]).arg(&path).arg("rho/7/1").arg("-o").arg(&got).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert_eq!(gsenc::format::read_model(&std::fs::read(&got).unwrap()).unwrap(), m);
}


/// `store add` of a run's folder: every `.gsm` in it (not its step indexes
/// or other files), in name order; and nothing is touched until every model
/// is read and checked and has an entry of its own, new to the store.
#[test]
fn a_folder_of_models_is_added_and_the_store_is_untouched_until_every_model_is_checked() {
    let _serial = common::hdf5_serial();
    let dir = tmpdir("folder");
    let add = |args: &[&std::path::Path]| Command::new(gsenc_bin()).args(["store", "add", "--json"]).args(args).output().unwrap();
    let write = |folder: &std::path::Path, m: &gsenc::model::Model| {
        std::fs::create_dir_all(folder).unwrap();
        let f = folder.join(format!("{}_{:06}.gsm", m.meta.field, m.meta.step));
        std::fs::write(&f, write_model_as(m, Payload::Float32).unwrap()).unwrap();
        f
    };
    let run = dir.join("run");
    let mut models = Vec::new();
    for field in ["temp", "rho"] {
        for step in 0..3u64 {
            let m = model(field, step, 0, 40 + 10 * step as usize, 0.5);
            write(&run, &m);
            models.push(m);
        }
    }
    std::fs::write(run.join("rho_000001.gsi"), "{}").unwrap(); // a step index is not a model
    std::fs::write(run.join("notes.txt"), "run 7").unwrap();
    let store = dir.join("s.h5");
    let out = add(&[&store, &run]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let added: Vec<&str> = v["added"].as_array().unwrap().iter().map(|a| a.as_str().unwrap()).collect();
    // Name order: rho's files before temp's.
    assert_eq!(added, ["/rho/0/rank_0", "/rho/1/rank_0", "/rho/2/rank_0", "/temp/0/rank_0", "/temp/1/rank_0", "/temp/2/rank_0"]);
    // The step index is named as not added, on stderr and in the output.
    assert_eq!(v["step_indexes_not_added"], serde_json::json!([run.join("rho_000001.gsi").display().to_string()]));
    assert!(String::from_utf8_lossy(&out.stderr).contains("1 step index(es) (.gsi) not added"));
    let s = Store::open_read(&store).unwrap();
    for m in &models {
        assert_eq!(&s.read(&EntryKey::of(&m.meta)).unwrap().0, m);
    }
    drop(s);
    let before = std::fs::read(&store).unwrap();
    let untouched = |out: &std::process::Output, says: &str| {
        assert!(!out.status.success());
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains(says), "{err}");
        assert!(std::fs::read(&store).unwrap() == before, "the store changed");
    };
    // A folder holding a step the store has: refused, and its new step not added.
    let again = dir.join("again");
    let new = write(&again, &model("rho", 9, 0, 30, 0.5));
    write(&again, &models[4]); // rho step 1
    untouched(&add(&[&store, &again]), "holds /rho/1/rank_0 already");
    // Two models for one entry.
    let twin = dir.join("twin.gsm");
    std::fs::copy(&new, &twin).unwrap();
    untouched(&add(&[&store, &new, &twin]), "are both /rho/9/rank_0");
    // A corrupt model after sound ones.
    let bad = dir.join("bad");
    write(&bad, &model("rho", 20, 0, 30, 0.5));
    let mut cut = std::fs::read(&new).unwrap();
    cut.truncate(cut.len() / 2);
    std::fs::write(bad.join("rho_000021.gsm"), cut).unwrap();
    untouched(&add(&[&store, &bad]), "rho_000021.gsm");
    // A folder with no model; and nothing is created for a store refused so.
    let empty = dir.join("empty");
    std::fs::create_dir_all(&empty).unwrap();
    untouched(&add(&[&store, &empty]), "no .gsm model file");
    let fresh = dir.join("fresh.h5");
    assert!(!add(&[&fresh, &new, &twin]).status.success());
    assert!(!fresh.exists());
}
