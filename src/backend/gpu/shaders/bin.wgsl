// Binning: for every cell of a pass, the primitives of a source list whose
// cell range overlaps the cell, in source order. One workgroup per cell
// gathers (no atomics, so every list is in a fixed order):
//   `count`: how many, per cell;  (then scan.wgsl: each list's start)
//   `fill`:  the lists themselves, written up to `P.counts.z` entries; the
//            scan's total tells the host whether they fitted.
// Mirrors cpu.rs `bin_points` (training bricks) and the layer and brick
// lists of cpu.rs `decode_lattice` (lattice slabs, then their bricks).

@group(0) @binding(0) var<uniform> P: Params;
@group(0) @binding(1) var<storage, read> ranges: array<vec4<u32>>;
// The source list is src[src_bounds[0] .. src_bounds[1]].
@group(0) @binding(2) var<storage, read> src: array<u32>;
@group(0) @binding(3) var<storage, read> src_bounds: array<u32>;
// BIN_LISTED: the cells' inclusive boxes, two vec4 per cell.
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

// The source list's bounds, clamped to the buffer (a source list that
// overflowed its own capacity is read no further than it was written).
fn source() -> vec2<u32> {
    let e = min(src_bounds[1], arrayLength(&src));
    return vec2<u32>(min(src_bounds[0], e), e);
}

@compute @workgroup_size(128)
fn count(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
         @builtin(local_invocation_index) lid: u32) {
    let c = group_index(wid, nwg);
    if c >= P.counts.y {
        return;
    }
    let bx = cell_box(c);
    let s = source();
    var n = 0u;
    for (var i = s.x + lid; i < s.y; i += WG) {
        if overlaps(src[i], bx[0], bx[1]) {
            n += 1u;
        }
    }
    shared_u[lid] = n;
    workgroupBarrier();
    for (var h = WG / 2u; h > 0u; h >>= 1u) {
        if lid < h {
            shared_u[lid] += shared_u[lid + h];
        }
        workgroupBarrier();
    }
    if lid == 0u {
        counts[c] = shared_u[0];
    }
}

@compute @workgroup_size(128)
fn fill(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
        @builtin(local_invocation_index) lid: u32) {
    let c = group_index(wid, nwg);
    if c >= P.counts.y {
        return;
    }
    let bx = cell_box(c);
    let s = source();
    let base = starts[c];
    var run = 0u;
    for (var i0 = s.x; i0 < s.y; i0 += WG) {
        let i = i0 + lid;
        var g = 0u;
        var f = 0u;
        if i < s.y {
            g = src[i];
            f = select(0u, 1u, overlaps(g, bx[0], bx[1]));
        }
        // Inclusive prefix sum of the flags (Hillis-Steele): each hit's place.
        shared_u[lid] = f;
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
        if f == 1u {
            let at = base + run + shared_u[lid] - 1u;
            if at < P.counts.z {
                lists[at] = g;
            }
        }
        run += shared_u[WG - 1u];
        workgroupBarrier();
    }
}
