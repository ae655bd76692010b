//! Crash-safe file writes: a temporary file in the target's folder, flushed to
//! disk, then renamed over the target. A failure (full disk, no permission)
//! leaves any earlier file under the final name untouched.
//!
//! The target is the file a path names, not the path's last link: a
//! symbolic link is followed (the link stays, its file is replaced, with the
//! replaced file's permissions), and a path that names something other than
//! a regular file or a folder (`/dev/null`, a named pipe, a terminal) is
//! written in place, since renaming over it would put a file where the
//! device was.

use crate::error::{Error, Result};
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

pub fn write_atomic(path: impl AsRef<Path>, bytes: &[u8]) -> Result<()> {
    let mut f = AtomicFile::create(path)?;
    f.write(bytes)?;
    f.commit()
}

/// Symbolic links followed at most this many times (Linux's own limit).
const MAX_LINKS: usize = 40;

/// `path` with its symbolic links followed, as far as they lead (a dangling
/// link gives the path it points at, which the write then creates).
fn follow_links(path: &Path) -> Result<PathBuf> {
    let mut p = path.to_path_buf();
    for _ in 0..MAX_LINKS {
        match std::fs::symlink_metadata(&p) {
            Ok(m) if m.file_type().is_symlink() => {
                let to = std::fs::read_link(&p).map_err(|e| Error::io(path, e))?;
                p = match p.parent() {
                    Some(dir) if to.is_relative() => dir.join(to),
                    _ => to,
                };
            }
            _ => return Ok(p),
        }
    }
    Err(Error::io(path, std::io::Error::other(format!("more than {MAX_LINKS} symbolic links"))))
}

/// Where a write to `path` goes.
enum Target {
    /// A regular file, or nothing yet: written beside it and renamed over it.
    File(PathBuf),
    /// A device or a pipe: written in place.
    Stream,
}

fn target(path: &Path) -> Result<Target> {
    match std::fs::metadata(path) {
        Ok(m) if m.is_dir() => Err(Error::io(path, std::io::Error::other("is a folder, not a file"))),
        Ok(m) if !m.is_file() => Ok(Target::Stream),
        _ => Ok(Target::File(follow_links(path)?)),
    }
}

/// A file written under a temporary name and then renamed over the file
/// `path` names (its links followed): for writers that create the file
/// themselves (HDF5). Refuses a path that names a device or a pipe, which
/// such a file cannot be written to in place.
pub struct Replacement {
    /// The file replaced.
    pub dest: PathBuf,
    /// A hidden name beside it, unique in this process.
    pub tmp: PathBuf,
}

impl Replacement {
    pub fn new(path: &Path) -> Result<Replacement> {
        match target(path)? {
            Target::File(dest) => Replacement::beside(dest),
            Target::Stream => Err(Error::arg(format!("'{}' is not a regular file, and this output must be one", path.display()))),
        }
    }

    fn beside(dest: PathBuf) -> Result<Replacement> {
        Ok(Replacement { tmp: hidden_beside(&dest)?, dest })
    }

    /// Renames the temporary file over the destination, keeping the
    /// permissions of a file it replaces; on failure the temporary file is
    /// removed and the destination is as it was.
    pub fn commit(&self) -> Result<()> {
        let kept = std::fs::metadata(&self.dest).ok().filter(|m| m.is_file()).map(|m| m.permissions());
        let done = kept.map_or(Ok(()), |p| std::fs::set_permissions(&self.tmp, p)).and_then(|_| std::fs::rename(&self.tmp, &self.dest));
        done.map_err(|e| {
            self.discard();
            Error::io(&self.dest, e)
        })
    }

