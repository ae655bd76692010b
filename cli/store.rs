//! The HDF5 store commands: `store add`, `store extract`, `decode-series`,
//! and `info` on a store. Without the cargo feature `hdf5` they exist but
//! say how to get them.

use crate::args::{one_of, OutputFlags};
use clap::{Args, Subcommand};
use gsenc::format::Payload;
use gsenc::{Error, Result};
use std::path::{Path, PathBuf};

#[derive(Subcommand)]
pub enum StoreCommand {
    /// Append model files to a store (created when missing), each as
    /// /<field>/<step>/rank_<r>, and step indexes (.gsi, with their models)
    /// as /<field>/<step>/index; an entry that exists is refused. A folder
    /// adds every .gsm and .gsi file in it (a run's output folder).
    Add(StoreAddArgs),
    /// Copy one model of a store out to a model file, or a step with its
    /// step index (FIELD/STEP) to a folder: FIELD_STEP.gsi and its ranks' models.
    Extract(StoreExtractArgs),
    /// Read every entry and step index of a store and check it (an
    /// entry's checksum, layout 1.4; an index's, and its pieces): each
    /// one's verdict, then exit 4 when any failed.
    Verify(StoreVerifyArgs),
}

#[derive(Args)]
pub struct StoreAddArgs {
    store: PathBuf,
    /// Model files, step indexes, and folders whose .gsm and .gsi files are added (in name order).
    #[arg(required = true)]
    models: Vec<PathBuf>,
    /// Payload in the store: f32, 8bit, 8bit-u16 or packed (default: each model's own).
    #[arg(long, value_parser = one_of(&Payload::ALL, Payload::name))]
    payload: Option<Payload>,
    #[arg(long)]
    json: bool,
}

#[derive(Args)]
pub struct StoreExtractArgs {
    store: PathBuf,
    /// FIELD/STEP/RANK of the model, or FIELD/STEP of a step with its index.
    entry: String,
    /// Output model file (`-`: standard output); for a step, a folder (made when missing).
    #[arg(short, long)]
    output: PathBuf,
    /// Payload of the output (default: the one it is stored with).
    #[arg(long, value_parser = one_of(&Payload::ALL, Payload::name))]
    payload: Option<Payload>,
}

#[derive(Args)]
pub struct StoreVerifyArgs {
    store: PathBuf,
    #[arg(long)]
    json: bool,
}

#[derive(Args)]
pub struct DecodeSeriesArgs {
    store: PathBuf,
    /// Output HDF5 file; the XDMF file is written beside it (same name, .xmf).
    #[arg(short, long)]
    output: PathBuf,
    /// Field to decode (needed when the store holds several).
    #[arg(long)]
    field: Option<String>,
    /// Lattice of each model: its reference dims times this factor.
    #[arg(long, default_value_t = 1.0)]
    scale: f64,
    /// Keep values normalised to [0, 1] instead of data units.
    #[arg(long)]
    normalized: bool,
    #[arg(long)]
    threads: Option<usize>,
    #[command(flatten)]
    device: crate::args::BackendArgs,
    #[command(flatten)]
    out: OutputFlags,
}

#[cfg(not(feature = "hdf5"))]
mod imp {
    use super::*;
    fn missing() -> Error {
        Error::arg("this gsenc was built without HDF5 support; rebuild with `cargo build --release --features hdf5` (needs libhdf5-dev)")
    }
    pub fn store(_: StoreCommand) -> Result<()> {
        Err(missing())
    }
    pub fn decode_series(_: DecodeSeriesArgs) -> Result<()> {
        Err(missing())
    }
    pub fn info(_: &Path, _: bool) -> Result<()> {
        Err(missing())
    }
}

#[cfg(feature = "hdf5")]
mod imp {
    use super::*;
    use crate::output::{print_result, write_output};
    use gsenc::threads::with_threads;
    use gsenc::format;
    use gsenc::format::step_index::StepIndex;
    use gsenc::io::{read_model_file, read_step_index};
    use gsenc::model::ModelMeta;
    use gsenc::io::series::{write_decoded_series, SeriesOptions};
    use gsenc::io::store::{EntryKey, Store, Verified};
    use serde_json::json;
    use std::collections::BTreeMap;
    use std::time::Instant;

