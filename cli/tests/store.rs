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
use std::process::{Command, Stdio};

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
        assert_eq!(back.params, payload.round_trip(m).unwrap());
        assert_eq!(back.meta.encode_psnr, None, "a lossy payload cannot keep the float32 PSNR");
        assert_eq!(back.meta.fell_back, m.meta.fell_back);
        assert_eq!(back.meta.warm, m.meta.warm);
    }
    drop(s);
    // This process appends; the tool reads it back in another process.
    let m = model("rho", 7, 1, 100, 0.5);
    Store::open_append(&path).unwrap().append(&m, Payload::Float32).unwrap();
    let v = info_json(&path);
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
    assert_listed_as_file(&entries[2], &got);
}

fn info_json(path: &std::path::Path) -> serde_json::Value {
    let out = Command::new(gsenc_bin()).args(["info", "--json"]).arg(path).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    serde_json::from_slice(&out.stdout).unwrap()
}

/// The store lists an entry's metadata as `gsenc info` shows the model's file.
fn assert_listed_as_file(listed: &serde_json::Value, file: &std::path::Path) {
    let shown = info_json(file);
    let listed = listed.as_object().unwrap();
    for key in ["field", "step", "rank", "precision", "dims", "value_max", "seed_sample", "target_curve"] {
        assert!(listed.contains_key(key), "the store's listing has no '{key}'");
    }
    for (key, value) in listed.iter().filter(|(k, _)| !["entry", "stored_bytes"].contains(&k.as_str())) {
        assert_eq!(&shown[key], value, "'{key}' listed by the store and shown by `gsenc info` of its model");
    }
}

