//! The stable counting sort that the point passes build their lists with:
//! points by brick, primitives by the bricks they overlap, primitives by
//! decode slab. Parallel over the tasks that produced the pairs, and the same
//! output whatever the thread count.

use rayon::prelude::*;

/// One task's `(key, value)` pairs, in the order it made them, and how many
/// each key has, counted as they are pushed (so that the sort needs no pass
/// of its own to count them).
pub(crate) struct Keyed {
    pairs: Vec<(u32, u32)>,
    counts: Vec<u32>,
}

impl Keyed {
    /// Room for `capacity` pairs with keys below `nkeys`.
    pub(crate) fn new(nkeys: usize, capacity: usize) -> Keyed {
        Keyed { pairs: Vec::with_capacity(capacity), counts: vec![0; nkeys] }
    }

    /// `pairs`, counted.
    pub(crate) fn from_pairs(nkeys: usize, pairs: Vec<(u32, u32)>) -> Keyed {
        let mut counts = vec![0; nkeys];
        for &(k, _) in &pairs {
            counts[k as usize] += 1;
        }
        Keyed { pairs, counts }
    }

    #[inline]
    pub(crate) fn push(&mut self, key: u32, value: u32) {
        self.counts[key as usize] += 1;
        self.pairs.push((key, value));
    }
}

/// Stable counting sort of `(key, value)` pairs, given per task in task order,
/// into CSR form over `nkeys` keys (the keys every part counted): values of
/// key `k` are `vals[start[k]..start[k + 1]]`, in task order. Parallel over
/// tasks, and the same output whatever the thread count.
pub(crate) fn csr(nkeys: usize, mut parts: Vec<Keyed>) -> (Vec<u32>, Vec<u32>) {
    // Each part's counts become its write offset per key.
    let (start, len) = offsets_of(nkeys, &mut parts);
    // Every element is written once below: no zeroing first (a serial
    // pass over about a megabyte a batch).
    let mut vals: Vec<u32> = Vec::with_capacity(len);
    let out = SyncPtr(vals.as_mut_ptr());
    parts.par_iter_mut().with_max_len(1).for_each(|part| {
        let out = &out;
        let Keyed { pairs, counts: off } = part;
        for &(k, v) in pairs.iter() {
            let o = &mut off[k as usize];
            // SAFETY: the offsets give every (task, key) its own disjoint
            // range inside `vals`, so no two tasks write one element.
            unsafe { *out.0.add(*o as usize) = v };
            *o += 1;
        }
    });
    // SAFETY: each task's offsets for key `k` start where the tasks before
    // it end and count its pairs of key `k`, and the keys' ranges tile
    // `0..len`, so the fill wrote every element of `0..len` exactly once.
    unsafe { vals.set_len(len) };
    (start, vals)
}

/// Where each key starts (`nkeys + 1` entries) and the number of pairs,
/// from the tasks' histograms, which become each task's write offset per
/// key: the key's start plus what the tasks before it put there.
/// Each loop runs along whole histograms (one loop key by key across every
/// task's histogram strided through them, and took a few times longer).
fn offsets_of(nkeys: usize, parts: &mut [Keyed]) -> (Vec<u32>, usize) {
    let mut start = vec![0u32; nkeys + 1];
    for h in parts.iter().map(|p| &p.counts) {
        assert_eq!(h.len(), nkeys, "a part counted keys below another bound");
        for (s, &c) in start[1..].iter_mut().zip(h) {
            *s += c;
        }
    }
    for k in 0..nkeys {
        start[k + 1] += start[k];
    }
    let mut cursor = start[..nkeys].to_vec();
    for h in parts.iter_mut().map(|p| &mut p.counts) {
        for (at, o) in cursor.iter_mut().zip(h.iter_mut()) {
            let c = *o;
            *o = *at;
            *at += c;
        }
    }
    let len = start[nkeys] as usize;
    (start, len)
}

/// A raw pointer that tasks writing disjoint ranges may share.
struct SyncPtr(*mut u32);
unsafe impl Sync for SyncPtr {}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::rng::Rng;

    #[test]
    fn csr_is_a_stable_sort_by_key() {
        let mut rng = Rng::new(8);
        let parts: Vec<Vec<(u32, u32)>> = (0..7)
            .map(|p| (0..(50 + 13 * p)).map(|i| (rng.below(20) as u32, (p * 1000 + i) as u32)).collect())
            .collect();
        let keyed = |parts: &[Vec<(u32, u32)>]| -> Vec<Keyed> {
            parts
                .iter()
                .map(|p| {
                    let mut k = Keyed::new(20, 0);
                    for &(key, v) in p {
                        k.push(key, v);
                    }
                    k
                })
                .collect()
        };
        let (start, vals) = csr(20, keyed(&parts));
        // Reference: a stable sort of all pairs by key, in task order.
        let mut flat: Vec<(u32, u32)> = parts.concat();
        flat.sort_by_key(|&(k, _)| k);
        assert_eq!(vals, flat.iter().map(|&(_, v)| v).collect::<Vec<_>>());
        for k in 0..20u32 {
            let n = flat.iter().filter(|&&(kk, _)| kk == k).count() as u32;
            assert_eq!(start[k as usize + 1] - start[k as usize], n);
        }
        assert_eq!(start[0], 0);
        // One task and no task at all go through the same path.
        assert_eq!(csr(20, vec![Keyed::from_pairs(20, parts.concat())]).1, vals);
        assert_eq!(csr(3, vec![]), (vec![0; 4], vec![]));
    }
}
