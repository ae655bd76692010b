// Forward: the mixture's density and numerator at each point of a brick, and
// (training) each point's share of L_val and L_cov with the loss's
// sensitivity to its density and numerator.
// One workgroup per occupied brick; the brick's candidates are staged in
// workgroup memory a tile at a time, every point of the brick reads them.
// Mirrors cpu.rs `BrickSoa::forward` and the loop of cpu.rs `grad_chunk`
// (then loss.rs `point_terms`, in math.wgsl).

@group(0) @binding(0) var<uniform> P: Params;
@group(0) @binding(1) var<storage, read> hot: array<Hot>;
@group(0) @binding(2) var<storage, read> starts: array<u32>;
@group(0) @binding(3) var<storage, read> lists: array<u32>;
// Per occupied brick: its points' range [x, y) in `points`.
@group(0) @binding(4) var<storage, read> brick_points: array<vec2<u32>>;
// Points sorted by brick: xyz, and the reference value in w.
@group(0) @binding(5) var<storage, read> points: array<vec4<f32>>;
// Per point: (rho, n).
@group(0) @binding(6) var<storage, read_write> rho_n: array<vec2<f32>>;
// Per point (training): (val, cov, g_rho, g_n).
@group(0) @binding(7) var<storage, read_write> terms: array<vec4<f32>>;

const WG: u32 = 128u;
var<workgroup> tile: array<Hot, WG>;

@compute @workgroup_size(128)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
        @builtin(local_invocation_index) lid: u32) {
    let b = group_index(wid, nwg);
    if b >= P.counts.y {
        return;
    }
    let c0 = min(starts[b], P.counts.z);
    let c1 = min(starts[b + 1u], P.counts.z);
    let pr = brick_points[b];
    for (var p0 = pr.x; p0 < pr.y; p0 += WG) {
        let p = p0 + lid;
        let live = p < pr.y;
        var x = vec4<f32>(0.0);
        if live {
            x = points[p];
        }
        var rho = 0.0;
        var n = 0.0;
        for (var t0 = c0; t0 < c1; t0 += WG) {
            workgroupBarrier();
            if t0 + lid < c1 {
                tile[lid] = hot[lists[t0 + lid]];
            }
            workgroupBarrier();
            let m = min(WG, c1 - t0);
            for (var j = 0u; j < m; j++) {
                let h = tile[j];
                let wk = h.w * kernel_at(h, x.xyz).w;
                rho += wk;
                n += wk * h.s;
            }
        }
        if live {
            rho_n[p] = vec2<f32>(rho, n);
            if P.stage.w == 1u {
                terms[p] = point_terms(rho, n, x.w, P.loss.x, P.loss.y, P.loss.z, P.loss.w);
            }
        }
    }
}
