//! How much memory this process can still take: the least of what Linux
//! says is available (`MemAvailable`), what the process's cgroup leaves
//! under its limit (a batch job's memory request), what its resource
//! limits leave (`ulimit -v`, `ulimit -d`), and what `GSENC_MEMORY_LIMIT`
//! leaves (the most memory the process may hold, for a code that shares
//! its node and wants gsenc's share bounded). What cannot fit is refused
//! before it is allocated, with an error that says so: an allocation that
//! fails aborts the process, and in a simulation that links gsenc that is
//! the whole run. Readers of inputs whose length nothing bounds use it
//! (`io/budget.rs`), and so do an encode, before it allocates its
//! training state (`encode::refine::validate`), and a deposit (its grid
//! and accumulators) and a decode (its slab, or its whole lattice), those
//! two through [`check_large`]. [`with_pages`] allocates a buffer whose
//! pages are in memory before its first write (a push's copy).

/// The variable that bounds the memory the process may hold: bytes, or a
/// number with a suffix `k`, `M`, `G` or `T` (powers of 1024), as `8G`.
pub const LIMIT_VARIABLE: &str = "GSENC_MEMORY_LIMIT";

/// Bytes of memory this process can take now, where the system says
/// (Linux); `None` elsewhere, where nothing is refused on its account
/// (unless `GSENC_MEMORY_LIMIT` is set: then the limit as a whole, since
/// what the process holds is not known there). An error only when
/// `GSENC_MEMORY_LIMIT` is set to what is not a size.
pub fn available() -> crate::Result<Option<u64>> {
    let limit = env_limit()?;
    #[cfg(target_os = "linux")]
    {
        let Some(system) = std::fs::read_to_string("/proc/meminfo").ok().and_then(|m| kib_value(&m, "MemAvailable:")) else {
            return Ok(limit);
        };
        let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
        let asked = limit.map(|limit| limit.saturating_sub(kib_value(&status, "VmRSS:").unwrap_or(0)));
        Ok(Some([cgroup_left(), limits_left(&status), asked].into_iter().flatten().fold(system, u64::min)))
    }
    #[cfg(not(target_os = "linux"))]
    {
        Ok(limit)
    }
}

/// Refuses to allocate `bytes` for `what` when this process cannot take them
/// now (an InvalidArgument error naming both sizes).
pub fn check_fits(what: &str, bytes: u64) -> crate::Result<()> {
    check_fits_in(what, bytes, available()?)
}

/// Requests of fewer bytes are not checked by [`check_large`]: the check
/// reads `/proc` (about 0.1 ms), and so little memory decides nothing.
pub const CHECKED_BYTES: u64 = 64 << 20;

/// [`check_fits`] for requests of [`CHECKED_BYTES`] or more. Rust's
/// fallible reservation (`try_reserve`) does not say whether memory fits:
/// Linux promises what it may not have (overcommit) and kills the process
/// (SIGKILL, no error) when the memory is written, so a large buffer is
/// checked here before it is reserved.
pub fn check_large(what: &str, bytes: u64) -> crate::Result<()> {
    match bytes < CHECKED_BYTES {
        true => Ok(()),
        false => check_fits(what, bytes),
    }
}

/// [`check_fits`] against `available` bytes (nothing is refused with `None`).
pub fn check_fits_in(what: &str, bytes: u64, available: Option<u64>) -> crate::Result<()> {
    match available {
        Some(left) if bytes > left => Err(crate::Error::arg(format!("{what} takes {bytes} bytes, more than the {left} this process can take now"))),
        _ => Ok(()),
    }
}

/// `GSENC_MEMORY_LIMIT` in bytes (`None` when unset or empty); a value
/// that is not a size is an error, as a bad `GSENC_BACKEND` is.
fn env_limit() -> crate::Result<Option<u64>> {
    match std::env::var(LIMIT_VARIABLE) {
        Ok(text) if !text.trim().is_empty() => parse_size(&text)
            .map(Some)
            .ok_or_else(|| crate::Error::arg(format!("{LIMIT_VARIABLE}: '{text}' is not a size such as 8G or 1073741824"))),
        _ => Ok(None),
    }
}

