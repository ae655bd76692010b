//! The HDF5 store (cargo feature `hdf5`): one file holding a time series of
//! models of many fields and ranks, laid out `/<field>/<step>/rank_<r>` with
//! the decoding metadata as attributes and the parameters as plain datasets,
//! so that h5py or h5dump read it without gsenc. `docs/FORMAT.md` ("The HDF5
//! store") is the reference. This file is the store around its entries
//! (creating, appending, committing, listing, reading, verifying);
//! `entry.rs` lays out one entry, written and read side by side, with its
//! checksum.
//!
//! Appends are made so that killing the writer mid-append leaves every
//! earlier step readable:
//! - the file is created under a temporary name and renamed, so a store
//!   exists only once its root is complete;
//! - file space is never reused (strategy "none"), so a new step's data never
//!   lands on bytes that an earlier step's metadata still points to;
//! - a new entry is built unlinked and flushed; then one link, into a group
//!   whose header was sized for it, commits it, and a second flush writes it;
//! - the metadata cache does not evict while an append builds and commits
//!   its entry, so nothing reaches the file between those points. Between
//!   appends, when every entry is clean, it may: a cache that never
//!   evicted kept every entry ever written, about 35 KB of memory an entry,
//!   and each flush walked them all (docs/BENCHMARKS.md "A long series'
//!   HDF5 store").
//!
//! `tests/store_crash.rs` kills writers at many points and checks every
//! earlier step.

mod entry;
pub(crate) mod host_errors;

pub use entry::PARAMETER_NAMES;
use entry::{entry_crc, read_all, read_info, read_params, read_support, scalar_attr, scalar_str_attr, utf8, write_entry, CRC};

use crate::error::{Error, Result};
use crate::format::Payload;
use crate::io::atomic::Replacement;
use crate::format::check_field_name;
use crate::math::kernel::Primitive;
use crate::model::{Model, ModelMeta};
use crate::format::step_index::StepIndex;
use hdf5::plist::file_access::{CacheDecreaseMode, CacheIncreaseMode, FlashIncreaseMode, MetadataCacheConfig};
use hdf5::plist::file_create::FileSpaceStrategy;
use hdf5::types::VarLenUnicode;
use hdf5::{File, Group, Location};
use host_errors::quiet;
use std::mem::ManuallyDrop;
use std::path::{Path, PathBuf};

/// What [`Store::verify`] found sound.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Verified {
    /// An entry, read whole, whose checksum held (layout 1.4).
    Checksum,
    /// An entry, read whole, that has no checksum (written before 1.4):
    /// what was read could not be checked against what was written.
    NoChecksum,
    /// A step index (its Fletcher-32 held) with every piece it names.
    StepIndex,
}

/// Layout version of the store, in the root attribute `gsenc_store`.
/// 1.1 adds the optional `support` dataset of an entry, 1.2 its optional
/// `outside` attribute, 1.3 the optional `index` dataset of a step, 1.4 an
/// entry's `crc32` attribute (`entry_crc`), 1.5 an entry's optional
/// `target_curve` attribute (a target PSNR's curve, in the checksum).
pub const STORE_VERSION: &str = "1.5";
/// The step index of a decomposed step, in the step's group (1.3).
const INDEX: &str = "index";

/// Where one model lives in a store.
#[derive(Clone, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub struct EntryKey {
    pub field: String,
    pub step: u64,
    pub rank: u32,
}

impl EntryKey {
    pub fn of(meta: &ModelMeta) -> EntryKey {
        EntryKey { field: meta.field.clone(), step: meta.step, rank: meta.rank }
    }

    /// `/<field>/<step>/rank_<r>`.
    pub fn path(&self) -> String {
        format!("/{}/{}/rank_{}", self.field, self.step, self.rank)
    }
}

/// One model of a store as listed by [`Store::entries`]: its key, and either
/// its metadata or why it cannot be read (an append that was cut short).
#[derive(Debug)]
pub struct Entry {
    pub key: EntryKey,
    pub content: Result<EntryInfo>,
}

