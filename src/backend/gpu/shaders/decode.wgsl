// Decode: V_eval at every lattice point of a slab of bricks. One workgroup
// per brick of BS^3 points (each thread PER of them); the brick's candidates
// are staged in workgroup memory a tile at a time. Mirrors cpu/mod.rs
// `decode_lattice` (which splats each candidate over its box instead of
// gathering per point; the kernel's cutoff lies inside that box, so both
// add the same terms) and loss.rs `v_eval`.

@group(0) @binding(0) var<uniform> P: Params;
@group(0) @binding(1) var<storage, read> hot: array<Hot>;
@group(0) @binding(2) var<storage, read> starts: array<u32>;
@group(0) @binding(3) var<storage, read> lists: array<u32>;
// The slab's values, x fastest, starting at lattice layer P.stage.z.
@group(0) @binding(4) var<storage, read_write> out: array<f32>;

const WG: u32 = 128u;
const BS: u32 = 8u;
const PER: u32 = 4u; // BS^3 / WG
var<workgroup> tile: array<Hot, WG>;

@compute @workgroup_size(128)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
        @builtin(local_invocation_index) lid: u32) {
    let b = group_index(wid, nwg);
    if b >= P.counts.y {
        return;
    }
    let cand = written(starts[b], starts[b + 1u]);
    let corner = vec3<u32>(b % P.grid_dims.x, b / P.grid_dims.x, P.stage.y) * BS;
    var idx: array<vec3<u32>, PER>;
    var x: array<vec3<f32>, PER>;
    var rho: array<f32, PER>;
    var n: array<f32, PER>;
    for (var q = 0u; q < PER; q++) {
        let l = lid + q * WG;
        idx[q] = corner + vec3<u32>(l % BS, (l / BS) % BS, l / (BS * BS));
        x[q] = P.grid_lo.xyz + vec3<f32>(idx[q]) * P.grid_step.xyz;
    }
    for (var t0 = cand.x; t0 < cand.y; t0 += WG) {
        workgroupBarrier();
        if t0 + lid < cand.y {
            tile[lid] = hot[lists[t0 + lid]];
        }
        workgroupBarrier();
        let m = min(WG, cand.y - t0);
        for (var j = 0u; j < m; j++) {
            let h = tile[j];
            for (var q = 0u; q < PER; q++) {
                let wk = h.w * kernel_at(h, x[q]).w;
                rho[q] += wk;
                n[q] += wk * h.s;
            }
        }
    }
    let d = P.lattice.xyz;
    for (var q = 0u; q < PER; q++) {
        let i = idx[q];
        if all(i < d) {
            out[i.x + d.x * (i.y + d.y * (i.z - P.stage.z))] = v_eval(rho[q], n[q]);
        }
    }
}
