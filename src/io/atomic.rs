//! Crash-safe file writes: a temporary file in the target's folder, flushed to
//! disk, then renamed over the target. A failure (full disk, no permission)
//! leaves any earlier file under the final name untouched.

use crate::error::{Error, Result};
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

pub fn write_atomic(path: impl AsRef<Path>, bytes: &[u8]) -> Result<()> {
    let mut f = AtomicFile::create(path)?;
    f.write(bytes)?;
    f.commit()
}

/// A hidden name beside `path` for a file to be renamed over it once whole.
pub fn temporary_path(path: &Path) -> Result<PathBuf> {
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let name = path.file_name().ok_or_else(|| Error::arg(format!("'{}' is not a file path", path.display())))?;
    Ok(dir.join(format!(".{}.tmp-{}", name.to_string_lossy(), std::process::id())))
}

/// A file written piece by piece under a temporary name and renamed over its
/// final name by [`AtomicFile::commit`]; dropped uncommitted (an error on the
/// way), the temporary file is removed and nothing under the final name changes.
pub struct AtomicFile {
    path: PathBuf,
    tmp: PathBuf,
    file: Option<BufWriter<File>>,
}

impl AtomicFile {
    pub fn create(path: impl AsRef<Path>) -> Result<AtomicFile> {
        let path = path.as_ref().to_path_buf();
        let tmp = temporary_path(&path)?;
        let file = File::create(&tmp).map_err(|e| Error::io(&path, e))?;
        Ok(AtomicFile { path, tmp, file: Some(BufWriter::with_capacity(1 << 20, file)) })
    }

    pub fn write(&mut self, bytes: &[u8]) -> Result<()> {
        let f = self.file.as_mut().expect("an AtomicFile is open until commit");
        f.write_all(bytes).map_err(|e| Error::io(&self.path, e))
    }

    /// Flushes to disk and renames over the final name.
    pub fn commit(mut self) -> Result<()> {
        let f = self.file.take().expect("an AtomicFile is open until commit");
        let done = f.into_inner().map_err(|e| e.into_error()).and_then(|f| f.sync_all()).and_then(|_| std::fs::rename(&self.tmp, &self.path));
        done.map_err(|e| Error::io(&self.path, e))
    }
}

impl Drop for AtomicFile {
    fn drop(&mut self) {
        // Uncommitted, or the commit failed: leave nothing behind.
        if self.file.take().is_some() || self.tmp.exists() {
            let _ = std::fs::remove_file(&self.tmp);
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
        let leftovers: Vec<_> = std::fs::read_dir(&dir).unwrap().filter_map(|e| e.ok()).collect();
        assert_eq!(leftovers.len(), 1, "temporary files left behind");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
