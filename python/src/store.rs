//! `gsenc.open_store`: an HDF5 store's entries (field, step, rank), and
//! `gsenc.read` of one of them. The file is opened for each call and
//! closed again, so that a writer (a running simulation) is never held up
//! by a reader left open in a notebook.

use crate::errors::IntoPy;
use crate::model::{in_memory, of_step, Model};
use gsenc::domain::global::GlobalField;
use gsenc::io::store::{EntryKey, Store as H5Store, Verified};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::path::{Path, PathBuf};

/// An HDF5 store of models, as listed when it was opened.
#[pyclass(module = "gsenc", frozen)]
pub struct Store {
    path: PathBuf,
    /// Key and, for a readable entry, what `entries` says of it; else why not.
    entries: Vec<(EntryKey, Result<Listed, String>)>,
}

/// What the listing keeps of a readable entry.
struct Listed {
    payload: String,
    count: u64,
    stored_bytes: u64,
    /// The simulation time the model carries, if any.
    time: Option<f64>,
}

/// Opens an HDF5 store and lists its entries.
#[pyfunction]
pub fn open_store(py: Python<'_>, path: PathBuf) -> PyResult<Store> {
    let entries = py
        .detach(|| -> gsenc::Result<_> {
            let store = H5Store::open_read(&path)?;
            let listed = |i: gsenc::io::store::EntryInfo| Listed {
                payload: i.payload.name().to_string(),
                count: i.count,
                stored_bytes: i.stored_bytes,
                time: i.meta.time,
            };
            Ok(store.entries()?.into_iter().map(|e| (e.key, e.content.map(listed).map_err(|e| e.to_string()))).collect())
        })
        .py_err()?;
    Ok(Store { path, entries })
}

/// What `read` reads: one entry, or every rank of a step.
enum Chosen {
    Entry(EntryKey),
    Step(String, u64),
}

/// The entry of `path` that `field`, `step` and `rank` name; any of them may
/// be left out where the store holds only one choice. Without a rank, a
/// step of several ranks is the step (read by its index).
fn choose(entries: &[EntryKey], path: &Path, field: Option<&str>, step: Option<u64>, rank: Option<u32>) -> PyResult<Chosen> {
    let matching: Vec<&EntryKey> =
        entries.iter().filter(|k| field.is_none_or(|f| k.field == f) && step.is_none_or(|s| k.step == s) && rank.is_none_or(|r| k.rank == r)).collect();
    match matching.as_slice() {
        [one] => Ok(Chosen::Entry((*one).clone())),
        [first, rest @ ..] if rank.is_none() && rest.iter().all(|k| k.field == first.field && k.step == first.step) => {
            Ok(Chosen::Step(first.field.clone(), first.step))
        }
        [] => Err(PyValueError::new_err(format!(
            "{} holds no entry with field {field:?}, step {step:?}, rank {rank:?} (open_store lists them)",
            path.display()
        ))),
        many => Err(PyValueError::new_err(format!(
            "{} holds {} entries with field {field:?}, step {step:?}, rank {rank:?}: give field, step and rank (open_store lists them)",
            path.display(),
            many.len()
        ))),
    }
}

/// `gsenc.read` of a store entry: the store is listed to find it.
pub fn read_entry(py: Python<'_>, path: &Path, field: Option<String>, step: Option<u64>, rank: Option<u32>) -> PyResult<Model> {
    py.detach(|| -> PyResult<Model> {
        let store = H5Store::open_read(path).py_err()?;
        let keys: Vec<EntryKey> = store.entries().py_err()?.into_iter().map(|e| e.key).collect();
        let chosen = choose(&keys, path, field.as_deref(), step, rank)?;
        read_chosen(&store, chosen)
    })
}

