// Exclusive prefix sum of `counts[0 .. n]` into `starts[0 .. n + 1]`
// (`starts[n]` is the total), n = P.counts.y cells times P.bin.x chunks
// (bin.wgsl), in one workgroup: each thread
// sums a contiguous run, the workgroup scans the 256 run sums, each thread
// writes its run. Integer sums, so the order does not matter; it is fixed
// anyway. Mirrors the offsets pass of backend/csr.rs `csr`.

@group(0) @binding(0) var<uniform> P: Params;
@group(0) @binding(1) var<storage, read> counts: array<u32>;
@group(0) @binding(2) var<storage, read_write> starts: array<u32>;

const WG: u32 = 256u;
var<workgroup> sums: array<u32, WG>;

@compute @workgroup_size(256)
fn main(@builtin(local_invocation_index) lid: u32) {
    let n = P.counts.y * max(P.bin.x, 1u);
    let per = (n + WG - 1u) / WG;
    let b = min(lid * per, n);
    let e = min(b + per, n);
    var s = 0u;
    for (var i = b; i < e; i++) {
        s += counts[i];
    }
    sums[lid] = s;
    workgroupBarrier();
    for (var h = 1u; h < WG; h <<= 1u) {
        var v = 0u;
        if lid >= h {
            v = sums[lid - h];
        }
        workgroupBarrier();
        sums[lid] += v;
        workgroupBarrier();
    }
    var run = sums[lid] - s;
    for (var i = b; i < e; i++) {
        starts[i] = run;
        run += counts[i];
    }
    if lid == WG - 1u {
        starts[n] = sums[WG - 1u];
    }
}
