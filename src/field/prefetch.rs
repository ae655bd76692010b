//! A hint to the cache: start loading an element that a loop will read a
//! few iterations later. Training draws read grid voxels and pool entries
//! at random places of arrays of megabytes, each a likely cache miss; one
//! point's lookups depend on each other (a pool entry gives the voxel, the
//! voxel its neighbours), so without hints a core waits for each miss in
//! turn. A hint changes no result: it is a no-op where the architecture has
//! no stable prefetch instruction in Rust (everything but x86-64), and for
//! an index past the end.

/// Asks the cache for the line holding `data[i]`, if `i` is in bounds.
#[inline(always)]
pub fn prefetch<T>(data: &[T], i: usize) {
    if let Some(x) = data.get(i) {
        prefetch_ptr(x as *const T);
    }
}

#[inline(always)]
fn prefetch_ptr<T>(p: *const T) {
    #[cfg(target_arch = "x86_64")]
    // SAFETY: a prefetch reads nothing architecturally and cannot fault;
    // `p` points into a live slice anyway.
    unsafe {
        use std::arch::x86_64::{_mm_prefetch, _MM_HINT_T0};
        _mm_prefetch::<_MM_HINT_T0>(p as *const i8);
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = p;
}