    pub fn store(cmd: StoreCommand) -> Result<()> {
        match cmd {
            StoreCommand::Add(a) => add(a),
            StoreCommand::Extract(a) => extract(a),
            StoreCommand::Verify(a) => verify(a),
        }
    }

    /// `store verify`: [`Store::verify`]'s verdicts, as lines or JSON, and a
    /// Format error (exit 4) naming how many failed.
    fn verify(a: StoreVerifyArgs) -> Result<()> {
        let checked = Store::open_read(&a.store)?.verify()?;
        let verdict = |r: &Result<Verified>| match r {
            Ok(Verified::Checksum) => "ok (checksum)".to_owned(),
            Ok(Verified::NoChecksum) => "read, unchecked (no checksum: written before store layout 1.4)".to_owned(),
            Ok(Verified::StepIndex) => "ok (step index and the pieces it names)".to_owned(),
            Err(e) => format!("FAILED: {e}"),
        };
        let failed = checked.iter().filter(|(_, r)| r.is_err()).count();
        if a.json {
            let items: Vec<serde_json::Value> = checked
                .iter()
                .map(|(what, r)| match r {
                    Ok(v) => json!({ "item": what, "ok": true, "checksum": *v != Verified::NoChecksum }),
                    Err(e) => json!({ "item": what, "ok": false, "error": e.to_string() }),
                })
                .collect();
            println!("{}", json!({ "store": a.store, "items": items, "failed": failed }));
        } else {
            for (what, r) in &checked {
                println!("  {what:<32} {}", verdict(r));
            }
            println!("{}: {} items, {failed} failed", a.store.display(), checked.len());
        }
        if failed > 0 {
            return Err(Error::format(format!("{}: {failed} of {} items failed verification", a.store.display(), checked.len())));
        }
        Ok(())
    }

    /// What `args` names: model files, step indexes (`.gsi`) and folders
    /// (their `.gsm`, then their `.gsi` files, in name order), as the model
    /// files and the indexes.
    fn inputs(args: &[PathBuf]) -> Result<(Vec<PathBuf>, Vec<PathBuf>)> {
        let is = |p: &Path, ext: &str| p.extension().is_some_and(|x| x == ext);
        let (mut models, mut indexes) = (Vec::new(), Vec::new());
        for a in args {
            if !a.is_dir() {
                if is(a, "gsi") { indexes.push(a.clone()) } else { models.push(a.clone()) }
                continue;
            }
            let mut found: Vec<PathBuf> = std::fs::read_dir(a)
                .map_err(|e| Error::io(a, e))?
                .map(|e| e.map(|e| e.path()).map_err(|e| Error::io(a, e)))
                .collect::<Result<Vec<_>>>()?
                .into_iter()
                .filter(|p| p.is_file())
                .collect();
            found.sort();
            if !found.iter().any(|p| is(p, "gsm")) {
                return Err(Error::arg(format!("{}: a folder with no .gsm model file", a.display())));
            }
            models.extend(found.iter().filter(|p| is(p, "gsm")).cloned());
            indexes.extend(found.into_iter().filter(|p| is(p, "gsi")));
        }
        Ok((models, indexes))
    }

    /// Where a model file is, to tell two names of one file apart from two files.
    fn same_file(p: &Path) -> PathBuf {
        std::fs::canonicalize(p).unwrap_or_else(|_| p.to_path_buf())
    }

    /// Everything `store add` will write, checked before the store is
    /// touched: every model read (then let go, so that a run's folder of
    /// any size is added in the memory one model takes) with an entry of
    /// its own that the store does not hold, and every step index with a
    /// step the store has no index of, whose pieces are models being added
    /// or held, each the piece it names.
    struct Plan {
        models: Vec<PathBuf>,
        indexes: Vec<(PathBuf, StepIndex)>,
    }

