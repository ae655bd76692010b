// Binning's second level for training: each occupied brick's candidates,
// the entries of its coarse cell's list (bin.wgsl, first level) whose
// brick range reaches the brick, in list order, which is primitive order.
// These are the lists bin.wgsl's gather makes when each brick tests its
// cell's whole list, made with one read of each entry instead of one per
// brick of the cell (up to 64). One workgroup per (coarse cell, chunk of
// its list), the chunk taken in tiles of TILE entries:
//   marking: each thread reads entries of the tile, one after another
//            across the threads, and sets the entry's bit in the bit row of
//            every brick of the cell its range covers (workgroup memory,
//            integer atomicOr: the same bits in any order);
//   then one thread per brick of the cell reads its own bit row:
//   `count`: how many, per (brick, chunk);
//   `total`: per brick, each chunk's place within the brick's list and the
//            brick's total (then scan.wgsl over the totals: the starts);
//   `fill`:  the lists, entry by entry in list order, written up to
//            P.counts.z entries; the scan's total tells the host whether
//            they fitted.
// Mirrors cpu/binning.rs `bin_points`, which lists the same bricks for a
// primitive in the same order.

@group(0) @binding(0) var<uniform> P: Params;
@group(0) @binding(1) var<storage, read> ranges: array<vec4<u32>>;
// The first level: coarse cell c's list is
// coarse_lists[coarse_starts[c * P.bin.y] .. coarse_starts[(c + 1) * P.bin.y]].
@group(0) @binding(2) var<storage, read> coarse_lists: array<u32>;
@group(0) @binding(3) var<storage, read> coarse_starts: array<u32>;
// The coarse cells' inclusive brick boxes, two vec4 per cell.
@group(0) @binding(4) var<storage, read> coarse_cells: array<vec4<u32>>;
// Dense brick index -> occupied brick, NONE when it holds no point.
@group(0) @binding(5) var<storage, read> occupied: array<u32>;
// Per (occupied brick, chunk), brick-major: `count` writes the chunk's
// entries for the brick, `total` turns them into the chunk's first place
// within the brick's list.
@group(0) @binding(6) var<storage, read_write> chunk_counts: array<u32>;
@group(0) @binding(7) var<storage, read_write> counts: array<u32>;
@group(0) @binding(8) var<storage, read> starts: array<u32>;
@group(0) @binding(9) var<storage, read_write> lists: array<u32>;

// Bricks per coarse cell along each axis: points.rs `COARSE`.
const COARSE: u32 = 4u;
const LOCAL: u32 = 64u;
const TILE: u32 = 1024u;
const WORDS: u32 = 32u;
const WG: u32 = 128u;

// Bit j % 32 of word j / 32 of row l: entry j of the tile reaches the
// cell's brick l (x + 4 (y + 4 z) within the cell).
var<workgroup> marks: array<atomic<u32>, 2048>;
// The tile's entries (primitive indices).
var<workgroup> entry: array<u32, 1024>;

fn chunks() -> u32 {
    return max(P.bin.z, 1u);
}

struct Chunk {
    lo: vec3<u32>,
    hi: vec3<u32>,
    s: u32,
    e: u32,
}

// Workgroup g's coarse cell (its brick box) and its chunk of the cell's
// list, clamped to what the first level could write.
fn chunk_of(g: u32) -> Chunk {
    let c = g / chunks();
    let k = g % chunks();
    let stride = max(P.bin.y, 1u);
    let e = min(min(coarse_starts[(c + 1u) * stride], P.coarse.y), arrayLength(&coarse_lists));
    let s = min(coarse_starts[c * stride], e);
    let per = (e - s + chunks() - 1u) / chunks();
    let b = min(s + k * per, e);
    return Chunk(coarse_cells[2u * c].xyz, coarse_cells[2u * c + 1u].xyz, b, min(b + per, e));
}

// The occupied brick that thread `lid` (< LOCAL) reads the row of, NONE
// where the cell has no such brick or it holds no point.
fn brick_of(ch: Chunk, lid: u32) -> u32 {
    let b = ch.lo + vec3<u32>(lid % COARSE, (lid / COARSE) % COARSE, lid / (COARSE * COARSE));
    if lid >= LOCAL || any(b > ch.hi) {
        return NONE;
    }
    return occupied[b.x + P.grid_dims.x * (b.y + P.grid_dims.y * b.z)];
}

// Marks the `n` entries of the tile that starts at list entry `t0`.
fn mark(ch: Chunk, t0: u32, n: u32, lid: u32) {
    let words = (n + 31u) / 32u;
    for (var i = lid; i < LOCAL * words; i += WG) {
        atomicStore(&marks[(i / words) * WORDS + i % words], 0u);
    }
    workgroupBarrier();
    for (var j = lid; j < n; j += WG) {
        let prim = coarse_lists[t0 + j];
        entry[j] = prim;
        let r0 = ranges[2u * prim];
        let lo = max(r0.xyz, ch.lo);
        let hi = min(ranges[2u * prim + 1u].xyz, ch.hi);
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
// (< LOCAL) reads its brick's bit row of the tile, counting its bits into
// the brick's slot (`count`) or writing their entries, in order, from the
// chunk's place in the brick's list on (`fill`).
fn rows(g: u32, lid: u32, filling: bool) {
    let ch = chunk_of(g);
    let b = brick_of(ch, lid);
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
    if g < P.coarse.x * chunks() {
        rows(g, lid, false);
    }
}

@compute @workgroup_size(128)
fn total(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
         @builtin(local_invocation_index) lid: u32) {
    let b = group_index(wid, nwg) * WG + lid;
    if b >= P.counts.y {
        return;
    }
    var run = 0u;
    for (var k = 0u; k < chunks(); k++) {
        let n = chunk_counts[b * chunks() + k];
        chunk_counts[b * chunks() + k] = run;
        run += n;
    }
    counts[b] = run;
}

@compute @workgroup_size(128)
fn fill(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
        @builtin(local_invocation_index) lid: u32) {
    let g = group_index(wid, nwg);
    if g < P.coarse.x * chunks() {
        rows(g, lid, true);
    }
}
