// Training binning from bit rows: for each child cell of a parent block
// of 4^3 cells, the entries of the parent's source list whose range
// reaches the child, in list order, which is primitive order. Two levels
// use it (points.rs):
//   coarse cells, children of one root block, from every primitive,
//     where the coarse grid is at most 4 cells a side (16 bricks: 256
//     voxels in bricks of 16; otherwise bin.wgsl gathers them);
//   bricks, children of their coarse cell, from the coarse cell's list.
// These are the lists bin.wgsl's gather makes when each child tests the
// parent's whole list, made with one read of each entry instead of one per
// child (up to 64). One workgroup per (parent, chunk of its list), the
// chunk taken in tiles of TILE entries:
//   marking: each thread reads entries of the tile, one after another
//            across the threads, and sets the entry's bit in the bit row of
//            every child its range covers (workgroup memory, integer
//            atomicOr: the same bits in any order);
//   then one thread per child of the block reads its own bit row:
//   `count`: how many, per (child, chunk);
//   `total`: per child, each chunk's place within the child's list and the
//            child's total (then scan.wgsl over the totals: the starts);
//   `fill`:  the lists, entry by entry in list order, written up to
//            P.counts.z entries; the scan's total tells the host whether
//            they fitted.
// Mirrors cpu/binning.rs `bin_points`, which lists the same bricks for a
// primitive in the same order.
// P.rows: x: parents; y: chunks a parent's list is cut into; z: log2 of a
// child's edge in bricks (0: bricks, 2: coarse cells); w: the stride of
// the source starts.

@group(0) @binding(0) var<uniform> P: Params;
// Each primitive's inclusive range in bricks (frames.wgsl).
@group(0) @binding(1) var<storage, read> ranges: array<vec4<u32>>;
// Parent p's list is src[src_starts[p * P.rows.w] .. src_starts[(p + 1) * P.rows.w]].
@group(0) @binding(2) var<storage, read> src: array<u32>;
@group(0) @binding(3) var<storage, read> src_starts: array<u32>;
// The parents' inclusive boxes in child cells, two vec4 per parent.
@group(0) @binding(4) var<storage, read> parents: array<vec4<u32>>;
// Dense child cell index -> child, NONE when there is none (a brick that
// holds no point, a coarse cell without such bricks).
@group(0) @binding(5) var<storage, read> child_map: array<u32>;
// Per (child, chunk), child-major: `count` writes the chunk's entries for
// the child, `total` turns them into the chunk's first place within the
// child's list.
@group(0) @binding(6) var<storage, read_write> chunk_counts: array<u32>;
@group(0) @binding(7) var<storage, read_write> counts: array<u32>;
@group(0) @binding(8) var<storage, read> starts: array<u32>;
@group(0) @binding(9) var<storage, read_write> lists: array<u32>;

// Children per parent block along each axis: points.rs `COARSE`.
const COARSE: u32 = 4u;
const LOCAL: u32 = 64u;
const TILE: u32 = 1024u;
const WORDS: u32 = 32u;
const WG: u32 = 128u;

// Bit j % 32 of word j / 32 of row l: entry j of the tile reaches the
// block's child l (x + 4 (y + 4 z) within the block).
var<workgroup> marks: array<atomic<u32>, 2048>;
// The tile's entries (primitive indices).
var<workgroup> entry: array<u32, 1024>;
// `total`: the threads' run sums, scanned (TW threads: a child has at
// most a few hundred chunks, and one warp of a GPU scans them without
// waiting on others).
const TW: u32 = 32u;
var<workgroup> run_sums: array<u32, TW>;

fn chunks() -> u32 {
    return max(P.rows.y, 1u);
}

struct Chunk {
    lo: vec3<u32>,
    hi: vec3<u32>,
    s: u32,
    e: u32,
}

// Workgroup g's parent (its box) and its chunk of the parent's list,
// clamped to the buffer (a source list that overflowed is read no further
// than it was written; the host runs the call again anyway).
fn chunk_of(g: u32) -> Chunk {
    let c = g / chunks();
    let k = g % chunks();
    let stride = max(P.rows.w, 1u);
    let e = min(src_starts[(c + 1u) * stride], arrayLength(&src));
    let s = min(src_starts[c * stride], e);
    let per = (e - s + chunks() - 1u) / chunks();
    let b = min(s + k * per, e);
    return Chunk(parents[2u * c].xyz, parents[2u * c + 1u].xyz, b, min(b + per, e));
}