    fn plan(store: &Path, args: &[PathBuf]) -> Result<Plan> {
        let (mut models, index_paths) = inputs(args)?;
        let held = if store.exists() { Some(Store::open_read(store)?) } else { None };
        // Every entry the store holds (also one cut short), and the
        // metadata of those it reads.
        let (mut held_keys, mut held_metas) = (std::collections::BTreeSet::new(), BTreeMap::new());
        for e in held.as_ref().map(|s| s.entries()).transpose()?.into_iter().flatten() {
            held_keys.insert(e.key.clone());
            if let Ok(info) = e.content {
                held_metas.insert(e.key, info.meta);
            }
        }
        let mut indexes = Vec::new();
        // The model files listed so far, each once (by where it is).
        let mut listed: std::collections::BTreeSet<PathBuf> = models.iter().map(|m| same_file(m)).collect();
        for p in index_paths {
            let index = read_step_index(&p)?;
            // The index's models, named relative to it, come with it,
            // unless the store holds them.
            let dir = p.parent().unwrap_or(Path::new("."));
            for piece in &index.pieces {
                let m = dir.join(&piece.model);
                let key = EntryKey { field: index.field.clone(), step: index.step, rank: piece.rank };
                if m.exists() && !held_keys.contains(&key) && listed.insert(same_file(&m)) {
                    models.push(m);
                }
            }
            indexes.push((p, index));
        }
        let mut metas: BTreeMap<EntryKey, (&Path, ModelMeta)> = BTreeMap::new();
        for p in &models {
            let meta = read_model_file(p)?.model.meta;
            let key = EntryKey::of(&meta);
            if held_keys.contains(&key) {
                return Err(Error::arg(format!("{}: the store holds {} already (steps are never rewritten)", p.display(), key.path())));
            }
            if let Some((other, _)) = metas.insert(key.clone(), (p.as_path(), meta)) {
                return Err(Error::arg(format!("{} and {} are both {}", other.display(), p.display(), key.path())));
            }
        }
        let mut steps = BTreeMap::new();
        for (p, index) in &indexes {
            let step = (index.field.clone(), index.step);
            if let Some(other) = steps.insert(step.clone(), p) {
                return Err(Error::arg(format!("{} and {} are both the index of /{}/{}", other.display(), p.display(), step.0, step.1)));
            }
            if held.as_ref().map(|s| s.step_index(&index.field, index.step)).transpose()?.flatten().is_some() {
                return Err(Error::arg(format!("{}: the store holds the index of /{}/{} already", p.display(), step.0, step.1)));
            }
            let mut pieces = Vec::with_capacity(index.pieces.len());
            for piece in &index.pieces {
                let key = EntryKey { field: index.field.clone(), step: index.step, rank: piece.rank };
                let meta = metas.get(&key).map(|(_, m)| m).or_else(|| held_metas.get(&key));
                pieces.push(meta.ok_or_else(|| {
                    Error::data(format!("{}: rank {}'s model ({}) is neither added nor in the store", p.display(), piece.rank, key.path()))
                })?);
            }
            index.check_piece_metas(&pieces).map_err(|e| e.in_context(&p.display().to_string()))?;
        }
        Ok(Plan { models, indexes })
    }

    fn add(a: StoreAddArgs) -> Result<()> {
        let payload = a.payload;
        let plan = plan(&a.store, &a.models)?;
        let mut store = Store::open_append(&a.store)?;
        let created = store.created();
        let (mut added, mut indexed) = (Vec::new(), Vec::new());
        let total = plan.models.len() + plan.indexes.len();
        // Each model read again (a file changed since it was checked fails
        // here), then the indexes.
        for path in &plan.models {
            let done = read_model_file(path).and_then(|f| {
                let chosen = payload.unwrap_or(f.payload);
                let mut model = f.model;
                if chosen != f.payload && chosen != Payload::Float32 {
                    model.meta.encode_psnr = None; // no longer the PSNR of what is stored
                }
                store.append(&model, chosen).map(|()| EntryKey::of(&model.meta).path())
            });
            match done {
                Ok(entry) => added.push(entry),
                Err(e) => return Err(cut_short(store, &a.store, created, path, &added, total, e)),
            }
        }
        for (path, index) in &plan.indexes {
            match store.append_step_index(index) {
                Ok(()) => indexed.push(format!("/{}/{}/index", index.field, index.step)),
                Err(e) => return Err(cut_short(store, &a.store, created, path, &added, total, e)),
            }
        }
        print_result(a.json, json!({ "store": a.store.display().to_string(), "added": added, "step_indexes": indexed }));
        Ok(())
    }

