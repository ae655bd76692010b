// Per primitive: the sum of its (brick, candidate) slots over the bricks
// its box overlaps, in brick order, then the chain rule to the gradient of
// its 12 stored parameters. Mirrors the fixed-order reduction of cpu/mod.rs
// `point_loss_grad` (bricks in order) and kernel.rs `Frame::finalize`.

@group(0) @binding(0) var<uniform> P: Params;
@group(0) @binding(1) var<storage, read> params: array<f32>;
@group(0) @binding(2) var<storage, read> ranges: array<vec4<u32>>;
// Dense brick index -> occupied brick, NONE when it holds no point.
@group(0) @binding(3) var<storage, read> occupied: array<u32>;
@group(0) @binding(4) var<storage, read> starts: array<u32>;
@group(0) @binding(5) var<storage, read> lists: array<u32>;
@group(0) @binding(6) var<storage, read> partial: array<vec4<f32>>;
@group(0) @binding(7) var<storage, read_write> grad: array<f32>;

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

@compute @workgroup_size(128)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let g = gid.x + gid.y * nwg.x * 128u;
    if g >= P.counts.x {
        return;
    }
    var acc = Acc(vec4<f32>(0.0), vec4<f32>(0.0), vec4<f32>(0.0));
    let r0 = ranges[2u * g];
    let r1 = ranges[2u * g + 1u];
    if r0.w == 0u {
        let d = P.grid_dims.xyz;
        for (var z = r0.z; z <= r1.z; z++) {
            for (var y = r0.y; y <= r1.y; y++) {
                for (var x = r0.x; x <= r1.x; x++) {
                    let o = occupied[x + d.x * (y + d.y * z)];
                    if o == NONE {
                        continue;
                    }
                    let j = find(g, written(starts[o], starts[o + 1u]));
                    if j != NONE {
                        acc.a += partial[3u * j];
                        acc.b += partial[3u * j + 1u];
                        acc.c += partial[3u * j + 2u];
                    }
                }
            }
        }
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