    /// Puts the temporary file under the destination's name only if no
    /// file has that name: `Ok(true)` when it did, `Ok(false)` (the
    /// temporary file removed) when another writer made the destination
    /// first, so that two processes creating one file never put a new one
    /// over what the first already wrote into. A hard link, which never
    /// replaces a file, publishes it; on a file system without hard links
    /// it is renamed where the destination is still missing (a window
    /// between the look and the rename there).
    pub fn commit_new(&self) -> Result<bool> {
        let linked = std::fs::hard_link(&self.tmp, &self.dest);
        let made = match linked {
            Ok(()) => Ok(true),
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => Ok(false),
            Err(_) if self.dest.exists() => Ok(false),
            Err(_) => std::fs::rename(&self.tmp, &self.dest).map(|()| true),
        };
        self.discard();
        made.map_err(|e| Error::io(&self.dest, e))
    }

    /// Removes the temporary file, if there is one.
    pub fn discard(&self) {
        let _ = std::fs::remove_file(&self.tmp);
    }
}

/// A hidden name beside `path`, unique among this process's writes (two
/// threads writing the same path each write their own file; the last
/// rename wins, and each file is whole).
fn hidden_beside(path: &Path) -> Result<PathBuf> {
    static NEXT: AtomicU64 = AtomicU64::new(0);
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let name = path.file_name().ok_or_else(|| Error::arg(format!("'{}' is not a file path", path.display())))?;
    let n = NEXT.fetch_add(1, Ordering::Relaxed);
    Ok(dir.join(format!(".{}.tmp-{}-{n}", name.to_string_lossy(), std::process::id())))
}

/// A file written piece by piece under a temporary name and renamed over its
/// final name by [`AtomicFile::commit`]; dropped uncommitted (an error on the
/// way), the temporary file is removed and nothing under the final name
/// changes. A device or a pipe is written in place (module docs).
pub struct AtomicFile {
    path: PathBuf,
    /// None when writing in place.
    replace: Option<Replacement>,
    file: Option<BufWriter<File>>,
}

impl AtomicFile {
    pub fn create(path: impl AsRef<Path>) -> Result<AtomicFile> {
        let path = path.as_ref().to_path_buf();
        let (replace, open) = match target(&path)? {
            Target::File(dest) => {
                let r = Replacement::beside(dest)?;
                let open = r.tmp.clone();
                (Some(r), open)
            }
            Target::Stream => (None, path.clone()),
        };
        let file = File::create(&open).map_err(|e| Error::io(&path, e))?;
        Ok(AtomicFile { path, replace, file: Some(BufWriter::with_capacity(1 << 20, file)) })
    }

    pub fn write(&mut self, bytes: &[u8]) -> Result<()> {
        let f = self.file.as_mut().expect("an AtomicFile is open until commit");
        f.write_all(bytes).map_err(|e| Error::io(&self.path, e))
    }

    /// Flushes to disk and renames over the final name (in place: flushes).
    pub fn commit(mut self) -> Result<()> {
        let f = self.file.take().expect("an AtomicFile is open until commit");
        let f = f.into_inner().map_err(|e| Error::io(&self.path, e.into_error()))?;
        match &self.replace {
            Some(r) => {
                f.sync_all().map_err(|e| Error::io(&self.path, e))?;
                drop(f);
                r.commit()
            }
            None => Ok(()),
        }
    }
}