/// An entry's model, or a step's global field: its ranks' models blended
/// by the step's index (layout 1.3).
fn read_chosen(store: &H5Store, chosen: Chosen) -> PyResult<Model> {
    match chosen {
        Chosen::Entry(key) => {
            let (model, payload) = store.read(&key).py_err()?;
            let psnr = model.meta.encode_psnr;
            Ok(in_memory(model, payload, psnr, "gsenc store entry"))
        }
        Chosen::Step(field, step) => {
            let Some(index) = store.step_index(&field, step).py_err()? else {
                return Err(PyValueError::new_err(format!(
                    "{}: /{field}/{step} holds several ranks and no step index to blend them (store add the run's .gsi files): give rank",
                    store.path().display()
                )));
            };
            let pieces = store.pieces_of(&index).py_err()?.into_iter().map(|(m, _)| m).collect();
            of_step(GlobalField::of_step(index, pieces).py_err()?).py_err()
        }
    }
}

#[pymethods]
impl Store {
    /// Every entry: field, step, rank, payload, primitives, bytes and time
    /// (the simulation time, None when the model carries none), or the
    /// error that makes it unreadable (an append cut short).
    #[getter]
    fn entries<'py>(&self, py: Python<'py>) -> PyResult<Vec<Bound<'py, PyDict>>> {
        self.entries
            .iter()
            .map(|(k, content)| {
                let d = PyDict::new(py);
                d.set_item("field", &k.field)?;
                d.set_item("step", k.step)?;
                d.set_item("rank", k.rank)?;
                match content {
                    Ok(l) => {
                        d.set_item("payload", &l.payload)?;
                        d.set_item("primitives", l.count)?;
                        d.set_item("bytes", l.stored_bytes)?;
                        d.set_item("time", l.time)?;
                    }
                    Err(why) => d.set_item("error", why)?,
                }
                Ok(d)
            })
            .collect()
    }

    /// The fields, sorted.
    fn fields(&self) -> Vec<String> {
        let mut f: Vec<String> = self.entries.iter().map(|(k, _)| k.field.clone()).collect();
        f.dedup();
        f
    }

    /// The steps of `field`, ascending.
    fn steps(&self, field: &str) -> Vec<u64> {
        let mut s: Vec<u64> = self.entries.iter().filter(|(k, _)| k.field == field).map(|(k, _)| k.step).collect();
        s.dedup();
        s
    }

    /// The ranks of `field` at `step`, ascending.
    fn ranks(&self, field: &str, step: u64) -> Vec<u32> {
        self.entries.iter().filter(|(k, _)| k.field == field && k.step == step).map(|(k, _)| k.rank).collect()
    }

    /// Reads one entry (see `gsenc.read`), chosen from this listing: only
    /// that entry is read, however many the store holds.
    #[pyo3(signature = (field=None, step=None, rank=None))]
    fn read(&self, py: Python<'_>, field: Option<String>, step: Option<u64>, rank: Option<u32>) -> PyResult<Model> {
        let keys: Vec<EntryKey> = self.entries.iter().map(|(k, _)| k.clone()).collect();
        let chosen = choose(&keys, &self.path, field.as_deref(), step, rank)?;
        py.detach(|| read_chosen(&H5Store::open_read(&self.path).py_err()?, chosen))
    }

    /// Reads and checks every entry and step index of the store as it is
    /// now (`gsenc store verify`): a list of dicts, each with `item` (its
    /// path in the store), `ok`, and `checksum` (whether its checksum was
    /// checked: False for an entry written before store layout 1.4) or
    /// `error` (why it failed).
    fn verify<'py>(&self, py: Python<'py>) -> PyResult<Vec<Bound<'py, PyDict>>> {
        let checked = py.detach(|| H5Store::open_read(&self.path)?.verify()).py_err()?;
        checked
            .into_iter()
            .map(|(item, verdict)| {
                let d = PyDict::new(py);
                d.set_item("item", item)?;
                d.set_item("ok", verdict.is_ok())?;
                match verdict {
                    Ok(v) => d.set_item("checksum", v != Verified::NoChecksum)?,
                    Err(e) => d.set_item("error", e.to_string())?,
                }
                Ok(d)
            })
            .collect()
    }

    #[getter]
    fn path(&self) -> PathBuf {
        self.path.clone()
    }

    fn __len__(&self) -> usize {
        self.entries.len()
    }

    fn __repr__(&self) -> String {
        format!("<gsenc.Store {}: {} entries of fields {:?}>", self.path.display(), self.entries.len(), self.fields())
    }
}
