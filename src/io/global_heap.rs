//! The global heap collections of an HDF5 file, checked before HDF5 reads
//! them. Variable-length strings (the store's string attributes) live in
//! these collections, which carry no checksum, and the HDF5 1.10 that
//! Debian 12 ships trusts their sizes: one corrupted byte there made
//! `H5HG_read` copy past its buffer (a segmentation fault) or loop forever
//! (an object of size 0). A file whose collection does not parse is
//! refused here instead, as a Format error naming the byte.
//!
//! A collection (HDF5 file format, "Global Heap") is `GCOL`, version 1,
//! three reserved bytes, its size (the superblock's "size of lengths"
//! bytes), then objects: a 2-byte index, a 2-byte reference count, four
//! reserved bytes, the object's size, its data padded to 8 bytes; index 0
//! is the free space, whose size counts its header. HDF5 finds collections
//! through the strings that point at them, which only HDF5 can read, so
//! the whole file is searched for collection headers. The 8-byte header
//! `GCOL 01 00 00 00` is not expected elsewhere (it is a float32 of 5.4e7
//! next to the smallest subnormal); a false match that does not parse
//! would refuse a sound file, one that parses changes nothing.
//!
//! The search reads the whole file (about 8 GB/s from the page cache, the
//! disk's speed from disk). A file found sound is remembered while it does
//! not change (`settled`), so that a process that opens one store again
//! and again (the ParaView reader at each time step) searches it once.

use crate::error::{Error, Result};
use std::fs::File;
use std::io::{Read, Seek, SeekFrom};
use std::path::Path;
use std::time::SystemTime;

/// The header that opens a collection, version 1.
const HEADER: &[u8; 8] = b"GCOL\x01\x00\x00\x00";
/// Bytes read at a time while searching.
const CHUNK: usize = 1 << 22;

/// Refuses the HDF5 file at `path` when a global heap collection in it
/// does not parse within its own size and the file.
pub fn check(path: &Path) -> Result<()> {
    let io = |e| Error::io(path, e);
    let mut f = File::open(path).map_err(io)?;
    let meta = f.metadata().map_err(io)?;
    let id = settled::Identity::of(&meta);
    if id.is_some_and(|id| settled::known(&id)) {
        return Ok(());
    }
    let started = SystemTime::now();
    #[cfg(test)]
    tests::SEARCHED.lock().unwrap().push(path.to_path_buf());
    let len = meta.len();
    let lengths = size_of_lengths(&mut f).map_err(io)?;
    for at in headers(&mut f).map_err(io)? {
        if let Err(why) = parse(&mut f, at, len, lengths).map_err(io)? {
            return Err(Error::format(format!(
                "{}: the HDF5 global heap collection at byte {at} is corrupt ({why}); refused before HDF5 reads it",
                path.display()
            )));
        }
    }
    // Remembered only when the file did not change while it was searched,
    // and its last change was well before the search began.
    let now = settled::Identity::of(&f.metadata().map_err(io)?);
    if let Some(id) = id.filter(|id| Some(*id) == now && id.settled_before(started)) {
        settled::remember(id);
    }
    Ok(())
}

/// The files this process found sound and that have not changed since.
/// A file is the same, unchanged, while its device, inode, size and
/// modification and change times are; a change sets the change time to
/// the file system's clock, which no program can set back. A file is
/// remembered only when its last change came `SETTLE` before the search
/// began, so that a change right after the search, within the same tick
/// of a coarse file system clock, cannot leave the times as they were.
mod settled {
    use std::collections::VecDeque;
    use std::sync::Mutex;
    use std::time::{Duration, SystemTime};

    const SETTLE: Duration = Duration::from_secs(2);
    /// Files remembered at most (the oldest is forgotten first).
    const MAX_KNOWN: usize = 64;

    #[derive(Clone, Copy, Debug, PartialEq, Eq)]
    pub struct Identity {
        dev: u64,
        ino: u64,
        len: u64,
        modified: (i64, i64),
        changed: (i64, i64),
    }

    impl Identity {
        /// None where the platform does not give inodes and change times.
        #[cfg(unix)]
        pub fn of(m: &std::fs::Metadata) -> Option<Identity> {
            use std::os::unix::fs::MetadataExt;
            Some(Identity { dev: m.dev(), ino: m.ino(), len: m.size(), modified: (m.mtime(), m.mtime_nsec()), changed: (m.ctime(), m.ctime_nsec()) })
        }

        #[cfg(not(unix))]
        pub fn of(_: &std::fs::Metadata) -> Option<Identity> {
            None
        }

