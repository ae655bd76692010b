// The batch's L_val and L_cov: the sums of every point's terms, and, in
// resident training, L_scale and L_aniso: the sums of every primitive's
// (reduce.wgsl `step`). One workgroup, a fixed order (each thread a strided run,
// then a tree). Mirrors the loss sums of cpu/mod.rs `point_loss_grad` and of
// loss.rs `regularizers` (which sum in f64; here f32, so the figures differ
// in the last digits).

@group(0) @binding(0) var<uniform> P: Params;
@group(0) @binding(1) var<storage, read> terms: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> reg_terms: array<vec2<f32>>;
// (L_val, L_cov), (L_scale, L_aniso).
@group(0) @binding(3) var<storage, read_write> out: array<vec2<f32>>;

const WG: u32 = 256u;
var<workgroup> sums: array<vec4<f32>, WG>;

@compute @workgroup_size(256)
fn main(@builtin(local_invocation_index) lid: u32) {
    var s = vec4<f32>(0.0);
    for (var i = lid; i < P.counts.w; i += WG) {
        s += vec4<f32>(terms[i].xy, 0.0, 0.0);
    }
    if P.coarse.z == 1u {
        for (var i = lid; i < P.counts.x; i += WG) {
            s += vec4<f32>(0.0, 0.0, reg_terms[i]);
        }
    }
    sums[lid] = s;
    workgroupBarrier();
    for (var h = WG / 2u; h > 0u; h >>= 1u) {
        if lid < h {
            sums[lid] += sums[lid + h];
        }
        workgroupBarrier();
    }
    if lid == 0u {
        out[0] = sums[0].xy;
        out[1] = sums[0].zw;
    }
}
