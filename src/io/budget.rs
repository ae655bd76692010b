//! How much a read of a whole input may hold: a share of the memory this
//! process can take when the read starts ([`crate::memory`]). An input whose
//! length nothing else bounds (the first array of particles or cells, a
//! `.vti`, a step index, a CSV, given as a pipe or a `.zst` that may expand
//! without end) is refused once its content goes beyond its share of that,
//! instead of filling memory until the kernel kills the process.

use crate::{Error, Result};
use std::io::Read;
use std::path::Path;

/// The most bytes a whole read may hold when what is read from them takes
/// `kept_per_byte` times as much memory again (the values parsed from it,
/// a decoded copy): the available memory's share for the bytes.
pub(crate) fn whole_read_budget(kept_per_byte: u64) -> Result<u64> {
    Ok(crate::memory::available()?.map_or(u64::MAX, |m| m / (1 + kept_per_byte)))
}

/// Reads `from` (the content of `path`) to its end when it holds no more
/// than `budget` bytes; refuses it, having read `budget + 1` of them, when
/// it holds more. `size` is the length a regular file says it has, refused
/// unread when it is over. A failed read is the error `failed` makes of it.
pub(crate) fn read_within(path: &Path, mut from: impl Read, size: Option<u64>, budget: u64, failed: impl Fn(std::io::Error) -> Error) -> Result<Vec<u8>> {
    if size.is_some_and(|s| s > budget) {
        return Err(beyond(path, budget));
    }
    let mut out = Vec::with_capacity(usize::try_from(size.unwrap_or(0)).unwrap_or(0));
    (&mut from).take(budget.saturating_add(1)).read_to_end(&mut out).map_err(failed)?;
    if out.len() as u64 > budget {
        return Err(beyond(path, budget));
    }
    Ok(out)
}

fn beyond(path: &Path, budget: u64) -> Error {
    let what = format!(
        "holds more than {budget} bytes, the share of the memory available here that reading it whole may take; \
         give it on a machine with more memory, or in smaller parts"
    );
    Error::io(path, std::io::Error::new(std::io::ErrorKind::OutOfMemory, what))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Content within the budget reads whole; content beyond it is refused
    /// by name after `budget + 1` bytes, a regular file over it unread, and
    /// an endless stream does not keep the read going.
    #[test]
    fn reads_stop_at_the_budget() {
        let p = Path::new("input.bin");
        let io = |e| Error::io(p, e);
        assert_eq!(read_within(p, &b"0123456789"[..], None, 10, io).unwrap(), b"0123456789");
        let e = read_within(p, &b"0123456789"[..], None, 9, io).unwrap_err();
        assert!(matches!(&e, Error::Io { path, source } if path == "input.bin" && source.kind() == std::io::ErrorKind::OutOfMemory && source.to_string().contains("more than 9 bytes")), "{e}");
        let mut endless = std::io::repeat(7);
        assert!(read_within(p, &mut endless, None, 1 << 20, io).is_err());
        struct Unread;
        impl Read for Unread {
            fn read(&mut self, _: &mut [u8]) -> std::io::Result<usize> {
                panic!("read content that its length refuses")
            }
        }
        let unread = read_within(p, Unread, Some(11), 10, io).unwrap_err();
        assert!(unread.to_string().contains("more than 10 bytes"), "{unread}");
    }
}