        /// Whether the file last changed `SETTLE` or more before `t`.
        pub fn settled_before(&self, t: SystemTime) -> bool {
            let (s, ns) = self.changed;
            let changed = u64::try_from(s).ok().and_then(|s| SystemTime::UNIX_EPOCH.checked_add(Duration::new(s, ns.clamp(0, 999_999_999) as u32)));
            changed.zip(t.checked_sub(SETTLE)).is_some_and(|(c, limit)| c < limit)
        }
    }

    static KNOWN: Mutex<VecDeque<Identity>> = Mutex::new(VecDeque::new());

    fn list() -> std::sync::MutexGuard<'static, VecDeque<Identity>> {
        KNOWN.lock().unwrap_or_else(|e| e.into_inner())
    }

    pub fn known(id: &Identity) -> bool {
        list().contains(id)
    }

    pub fn remember(id: Identity) {
        let mut known = list();
        if !known.contains(&id) {
            if known.len() == MAX_KNOWN {
                known.pop_front();
            }
            known.push_back(id);
        }
    }
}

/// The superblock's size of lengths (8 unless it says otherwise).
fn size_of_lengths(f: &mut File) -> std::io::Result<u64> {
    let mut sb = [0u8; 16];
    f.seek(SeekFrom::Start(0))?;
    let n = f.read(&mut sb)?;
    // Versions 0 and 1 keep it at byte 14, versions 2 and 3 at byte 10.
    let at = match sb[8] {
        0 | 1 => 14,
        _ => 10,
    };
    Ok(match (n > at).then(|| sb[at]) {
        Some(s @ (2 | 4 | 8)) => s as u64,
        _ => 8,
    })
}

/// Where the file holds a collection header.
fn headers(f: &mut File) -> std::io::Result<Vec<u64>> {
    let mut found = Vec::new();
    let mut buf = vec![0u8; CHUNK + HEADER.len()];
    let (mut base, mut kept) = (0u64, 0usize);
    f.seek(SeekFrom::Start(0))?;
    loop {
        let n = f.read(&mut buf[kept..])?;
        if n == 0 {
            return Ok(found);
        }
        let end = kept + n;
        found.extend(memchr::memmem::find_iter(&buf[..end], HEADER).map(|i| base + i as u64));
        // The last 7 bytes start the next window, so that a header across
        // two reads is found once.
        kept = end.min(HEADER.len() - 1);
        buf.copy_within(end - kept..end, 0);
        base += (end - kept) as u64;
    }
}

/// Walks the collection at `at` as HDF5 does; `Ok(Err(why))` when it does
/// not parse.
fn parse(f: &mut File, at: u64, len: u64, lengths: u64) -> std::io::Result<std::result::Result<(), String>> {
    let object_header = 8 + lengths;
    if at + object_header > len {
        return Ok(Err("its size is past the end of the file".into()));
    }
    let size = Bytes::File(f).le(at + 8, lengths)?;
    let Some(end) = at.checked_add(size).filter(|&e| e <= len && size >= object_header) else {
        return Ok(Err(format!("its size {size} does not fit the file")));
    };
    // A small collection (as those of strings are: 4 KiB and up) is read
    // whole, so that walking it costs one read.
    let mut bytes = match size <= 1 << 20 {
        true => {
            let mut b = vec![0u8; size as usize];
            f.seek(SeekFrom::Start(at))?;
            f.read_exact(&mut b)?;
            Bytes::Memory(at, b)
        }
        false => Bytes::File(f),
    };
    let mut p = at + object_header;
    // Until the tail is too small for an object's header (free space).
    while p + object_header <= end {
        let index = bytes.le(p, 2)?;
        let object = bytes.le(p + 8, lengths)?;
        let need = match index {
            0 => object,
            _ => object.checked_add(7).map_or(u64::MAX, |s| object_header.saturating_add(s & !7)),
        };
        if need == 0 || need > end - p {
            return Ok(Err(format!("object {index} at byte {p} of size {object} runs past the collection's end")));
        }
        p += need;
    }
    Ok(Ok(()))
}

/// Where a collection is read from: the file, or its bytes from `.0` on.
enum Bytes<'a> {
    File(&'a mut File),
    Memory(u64, Vec<u8>),
}