#[derive(Clone, Debug, PartialEq)]
pub struct EntryInfo {
    pub meta: ModelMeta,
    pub payload: Payload,
    pub count: u64,
    /// Bytes the entry's datasets take in the file.
    pub stored_bytes: u64,
}

/// An open store. Opened for append, it holds HDF5's lock on the file: other
/// processes can read it once the writer has dropped it (or with HDF5's file
/// locking turned off, `HDF5_USE_FILE_LOCKING=FALSE`, as of the last append).
/// Every call that reaches HDF5, closing the file included, turns HDF5's
/// error printing off while it runs and sets it back as the host had it
/// (`host_errors.rs`).
pub struct Store {
    file: ManuallyDrop<File>,
    path: PathBuf,
    /// Whether opening it made the file ([`Store::created`]).
    created: bool,
}

impl Drop for Store {
    fn drop(&mut self) {
        let _quiet = quiet();
        // SAFETY: dropped once, here; not used after.
        unsafe { ManuallyDrop::drop(&mut self.file) }
    }
}

fn h5(path: &Path) -> impl Fn(hdf5::Error) -> Error + '_ {
    move |e| Error::Hdf5 { path: path.display().to_string(), message: e.to_string() }
}

impl Store {
    /// Opens a store to append to, creating it when `path` does not exist.
    pub fn open_append(path: impl AsRef<Path>) -> Result<Store> {
        let _quiet = quiet();
        let path = path.as_ref().to_path_buf();
        let created = !path.exists() && create_empty(&path)?;
        regular_file(&path)?;
        super::global_heap::check(&path)?;
        let file = File::with_options()
            .with_fapl(|p| p.mdc_config(&fixed_size_cache()).libver_v18())
            .open_rw(&path)
            .map_err(h5(&path))?;
        check_root(&file, &path)?;
        Ok(Store { file: ManuallyDrop::new(file), path, created })
    }

    /// Whether [`Store::open_append`] made the file (it was not there, and
    /// no other writer made it first): a writer that then adds nothing to
    /// it may remove it.
    pub fn created(&self) -> bool {
        self.created
    }

