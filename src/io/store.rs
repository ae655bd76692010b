//! The HDF5 store (cargo feature `hdf5`): one file holding a time series of
//! models of many fields and ranks, laid out `/<field>/<step>/rank_<r>` with
//! the decoding metadata as attributes and the parameters as plain datasets,
//! so that h5py or h5dump read it without gsenc. `docs/FORMAT.md` ("The HDF5
//! store") is the reference.
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

use crate::error::{Error, Result};
use crate::field::{IndexFrame, Transform, ValueRange};
use crate::format::model_file::{packed_payload, put_header_start, read_packed_payload};
use crate::format::packed::Precision;
use crate::format::Payload;
use crate::io::atomic::Replacement;
use crate::format::check_field_name;
use crate::math::kernel::Primitive;
use crate::model::{Curve, Model, ModelMeta, Outside, Support, WarmRecord, WarmTaken};
use crate::format::quantize::{Affine, CentreCoding, Centres, Quantized};
use crate::format::step_index::StepIndex;
use hdf5::plist::file_access::{CacheDecreaseMode, CacheIncreaseMode, FlashIncreaseMode, MetadataCacheConfig};
use hdf5::plist::file_create::FileSpaceStrategy;
use hdf5::types::VarLenUnicode;
use hdf5::{Dataset, File, Group, H5Type, Location};
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
/// entry's `crc32` attribute (`entry_crc`).
pub const STORE_VERSION: &str = "1.5";
/// An entry's checksum attribute (1.4).
const CRC: &str = "crc32";
/// The step index of a decomposed step, in the step's group (1.3).
const INDEX: &str = "index";
/// Names of the twelve parameters, in the order of the `params` rows.
pub const PARAMETER_NAMES: [&str; 12] =
    ["mu_x", "mu_y", "mu_z", "l_x", "l_y", "l_z", "q_w", "q_x", "q_y", "q_z", "alpha", "beta"];
/// Most primitives in one chunk of a parameter row (deflate works per chunk).
const CHUNK: usize = 1 << 20;
const DEFLATE_LEVEL: u8 = 6;

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
pub struct Store {
    file: File,
    path: PathBuf,
}

fn h5(path: &Path) -> impl Fn(hdf5::Error) -> Error + '_ {
    move |e| Error::Hdf5 { path: path.display().to_string(), message: e.to_string() }
}

impl Store {
    /// Opens a store to append to, creating it when `path` does not exist.
    pub fn open_append(path: impl AsRef<Path>) -> Result<Store> {
        let path = path.as_ref().to_path_buf();
        if !path.exists() {
            create_empty(&path)?;
        }
        regular_file(&path)?;
        super::global_heap::check(&path)?;
        let file = File::with_options()
            .with_fapl(|p| p.mdc_config(&fixed_size_cache()).libver_v18())
            .open_rw(&path)
            .map_err(h5(&path))?;
        check_root(&file, &path)?;
        Ok(Store { file, path })
    }