impl Bytes<'_> {
    /// The little-endian number of `n` (at most 8) bytes at file offset
    /// `pos` (which the caller keeps inside the file or the collection).
    fn le(&mut self, pos: u64, n: u64) -> std::io::Result<u64> {
        let mut b = [0u8; 8];
        match self {
            Bytes::File(f) => {
                f.seek(SeekFrom::Start(pos))?;
                f.read_exact(&mut b[..n as usize])?;
            }
            Bytes::Memory(start, bytes) => {
                let i = (pos - *start) as usize;
                b[..n as usize].copy_from_slice(&bytes[i..i + n as usize]);
            }
        }
        Ok(u64::from_le_bytes(b))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::PathBuf;
    use std::sync::Mutex;

    /// Every path `check` searched, in this test process.
    pub(super) static SEARCHED: Mutex<Vec<PathBuf>> = Mutex::new(Vec::new());

    fn searches(p: &Path) -> usize {
        SEARCHED.lock().unwrap().iter().filter(|s| s.as_path() == p).count()
    }

    /// A collection of `objects` (index, data) and its free space, as HDF5
    /// lays it out, after `pad` bytes of something else.
    fn collection(pad: usize, objects: &[(u16, &[u8])], size: u64) -> Vec<u8> {
        let mut c = vec![0xAB; pad];
        c.extend(HEADER);
        c.extend(size.to_le_bytes());
        for (i, d) in objects {
            c.extend(i.to_le_bytes());
            c.extend([1, 0, 0, 0, 0, 0]);
            c.extend((d.len() as u64).to_le_bytes());
            c.extend(*d);
            c.resize(c.len() + (8 - d.len() % 8) % 8, 0);
        }
        let free = pad as u64 + size - c.len() as u64;
        c.extend([0, 0, 0, 0, 0, 0, 0, 0]);
        c.extend(free.to_le_bytes());
        c.resize(pad + size as usize, 0);
        c
    }

    fn check_bytes(name: &str, bytes: &[u8]) -> Result<()> {
        let p = std::env::temp_dir().join(format!("gsenc-gcol-{name}-{}", std::process::id()));
        std::fs::write(&p, bytes).unwrap();
        let r = check(&p);
        std::fs::remove_file(&p).unwrap();
        r
    }

    #[test]
    fn sound_collections_pass_and_corrupt_sizes_are_refused() {
        let good = collection(100, &[(1, b"1.2"), (2, b"gsenc 0.1.0"), (3, b"matched")], 4096);
        check_bytes("good", &good).unwrap();
        // Two collections, the second's header across the search's first
        // and second reads (the first reads CHUNK + 8 bytes).
        let second = CHUNK + 4;
        let mut two = good.clone();
        two.resize(second, 0);
        two.extend(collection(0, &[(1, b"f32")], 4096));
        check_bytes("two", &two).unwrap();
        // An object's size past the end (the copy HDF5 made past its buffer).
        let mut bad = good.clone();
        bad[100 + 16 + 8 + 1] = 0xF5;
        let e = check_bytes("object", &bad).unwrap_err();
        assert!(matches!(e, Error::Format(_)) && e.to_string().contains("byte 100") && e.to_string().contains("object 1"), "{e}");
        // The collection's own size past the end of the file.
        let mut bad = good.clone();
        bad[100 + 9] = 0x80;
        assert!(check_bytes("size", &bad).unwrap_err().to_string().contains("does not fit the file"));
        // A free space of size 0 (HDF5 looped forever on it).
        let mut bad = good;
        let free = 100 + 16 + 3 * 16 + 8 + 16 + 8;
        bad[free + 8..free + 16].copy_from_slice(&0u64.to_le_bytes());
        assert!(check_bytes("zero", &bad).unwrap_err().to_string().contains("object 0"));
        // In the second collection, across the reads.
        let mut bad = two;
        bad[second + 16 + 8 + 2] = 0xFF;
        assert!(check_bytes("straddle", &bad).unwrap_err().to_string().contains(&format!("collection at byte {second}")));
    }

    #[test]
    fn a_settled_sound_file_is_searched_once_until_it_changes() {
        let good = collection(100, &[(1, b"1.2"), (2, b"gsenc 0.1.0")], 4096);
        let p = std::env::temp_dir().join(format!("gsenc-gcol-settled-{}", std::process::id()));
        std::fs::write(&p, &good).unwrap();
        // Just written: searched every time.
        check(&p).unwrap();
        check(&p).unwrap();
        assert_eq!(searches(&p), 2);
        // Settled: searched once more, then remembered.
        std::thread::sleep(std::time::Duration::from_millis(2100));
        check(&p).unwrap();
        check(&p).unwrap();
        check(&p).unwrap();
        assert_eq!(searches(&p), 3);
        // One byte changed in place (the size kept): searched, and refused.
        let mut f = std::fs::OpenOptions::new().write(true).open(&p).unwrap();
        f.seek(SeekFrom::Start(100 + 16 + 8 + 1)).unwrap();
        std::io::Write::write_all(&mut f, &[0xF5]).unwrap();
        drop(f);
        assert!(matches!(check(&p), Err(Error::Format(_))));
        assert_eq!(searches(&p), 4);
        std::fs::remove_file(&p).unwrap();
    }
}
