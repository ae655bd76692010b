// Resident training, per primitive: the regularisers' gradient added to the
// point terms' (reduce.wgsl's output), then one Adam step on the parameters
// and moments that stay on the device. Mirrors loss.rs `regularizers` and
// optim.rs `Adam::step` (both in math.wgsl), as refine.rs calls them.
// When either level of candidate lists overflowed, the gradient is
// incomplete: nothing is changed, `mark` sets `poison` so that the steps
// queued after this one change nothing either (they ran on parameters
// this one did not update), and the host runs them all again.

@group(0) @binding(0) var<uniform> P: Params;
@group(0) @binding(1) var<storage, read> grad: array<f32>;
@group(0) @binding(2) var<storage, read_write> params: array<f32>;
// Per primitive: Adam's m (12 floats), then v (12 floats).
@group(0) @binding(3) var<storage, read_write> moments: array<f32>;
// Per primitive: the values of L_scale and L_aniso (summed by loss.wgsl).
@group(0) @binding(4) var<storage, read_write> reg_terms: array<vec2<f32>>;
@group(0) @binding(5) var<storage, read> starts: array<u32>;
@group(0) @binding(6) var<storage, read> coarse_starts: array<u32>;
// Nonzero from a step whose lists overflowed until the host clears it.
@group(0) @binding(7) var<storage, read_write> poison: array<u32>;

fn overflowed() -> bool {
    return starts[P.counts.y] > P.counts.z || coarse_starts[P.coarse.x * max(P.bin.y, 1u)] > P.coarse.y;
}

@compute @workgroup_size(128)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let g = gid.x + gid.y * nwg.x * 128u;
    if g >= P.counts.x {
        return;
    }
    if overflowed() || poison[0] != 0u {
        return;
    }
    var p: array<f32, 12>;
    var d: array<f32, 12>;
    for (var i = 0u; i < 12u; i++) {
        p[i] = params[12u * g + i];
        d[i] = grad[12u * g + i];
    }
    reg_terms[g] = regularize(p, P.reg, P.objective.z, &d);
    for (var i = 0u; i < 12u; i++) {
        let r = adam_update(p[i], d[i], moments[24u * g + i], moments[24u * g + 12u + i], P.optim.x, P.optim.y, P.optim.z);
        params[12u * g + i] = r.x;
        moments[24u * g + i] = r.y;
        moments[24u * g + 12u + i] = r.z;
    }
}

// One thread, after `main`: poisons the steps queued after an overflowed one.
@compute @workgroup_size(1)
fn mark() {
    if overflowed() {
        poison[0] = 1u;
    }
}
