// Per primitive: the sum of its (brick, candidate) slots over the bricks
// its box overlaps, in brick order, then the chain rule to the gradient of
// its 12 stored parameters. Mirrors the fixed-order reduction of cpu/mod.rs
// `point_loss_grad` (bricks in order) and kernel.rs `Frame::finalize`.
// Two entry points share the reduction (`team_sum`):
// - `main` writes the gradient (`point_loss_grad` brings it back);
// - `step`, resident training: the regularisers' gradient added to it, then
//   one Adam step on the parameters and moments that stay on the device.
//   Mirrors loss.rs `regularizers` and optim.rs `Adam::step` (both in
//   math.wgsl), as refine.rs calls them. The gradient never leaves the
//   thread that summed it.
//   When either level of candidate lists overflowed, the gradient is
//   incomplete: nothing is changed, and `poison` is set so that the steps
//   queued after this one change nothing either (they ran on parameters
//   this one did not update); the host runs them all again.
//
// Finding a primitive's slot in a brick's list is a binary search, a chain
// of dependent loads; a primitive whose box spans many bricks did them one
// after another. So each primitive has a team of P.split.z threads (a power
// of two up to WG; 0 reads as 1): in each round, thread `t` of the team
// finds the slot of the primitive's brick `round * team + t` (bricks
// counted x fastest, as the loops of one thread walked them), and the
// team's first thread adds the round's slots in that order. The sums are
// those of one thread walking the bricks, whatever the team's size.

@group(0) @binding(0) var<uniform> P: Params;
// Written by `step` only.
@group(0) @binding(1) var<storage, read_write> params: array<f32>;
@group(0) @binding(2) var<storage, read> ranges: array<vec4<u32>>;
// Dense brick index -> occupied brick, NONE when it holds no point.
@group(0) @binding(3) var<storage, read> occupied: array<u32>;
@group(0) @binding(4) var<storage, read> starts: array<u32>;
@group(0) @binding(5) var<storage, read> lists: array<u32>;
@group(0) @binding(6) var<storage, read> partial: array<vec4<f32>>;
// `main` only.
@group(0) @binding(7) var<storage, read_write> grad: array<f32>;
// `step` only. Per primitive: Adam's m (12 floats), then v (12 floats).
@group(0) @binding(8) var<storage, read_write> moments: array<f32>;
// Per primitive: the values of L_scale and L_aniso (summed by loss.wgsl).
@group(0) @binding(9) var<storage, read_write> reg_terms: array<vec2<f32>>;
@group(0) @binding(10) var<storage, read> coarse_starts: array<u32>;
// Nonzero from a step whose lists overflowed until the host clears it.
@group(0) @binding(11) var<storage, read_write> poison: array<atomic<u32>>;

const WG: u32 = 128u;
// Each thread's slot of the round (NONE: its brick is empty, lists no
// such primitive, or lies past the primitive's last).
var<workgroup> slot: array<u32, WG>;
// The rounds the workgroup's longest range takes.
var<workgroup> most_rounds: atomic<u32>;
var<workgroup> rounds: u32;

// The place of `g` in the sorted list lists[r.x .. r.y], or NONE.
fn find(g: u32, r: vec2<u32>) -> u32 {
    var lo = r.x;
    var hi = r.y;
    while lo < hi {
        let mid = (lo + hi) / 2u;
        let v = lists[mid];
        if v == g {
            return mid;
        }
        if v < g {
            lo = mid + 1u;
        } else {
            hi = mid;
        }
    }
    return NONE;
}

fn team_size() -> u32 {
    return clamp(P.split.z, 1u, WG);
}

// What a thread of the reduction ends with: its primitive `g`, whether it
// is its team's first thread (`lead`), and then the primitive's sums.
struct Summed {
    g: u32,
    lead: bool,
    acc: Acc,
}