    /// Opens an existing store for reading.
    pub fn open_read(path: impl AsRef<Path>) -> Result<Store> {
        let _quiet = quiet();
        let path = path.as_ref().to_path_buf();
        if !path.exists() {
            return Err(Error::io(&path, std::io::Error::from(std::io::ErrorKind::NotFound)));
        }
        regular_file(&path)?;
        if !super::hdf5_signature(&path).map_err(|e| Error::io(&path, e))? {
            return Err(Error::format(format!("'{}' is not an HDF5 file", path.display())));
        }
        super::global_heap::check(&path)?;
        let file = File::open(&path).map_err(h5(&path))?;
        check_root(&file, &path)?;
        Ok(Store { file: ManuallyDrop::new(file), path, created: false })
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The bytes and entries HDF5's metadata cache holds for this store
    /// now: about [`CACHE_BYTES`] at most between appends, whatever the
    /// number of entries written (`tests/store.rs`).
    pub fn cache_size(&self) -> (usize, usize) {
        let _quiet = quiet();
        let (mut max, mut min_clean, mut cur, mut n) = (0, 0, 0, 0);
        // SAFETY: an open file's id and four writable counters.
        hdf5::sync::sync(|| unsafe { hdf5_sys::h5f::H5Fget_mdc_size(self.file.id(), &mut max, &mut min_clean, &mut cur, &mut n) });
        (cur, n.max(0) as usize)
    }

    /// Appends `model` as `/<field>/<step>/rank_<r>` with `payload`.
    /// Earlier steps are never rewritten: where the entry exists already,
    /// the append changes nothing, and succeeds when the entry holds what
    /// it would have stored (a run restarted from an earlier step stores
    /// its next steps again, the same models where the simulation repeats
    /// itself) and fails otherwise. The entry (and a new step or field
    /// group above it) is built unlinked and flushed first; one link then
    /// commits it, and a second flush writes that link (see the module
    /// documentation).
    pub fn append(&mut self, model: &Model, payload: Payload) -> Result<()> {
        let _quiet = quiet();
        let key = EntryKey::of(&model.meta);
        check_field_name(&key.field)?;
        // Coded once, refusing unstorable parameters before the file is touched.
        let coded = payload.coded(model)?;
        let params = coded.params()?;
        let rank_name = format!("rank_{}", key.rank);
        let groups = self.groups(&key.field, key.step)?;
        if groups.1.as_ref().is_some_and(|s| s.link_exists(&rank_name)) {
            return match self.holds(&key, model, payload, &params)? {
                true => Ok(()),
                false => Err(Error::arg(format!("{} already holds a model, another than this one; a store never rewrites a step", key.path()))),
            };
        }
        self.unevicted(|s| {
            // Everything new, unlinked: nothing existing changes until the commit.
            let entry = anonymous_group(&s.file, 0).map_err(h5(&s.path))?;
            write_entry(&entry, model, &coded, &params).map_err(h5(&s.path))?;
            s.commit(groups, &key.field, key.step, model.meta.time, &rank_name, &entry)
        })
    }

    /// Appends the step index of a decomposed step (the `.gsi` of an MPI
    /// run) as `/<field>/<step>/index` (1.3), so that the store gives the
    /// step's global field ([`Store::read_step`]). Its pieces name their
    /// models by entry (`rank_<r>`), which may be appended before or after
    /// it. Refuses a step that has an index, as [`Store::append`] refuses
    /// an entry that exists.
    pub fn append_step_index(&mut self, index: &StepIndex) -> Result<()> {
        let _quiet = quiet();
        check_field_name(&index.field)?;
        let mut stored = index.clone();
        for p in &mut stored.pieces {
            p.model = format!("rank_{}", p.rank);
        }
        let text = stored.to_json();
        let groups = self.groups(&index.field, index.step)?;
        if groups.1.as_ref().is_some_and(|s| s.link_exists(INDEX)) {
            // The same index again (a restarted run's) changes nothing.
            if self.step_index(&index.field, index.step)?.is_some_and(|held| held.to_json() == text) {
                return Ok(());
            }
            return Err(Error::arg(format!("/{}/{} already holds a step index, another than this one; a store never rewrites a step", index.field, index.step)));
        }
        self.unevicted(|s| {
            // With HDF5's Fletcher-32 checksum: a changed byte of an index
            // would otherwise blend the step otherwise, unseen.
            let ds = s.file.new_dataset::<u8>().shape(text.len()).chunk(text.len()).fletcher32().create(None).map_err(h5(&s.path))?;
            ds.write_raw(text.as_bytes()).map_err(h5(&s.path))?;
            s.commit(groups, &index.field, index.step, index.time, INDEX, &ds)
        })
    }

    /// Whether the entry `key` holds `model` as appending it with `payload`
    /// would store it (`params`: its parameters as read back): the same
    /// payload, parameters and support, and the same metadata as a reader
    /// gets it (compared through the entry's checksum of it).
    fn holds(&self, key: &EntryKey, model: &Model, payload: Payload, params: &[Primitive]) -> Result<bool> {
        let (held, held_payload) = self.read(key)?;
        Ok(held_payload == payload
            && held.params == params
            && held.support == model.support
            && entry_crc(&held.meta, payload, &held.params, held.support.as_ref())? == entry_crc(&model.meta, payload, params, model.support.as_ref())?)
    }

    /// Runs `append` (the building and commit of an entry) with the
    /// metadata cache's evictions off, so that nothing reaches the file but
    /// by the commit's flushes, then turns them on again, also when
    /// `append` failed: the cache then holds only clean entries, or the
    /// dirty ones of an entry left unlinked, whose writing changes nothing
    /// that exists. The cache is made a page larger while evictions are off
    /// and given back its size with them: a cache whose size decreased is
    /// brought within it at the next lookup (HDF5's `H5C_protect`), the
    /// next append's, so it never holds much more than [`CACHE_BYTES`].
    /// Evictions turned on alone evict nothing until the cache misses, and
    /// the lookups of an append hit.
    fn unevicted(&mut self, append: impl FnOnce(&mut Self) -> Result<()>) -> Result<()> {
        self.set_cache(false, CACHE_BYTES + 4096)?;
        let done = append(self);
        let on = self.set_cache(true, CACHE_BYTES);
        done.and(on)
    }

    /// Sets whether the metadata cache may evict, and its size.
    fn set_cache(&self, evictions: bool, bytes: usize) -> Result<()> {
        let id = self.file.id();
        // SAFETY: an open file's id and a configuration of the version the
        // library is asked for, filled by the library.
        let ok = hdf5::sync::sync(|| unsafe {
            let mut c = hdf5_sys::h5ac::H5AC_cache_config_t { version: hdf5_sys::h5ac::H5AC__CURR_CACHE_CONFIG_VERSION, ..Default::default() };
            hdf5_sys::h5f::H5Fget_mdc_config(id, &mut c) >= 0 && {
                c.evictions_enabled = evictions as _;
                c.set_initial_size = true as _;
                c.initial_size = bytes;
                hdf5_sys::h5f::H5Fset_mdc_config(id, &mut c) >= 0
            }
        });
        if ok {
            Ok(())
        } else {
            let what = if evictions { "turn the metadata cache's evictions on" } else { "turn the metadata cache's evictions off" };
            Err(Error::Hdf5 { path: self.path.display().to_string(), message: format!("cannot {what}") })
        }
    }

    /// The groups of `field` and of its `step`, where they exist.
    fn groups(&self, field: &str, step: u64) -> Result<(Option<Group>, Option<Group>)> {
        let err = h5(&self.path);
        let step_name = step.to_string();
        let fg = self.file.link_exists(field).then(|| self.file.group(field)).transpose().map_err(&err)?;
        let sg = match &fg {
            Some(f) if f.link_exists(&step_name) => Some(f.group(&step_name).map_err(&err)?),
            _ => None,
        };
        Ok((fg, sg))
    }

    /// Commits `child`, new and unlinked, as `name` in the group of `step`
    /// of `field` (whose groups `groups` are, where they exist): a missing
    /// step (and field) group is built unlinked around it, everything is
    /// flushed, then one link into what exists commits it, and a second
    /// flush writes that link.
    fn commit(&mut self, groups: (Option<Group>, Option<Group>), field: &str, step: u64, time: Option<f64>, name: &str, child: &Location) -> Result<()> {
        let err = h5(&self.path);
        let step_name = step.to_string();
        let (parent, name, top): (Group, String, Location) = match groups {
            (Some(_), Some(step)) => (step, name.to_string(), child.clone()),
            (field_group, None) => {
                let new_step = anonymous_group(&self.file, RANKS_PER_STEP).map_err(&err)?;
                scalar_attr(&new_step, "step", &step).map_err(&err)?;
                scalar_attr(&new_step, "time", &time.unwrap_or(f64::NAN)).map_err(&err)?;
                link(child, &new_step, name).map_err(&err)?;
                match field_group {
                    Some(f) => (f, step_name, (*new_step).clone()),
                    None => {
                        let new_field = anonymous_group(&self.file, STEPS_PER_FIELD).map_err(&err)?;
                        link(&new_step, &new_field, &step_name).map_err(&err)?;
                        ((**self.file).clone(), field.to_string(), (*new_field).clone())
                    }
                }
            }
            (None, Some(_)) => unreachable!("a step exists only inside its field"),
        };
        self.file.flush().map_err(&err)?;
        link(&top, &parent, &name).map_err(&err)?;
        self.file.flush().map_err(&err)?;
        Ok(())
    }

    /// Every entry, sorted by field, step and rank. An entry that cannot be
    /// read is listed with its error (a step whose whole group is unreadable,
    /// as its rank 0); the others are unaffected.
    pub fn entries(&self) -> Result<Vec<Entry>> {
        let _quiet = quiet();
        let err = h5(&self.path);
        // One share of the memory for the whole listing: asking it costs
        // tens of microseconds, and a store may hold thousands of entries.
        let budget = super::budget::whole_read_budget(1)?;
        let mut out = Vec::new();
        for field in self.file.member_names().map_err(&err)? {
            let Ok(fg) = self.file.group(&field) else { continue };
            for step_name in fg.member_names().map_err(&err)? {
                let Ok(step) = step_name.parse::<u64>() else { continue };
                let sg = match fg.group(&step_name) {
                    Ok(g) => g,
                    Err(e) => {
                        // A step whose own group cannot be opened (an append
                        // cut short) is listed once, as rank 0, with why.
                        let key = EntryKey { field: field.clone(), step, rank: 0 };
                        let why = format!("{}: group /{field}/{step} is unreadable ({e}); an append cut short", self.path.display());
                        out.push(Entry { key, content: Err(Error::Format(why)) });
                        continue;
                    }
                };
                for rank_name in sg.member_names().map_err(&err)? {
                    let Some(rank) = rank_name.strip_prefix("rank_").and_then(|r| r.parse::<u32>().ok()) else { continue };
                    let key = EntryKey { field: field.clone(), step, rank };
                    let content = sg.group(&rank_name).map_err(&err).and_then(|g| read_info(&g, &key, &self.path, budget));
                    out.push(Entry { key, content });
                }
            }
        }
        out.sort_by(|a, b| a.key.cmp(&b.key));
        Ok(out)
    }

    /// Reads one model and the payload it was stored with.
    pub fn read(&self, key: &EntryKey) -> Result<(Model, Payload)> {
        let _quiet = quiet();
        let g = self.entry_group(key)?;
        let budget = super::budget::whole_read_budget(1)?;
        let info = read_info(&g, key, &self.path, budget)?;
        let params = read_params(&g, &info, &self.path, budget)?;
        let support = read_support(&g, &info, &self.path, budget)?;
        // 1.4: the entry as read against its checksum (older entries have none).
        if let Ok(a) = g.attr(CRC) {
            let at = format!("{}:{}", self.path.display(), key.path());
            let want = a.read_scalar::<u32>().map_err(|e| Error::format(format!("{at} attribute {CRC}: {e}")))?;
            let got = entry_crc(&info.meta, info.payload, &params, support.as_ref())?;
            if got != want {
                return Err(Error::format(format!("{at} fails its checksum (its {CRC} is {want:08x}, its content gives {got:08x}): it changed after it was written")));
            }
        }
        Ok((Model { meta: info.meta, params, support }, info.payload))
    }

    fn entry_group(&self, key: &EntryKey) -> Result<Group> {
        self.file.group(&key.path()).map_err(|_| Error::arg(format!("{} holds no model {}", self.path.display(), key.path())))
    }

    /// The step index of `/<field>/<step>`, where the step has one (1.3).
    pub fn step_index(&self, field: &str, step: u64) -> Result<Option<StepIndex>> {
        let _quiet = quiet();
        let Some(sg) = self.groups(field, step)?.1 else { return Ok(None) };
        if !sg.link_exists(INDEX) {
            return Ok(None);
        }
        let at = format!("{}:/{field}/{step}/{INDEX}", self.path.display());
        let bad = |what: String| Error::format(format!("{at} {what}"));
        let ds = sg.dataset(INDEX).map_err(|e| bad(format!("is not a dataset ({e})")))?;
        let bytes: Vec<u8> = read_all(&ds, "dataset index", super::budget::whole_read_budget(1)?, &bad)?;
        let text = String::from_utf8(bytes).map_err(|_| bad("is not a step index (not UTF-8 text)".into()))?;
        let index = StepIndex::from_json(&text).map_err(|e| e.in_context(&at))?;
        if index.field != field || index.step != step {
            return Err(bad(format!("is the index of field '{}' step {}", index.field, index.step)));
        }
        Ok(Some(index))
    }

    /// A decomposed step's index and its pieces, each rank's model, in rank
    /// order, each checked to be the piece the index names (as a `.gsi`
    /// and its model files are read).
    pub fn read_step(&self, field: &str, step: u64) -> Result<(StepIndex, Vec<Model>)> {
        let _quiet = quiet();
        let index = self
            .step_index(field, step)?
            .ok_or_else(|| Error::arg(format!("{} holds no step index of /{field}/{step} (a step of one rank's model, or its index was not added)", self.path.display())))?;
        let models = self.pieces_of(&index)?.into_iter().map(|(m, _)| m).collect();
        Ok((index, models))
    }

    /// Reads every entry and every step index, as a reader would, and says
    /// of each (by its path in the store, in the listing's order, the step
    /// indexes last) what held or why it failed: an archive's check
    /// (`gsenc store verify`). Fails only when the store cannot be listed.
    pub fn verify(&self) -> Result<Vec<(String, Result<Verified>)>> {
        let _quiet = quiet();
        let entries = self.entries()?;
        let mut steps: Vec<(String, u64)> = entries.iter().map(|e| (e.key.field.clone(), e.key.step)).collect();
        steps.dedup();
        let mut out = Vec::with_capacity(entries.len() + steps.len());
        for e in entries {
            let checked = e.content.and_then(|_| {
                self.read(&e.key)?;
                let summed = self.entry_group(&e.key)?.attr(CRC).is_ok();
                Ok(if summed { Verified::Checksum } else { Verified::NoChecksum })
            });
            out.push((e.key.path(), checked));
        }
        for (field, step) in steps {
            let checked = match self.step_index(&field, step) {
                Ok(None) => continue,
                Ok(Some(_)) => self.read_step(&field, step).map(|_| Verified::StepIndex),
                Err(e) => Err(e),
            };
            out.push((format!("/{field}/{step}/{INDEX}"), checked));
        }
        Ok(out)
    }

    /// The pieces `index` (this store's index of its step) names, each
    /// rank's model with its payload, in rank order, each checked to be the
    /// piece the index names.
    pub fn pieces_of(&self, index: &StepIndex) -> Result<Vec<(Model, Payload)>> {
        let _quiet = quiet();
        let (field, step) = (&index.field, index.step);
        let sg = self.groups(field, step)?.1;
        let mut pieces = Vec::with_capacity(index.pieces.len());
        for p in &index.pieces {
            let key = EntryKey { field: field.clone(), step, rank: p.rank };
            if sg.as_ref().is_none_or(|sg| !sg.link_exists(&format!("rank_{}", p.rank))) {
                return Err(Error::data(format!(
                    "the step index of /{field}/{step} names rank {}, whose model {} the store does not hold (an MPI run writes a step's index at its push: the step was cancelled, failed on that rank, or the run stopped before it was stored)",
                    p.rank,
                    key.path()
                )));
            }
            pieces.push(self.read(&key)?);
        }
        index.check_piece_metas(&pieces.iter().map(|(m, _)| &m.meta).collect::<Vec<_>>())?;
        Ok(pieces)
    }
}

/// The metadata cache's size between appends (HDF5's default).
pub const CACHE_BYTES: usize = 1 << 21;

/// A metadata cache of a fixed size, [`CACHE_BYTES`]: automatic resizing
/// off, which HDF5 requires of a cache whose evictions are turned off
/// ([`Store::unevicted`]).
fn fixed_size_cache() -> MetadataCacheConfig {
    MetadataCacheConfig {
        set_initial_size: true,
        initial_size: CACHE_BYTES,
        incr_mode: CacheIncreaseMode::Off,
        flash_incr_mode: FlashIncreaseMode::Off,
        decr_mode: CacheDecreaseMode::Off,
        ..MetadataCacheConfig::default()
    }
}

/// A store is a regular file: HDF5 would wait for ever reading a named pipe.
fn regular_file(path: &Path) -> Result<()> {
    match std::fs::metadata(path) {
        Ok(m) if !m.is_file() => Err(Error::arg(format!("'{}' is not a regular file, so not a store", path.display()))),
        _ => Ok(()),
    }
}

/// Makes an empty store at `path`, unless another writer made a file
/// there first (two processes appending to a store that is not yet there):
/// then that file is left as it is, to be opened (and locked) as any
/// store. Whether it made the file.
fn create_empty(path: &Path) -> Result<bool> {
    let out = Replacement::new(path)?;
    let made = (|| -> hdf5::Result<()> {
        let f = File::with_options()
            .with_fapl(|p| p.libver_v18())
            .with_fcpl(|p| p.file_space_strategy(FileSpaceStrategy::None))
            .create_excl(&out.tmp)?;
        scalar_str_attr(&f, "gsenc_store", STORE_VERSION)?;
        scalar_str_attr(&f, "creator", &format!("gsenc {}", crate::VERSION))?;
        f.close()
    })();
    if let Err(e) = made {
        out.discard();
        return Err(h5(path)(e));
    }
    out.commit_new()
}

fn check_root(file: &File, path: &Path) -> Result<()> {
    let version: String = file
        .attr("gsenc_store")
        .and_then(|a| a.read_scalar::<VarLenUnicode>())
        .map_err(|_| Error::format(format!("'{}' is an HDF5 file but not a gsenc store (no gsenc_store attribute)", path.display())))
        .and_then(|v| utf8(&v).ok_or_else(|| Error::format(format!("'{}': its gsenc_store attribute is not UTF-8 text", path.display()))))?;
    let major = version.split('.').next().and_then(|m| m.parse::<u32>().ok());
    match major {
        Some(1) => Ok(()),
        Some(m) if m > 1 => Err(Error::Version(format!("store layout {version} is newer than this gsenc reads (1.x); upgrade gsenc"))),
        _ => Err(Error::format(format!("store layout version '{version}' is not one gsenc wrote"))),
    }
}

/// Links a group the file sees as compact: new-style groups keep their
/// links in their object header, sized at creation for this many links, so
/// that linking one more rewrites that header in place and allocates nothing.
const STEPS_PER_FIELD: usize = 4096;
const RANKS_PER_STEP: usize = 256;

/// A new group linked nowhere, with room for `links` links in its header.
fn anonymous_group(file: &File, links: usize) -> hdf5::Result<Group> {
    let gcpl = hdf5::plist::GroupCreate::try_new()?;
    if links > 0 {
        let max_compact = u32::try_from(links).unwrap_or(u32::MAX);
        // SAFETY: a valid group-creation property list.
        let ok = hdf5::sync::sync(|| unsafe {
            hdf5_sys::h5p::H5Pset_link_phase_change(gcpl.id(), max_compact, max_compact.saturating_sub(1).max(1)) >= 0
                && hdf5_sys::h5p::H5Pset_est_link_info(gcpl.id(), max_compact, 12) >= 0
        });
        if !ok {
            return Err("cannot size a group's link storage".into());
        }
    }
    file.create_group_builder().set_gcpl(&gcpl).create(None)
}

/// Links `obj` into `parent` as `name`: the one change an append makes to
/// objects that already exist.
fn link(obj: &Location, parent: &Group, name: &str) -> hdf5::Result<()> {
    let cname = std::ffi::CString::new(name).map_err(|_| hdf5::Error::from("a name holds NUL"))?;
    // SAFETY: valid object and location ids, a NUL-terminated name.
    let status = hdf5::sync::sync(|| unsafe {
        hdf5_sys::h5o::H5Olink(obj.id(), parent.id(), cname.as_ptr(), hdf5_sys::h5p::H5P_DEFAULT, hdf5_sys::h5p::H5P_DEFAULT)
    });
    if status < 0 {
        return Err(format!("cannot link {name}").into());
    }
    Ok(())
}