/// A packed model file added to a store and extracted again is the same
/// file: the store holds the model's payload, packed again from the model
/// as read, and a packed model packed again is the same bytes.
#[test]
fn a_packed_model_stored_and_extracted_is_the_same_file() {
    let _serial = common::hdf5_serial();
    let dir = tmpdir("packed");
    let (store, file, got) = (dir.join("s.h5"), dir.join("rho_000003.gsm"), dir.join("got.gsm"));
    std::fs::write(&file, write_model_as(&model("rho", 3, 0, 400, 1.5), Payload::Packed).unwrap()).unwrap();
    let out = Command::new(gsenc_bin()).args(["store", "add"]).arg(&store).arg(&file).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let out = Command::new(gsenc_bin()).args(["store", "extract"]).arg(&store).arg("rho/3/0").arg("-o").arg(&got).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(std::fs::read(&file).unwrap() == std::fs::read(&got).unwrap(), "the extracted file differs from the one added");
    // Listed with the precision its payload was packed at.
    let listing = info_json(&store);
    assert!(listing["entries"][0]["precision"]["scale"].is_u64(), "{listing}");
    assert_listed_as_file(&listing["entries"][0], &file);
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
    std::fs::write(run.join("notes.txt"), "run 7").unwrap();
    let store = dir.join("s.h5");
    // A step index that is not one refuses the whole folder, before a store is made.
    std::fs::write(run.join("rho_000001.gsi"), "{}").unwrap();
    let out = add(&[&store, &run]);
    assert!(!out.status.success() && String::from_utf8_lossy(&out.stderr).contains("not a gsenc step index"));
    assert!(!store.exists());
    std::fs::remove_file(run.join("rho_000001.gsi")).unwrap();
    let out = add(&[&store, &run]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let added: Vec<&str> = v["added"].as_array().unwrap().iter().map(|a| a.as_str().unwrap()).collect();
    // Name order: rho's files before temp's.
    assert_eq!(added, ["/rho/0/rank_0", "/rho/1/rank_0", "/rho/2/rank_0", "/temp/0/rank_0", "/temp/1/rank_0", "/temp/2/rank_0"]);
    assert_eq!(v["step_indexes"], serde_json::json!([]));
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

/// An MPI run's folder (each rank's model and rank 0's step index of each
/// step) in one store that gives each step's pieces back through its index.
#[test]
fn an_mpi_runs_folder_keeps_its_step_indexes() {
    let _serial = common::hdf5_serial();
    let dir = tmpdir("mpi-folder");
    let add = |args: &[&std::path::Path]| Command::new(gsenc_bin()).args(["store", "add", "--json"]).args(args).output().unwrap();
    let run = dir.join("run");
    std::fs::create_dir_all(&run).unwrap();
    let mut steps = Vec::new();
    for step in [4u64, 5] {
        let (index, pieces) = common::decomposed_step("rho", step);
        for (p, m) in index.pieces.iter().zip(&pieces) {
            std::fs::write(run.join(&p.model), write_model_as(m, Payload::Float32).unwrap()).unwrap();
        }
        std::fs::write(run.join(format!("rho_{step:06}.gsi")), index.to_json()).unwrap();
        steps.push((index, pieces));
    }
    let store = dir.join("s.h5");
    // An index whose model is missing is refused before anything is written.
    let lone = dir.join("lone");
    std::fs::create_dir_all(&lone).unwrap();
    std::fs::copy(run.join("rho_000004.gsi"), lone.join("rho_000004.gsi")).unwrap();
    std::fs::copy(run.join("rho_000004_r0.gsm"), lone.join("rho_000004_r0.gsm")).unwrap();
    let out = add(&[&store, &lone]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("rank 1's model (/rho/4/rank_1) is neither added nor in the store"), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(!store.exists());
    // The folder: models first (name order), then the indexes.
    let out = add(&[&store, &run]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["added"], serde_json::json!(["/rho/4/rank_0", "/rho/4/rank_1", "/rho/5/rank_0", "/rho/5/rank_1"]));
    assert_eq!(v["step_indexes"], serde_json::json!(["/rho/4/index", "/rho/5/index"]));
    let info = Command::new(gsenc_bin()).args(["info", "--json"]).arg(&store).output().unwrap();
    let v: serde_json::Value = serde_json::from_slice(&info.stdout).unwrap();
    assert_eq!(v["step_indexes"], serde_json::json!([
        { "step": "/rho/4", "ranks": 2, "halo": 2, "dims": [24, 16, 12] },
        { "step": "/rho/5", "ranks": 2, "halo": 2, "dims": [24, 16, 12] }
    ]));
    assert_eq!(v["entries"].as_array().unwrap().len(), 4);
    let s = Store::open_read(&store).unwrap();
    for (index, pieces) in &steps {
        let (back, models) = s.read_step("rho", index.step).unwrap();
        assert_eq!(&models, pieces);
        assert_eq!((back.halo, back.dims, back.bmin), (index.halo, index.dims, index.bmin));
    }
    drop(s);
    // A step extracted to a folder decodes as the run's own .gsi does.
    let out = dir.join("out");
    let extract = |entry: &str, to: &std::path::Path| Command::new(gsenc_bin()).args(["store", "extract"]).arg(&store).arg(entry).arg("-o").arg(to).output().unwrap();
    let done = extract("rho/4", &out);
    assert!(done.status.success(), "{}", String::from_utf8_lossy(&done.stderr));
    let mut files: Vec<String> = std::fs::read_dir(&out).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    files.sort();
    assert_eq!(files, ["rho_000004.gsi", "rho_000004.gsm", "rho_000004_r1.gsm"]);
    let decode = |gsi: std::path::PathBuf, raw: &str| {
        let d = Command::new(gsenc_bin()).args(["decode", "--backend", "cpu"]).arg(&gsi).arg("-o").arg(dir.join(raw)).output().unwrap();
        assert!(d.status.success(), "{}", String::from_utf8_lossy(&d.stderr));
        std::fs::read(dir.join(raw)).unwrap()
    };
    assert_eq!(decode(out.join("rho_000004.gsi"), "a.raw"), decode(run.join("rho_000004.gsi"), "b.raw"));
    let refused = extract("rho/4", std::path::Path::new("-"));
    assert!(!refused.status.success() && String::from_utf8_lossy(&refused.stderr).contains("to a folder"));
    let refused = extract("rho/9", &dir.join("none"));
    assert!(!refused.status.success() && String::from_utf8_lossy(&refused.stderr).contains("holds no step index of /rho/9"));
    // An index given alone brings its models; one whose models the store
    // holds adds the index only; one the store holds is refused.
    let one = dir.join("one.h5");
    let out = add(&[&one, &run.join("rho_000005.gsi")]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!((&v["added"], &v["step_indexes"]), (&serde_json::json!(["/rho/5/rank_0", "/rho/5/rank_1"]), &serde_json::json!(["/rho/5/index"])));
    let models_only = dir.join("models.h5");
    let r4: Vec<std::path::PathBuf> = ["rho_000004_r0.gsm", "rho_000004_r1.gsm"].iter().map(|f| run.join(f)).collect();
    assert!(add(&[&models_only, &r4[0], &r4[1]]).status.success());
    let out = add(&[&models_only, &run.join("rho_000004.gsi")]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!((&v["added"], &v["step_indexes"]), (&serde_json::json!([]), &serde_json::json!(["/rho/4/index"])));
    assert_eq!(Store::open_read(&models_only).unwrap().read_step("rho", 4).unwrap().1, steps[0].1);
    let out = add(&[&models_only, &run.join("rho_000004.gsi")]);
    assert!(!out.status.success() && String::from_utf8_lossy(&out.stderr).contains("holds the index of /rho/4 already"));
}

/// `store verify`: every entry and step index of a sound store checked
/// (exit 0); then one float32 value of one entry changed in the file's
/// bytes: that entry fails its checksum by name (exit 4), the others and
/// the step index still pass.
#[test]
fn verify_names_the_entry_that_changed() {
    let _serial = common::hdf5_serial();
    let dir = tmpdir("verify");
    let path = dir.join("s.h5");
    let changed = model("temp", 3, 0, 50, 0.5);
    {
        let mut s = Store::open_append(&path).unwrap();
        s.append(&model("rho", 0, 0, 40, 0.5), Payload::Packed).unwrap();
        s.append(&changed, Payload::Float32).unwrap();
        let (index, pieces) = common::decomposed_step("rho", 4);
        for m in &pieces {
            s.append(m, Payload::Float32).unwrap();
        }
        s.append_step_index(&index).unwrap();
    }
    let verify = || {
        let out = Command::new(gsenc_bin()).args(["store", "verify", "--json"]).arg(&path).output().unwrap();
        let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
        (out.status.code(), v)
    };
    let (code, v) = verify();
    assert_eq!(code, Some(0), "{v}");
    let items = v["items"].as_array().unwrap();
    assert!(items.len() >= 4 && items.iter().all(|i| i["ok"] == true), "{v}");
    assert!(items.iter().any(|i| i["item"] == "/rho/4/index"), "{v}");
    // The entry's first row (mu_x of every primitive) as it lies in the file.
    let row: Vec<u8> = changed.params.iter().flat_map(|p| p[0].to_le_bytes()).collect();
    let mut bytes = std::fs::read(&path).unwrap();
    let at = bytes.windows(row.len()).position(|w| w == row).expect("the float32 rows lie in the file as written");
    bytes[at + 4 * 17] ^= 1;
    std::fs::write(&path, &bytes).unwrap();
    let (code, v) = verify();
    assert_eq!(code, Some(4), "{v}");
    assert_eq!(v["failed"], 1, "{v}");
    for i in v["items"].as_array().unwrap() {
        let bad = i["item"] == "/temp/3/rank_0";
        assert_eq!(i["ok"], !bad, "{i}");
        assert!(!bad || i["error"].as_str().unwrap().contains("fails its checksum"), "{i}");
    }
}

/// Processes adding to one store that is not there yet: each either adds
/// its model or fails (exit 5: another holds the store's lock), and every
/// model a process said it added is in the store. Two processes that both
/// found no store used to each make one and rename it over the other's,
/// so that a model added to the first was lost though its process said it
/// was added.
#[test]
fn processes_adding_to_a_new_store_at_once_lose_nothing() {
    let _serial = common::hdf5_serial();
    let dir = tmpdir("concurrent-adds");
    let files: Vec<_> = (0..8u64)
        .map(|step| {
            let f = dir.join(format!("m{step}.gsm"));
            std::fs::write(&f, write_model_as(&model("rho", step, 0, 40, 0.5), Payload::Float32).unwrap()).unwrap();
            f
        })
        .collect();
    for round in 0..8 {
        let path = dir.join(format!("s{round}.h5"));
        let running: Vec<_> = files
            .iter()
            .map(|f| Command::new(gsenc_bin()).args(["store", "add"]).arg(&path).arg(f).stdout(Stdio::piped()).stderr(Stdio::piped()).spawn().unwrap())
            .collect();
        let mut said_added = Vec::new();
        for (step, child) in running.into_iter().enumerate() {
            let out = child.wait_with_output().unwrap();
            let err = String::from_utf8_lossy(&out.stderr);
            match out.status.code() {
                Some(0) => said_added.push(step as u64),
                Some(5) => assert!(err.contains("lock"), "round {round}, step {step}: {err}"),
                code => panic!("round {round}, step {step}: exit {code:?}: {err}"),
            }
        }
        assert!(!said_added.is_empty(), "round {round}: no process added its model");
        let held: Vec<u64> = Store::open_read(&path).unwrap().entries().unwrap().iter().map(|e| e.key.step).collect();
        for step in &said_added {
            assert!(held.contains(step), "round {round}: step {step} was said to be added, but the store holds {held:?}");
        }
        assert_eq!(held.len(), said_added.len(), "round {round}: the store holds {held:?}, the processes added {said_added:?}");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}