// The reduction, called by every thread of the workgroup (it has barriers).
fn team_sum(wid: vec3<u32>, nwg: vec3<u32>, lid: u32) -> Summed {
    let team = team_size();
    let g = group_index(wid, nwg) * (WG / team) + lid / team;
    let t = lid % team;
    // The primitive's brick range (every thread of its team reads it), and
    // how many bricks it spans; none past the last primitive, or when its
    // box misses the grid.
    var r0 = vec4<u32>(0u);
    var span = vec3<u32>(0u);
    if g < P.counts.x {
        r0 = ranges[2u * g];
        let r1 = ranges[2u * g + 1u];
        if r0.w == 0u && all(r1.xyz >= r0.xyz) {
            span = r1.xyz - r0.xyz + vec3<u32>(1u);
        }
    }
    let bricks = span.x * span.y * span.z;
    if lid == 0u {
        atomicStore(&most_rounds, 0u);
    }
    workgroupBarrier();
    atomicMax(&most_rounds, (bricks + team - 1u) / team);
    workgroupBarrier();
    if lid == 0u {
        rounds = atomicLoad(&most_rounds);
    }
    let n_rounds = workgroupUniformLoad(&rounds);

    var acc = Acc(vec4<f32>(0.0), vec4<f32>(0.0), vec4<f32>(0.0));
    let d = P.grid_dims.xyz;
    for (var round = 0u; round < n_rounds; round++) {
        let k = round * team + t;
        var j = NONE;
        if k < bricks {
            let x = r0.x + k % span.x;
            let y = r0.y + (k / span.x) % span.y;
            let z = r0.z + k / (span.x * span.y);
            let o = occupied[x + d.x * (y + d.y * z)];
            if o != NONE {
                j = find(g, written(starts[o], starts[o + 1u]));
            }
        }
        slot[lid] = j;
        workgroupBarrier();
        if t == 0u {
            for (var i = 0u; i < team; i++) {
                let s = slot[lid + i];
                if s != NONE {
                    acc.a += partial[3u * s];
                    acc.b += partial[3u * s + 1u];
                    acc.c += partial[3u * s + 2u];
                }
            }
        }
        workgroupBarrier();
    }
    return Summed(g, t == 0u && g < P.counts.x, acc);
}

fn load_primitive(g: u32) -> array<f32, 12> {
    var p: array<f32, 12>;
    for (var i = 0u; i < 12u; i++) {
        p[i] = params[12u * g + i];
    }
    return p;
}

@compute @workgroup_size(128)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>, @builtin(local_invocation_index) lid: u32) {
    let s = team_sum(wid, nwg, lid);
    if !s.lead {
        return;
    }
    let out = finalize(frame_new(load_primitive(s.g)), s.acc);
    for (var i = 0u; i < 12u; i++) {
        grad[12u * s.g + i] = out[i];
    }
}

fn overflowed() -> bool {
    return starts[P.counts.y] > P.counts.z || coarse_starts[P.coarse.x * max(P.bin.y, 1u)] > P.coarse.y;
}

@compute @workgroup_size(128)
fn step(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>, @builtin(local_invocation_index) lid: u32) {
    let s = team_sum(wid, nwg, lid);
    // `overflowed()` is the same for every thread, so no thread reads the
    // word this one sets but one that changes nothing anyway.
    let over = overflowed();
    if over && s.lead && s.g == 0u {
        atomicStore(&poison[0], 1u);
    }
    if !s.lead || over || atomicLoad(&poison[0]) != 0u {
        return;
    }
    let g = s.g;
    let p = load_primitive(g);
    var d = finalize(frame_new(p), s.acc);
    reg_terms[g] = regularize(p, P.reg, P.objective.z, &d);
    for (var i = 0u; i < 12u; i++) {
        let r = adam_update(p[i], d[i], moments[24u * g + i], moments[24u * g + 12u + i], P.optim.x, P.optim.y, P.optim.z);
        params[12u * g + i] = r.x;
        moments[24u * g + i] = r.y;
        moments[24u * g + 12u + i] = r.z;
    }
}