/// A size in bytes: digits, then at most one of `k`, `M`, `G`, `T`
/// (powers of 1024).
fn parse_size(text: &str) -> Option<u64> {
    let t = text.trim();
    let (digits, shift) = match t.char_indices().last()? {
        (i, 'k' | 'K') => (&t[..i], 10),
        (i, 'm' | 'M') => (&t[..i], 20),
        (i, 'g' | 'G') => (&t[..i], 30),
        (i, 't' | 'T') => (&t[..i], 40),
        _ => (t, 0),
    };
    digits.parse::<u64>().ok()?.checked_mul(1 << shift)
}

/// One of this process's memory figures in bytes, as Linux's
/// `/proc/self/status` gives it: `"VmHWM:"` (peak resident), `"VmRSS:"`,
/// `"VmSize:"` (virtual); `None` elsewhere or where it cannot be read. For
/// reports (the CLI's `peak_rss_bytes`, the examples); nothing is refused
/// on its account.
pub fn process_status(key: &str) -> Option<u64> {
    #[cfg(target_os = "linux")]
    {
        kib_value(&std::fs::read_to_string("/proc/self/status").ok()?, key)
    }
    #[cfg(not(target_os = "linux"))]
    {
        let _ = key;
        None
    }
}

/// An empty vector with room for `len` values whose memory the system has
/// already given (Linux's `madvise(MADV_POPULATE_WRITE)`, since 5.14: one
/// call, instead of a fault on the first write of every 4 KiB page; 2,048
/// faults for a 128^3 field of f32). Where that is not available, a plain
/// `Vec::with_capacity`, whose pages fault in as they are written.
pub fn with_pages<T>(len: usize) -> Vec<T> {
    let v: Vec<T> = Vec::with_capacity(len);
    #[cfg(target_os = "linux")]
    {
        const PAGE: usize = 4096;
        let (at, bytes) = (v.as_ptr() as usize, v.capacity() * std::mem::size_of::<T>());
        let (start, end) = (at.next_multiple_of(PAGE), (at + bytes) / PAGE * PAGE);
        if end > start {
            // SAFETY: the whole pages inside this vector's allocation,
            // which nothing has written yet; populating them changes no
            // contents (an error, such as an older kernel's, changes
            // nothing either).
            unsafe { libc::madvise(start as *mut libc::c_void, end - start, libc::MADV_POPULATE_WRITE) };
        }
    }
    v
}