    /// An add that failed at `path`: what was added stays (and is named); a
    /// store this command created and could add nothing to (a full disk)
    /// is removed, while its lock is still held, so that no other writer
    /// can have opened it and added to it first.
    fn cut_short(store: Store, at: &Path, created: bool, path: &Path, added: &[String], total: usize, e: Error) -> Error {
        if added.is_empty() && created {
            let _ = std::fs::remove_file(at);
        }
        drop(store);
        eprintln!("gsenc store add: {} not added; {} of {} added before it: {added:?}", path.display(), added.len(), total);
        e
    }

    /// `FIELD/STEP/RANK`, also as `/FIELD/STEP/rank_RANK`.
    /// `FIELD/STEP/RANK` (also `/FIELD/STEP/rank_RANK`): an entry;
    /// `FIELD/STEP`: a step. Field names hold no '/'.
    fn parse_entry(s: &str) -> Result<(String, u64, Option<u32>)> {
        let bad = || Error::arg(format!("entry '{s}' is not FIELD/STEP/RANK (a model) or FIELD/STEP (a step with its index)"));
        let parts: Vec<&str> = s.trim_start_matches('/').split('/').collect();
        let (field, step, rank) = match parts[..] {
            [f, s] => (f, s, None),
            [f, s, r] => (f, s, Some(r)),
            _ => return Err(bad()),
        };
        let rank = rank.map(|r| r.strip_prefix("rank_").unwrap_or(r).parse().map_err(|_| bad())).transpose()?;
        Ok((field.to_owned(), step.parse().map_err(|_| bad())?, rank))
    }

    fn extract(a: StoreExtractArgs) -> Result<()> {
        let store = Store::open_read(&a.store)?;
        let (field, step, rank) = parse_entry(&a.entry)?;
        let Some(rank) = rank else { return extract_step(&store, &field, step, &a) };
        let (model, stored) = store.read(&EntryKey { field, step, rank })?;
        let payload = a.payload.unwrap_or(stored);
        write_output(&a.output, &format::write_model_as(&model, payload)?)
    }

    /// A step with its index, out to the folder `a.output` as the MPI
    /// encoder writes it: each rank's model file and the step index that
    /// names them, which `gsenc decode` reads as the global field.
    fn extract_step(store: &Store, field: &str, step: u64, a: &StoreExtractArgs) -> Result<()> {
        if a.output == Path::new("-") {
            return Err(Error::arg("a step is extracted to a folder (its index and each rank's model), not to standard output"));
        }
        let mut index = store
            .step_index(field, step)?
            .ok_or_else(|| Error::arg(format!("{} holds no step index of /{field}/{step}", a.store.display())))?;
        let pieces = store.pieces_of(&index)?;
        std::fs::create_dir_all(&a.output).map_err(|e| Error::io(&a.output, e))?;
        for (piece, (model, stored)) in index.pieces.iter_mut().zip(&pieces) {
            piece.model = format::model_file_name(field, step, piece.rank);
            let bytes = format::write_model_as(model, a.payload.unwrap_or(*stored))?;
            gsenc::io::write_atomic(a.output.join(&piece.model), &bytes)?;
        }
        // The index last: it names only models already written.
        gsenc::io::write_atomic(a.output.join(format::step_index_file_name(field, step)), index.to_json().as_bytes())
    }

