// Per primitive: the sum of its (brick, candidate) slots over the bricks
// its box overlaps, in brick order, then the chain rule to the gradient of
// its 12 stored parameters. Mirrors the fixed-order reduction of cpu/mod.rs
// `point_loss_grad` (bricks in order) and kernel.rs `Frame::finalize`.
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
@group(0) @binding(1) var<storage, read> params: array<f32>;
@group(0) @binding(2) var<storage, read> ranges: array<vec4<u32>>;
// Dense brick index -> occupied brick, NONE when it holds no point.
@group(0) @binding(3) var<storage, read> occupied: array<u32>;
@group(0) @binding(4) var<storage, read> starts: array<u32>;
@group(0) @binding(5) var<storage, read> lists: array<u32>;
@group(0) @binding(6) var<storage, read> partial: array<vec4<f32>>;
@group(0) @binding(7) var<storage, read_write> grad: array<f32>;

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

@compute @workgroup_size(128)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>, @builtin(local_invocation_index) lid: u32) {
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
    if t != 0u || g >= P.counts.x {
        return;
    }
    var p: array<f32, 12>;
    for (var i = 0u; i < 12u; i++) {
        p[i] = params[12u * g + i];
    }
    let out = finalize(frame_new(p), acc);
    for (var i = 0u; i < 12u; i++) {
        grad[12u * g + i] = out[i];
    }
}
