//! Files and the file system, above the core (which works on memory only):
//! raw arrays ([`raw`]), VTK ImageData ([`vti`]), crash-safe writes
//! ([`atomic`]), model files and folders of them ([`models`]), the HDF5
//! store of a time series and its decoded series (`store`, `series`,
//! feature `hdf5`), and PNG charts ([`plot`]). Used by the command-line
//! tool, the C API and the MPI layer; never by the encoder.

pub mod atomic;
mod budget;
#[cfg(feature = "hdf5")]
mod global_heap;
pub mod image;
pub mod models;
pub mod plot;
pub mod preview;
pub mod raw;
#[cfg(feature = "hdf5")]
pub mod series;
#[cfg(feature = "hdf5")]
pub mod store;
pub mod vti;

pub use atomic::{write_atomic, AtomicFile};
pub use models::{read_field, read_model_file, read_step, read_step_index, ModelFolder};

/// Whether `path` starts with HDF5's signature (an HDF5 store, as opposed
/// to a model file); false when it cannot be read. Builds without the
/// `hdf5` feature have it too, to say that a store needs that feature.
pub fn is_hdf5_file(path: &std::path::Path) -> bool {
    hdf5_signature(path).unwrap_or(false)
}

/// Whether `path` starts with HDF5's signature (gsenc stores have no user
/// block); an error only when the file cannot be opened or read, not when
/// it is shorter than the signature.
pub fn hdf5_signature(path: &std::path::Path) -> std::io::Result<bool> {
    use std::io::Read;
    let mut head = [0u8; 8];
    match std::fs::File::open(path)?.read_exact(&mut head) {
        Ok(()) => Ok(&head == b"\x89HDF\r\n\x1a\n"),
        Err(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => Ok(false),
        Err(e) => Err(e),
    }
}

/// The whole content of a file or a pipe, refusing a device (`/dev/zero`, a
/// disk, a terminal) unread: its content may have no end to read to. Content
/// beyond half the memory available (what is parsed from it takes as much
/// again) is refused by name rather than read on (`budget`). The readers of
/// whole files (`.vti`, step indexes, CSV) read through it.
pub fn read_whole(path: &std::path::Path) -> crate::Result<Vec<u8>> {
    let file = open_to_end(path)?;
    budget::read_within(path, &file, file_len(&file), budget::whole_read_budget(1)?, |e| crate::Error::io(path, e))
}

/// A text made safe inside an XML attribute or element (the `.vti` and
/// XDMF writers); the `.vti` reader's attribute lookup undoes it.
pub(crate) fn xml_escape(s: &str) -> String {
    s.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;").replace('"', "&quot;").replace('\'', "&apos;")
}

/// The length of a regular file (not of a pipe, whose metadata says 0).
fn file_len(file: &std::fs::File) -> Option<u64> {
    file.metadata().ok().filter(|m| m.is_file()).map(|m| m.len())
}

/// Opens `path` for a read to its end: a device is refused (InvalidArgument,
/// naming it), since its content may have no end. [`read_whole`] and the
/// unbounded readers of `raw` open through it.
pub(crate) fn open_to_end(path: &std::path::Path) -> crate::Result<std::fs::File> {
    let file = std::fs::File::open(path).map_err(|e| crate::Error::io(path, e))?;
    if is_device(&file) {
        return Err(crate::Error::arg(format!("{}: is a device, whose content has no end to read to; give a file or a pipe", path.display())));
    }
    Ok(file)
}

/// Whether `file` is a character or block device (`/dev/zero`, a disk, a
/// terminal): one that can be read without end, unlike a file or a pipe.
fn is_device(file: &std::fs::File) -> bool {
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        file.metadata().is_ok_and(|m| m.file_type().is_char_device() || m.file_type().is_block_device())
    }
    #[cfg(not(unix))]
    {
        let _ = file;
        false
    }
}

#[cfg(test)]
mod tests {
    use crate::Error;

    /// Whole-file readers refuse a device by name, before reading it (a read
    /// of `/dev/zero` to its end would never return), and read files whole.
    #[cfg(unix)]
    #[test]
    fn whole_file_readers_refuse_devices() {
        let zero = std::path::Path::new("/dev/zero");
        let errors = [
            super::read_whole(zero).unwrap_err(),
            super::vti::read_vti(zero, None).unwrap_err(),
            super::read_step(zero).map(|_| ()).unwrap_err(),
        ];
        for e in errors {
            assert!(matches!(&e, Error::InvalidArgument(m) if m.contains("/dev/zero") && m.contains("is a device")), "{e}");
        }
        let p = std::env::temp_dir().join(format!("gsenc-read-whole-{}", std::process::id()));
        std::fs::write(&p, b"\xffwhole").unwrap();
        assert_eq!(super::read_whole(&p).unwrap(), b"\xffwhole");
        let e = super::read_step(&p).map(|_| ()).unwrap_err();
        assert!(matches!(&e, Error::Format(m) if m.contains("not a step index")), "{e}");
        std::fs::remove_file(&p).unwrap();
    }
}