    pub fn decode_series(a: DecodeSeriesArgs) -> Result<()> {
        let t = Instant::now();
        let store = Store::open_read(&a.store)?;
        let opts = SeriesOptions {
            field: a.field.as_deref(),
            scale: a.scale,
            normalized: a.normalized,
            slab_voxels: gsenc::model::DEFAULT_SLAB_VOXELS,
        };
        let mut backend = a.device.choice().open()?;
        let s = with_threads(a.threads, || write_decoded_series(&store, &a.output, &opts, backend.as_mut()))??;
        let seconds = t.elapsed().as_secs_f64();
        for (key, why) in &s.skipped {
            eprintln!("gsenc: skipped {}: {why}", key.path());
        }
        for (step, why) in &s.unblended {
            eprintln!("gsenc: step {step} decoded rank by rank, not blended by its index: {why}");
        }
        print_result(
            a.out.json,
            json!({
                "field": s.field,
                "grids": s.pieces.len(),
                "steps": s.pieces.iter().map(|p| p.key.step).collect::<std::collections::BTreeSet<_>>().len(),
                "skipped": s.skipped.len(),
                "global_steps": s.pieces.iter().filter(|p| p.global).count(),
                "unblended_steps": s.unblended.len(),
                "voxels": s.voxels,
                "seconds": seconds,
                "voxels_per_second": s.voxels as f64 / seconds.max(1e-9),
                "hdf5": a.output.display().to_string(),
                "xdmf": s.xdmf.display().to_string(),
            }),
        );
        Ok(())
    }

    pub fn info(path: &Path, json_out: bool) -> Result<()> {
        let store = Store::open_read(path)?;
        let entries = store.entries()?;
        let bytes = std::fs::metadata(path).map_err(|e| Error::io(path, e))?.len();
        let list: Vec<serde_json::Value> = entries
            .iter()
            .map(|e| match &e.content {
                Ok(i) => {
                    let mut entry = serde_json::Map::new();
                    entry.insert("entry".into(), json!(e.key.path()));
                    entry.insert("payload".into(), json!(i.payload.name()));
                    entry.insert("primitives".into(), json!(i.count));
                    entry.insert("stored_bytes".into(), json!(i.stored_bytes));
                    entry.extend(gsenc::format::info::metadata_info(&i.meta));
                    serde_json::Value::Object(entry)
                }
                Err(why) => json!({ "entry": e.key.path(), "error": why.to_string() }),
            })
            .collect();
        // The steps that hold a step index (1.3): their ranks blend into one field.
        let mut steps: Vec<(&str, u64)> = entries.iter().map(|e| (e.key.field.as_str(), e.key.step)).collect();
        steps.dedup();
        let mut indexed = Vec::new();
        for (field, step) in steps {
            if let Some(index) = store.step_index(field, step)? {
                indexed.push(json!({ "step": format!("/{field}/{step}"), "ranks": index.ranks, "halo": index.halo, "dims": index.dims }));
            }
        }
        if json_out {
            println!("{}", json!({ "format": "gsenc HDF5 store", "bytes": bytes, "entries": list, "step_indexes": indexed }));
            return Ok(());
        }
        println!("{}: gsenc HDF5 store, {} entries, {bytes} bytes", path.display(), entries.len());
        for i in &indexed {
            println!("  {:<32} step index: {} ranks, halo {}, global dims {}", i["step"].as_str().unwrap_or(""), i["ranks"], i["halo"], i["dims"]);
        }
        for e in &entries {
            match &e.content {
                Ok(i) => println!(
                    "  {:<32} {:>9} primitives  {:<8} time {:<12} psnr {}",
                    e.key.path(),
                    i.count,
                    i.payload.name(),
                    i.meta.time.map_or("-".into(), |t| format!("{t}")),
                    i.meta.encode_psnr.map_or("-".into(), |p| format!("{p:.2} dB")),
                ),
                Err(why) => println!("  {:<32} unreadable: {why}", e.key.path()),
            }
        }
        Ok(())
    }
}

pub use imp::{decode_series, info, store};
