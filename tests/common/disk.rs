//! A small disk, for the tests of a full one: a tmpfs of a few KiB where
//! this process may mount one (root on Linux, as in CI); elsewhere an
//! ordinary folder whose writers run under `ulimit -f` (SIGXFSZ ignored), so
//! that a write past the limit fails with EFBIG where a full disk's fails
//! with ENOSPC: the same failing write on any machine. Each disk says which
//! it is on standard error.

use std::ffi::OsStr;
use std::path::PathBuf;
use std::process::Command;

/// A folder on a disk of `kib` KiB, unmounted when dropped.
pub struct SmallDisk {
    pub dir: PathBuf,
    kib: u64,
    mounted: bool,
    /// The test's folder that holds `dir`, removed after the unmount.
    _root: super::TmpDir,
}

impl SmallDisk {
    /// The folder `disk` in a fresh `tmpdir(name)`.
    pub fn new(name: &str, kib: u64) -> SmallDisk {
        let root = super::tmpdir(name);
        let dir = root.join("disk");
        std::fs::create_dir_all(&dir).unwrap();
        let size = format!("size={kib}k");
        let mounted = cfg!(target_os = "linux")
            && Command::new("mount").args(["-t", "tmpfs", "-o", &size, "tmpfs"]).arg(&dir).output().is_ok_and(|o| o.status.success());
        match mounted {
            true => eprintln!("full disk: a {kib} KiB tmpfs at {}", dir.display()),
            false => eprintln!("full disk: no tmpfs could be mounted (not root?): files of at most {kib} KiB (ulimit -f)"),
        }
        SmallDisk { dir, kib, mounted, _root: root }
    }

    pub fn path(&self, name: &str) -> PathBuf {
        self.dir.join(name)
    }

    /// `program`, to write on this disk (under `ulimit -f` without a tmpfs;
    /// bash counts it in KiB, and exec keeps the process id).
    pub fn command(&self, program: impl AsRef<OsStr>) -> Command {
        if self.mounted {
            return Command::new(program);
        }
        let mut c = Command::new("bash");
        c.args(["-c", &format!("trap '' XFSZ; ulimit -S -f {}; exec \"$0\" \"$@\"", self.kib)]).arg(program);
        c
    }

    /// Gives the disk room while `writer` (a process from [`command`]) runs:
    /// the tmpfs grows to `kib`, or the writer's file size limit is lifted.
    pub fn grow(&self, kib: u64, writer: u32) {
        let out = match self.mounted {
            true => Command::new("mount").args(["-o", &format!("remount,size={kib}k")]).arg(&self.dir).output(),
            false => Command::new("prlimit").args(["--pid", &writer.to_string(), "--fsize=unlimited:unlimited"]).output(),
        }
        .unwrap();
        assert!(out.status.success(), "growing the disk: {}", String::from_utf8_lossy(&out.stderr));
    }

    /// The names in the folder, sorted.
    pub fn names(&self) -> Vec<String> {
        let mut v: Vec<String> = std::fs::read_dir(&self.dir).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
        v.sort();
        v
    }
}

impl Drop for SmallDisk {
    fn drop(&mut self) {
        if self.mounted {
            // Lazily: a writer that a failed test left running may still
            // hold a file there.
            let _ = Command::new("umount").arg("-l").arg(&self.dir).status();
        }
    }
}

/// Whether an error says the write failed for want of room: the disk's
/// (ENOSPC) or the file size limit's (EFBIG).
pub fn says_full(err: &str) -> bool {
    err.contains("No space left on device") || err.contains("File too large")
}
