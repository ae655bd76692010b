//! How much a read of a whole input may hold: the memory this machine has
//! available when the read starts (Linux's `MemAvailable`, or what is left
//! under the process's cgroup limit when that is lower). An input whose
//! length nothing else bounds (the first array of particles or cells, a
//! `.vti`, a step index, a CSV, given as a pipe or a `.zst` that may expand
//! without end) is refused once its content goes beyond its share of that,
//! instead of filling memory until the kernel kills the process.

use crate::{Error, Result};
use std::io::Read;
use std::path::Path;

/// Bytes of memory available to this process now, where the system says
/// (Linux); `None` elsewhere, where whole reads are not bounded.
pub(crate) fn memory_available() -> Option<u64> {
    #[cfg(target_os = "linux")]
    {
        let meminfo = std::fs::read_to_string("/proc/meminfo").ok()?;
        let kib = meminfo.lines().find_map(|l| l.strip_prefix("MemAvailable:"))?.trim().strip_suffix("kB")?.trim().parse::<u64>().ok()?;
        let system = kib.saturating_mul(1024);
        Some(cgroup_left().map_or(system, |left| left.min(system)))
    }
    #[cfg(not(target_os = "linux"))]
    {
        None
    }
}

/// What the process's cgroup (v2, or v1's memory controller) allows beyond
/// what it uses now, counting its inactive file cache as free (the kernel
/// reclaims that before it refuses memory: a job that has written much
/// output has its usage near the limit without being short of memory);
/// `None` without a limit or where it cannot be read.
#[cfg(target_os = "linux")]
fn cgroup_left() -> Option<u64> {
    let groups = std::fs::read_to_string("/proc/self/cgroup").ok()?;
    let read = |p: String| std::fs::read_to_string(p).ok().and_then(|s| s.trim().parse::<u64>().ok());
    for line in groups.lines() {
        let mut parts = line.splitn(3, ':');
        let (_, controllers, group) = (parts.next()?, parts.next()?, parts.next()?);
        let (dir, limit, usage, cache) = match controllers {
            "" => (format!("/sys/fs/cgroup{group}"), "memory.max", "memory.current", "inactive_file"),
            c if c.split(',').any(|c| c == "memory") => {
                (format!("/sys/fs/cgroup/memory{group}"), "memory.limit_in_bytes", "memory.usage_in_bytes", "total_inactive_file")
            }
            _ => continue,
        };
        let (Some(limit), Some(usage)) = (read(format!("{dir}/{limit}")), read(format!("{dir}/{usage}"))) else { continue };
        let stat = std::fs::read_to_string(format!("{dir}/memory.stat")).unwrap_or_default();
        return Some(limit.saturating_sub(usage).saturating_add(stat_value(&stat, cache).unwrap_or(0)).min(limit));
    }
    None
}

/// The value of `key` in a cgroup's `memory.stat` (lines of `key value`).
#[cfg(target_os = "linux")]
fn stat_value(stat: &str, key: &str) -> Option<u64> {
    stat.lines().find_map(|l| l.strip_prefix(key)?.strip_prefix(' ')?.trim().parse().ok())
}

/// The most bytes a whole read may hold when what is read from them takes
/// `kept_per_byte` times as much memory again (the values parsed from it,
/// a decoded copy): the available memory's share for the bytes.
pub(crate) fn whole_read_budget(kept_per_byte: u64) -> u64 {
    memory_available().map_or(u64::MAX, |m| m / (1 + kept_per_byte))
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

    /// The available memory is read where Linux says it, and is no more than
    /// the machine's total (read here from the same file, independently).
    #[cfg(target_os = "linux")]
    #[test]
    fn available_memory_is_positive_and_at_most_the_total() {
        let meminfo = std::fs::read_to_string("/proc/meminfo").unwrap();
        let total: u64 = meminfo.lines().find(|l| l.starts_with("MemTotal:")).unwrap().split_whitespace().nth(1).unwrap().parse().unwrap();
        let available = memory_available().expect("Linux says how much memory is available");
        assert!(available > 0 && available <= total * 1024, "{available} of {total} KiB");
        assert_eq!(whole_read_budget(1), available / 2);
    }

    /// A cgroup's inactive file cache is read by its exact key.
    #[cfg(target_os = "linux")]
    #[test]
    fn cgroup_stats_are_read_by_key() {
        let stat = "active_file 7\ninactive_file_extra 5\ninactive_file 4096\ntotal_inactive_file 8192\n";
        assert_eq!(stat_value(stat, "inactive_file"), Some(4096));
        assert_eq!(stat_value(stat, "total_inactive_file"), Some(8192));
        assert_eq!(stat_value(stat, "missing"), None);
    }

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
