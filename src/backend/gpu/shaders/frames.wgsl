// Per primitive, once per backend call: its `Hot` record and the inclusive
// range of grid cells its 5-sigma box overlaps.
// Mirrors cpu/mod.rs `Prepared::update` (Frame::new, Hot::new, the tight box),
// then bricks.rs `PointBricks::range_of` (training bricks) or the box test
// of cpu/mod.rs `decode_lattice` (lattice bricks).

@group(0) @binding(0) var<uniform> P: Params;
@group(0) @binding(1) var<storage, read> params: array<f32>;
@group(0) @binding(2) var<storage, read_write> hot: array<Hot>;
// Two per primitive: (r0, empty) and (r1, 0); empty = 1 when the box misses the grid.
@group(0) @binding(3) var<storage, read_write> ranges: array<vec4<u32>>;

fn load_primitive(g: u32) -> array<f32, 12> {
    var p: array<f32, 12>;
    for (var i = 0u; i < 12u; i++) {
        p[i] = params[12u * g + i];
    }
    return p;
}

// bricks.rs `PointBricks::range_of`
fn training_range(lo: vec3<f32>, hi: vec3<f32>) -> array<vec4<u32>, 2> {
    var r: array<vec4<u32>, 2>;
    for (var a = 0u; a < 3u; a++) {
        let l = (lo[a] - P.grid_lo[a]) * P.grid_lo.w;
        let h = (hi[a] - P.grid_lo[a]) * P.grid_lo.w;
        let last = f32(P.grid_dims[a] - 1u);
        // NaN fails every comparison: `!(l == l)` catches it.
        if h < 0.0 || l >= f32(P.grid_dims[a]) || !(l == l) || !(h == h) {
            r[0].w = 1u;
            return r;
        }
        r[0][a] = u32(max(l, 0.0));
        r[1][a] = u32(min(h, last));
    }
    return r;
}

// The box test of cpu/mod.rs `decode_lattice`: the lattice points inside the box,
// then the bricks (of `P.lattice.w` points a side) that hold them.
fn lattice_range(lo: vec3<f32>, hi: vec3<f32>) -> array<vec4<u32>, 2> {
    var r: array<vec4<u32>, 2>;
    for (var a = 0u; a < 3u; a++) {
        let l = ceil((lo[a] - P.grid_lo[a]) / P.grid_step[a]);
        let h = floor((hi[a] - P.grid_lo[a]) / P.grid_step[a]);
        let last = f32(P.lattice[a] - 1u);
        if !(h >= 0.0 && l <= last) || h < l {
            r[0].w = 1u;
            return r;
        }
        r[0][a] = u32(max(l, 0.0)) / P.lattice.w;
        r[1][a] = u32(min(h, last)) / P.lattice.w;
    }
    return r;
}

@compute @workgroup_size(128)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let g = gid.x + gid.y * nwg.x * 128u;
    if g >= P.counts.x {
        return;
    }
    let f = frame_new(load_primitive(g));
    hot[g] = hot_new(f);
    var r: array<vec4<u32>, 2>;
    if P.grid_dims.w == CELLS_TRAINING {
        r = training_range(f.mu - f.ext, f.mu + f.ext);
    } else {
        r = lattice_range(f.mu - f.ext, f.mu + f.ext);
    }
    ranges[2u * g] = r[0];
    ranges[2u * g + 1u] = r[1];
}
