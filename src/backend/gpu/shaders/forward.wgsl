// Forward: the mixture's density and numerator at each point of a brick, and
// (training) each point's share of L_val and L_cov with the loss's
// sensitivity to its density and numerator.
// One workgroup per piece of a brick's points (kernels.rs `FORWARD_PIECE`
// points, so that a few dense bricks still give many workgroups), PTS
// points at a time: every thread sums its share of the brick's candidates
// (every WG-th) at those points, then the workgroup adds the threads' sums
// in a fixed tree order. Training bricks hold a handful of points and
// hundreds of candidates, so the candidates, not the points, are spread
// over the threads. A point's sums are the same whichever piece holds it.
// Mirrors cpu/lanes.rs `BrickSoa::forward` and the loop of cpu/mod.rs `grad_chunk`
// (then loss.rs `point_terms`, in math.wgsl).

@group(0) @binding(0) var<uniform> P: Params;
@group(0) @binding(1) var<storage, read> hot: array<Hot>;
@group(0) @binding(2) var<storage, read> starts: array<u32>;
@group(0) @binding(3) var<storage, read> lists: array<u32>;
// Per piece (P.split.x of them): its brick, and its points' range [y, z)
// in `points`.
@group(0) @binding(4) var<storage, read> pieces: array<vec4<u32>>;
// Points sorted by brick: xyz, and the reference value in w.
@group(0) @binding(5) var<storage, read> points: array<vec4<f32>>;
// Per point: (rho, n).
@group(0) @binding(6) var<storage, read_write> rho_n: array<vec2<f32>>;
// Per point (training): (val, cov, g_rho, g_n).
@group(0) @binding(7) var<storage, read_write> terms: array<vec4<f32>>;

const WG: u32 = 128u;
const PTS: u32 = 8u;
var<workgroup> sum_rho: array<array<f32, PTS>, WG>;
var<workgroup> sum_n: array<array<f32, PTS>, WG>;

@compute @workgroup_size(128)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
        @builtin(local_invocation_index) lid: u32) {
    let g = group_index(wid, nwg);
    if g >= P.split.x {
        return;
    }
    let piece = pieces[g];
    let b = piece.x;
    let cand = written(starts[b], starts[b + 1u]);
    let pr = piece.yz;
    for (var p0 = pr.x; p0 < pr.y; p0 += PTS) {
        let m = min(PTS, pr.y - p0);
        // Loops of a constant PTS trips over registers: no dynamically
        // indexed private arrays, which compilers put in memory. Slots past
        // `m` evaluate a point far away (every kernel 0) and are not written.
        var x: array<vec3<f32>, PTS>;
        for (var q = 0u; q < PTS; q++) {
            x[q] = select(vec3<f32>(3.0e38), points[min(p0 + q, pr.y - 1u)].xyz, q < m);
        }
        var rho: array<f32, PTS>;
        var n: array<f32, PTS>;
        for (var j = cand.x + lid; j < cand.y; j += WG) {
            let h = hot[lists[j]];
            for (var q = 0u; q < PTS; q++) {
                let wk = h.w * kernel_at(h, x[q]).w;
                rho[q] += wk;
                n[q] += wk * h.s;
            }
        }
        sum_rho[lid] = rho;
        sum_n[lid] = n;
        workgroupBarrier();
        for (var h = WG / 2u; h > 0u; h >>= 1u) {
            if lid < h {
                for (var q = 0u; q < PTS; q++) {
                    sum_rho[lid][q] += sum_rho[lid + h][q];
                    sum_n[lid][q] += sum_n[lid + h][q];
                }
            }
            workgroupBarrier();
        }
        if lid < m {
            let p = p0 + lid;
            let r = sum_rho[0][lid];
            let nn = sum_n[0][lid];
            rho_n[p] = vec2<f32>(r, nn);
            if P.stage.w == 1u {
                terms[p] = point_terms(r, nn, points[p].w, P.loss.x, P.loss.y, P.loss.z, P.loss.w, P.objective.xy);
            }
        }
        workgroupBarrier();
    }
}
