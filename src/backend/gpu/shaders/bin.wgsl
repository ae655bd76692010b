// Binning: for every cell of a pass, the primitives of its source list
// whose cell range overlaps the cell, in source order. One workgroup per
// (cell, chunk of its source list) gathers, each thread over its own
// contiguous run of the chunk (no atomics, so every list is in a fixed
// order); a pass from every primitive splits the source into chunks of
// BIN_CHUNK (kernels.rs), so that a handful of coarse cells still gives the
// GPU thousands of workgroups. Counts and starts are per (cell, chunk),
// cell-major, so a cell's chunks follow each other in its list:
//   `count`: how many, per (cell, chunk);  (then scan.wgsl: the starts)
//   `fill`:  the lists themselves, written up to `P.counts.z` entries; the
//            scan's total tells the host whether they fitted.
// A cell's source list is its parent's list of the pass before: every
// primitive for the first level; a coarse cell's list for a training brick
// (4^3 bricks a coarse cell), the slab's list for a decode brick. Two
// levels keep the work near (cells + primitives) rather than their product.
// Mirrors cpu/mod.rs `bin_points` (training bricks) and the layer and brick
// lists of cpu/mod.rs `decode_lattice` (lattice slabs, then their bricks).

@group(0) @binding(0) var<uniform> P: Params;
@group(0) @binding(1) var<storage, read> ranges: array<vec4<u32>>;
// The source lists: parent p's is src[src_starts[p] .. src_starts[p + 1]].
@group(0) @binding(2) var<storage, read> src: array<u32>;
@group(0) @binding(3) var<storage, read> src_starts: array<u32>;
// BIN_LISTED: the cells' inclusive boxes, two vec4 per cell; the first's w
// is the cell's parent.
@group(0) @binding(4) var<storage, read> cells: array<vec4<u32>>;
@group(0) @binding(5) var<storage, read_write> counts: array<u32>;
@group(0) @binding(6) var<storage, read> starts: array<u32>;
@group(0) @binding(7) var<storage, read_write> lists: array<u32>;

const WG: u32 = 128u;
var<workgroup> shared_u: array<u32, WG>;

// The inclusive box of cell `c` in grid cells.
fn cell_box(c: u32) -> array<vec3<u32>, 2> {
    let z = P.stage.y;
    if P.stage.x == BIN_SLAB {
        return array<vec3<u32>, 2>(vec3<u32>(0u, 0u, z), vec3<u32>(P.grid_dims.x - 1u, P.grid_dims.y - 1u, z));
    }
    if P.stage.x == BIN_SLAB_BRICKS {
        let b = vec3<u32>(c % P.grid_dims.x, c / P.grid_dims.x, z);
        return array<vec3<u32>, 2>(b, b);
    }
    return array<vec3<u32>, 2>(cells[2u * c].xyz, cells[2u * c + 1u].xyz);
}

fn overlaps(g: u32, lo: vec3<u32>, hi: vec3<u32>) -> bool {
    let r0 = ranges[2u * g];
    let r1 = ranges[2u * g + 1u].xyz;
    return r0.w == 0u && all(r0.xyz <= hi) && all(r1 >= lo);
}

fn split() -> u32 {
    return max(P.bin.x, 1u);
}

// Chunk k of cell c's source list, clamped to the buffer (a parent list
// that overflowed its capacity is read no further than it was written; the
// host runs the call again anyway).
fn source(c: u32, k: u32) -> vec2<u32> {
    var parent = 0u;
    if P.stage.x == BIN_LISTED {
        parent = cells[2u * c].w;
    }
    let stride = max(P.bin.y, 1u);
    let e = min(src_starts[(parent + 1u) * stride], arrayLength(&src));
    let s = min(src_starts[parent * stride], e);
    let per = (e - s + split() - 1u) / split();
    let b = min(s + k * per, e);
    return vec2<u32>(b, min(b + per, e));
}

// This thread's contiguous run of the source list: the runs follow each
// other in thread order, so hits written run by run stay in source order.
fn own_run(s: vec2<u32>, lid: u32) -> vec2<u32> {
    let n = s.y - s.x;
    let per = (n + WG - 1u) / WG;
    let b = min(lid * per, n);
    return vec2<u32>(s.x + b, s.x + min(b + per, n));
}

// What workgroup g of a pass gathers: its cell's box, and this thread's
// run of the cell's source chunk g % split().
struct Work {
    bx: array<vec3<u32>, 2>,
    run: vec2<u32>,
}

fn work(g: u32, lid: u32) -> Work {
    let c = g / split();
    return Work(cell_box(c), own_run(source(c, g % split()), lid));
}

// Hits of cell box `bx` in the run `r`.
fn hits(r: vec2<u32>, bx: array<vec3<u32>, 2>) -> u32 {
    var n = 0u;
    for (var i = r.x; i < r.y; i++) {
        if overlaps(src[i], bx[0], bx[1]) {
            n += 1u;
        }
    }
    return n;
}

@compute @workgroup_size(128)
fn count(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
         @builtin(local_invocation_index) lid: u32) {
    let g = group_index(wid, nwg);
    if g >= P.counts.y * split() {
        return;
    }
    let w = work(g, lid);
    shared_u[lid] = hits(w.run, w.bx);
    workgroupBarrier();
    for (var h = WG / 2u; h > 0u; h >>= 1u) {
        if lid < h {
            shared_u[lid] += shared_u[lid + h];
        }
        workgroupBarrier();
    }
    if lid == 0u {
        counts[g] = shared_u[0];
    }
}

@compute @workgroup_size(128)
fn fill(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
        @builtin(local_invocation_index) lid: u32) {
    let g = group_index(wid, nwg);
    if g >= P.counts.y * split() {
        return;
    }
    let w = work(g, lid);
    let n = hits(w.run, w.bx);
    // Inclusive prefix sum of the runs' hit counts (Hillis-Steele): where
    // this run's hits go.
    shared_u[lid] = n;
    workgroupBarrier();
    for (var h = 1u; h < WG; h <<= 1u) {
        var v = 0u;
        if lid >= h {
            v = shared_u[lid - h];
        }
        workgroupBarrier();
        shared_u[lid] += v;
        workgroupBarrier();
    }
    var at = starts[g] + shared_u[lid] - n;
    for (var i = w.run.x; i < w.run.y; i++) {
        let prim = src[i];
        if overlaps(prim, w.bx[0], w.bx[1]) {
            if at < P.counts.z {
                lists[at] = prim;
            }
            at += 1u;
        }
    }
}
