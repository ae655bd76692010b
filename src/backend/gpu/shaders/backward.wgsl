// Backward: for each (brick, candidate) pair, the sums of kernel.rs
// `GradAcc` over the brick's points, written to the pair's own slot (the
// candidate's place in the brick's list). P.split.y workgroups per occupied
// brick, each taking every P.split.y-th chunk of WG candidates (so that a
// few bricks with many candidates still give many workgroups); one thread
// per candidate sums over every point of the brick in order, points staged
// in workgroup memory a tile at a time. No two threads write one location,
// so there are no atomics and the sums are the same each run, whatever
// the slices.
// Mirrors cpu/lanes.rs `BrickSoa::backward` (kernel.rs `GradAcc::add_pair`).

@group(0) @binding(0) var<uniform> P: Params;
@group(0) @binding(1) var<storage, read> hot: array<Hot>;
@group(0) @binding(2) var<storage, read> starts: array<u32>;
@group(0) @binding(3) var<storage, read> lists: array<u32>;
@group(0) @binding(4) var<storage, read> brick_points: array<vec2<u32>>;
@group(0) @binding(5) var<storage, read> points: array<vec4<f32>>;
@group(0) @binding(6) var<storage, read> terms: array<vec4<f32>>;
// Three vec4 (an `Acc`) per list slot.
@group(0) @binding(7) var<storage, read_write> partial: array<vec4<f32>>;

const WG: u32 = 128u;
// xyz and g_rho; g_n.
var<workgroup> tile_x: array<vec4<f32>, WG>;
var<workgroup> tile_gn: array<f32, WG>;

@compute @workgroup_size(128)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
        @builtin(local_invocation_index) lid: u32) {
    let slices = max(P.split.y, 1u);
    let g = group_index(wid, nwg);
    let b = g / slices;
    if b >= P.counts.y {
        return;
    }
    let cand = written(starts[b], starts[b + 1u]);
    let pr = brick_points[b];
    for (var j0 = cand.x + (g % slices) * WG; j0 < cand.y; j0 += slices * WG) {
        let j = j0 + lid;
        let live = j < cand.y;
        var h: Hot;
        if live {
            h = hot[lists[j]];
        }
        var acc = Acc(vec4<f32>(0.0), vec4<f32>(0.0), vec4<f32>(0.0));
        for (var p0 = pr.x; p0 < pr.y; p0 += WG) {
            workgroupBarrier();
            if p0 + lid < pr.y {
                let t = terms[p0 + lid];
                tile_x[lid] = vec4<f32>(points[p0 + lid].xyz, t.z);
                tile_gn[lid] = t.w;
            }
            workgroupBarrier();
            if live {
                let m = min(WG, pr.y - p0);
                for (var q = 0u; q < m; q++) {
                    let ky = kernel_at(h, tile_x[q].xyz);
                    if ky.w > 0.0 {
                        add_pair(&acc, h, ky, tile_x[q].w, tile_gn[q]);
                    }
                }
            }
        }
        if live {
            partial[3u * j] = acc.a;
            partial[3u * j + 1u] = acc.b;
            partial[3u * j + 2u] = acc.c;
        }
    }
}