// The child that thread `lid` (< LOCAL) reads the row of, NONE where the
// block has no such child.
fn child_of(ch: Chunk, lid: u32) -> u32 {
    let b = ch.lo + vec3<u32>(lid % COARSE, (lid / COARSE) % COARSE, lid / (COARSE * COARSE));
    if lid >= LOCAL || any(b > ch.hi) {
        return NONE;
    }
    let d = (P.grid_dims.xyz + (1u << P.rows.z) - 1u) >> vec3<u32>(P.rows.z);
    return child_map[b.x + d.x * (b.y + d.y * b.z)];
}

// Marks the `n` entries of the tile that starts at list entry `t0`.
fn mark(ch: Chunk, t0: u32, n: u32, lid: u32) {
    let words = (n + 31u) / 32u;
    for (var i = lid; i < LOCAL * words; i += WG) {
        atomicStore(&marks[(i / words) * WORDS + i % words], 0u);
    }
    workgroupBarrier();
    for (var j = lid; j < n; j += WG) {
        let prim = src[t0 + j];
        entry[j] = prim;
        let r0 = ranges[2u * prim];
        let lo = max(r0.xyz >> vec3<u32>(P.rows.z), ch.lo);
        let hi = min(ranges[2u * prim + 1u].xyz >> vec3<u32>(P.rows.z), ch.hi);
        if r0.w != 0u || any(lo > hi) {
            continue;
        }
        let a = lo - ch.lo;
        let z = hi - ch.lo;
        let bit = 1u << (j % 32u);
        for (var bz = a.z; bz <= z.z; bz++) {
            for (var by = a.y; by <= z.y; by++) {
                for (var bx = a.x; bx <= z.x; bx++) {
                    atomicOr(&marks[(bx + COARSE * (by + COARSE * bz)) * WORDS + j / 32u], bit);
                }
            }
        }
    }
    workgroupBarrier();
}

// Workgroup g's chunk, tile by tile: each tile marked, then thread `lid`
// (< LOCAL) reads its child's bit row of the tile, counting its bits into
// the child's slot (`count`) or writing their entries, in order, from the
// chunk's place in the child's list on (`fill`).
fn rows(g: u32, lid: u32, filling: bool) {
    let ch = chunk_of(g);
    let b = child_of(ch, lid);
    let slot = b * chunks() + g % chunks();
    var at = 0u;
    if filling && b != NONE {
        at = starts[b] + chunk_counts[slot];
    }
    for (var t0 = ch.s; t0 < ch.e; t0 += TILE) {
        let len = min(ch.e - t0, TILE);
        mark(ch, t0, len, lid);
        if b != NONE {
            for (var w = 0u; w < (len + 31u) / 32u; w++) {
                var bits = atomicLoad(&marks[lid * WORDS + w]);
                if !filling {
                    at += countOneBits(bits);
                    continue;
                }
                while bits != 0u {
                    if at < P.counts.z {
                        lists[at] = entry[w * 32u + firstTrailingBit(bits)];
                    }
                    at += 1u;
                    bits &= bits - 1u;
                }
            }
        }
        workgroupBarrier();
    }
    if !filling && b != NONE {
        chunk_counts[slot] = at;
    }
}

@compute @workgroup_size(128)
fn count(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
         @builtin(local_invocation_index) lid: u32) {
    let g = group_index(wid, nwg);
    if g < P.rows.x * chunks() {
        rows(g, lid, false);
    }
}

// One workgroup per child: its chunks' counts turned into each chunk's
// place within the child's list (in place), and the child's total.
// Each thread sums a contiguous run of the chunks, the workgroup scans the
// run sums, each thread writes its run (as scan.wgsl does for a whole
// array), so a child of many chunks costs a few steps, not one load after
// another.
@compute @workgroup_size(32)
fn total(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
         @builtin(local_invocation_index) lid: u32) {
    let b = group_index(wid, nwg);
    if b >= P.counts.y {
        return;
    }
    let per = (chunks() + TW - 1u) / TW;
    let s = b * chunks() + min(lid * per, chunks());
    let e = b * chunks() + min(lid * per + per, chunks());
    var n = 0u;
    for (var i = s; i < e; i++) {
        n += chunk_counts[i];
    }
    run_sums[lid] = n;
    workgroupBarrier();
    for (var h = 1u; h < TW; h <<= 1u) {
        var v = 0u;
        if lid >= h {
            v = run_sums[lid - h];
        }
        workgroupBarrier();
        run_sums[lid] += v;
        workgroupBarrier();
    }
    var run = run_sums[lid] - n;
    for (var i = s; i < e; i++) {
        let c = chunk_counts[i];
        chunk_counts[i] = run;
        run += c;
    }
    if lid == TW - 1u {
        counts[b] = run_sums[TW - 1u];
    }
}

@compute @workgroup_size(128)
fn fill(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
        @builtin(local_invocation_index) lid: u32) {
    let g = group_index(wid, nwg);
    if g < P.rows.x * chunks() {
        rows(g, lid, true);
    }
}