/// The value in bytes of a `key: N kB` line (`/proc/meminfo`, `/proc/self/status`).
#[cfg(target_os = "linux")]
fn kib_value(text: &str, key: &str) -> Option<u64> {
    let kib: u64 = text.lines().find_map(|l| l.strip_prefix(key))?.trim().strip_suffix("kB")?.trim().parse().ok()?;
    Some(kib.saturating_mul(1024))
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

/// What the process's soft limits on its address space and its data leave
/// beyond what it has mapped now (`status`: `/proc/self/status`); `None`
/// when neither is set.
#[cfg(target_os = "linux")]
fn limits_left(status: &str) -> Option<u64> {
    let limits = std::fs::read_to_string("/proc/self/limits").ok()?;
    let left = |name: &str, used: &str| Some(soft_limit(&limits, name)?.saturating_sub(kib_value(status, used).unwrap_or(0)));
    [left("Max address space", "VmSize:"), left("Max data size", "VmData:")].into_iter().flatten().min()
}

/// The soft limit in bytes on the `name` line of `/proc/self/limits`;
/// `None` when it is unlimited.
#[cfg(target_os = "linux")]
fn soft_limit(limits: &str, name: &str) -> Option<u64> {
    limits.lines().find_map(|l| l.strip_prefix(name))?.split_whitespace().next()?.parse().ok()
}

#[cfg(test)]
mod tests {
    #[cfg(target_os = "linux")]
    use super::*;

    /// A buffer from `with_pages` is empty, has its room, and (Linux) every
    /// whole page of it is in memory before anything is written, as
    /// `mincore` reports page by page; a plain `Vec::with_capacity` of the
    /// same size has none (so the check can tell them apart).
    #[cfg(target_os = "linux")]
    #[test]
    fn with_pages_gives_pages_before_they_are_written() {
        const PAGE: usize = 4096;
        let resident = |v: &Vec<f32>| -> (usize, usize) {
            let at = v.as_ptr() as usize;
            let (start, end) = (at.next_multiple_of(PAGE), (at + 4 * v.capacity()) / PAGE * PAGE);
            let mut pages = vec![0u8; (end - start) / PAGE];
            // SAFETY: a range inside the vector's allocation; `pages` has a
            // byte for each of its pages.
            let rc = unsafe { libc::mincore(start as *mut libc::c_void, end - start, pages.as_mut_ptr()) };
            assert_eq!(rc, 0, "mincore");
            (pages.iter().filter(|&&p| p & 1 == 1).count(), pages.len())
        };
        let n = 16 << 20; // 64 MiB: its own mapping, never memory reused from before
        let v: Vec<f32> = with_pages(n);
        assert!(v.is_empty() && v.capacity() >= n);
        let (got, of) = resident(&v);
        assert_eq!(got, of, "pages in memory before any write");
        let plain: Vec<f32> = Vec::with_capacity(n);
        let (got, of) = resident(&plain);
        assert!(got < of / 2, "a plain allocation already had {got} of {of} pages");
    }

    /// The available memory is read where Linux says it, and is no more than
    /// the machine's total (read here from the same file, independently).
    #[cfg(target_os = "linux")]
    #[test]
    fn available_memory_is_positive_and_at_most_the_total() {
        let meminfo = std::fs::read_to_string("/proc/meminfo").unwrap();
        let total: u64 = meminfo.lines().find(|l| l.starts_with("MemTotal:")).unwrap().split_whitespace().nth(1).unwrap().parse().unwrap();
        let available = available().unwrap().expect("Linux says how much memory is available");
        assert!(available > 0 && available <= total * 1024, "{available} of {total} KiB");
    }

    /// The process's own figures: a 64 MiB buffer it has written shows in
    /// its resident size, its peak and its virtual size (each read anew, so
    /// they are not compared with each other), and a key that is not there
    /// gives nothing.
    #[cfg(target_os = "linux")]
    #[test]
    fn process_figures_are_read_in_bytes() {
        let held = std::hint::black_box(vec![1u8; 64 << 20]);
        let want = held.len() as u64;
        for key in ["VmRSS:", "VmHWM:", "VmSize:"] {
            let got = process_status(key).unwrap_or_else(|| panic!("Linux gives {key}"));
            assert!(got >= want, "{key} {got} bytes while holding {want}");
        }
        assert_eq!(process_status("VmNoSuchKey:"), None);
        drop(held);
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

    /// What fits is taken to the byte; one byte more is refused with both
    /// sizes and what wanted them; nothing is refused where the system does
    /// not say.
    #[test]
    fn what_fits_is_taken_to_the_byte() {
        assert!(super::check_fits_in("a field", 4096, Some(4096)).is_ok());
        let e = super::check_fits_in("a field", 4097, Some(4096)).unwrap_err();
        assert!(matches!(&e, crate::Error::InvalidArgument(m) if m.contains("a field takes 4097 bytes") && m.contains("the 4096 this process")), "{e}");
        assert!(super::check_fits_in("a field", u64::MAX, None).is_ok());
        assert!(super::check_fits_in("a field", 1, Some(0)).is_err());
    }

    /// Sizes read with their suffixes; what is not a size is none.
    #[test]
    fn sizes_read_with_their_suffixes() {
        for (text, bytes) in [("1073741824", 1 << 30), ("8G", 8 << 30), ("512m", 512 << 20), (" 3k ", 3 << 10), ("2T", 2 << 40)] {
            assert_eq!(super::parse_size(text), Some(bytes), "{text}");
        }
        for text in ["", "G", "-1", "1.5G", "8GB", "lots", "99999999999T"] {
            assert_eq!(super::parse_size(text), None, "{text}");
        }
    }

    /// Soft limits are read from their line, unlimited ones are none, and
    /// `kB` values are read in bytes.
    #[cfg(target_os = "linux")]
    #[test]
    fn limits_and_sizes_are_read_by_name() {
        let limits = "Limit                     Soft Limit           Hard Limit           Units     \n\
                      Max data size             unlimited            unlimited            bytes     \n\
                      Max address space         4096000000           unlimited            bytes     \n";
        assert_eq!(soft_limit(limits, "Max address space"), Some(4_096_000_000));
        assert_eq!(soft_limit(limits, "Max data size"), None);
        assert_eq!(kib_value("VmPeak:\t  900 kB\nVmSize:\t  812 kB\n", "VmSize:"), Some(812 * 1024));
    }
}