    /// Opens an existing store for reading.
    pub fn open_read(path: impl AsRef<Path>) -> Result<Store> {
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
        Ok(Store { file, path })
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The bytes and entries HDF5's metadata cache holds for this store
    /// now: about [`CACHE_BYTES`] at most between appends, whatever the
    /// number of entries written (`tests/store.rs`).
    pub fn cache_size(&self) -> (usize, usize) {
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
        let key = EntryKey::of(&model.meta);
        check_field_name(&key.field)?;
        let params = payload.round_trip(model)?; // refuses unstorable parameters before touching the file
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
            write_entry(&entry, model, payload).map_err(h5(&s.path))?;
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
                        ((*self.file).clone(), field.to_string(), (*new_field).clone())
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
        let g = self.entry_group(key)?;
        let budget = super::budget::whole_read_budget(1)?;
        let info = read_info(&g, key, &self.path, budget)?;
        let (params, precision) = read_params(&g, &info, &self.path, budget)?;
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
        Ok((Model { meta: ModelMeta { precision, ..info.meta }, params, support }, info.payload))
    }

    fn entry_group(&self, key: &EntryKey) -> Result<Group> {
        self.file.group(&key.path()).map_err(|_| Error::arg(format!("{} holds no model {}", self.path.display(), key.path())))
    }

    /// The step index of `/<field>/<step>`, where the step has one (1.3).
    pub fn step_index(&self, field: &str, step: u64) -> Result<Option<StepIndex>> {
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
        let (field, step) = (&index.field, index.step);
        let sg = self.groups(field, step)?.1;
        let mut pieces = Vec::with_capacity(index.pieces.len());
        for p in &index.pieces {
            let key = EntryKey { field: field.clone(), step, rank: p.rank };
            if sg.as_ref().is_none_or(|sg| !sg.link_exists(&format!("rank_{}", p.rank))) {
                return Err(Error::data(format!("the step index of /{field}/{step} names rank {}, whose model {} the store does not hold", p.rank, key.path())));
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

fn create_empty(path: &Path) -> Result<()> {
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
    out.commit()
}

/// The text of a string attribute as read, or `None` when its bytes are
/// not UTF-8 (a damaged or foreign file): `VarLenUnicode::as_str` does not
/// check them, and a `String` that is not UTF-8 breaks what every `str`
/// operation relies on (formatting one panicked; anything may happen).
fn utf8(v: &VarLenUnicode) -> Option<String> {
    std::str::from_utf8(v.as_bytes()).ok().map(str::to_owned)
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

fn scalar_attr<T: H5Type>(loc: &Location, name: &str, v: &T) -> hdf5::Result<()> {
    loc.new_attr::<T>().create(name)?.write_scalar(v)
}

fn scalar_str_attr(loc: &Location, name: &str, v: &str) -> hdf5::Result<()> {
    let v: VarLenUnicode = v.parse().map_err(|e| hdf5::Error::from(format!("attribute {name}: {e}")))?;
    scalar_attr(loc, name, &v)
}

fn array_attr<T: H5Type + Copy>(loc: &Location, name: &str, v: &[T]) -> hdf5::Result<()> {
    loc.new_attr::<T>().shape(v.len()).create(name)?.write_raw(v)
}

/// A `rows x n` dataset of one parameter per row, deflated when `compress`.
fn rows_dataset<T: H5Type + Copy>(g: &Group, name: &str, rows: usize, data: &[T], compress: bool) -> hdf5::Result<Dataset> {
    let n = data.len() / rows;
    let mut b = g.new_dataset::<T>().shape((rows, n));
    if compress && n > 0 {
        b = b.chunk((1, n.min(CHUNK))).shuffle().deflate(DEFLATE_LEVEL);
    }
    let ds = b.create(name)?;
    ds.write_raw(data)?;
    Ok(ds)
}

fn maps_attrs(ds: &Dataset, maps: &[Affine]) -> hdf5::Result<()> {
    array_attr(ds, "lo", &maps.iter().map(|m| m.lo).collect::<Vec<_>>())?;
    array_attr(ds, "hi", &maps.iter().map(|m| m.hi).collect::<Vec<_>>())
}

/// An entry's checksum (1.4, attribute `crc32`): CRC-32 (IEEE, as zlib)
/// of its payload's code, count and metadata laid out as a model file's
/// header starts (`put_header_start`), then the metadata the header keeps
/// further on (why the encode fell back to the CPU, as a u64 length and
/// UTF-8 bytes; a warm start's code and moved count, or 0xff; a target
/// PSNR's curve, 1.5, only where there is one), the support's bits and its
/// outside (offset, gain), and last the float32
/// bits of every parameter as a reader gets them, little-endian, primitive
/// by primitive. So whatever a reader makes of the entry is checked, and
/// nothing in it depends on a compressor's version.
fn entry_crc(m: &ModelMeta, payload: Payload, params: &[Primitive], support: Option<&Support>) -> Result<u32> {
    // The metadata as a reader gets it: a NaN time or PSNR (of whatever
    // bits) reads as unknown, which the header writes as the one NaN.
    let known = |v: Option<f64>| v.filter(|v| !v.is_nan());
    let m = &ModelMeta { time: known(m.time), encode_psnr: known(m.encode_psnr), ..m.clone() };
    let mut h = Vec::with_capacity(256);
    put_header_start(&mut h, m, payload, params.len())?;
    let fell_back = m.fell_back.as_deref().unwrap_or("");
    h.extend_from_slice(&(fell_back.len() as u64).to_le_bytes());
    h.extend_from_slice(fell_back.as_bytes());
    match m.warm {
        Some(w) => {
            h.push(w.taken.code());
            h.extend_from_slice(&w.moved.to_le_bytes());
        }
        None => h.push(u8::MAX),
    }
    if let Some(c) = m.curve {
        h.extend_from_slice(&c.per_budget_doubling.to_le_bytes());
        h.extend_from_slice(&c.per_iteration_doubling.to_le_bytes());
    }
    let mut crc = crc32fast::Hasher::new();
    crc.update(&h);
    if let Some(s) = support {
        crc.update(s.bits());
        crc.update(&s.outside().offset.to_le_bytes());
        crc.update(&s.outside().gain.to_le_bytes());
    }
    let mut bytes = [0u8; 48];
    for p in params {
        for (b, v) in bytes.chunks_exact_mut(4).zip(p) {
            b.copy_from_slice(&v.to_le_bytes());
        }
        crc.update(&bytes);
    }
    Ok(crc.finalize())
}

fn write_entry(g: &Group, model: &Model, payload: Payload) -> hdf5::Result<()> {
    let m = &model.meta;
    let n = model.params.len();
    let lib = |e: Error| hdf5::Error::from(e.to_string());
    // The parameters a reader gets back, for the checksum: from what is
    // written, as `read_params` makes them.
    let read_back: Vec<Primitive> = match payload {
        Payload::Float32 => {
            let rows: Vec<f32> = (0..12).flat_map(|k| model.params.iter().map(move |p| p[k])).collect();
            rows_dataset(g, "params", 12, &rows, false)?;
            model.params.clone()
        }
        Payload::Bits8(coding) => {
            let q = Quantized::of(&model.params, coding);
            match &q.centres {
                Centres::Float16(bits) => {
                    let half: Vec<half::f16> = bits.iter().map(|&b| half::f16::from_bits(b)).collect();
                    rows_dataset(g, "centres", 3, &half, true)?;
                }
                Centres::Fixed16 { maps, codes } => maps_attrs(&rows_dataset(g, "centres", 3, codes, true)?, maps)?,
            }
            maps_attrs(&rows_dataset(g, "codes", 9, &q.codes, true)?, &q.maps)?;
            q.dequantize().map_err(lib)?
        }
        Payload::Packed => {
            // The model file's packed payload as it is (already entropy-coded).
            let bytes = packed_payload(model).map_err(lib)?;
            g.new_dataset::<u8>().shape(bytes.len()).create("packed")?.write_raw(&bytes)?;
            read_packed_payload(&bytes, n).and_then(|p| p.params()).map_err(lib)?
        }
    };
    scalar_attr(g, CRC, &entry_crc(m, payload, &read_back, model.support.as_ref()).map_err(lib)?)?;
    scalar_str_attr(g, "payload", payload.name())?;
    scalar_attr(g, "count", &(n as u64))?;
    scalar_str_attr(g, "field", &m.field)?;
    scalar_attr(g, "step", &m.step)?;
    scalar_attr(g, "time", &m.time.unwrap_or(f64::NAN))?;
    scalar_attr(g, "rank", &m.rank)?;
    array_attr(g, "dims", &m.frame.dims.map(|d| d as u64))?;
    array_attr(g, "bmin", &m.frame.bmin)?;
    scalar_attr(g, "gamma", &m.frame.gamma)?;
    scalar_attr(g, "vmin", &m.range.vmin)?;
    scalar_attr(g, "vmax", &m.range.vmax)?;
    scalar_str_attr(g, "transform", m.range.transform.name())?;
    scalar_str_attr(g, "schedule", &m.schedule)?;
    scalar_attr(g, "iterations", &m.iterations)?;
    scalar_attr(g, "points", &m.points)?;
    scalar_attr(g, "seed_init", &m.seed_init)?;
    scalar_attr(g, "seed_sample", &m.seed_sample)?;
    scalar_attr(g, "encode_psnr", &m.encode_psnr.unwrap_or(f64::NAN))?;
    if let Some(why) = &m.fell_back {
        scalar_str_attr(g, "fell_back", why)?;
    }
    if let Some(w) = &m.warm {
        scalar_str_attr(g, "warm_start", w.taken.name())?;
        scalar_attr(g, "warm_moved", &w.moved)?;
    }
    if let Some(c) = &m.curve {
        array_attr(g, "target_curve", &[c.per_budget_doubling, c.per_iteration_doubling])?;
    }
    if let Some(support) = &model.support {
        // The packed bits, one per reference voxel (x fastest, least
        // significant bit first), deflated like the 8-bit codes.
        let bits = support.bits();
        let ds = g.new_dataset::<u8>().shape(bits.len()).chunk(bits.len().clamp(1, CHUNK)).deflate(DEFLATE_LEVEL).create("support")?;
        ds.write_raw(bits)?;
        let o = support.outside();
        if !o.is_zero() {
            array_attr(&ds, "outside", &[o.offset, o.gain])?;
        }
    }
    scalar_str_attr(g, "parameters", &PARAMETER_NAMES.join(" "))
}

/// The entry's support, when it has one.
fn read_support(g: &Group, info: &EntryInfo, path: &Path, budget: u64) -> Result<Option<Support>> {
    let Ok(ds) = g.dataset("support") else { return Ok(None) };
    let bad = |what: String| Error::format(format!("{}:{} {what}", path.display(), EntryKey::of(&info.meta).path()));
    let bits: Vec<u8> = read_all(&ds, "support", budget, &bad)?;
    let support = Support::from_bits(info.meta.frame.dims, bits).map_err(|e| bad(e.to_string()))?;
    // 1.2: the decode outside it, when not zero.
    let Ok(a) = ds.attr("outside") else { return Ok(Some(support)) };
    let v: Vec<f32> = read_all(&a, "support attribute outside", budget, &bad)?;
    let [offset, gain] = v[..] else { return Err(bad(format!("support attribute outside holds {} values, not 2", v.len()))) };
    support.with_outside(Outside { offset, gain }).map(Some).map_err(|e| bad(e.to_string()))
}

fn read_info(g: &Group, key: &EntryKey, path: &Path, budget: u64) -> Result<EntryInfo> {
    let bad = |what: String| Error::format(format!("{}:{} {what} (an append cut short, or not written by gsenc)", path.display(), key.path()));
    let scalar = |name: &str| -> Result<hdf5::Attribute> { g.attr(name).map_err(|_| bad(format!("has no attribute '{name}'"))) };
    let f64a = |name: &str| scalar(name)?.read_scalar::<f64>().map_err(|e| bad(format!("attribute {name}: {e}")));
    let u64a = |name: &str| scalar(name)?.read_scalar::<u64>().map_err(|e| bad(format!("attribute {name}: {e}")));
    let u32a = |name: &str| scalar(name)?.read_scalar::<u32>().map_err(|e| bad(format!("attribute {name}: {e}")));
    let stra = |name: &str| {
        let v = scalar(name)?.read_scalar::<VarLenUnicode>().map_err(|e| bad(format!("attribute {name}: {e}")))?;
        utf8(&v).ok_or_else(|| bad(format!("attribute {name} is not UTF-8 text")))
    };
    let f64s = |name: &str, len: usize| -> Result<Vec<f64>> {
        let v: Vec<f64> = read_all(&*scalar(name)?, &format!("attribute {name}"), budget, &bad)?;
        if v.len() != len {
            return Err(bad(format!("attribute {name} holds {} values, not {len}", v.len())));
        }
        Ok(v)
    };
    let payload_name = stra("payload")?;
    let payload = Payload::from_name(&payload_name).map_err(|_| bad(format!("has an unknown payload '{payload_name}'")))?;
    let dims_raw: Vec<u64> = read_all(&*scalar("dims")?, "attribute dims", budget, &bad)?;
    let dims: [usize; 3] = match dims_raw.as_slice() {
        [x, y, z] if [x, y, z].iter().all(|&&d| d > 0 && d <= u32::MAX as u64) => [*x as usize, *y as usize, *z as usize],
        _ => return Err(bad(format!("has invalid dims {dims_raw:?}"))),
    };
    let bmin = f64s("bmin", 3)?;
    let frame = IndexFrame { dims, bmin: [bmin[0], bmin[1], bmin[2]], gamma: f64a("gamma")? };
    if !frame.is_valid() {
        return Err(bad("holds an invalid index frame".into()));
    }
    let transform_name = stra("transform")?;
    let transform = Transform::from_name(&transform_name).ok_or_else(|| bad(format!("has an unknown transform '{transform_name}'")))?;
    let range = ValueRange::new(f64a("vmin")?, f64a("vmax")?, transform).map_err(|e| bad(e.to_string()))?;
    let unknown_is_none = |v: f64| (!v.is_nan()).then_some(v);
    let meta = ModelMeta {
        frame,
        range,
        field: stra("field")?,
        step: u64a("step")?,
        schedule: stra("schedule")?,
        iterations: u32a("iterations")?,
        points: u32a("points")?,
        seed_init: u64a("seed_init")?,
        seed_sample: u64a("seed_sample")?,
        time: unknown_is_none(f64a("time")?),
        rank: u32a("rank")?,
        encode_psnr: unknown_is_none(f64a("encode_psnr")?),
        // Only where the encode fell back to the CPU.
        fell_back: if g.attr("fell_back").is_ok() { Some(stra("fell_back")?) } else { None },
        // Only for an `auto` warm-started step.
        warm: if g.attr("warm_start").is_ok() {
            let name = stra("warm_start")?;
            let taken = WarmTaken::from_name(&name).map_err(|_| bad(format!("has an unknown warm start '{name}'")))?;
            Some(WarmRecord { taken, moved: u32a("warm_moved")? })
        } else {
            None
        },
        precision: None, // read with the parameters
        // Only for a target PSNR's encode (1.5).
        curve: if g.attr("target_curve").is_ok() {
            let v = f64s("target_curve", 2)?;
            let c = Curve { per_budget_doubling: v[0], per_iteration_doubling: v[1] };
            if !c.is_valid() {
                return Err(bad(format!("has a target curve that no encode makes: {c:?}")));
            }
            Some(c)
        } else {
            None
        },
    };
    if EntryKey::of(&meta) != *key {
        return Err(bad(format!("says it is /{}/{}/rank_{}", meta.field, meta.step, meta.rank)));
    }
    let count = u64a("count")?;
    let names: &[&str] = match payload {
        Payload::Float32 => &["params"],
        Payload::Bits8(_) => &["centres", "codes"],
        Payload::Packed => &["packed"],
    };
    let mut stored_bytes = 0;
    for name in names {
        stored_bytes += g.dataset(name).map_err(|_| bad(format!("has no dataset '{name}'")))?.storage_size();
    }
    Ok(EntryInfo { meta, payload, count, stored_bytes })
}

/// The values of a dataset or an attribute, refusing one whose declared
/// size goes beyond `budget` (the reader's share of the memory available,
/// `io/budget.rs`) unread: a foreign file may declare a dataset far larger
/// than it stores (HDF5 reads unwritten chunks as the fill value), whose
/// read would otherwise ask for that much memory.
fn read_all<T: H5Type>(c: &hdf5::Container, what: &str, budget: u64, bad: &dyn Fn(String) -> Error) -> Result<Vec<T>> {
    let bytes = (c.size() as u64).saturating_mul(std::mem::size_of::<T>() as u64);
    if bytes > budget {
        return Err(bad(format!("{what} declares {bytes} bytes, more than the {budget} a read of it may take of the memory available")));
    }
    c.read_raw::<T>().map_err(|e| bad(format!("{what}: {e}")))
}

fn read_rows<T: H5Type>(g: &Group, name: &str, rows: usize, n: usize, budget: u64, bad: &dyn Fn(String) -> Error) -> Result<(Dataset, Vec<T>)> {
    let ds = g.dataset(name).map_err(|_| bad(format!("has no dataset '{name}'")))?;
    if ds.shape() != [rows, n] {
        return Err(bad(format!("dataset {name} has shape {:?}, not [{rows}, {n}]", ds.shape())));
    }
    let v = read_all::<T>(&ds, &format!("dataset {name}"), budget, bad)?;
    Ok((ds, v))
}

fn read_maps(ds: &Dataset, len: usize, budget: u64, bad: &dyn Fn(String) -> Error) -> Result<Vec<Affine>> {
    let get = |name: &str| -> Result<Vec<f32>> {
        let what = format!("{} attribute {name}", ds.name());
        let a = ds.attr(name).map_err(|e| bad(format!("{what}: {e}")))?;
        let v: Vec<f32> = read_all(&a, &what, budget, bad)?;
        if v.len() != len {
            return Err(bad(format!("{} attribute {name} holds {} values, not {len}", ds.name(), v.len())));
        }
        Ok(v)
    };
    let (lo, hi) = (get("lo")?, get("hi")?);
    Ok(lo.into_iter().zip(hi).map(|(lo, hi)| Affine { lo, hi }).collect())
}

/// The entry's primitives, and the packed payload's precision when it has one.
fn read_params(g: &Group, info: &EntryInfo, path: &Path, budget: u64) -> Result<(Vec<Primitive>, Option<Precision>)> {
    let key = EntryKey::of(&info.meta);
    let bad = |what: String| Error::format(format!("{}:{} {what}", path.display(), key.path()));
    let n = usize::try_from(info.count).map_err(|_| bad("count exceeds this machine's memory".into()))?;
    let mut precision = None;
    let params = match info.payload {
        Payload::Packed => {
            let ds = g.dataset("packed").map_err(|_| bad("has no dataset 'packed'".into()))?;
            let bytes: Vec<u8> = read_all(&ds, "dataset packed", budget, &bad)?;
            let packed = read_packed_payload(&bytes, n).map_err(|e| bad(e.to_string()))?;
            precision = Some(packed.precision);
            packed.params().map_err(|e| bad(e.to_string()))?
        }
        Payload::Float32 => {
            let (_, rows) = read_rows::<f32>(g, "params", 12, n, budget, &bad)?;
            (0..n).map(|i| std::array::from_fn(|k| rows[k * n + i])).collect()
        }
        Payload::Bits8(coding) => {
            let centres = match coding {
                CentreCoding::Float16 => {
                    let (_, half) = read_rows::<half::f16>(g, "centres", 3, n, budget, &bad)?;
                    Centres::Float16(half.into_iter().map(|h| h.to_bits()).collect())
                }
                CentreCoding::Fixed16 => {
                    let (ds, codes) = read_rows::<u16>(g, "centres", 3, n, budget, &bad)?;
                    let m = read_maps(&ds, 3, budget, &bad)?;
                    Centres::Fixed16 { maps: [m[0], m[1], m[2]], codes }
                }
            };
            let (ds, codes) = read_rows::<u8>(g, "codes", 9, n, budget, &bad)?;
            let m = read_maps(&ds, 9, budget, &bad)?;
            let q = Quantized { n, centres, maps: std::array::from_fn(|k| m[k]), codes };
            q.dequantize().map_err(|e| bad(e.to_string()))?
        }
    };
    if params.iter().any(|p: &Primitive| p.iter().any(|v| !v.is_finite())) {
        return Err(bad("holds non-finite parameters".into()));
    }
    Ok((params, precision))
}
