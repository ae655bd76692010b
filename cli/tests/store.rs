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