impl Drop for AtomicFile {
    fn drop(&mut self) {
        // Uncommitted, or the commit failed: leave nothing behind.
        self.file.take();
        if let Some(r) = &self.replace {
            r.discard();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn failed_write_keeps_the_old_file() {
        let dir = std::env::temp_dir().join(format!("gsenc-atomic-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("m.gsm");
        write_atomic(&p, b"first").unwrap();
        // Writing into a folder that does not exist fails and touches nothing.
        assert!(write_atomic(dir.join("missing/m.gsm"), b"x").is_err());
        write_atomic(&p, b"second").unwrap();
        assert_eq!(std::fs::read(&p).unwrap(), b"second");
        // A file dropped uncommitted (its writer failed on the way) leaves
        // the old one, and no temporary file.
        let mut f = AtomicFile::create(&p).unwrap();
        f.write(&[7; 3 << 20]).unwrap();
        drop(f);
        assert_eq!(std::fs::read(&p).unwrap(), b"second");
        let leftovers: Vec<_> = std::fs::read_dir(&dir).unwrap().filter_map(|e| e.ok()).collect();
        assert_eq!(leftovers.len(), 1, "temporary files left behind");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// A new file is published only where none is: the second of two
    /// writers creating one file leaves the first one's, and no temporary
    /// file.
    #[test]
    fn commit_new_never_replaces_a_file() {
        let dir = scratch("new");
        let p = dir.join("s.h5");
        let write = |bytes: &[u8]| {
            let r = Replacement::new(&p).unwrap();
            std::fs::write(&r.tmp, bytes).unwrap();
            r
        };
        let (first, second) = (write(b"first"), write(b"second"));
        assert!(first.commit_new().unwrap());
        assert!(!second.commit_new().unwrap());
        assert_eq!(std::fs::read(&p).unwrap(), b"first");
        assert_eq!(names(&dir), ["s.h5"]);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    fn scratch(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("gsenc-atomic-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    fn names(dir: &Path) -> Vec<String> {
        let mut v: Vec<String> = std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
        v.sort();
        v
    }

    #[cfg(unix)]
    #[test]
    fn a_link_is_followed_and_stays_a_link() {
        use std::os::unix::fs::{symlink, PermissionsExt};
        let dir = scratch("link");
        std::fs::create_dir(dir.join("data")).unwrap();
        let file = dir.join("data/m.gsm");
        std::fs::write(&file, b"old").unwrap();
        std::fs::set_permissions(&file, std::fs::Permissions::from_mode(0o640)).unwrap();
        // A relative link in another folder, and a link to that link.
        symlink("data/m.gsm", dir.join("link.gsm")).unwrap();
        symlink("link.gsm", dir.join("link2.gsm")).unwrap();
        write_atomic(dir.join("link2.gsm"), b"new").unwrap();
        assert!(std::fs::symlink_metadata(dir.join("link2.gsm")).unwrap().file_type().is_symlink());
        assert!(std::fs::symlink_metadata(dir.join("link.gsm")).unwrap().file_type().is_symlink());
        assert_eq!(std::fs::read(&file).unwrap(), b"new");
        assert_eq!(std::fs::metadata(&file).unwrap().permissions().mode() & 0o777, 0o640, "the replaced file's permissions");
        // A dangling link: its target is created.
        symlink("data/fresh.gsm", dir.join("dangling.gsm")).unwrap();
        let mut f = AtomicFile::create(dir.join("dangling.gsm")).unwrap();
        f.write(b"made").unwrap();
        f.commit().unwrap();
        assert_eq!(std::fs::read(dir.join("data/fresh.gsm")).unwrap(), b"made");
        assert!(std::fs::symlink_metadata(dir.join("dangling.gsm")).unwrap().file_type().is_symlink());
        // The HDF5 writers' replacement follows links the same way.
        let r = Replacement::new(&dir.join("link2.gsm")).unwrap();
        assert_eq!(r.dest, dir.join("data/m.gsm"));
        assert_eq!(r.tmp.parent(), Some(dir.join("data").as_path()));
        assert_eq!(names(&dir.join("data")), ["fresh.gsm", "m.gsm"], "temporary files left behind");
        // A loop of links is an error, not a hang.
        symlink("loop_b", dir.join("loop_a")).unwrap();
        symlink("loop_a", dir.join("loop_b")).unwrap();
        assert!(matches!(write_atomic(dir.join("loop_a"), b"x"), Err(Error::Io { .. })));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// A reader of the named pipe `at` that takes `limit` bytes, then hangs up.
    #[cfg(unix)]
    fn reader(at: &Path, limit: usize) -> std::thread::JoinHandle<Vec<u8>> {
        use std::io::Read;
        let at = at.to_path_buf();
        std::thread::spawn(move || {
            let mut got = vec![];
            File::open(at).unwrap().take(limit as u64).read_to_end(&mut got).unwrap();
            got
        })
    }

    #[cfg(unix)]
    #[test]
    fn a_device_or_a_pipe_is_written_in_place() {
        use std::os::unix::fs::FileTypeExt;
        let dir = scratch("pipe");
        // Renaming over the pipe would leave a regular file there and the
        // reader waiting for ever; written in place, the reader gets it all.
        let fifo = dir.join("pipe");
        let made = std::process::Command::new("mkfifo").arg(&fifo).status().expect("mkfifo runs");
        assert!(made.success(), "mkfifo failed");
        let all = reader(&fifo, usize::MAX);
        write_atomic(&fifo, b"through the pipe").unwrap();
        // Checked before the join: a reader left waiting would hang it.
        assert!(std::fs::symlink_metadata(&fifo).unwrap().file_type().is_fifo());
        assert_eq!(all.join().unwrap(), b"through the pipe");
        assert_eq!(names(&dir), ["pipe"], "temporary files left behind");
        // A reader that hangs up early: the write fails, and says so.
        let first = reader(&fifo, 10);
        let big = vec![7u8; 4 << 20];
        assert!(matches!(write_atomic(&fifo, &big), Err(Error::Io { .. })));
        assert_eq!(first.join().unwrap().len(), 10);
        // HDF5 output cannot go to a pipe: refused before anything is made.
        assert!(matches!(Replacement::new(&fifo), Err(Error::InvalidArgument(_))));
        assert_eq!(names(&dir), ["pipe"]);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_folder_is_refused() {
        let dir = scratch("folder");
        std::fs::create_dir(dir.join("out.gsm")).unwrap();
        assert!(matches!(write_atomic(dir.join("out.gsm"), b"x"), Err(Error::Io { .. })));
        assert!(Replacement::new(&dir.join("out.gsm")).is_err());
        assert!(std::fs::metadata(dir.join("out.gsm")).unwrap().is_dir());
        assert_eq!(names(&dir), ["out.gsm"]);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// A rename that fails at the commit (a folder made under the final
    /// name while the file was written) is an error naming the path, leaves
    /// the folder as it was and removes the temporary file, for either writer.
    #[test]
    fn a_failed_rename_leaves_no_temporary_file() {
        let dir = scratch("rename");
        let p = dir.join("out.gsm");
        let mut f = AtomicFile::create(&p).unwrap();
        f.write(b"bytes").unwrap();
        std::fs::create_dir(&p).unwrap();
        std::fs::write(p.join("inside"), b"kept").unwrap();
        let e = f.commit().unwrap_err();
        assert!(matches!(&e, Error::Io { path, .. } if path.contains("out.gsm")), "{e}");
        assert_eq!(names(&dir), ["out.gsm"], "temporary files left behind");
        assert_eq!(std::fs::read(p.join("inside")).unwrap(), b"kept");
        std::fs::remove_dir_all(&p).unwrap();
        let r = Replacement::new(&p).unwrap();
        std::fs::write(&r.tmp, b"made by another writer").unwrap();
        std::fs::create_dir(&p).unwrap();
        std::fs::write(p.join("inside"), b"kept").unwrap();
        assert!(r.commit().is_err());
        assert_eq!(names(&dir), ["out.gsm"], "temporary files left behind");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn threads_writing_one_path_each_leave_a_whole_file() {
        let dir = scratch("threads");
        let p = dir.join("m.gsm");
        let len = 1 << 20;
        std::thread::scope(|s| {
            for t in 0..4u8 {
                let p = &p;
                s.spawn(move || {
                    for _ in 0..10 {
                        write_atomic(p, &vec![t + 1; len]).unwrap();
                    }
                });
            }
        });
        let got = std::fs::read(&p).unwrap();
        assert_eq!(got.len(), len);
        assert!(got.iter().all(|&b| b == got[0]), "two writers' bytes in one file");
        assert_eq!(names(&dir), ["m.gsm"], "temporary files left behind");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
