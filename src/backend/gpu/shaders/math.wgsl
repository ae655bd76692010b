// The one math definition (src/math/kernel.rs, src/math/loss.rs) in WGSL.
// Every function names the Rust it mirrors; read the two side by side.
// This file is prepended to every kernel of the GPU backend.

// kernel.rs: SIGMA_MIN, SIGMA_MAX, CUTOFF_D2, CUTOFF_SIGMAS
const SIGMA_MIN: f32 = 0.4;
const SIGMA_MAX: f32 = 8.0;
const CUTOFF_D2: f32 = 25.0;
const CUTOFF_SIGMAS: f32 = 5.0;
// loss.rs: HUBER_DELTA, MASK_REF, COVER_RHO, TRAIN_FLOOR, EVAL_FLOOR
const HUBER_DELTA: f32 = 0.1;
const MASK_REF: f32 = 0.005;
const COVER_RHO: f32 = 0.05;
const TRAIN_FLOOR: f32 = 1e-3;
const EVAL_FLOOR: f32 = 0.05;
// kernel.rs `layout`: offsets inside a primitive's 12 floats.
const MU: u32 = 0u;
const LOG_SCALE: u32 = 3u;
const QUAT: u32 = 6u;
const ALPHA: u32 = 10u;
const BETA: u32 = 11u;

// kernel.rs `sigmoid`
fn sigmoid(x: f32) -> f32 {
    return 1.0 / (1.0 + exp(-x));
}

// kernel.rs `exp_neg_half`: the same Cephes polynomial and Cody-Waite
// reduction, so that both backends evaluate one function. (The Rust reads
// round(x log2 e) from float bits so that its loops vectorise; here `round`
// gives the same integer: both round half to even.)
fn exp_neg_half(d2: f32) -> f32 {
    let x = max(-0.5 * d2, -87.0);
    let nf = round(x * 1.4426950408889634);
    let n = i32(nf);
    let r = x - nf * 0.6933594 - nf * -2.1219444e-4;
    var p = 1.9875691e-4;
    p = p * r + 1.3981999e-3;
    p = p * r + 8.333452e-3;
    p = p * r + 4.1665796e-2;
    p = p * r + 1.6666665e-1;
    p = p * r + 5.0000001e-1;
    let e = p * r * r + r + 1.0;
    return e * bitcast<f32>(u32((n + 127) << 23u));
}

// kernel.rs `rotation`: rows of R for the unit quaternion (w, x, y, z).
fn rotation(q: vec4<f32>) -> array<vec3<f32>, 3> {
    let w = q.x;
    let x = q.y;
    let y = q.z;
    let z = q.w;
    return array<vec3<f32>, 3>(
        vec3<f32>(1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y)),
        vec3<f32>(2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x)),
        vec3<f32>(2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y)),
    );
}

// kernel.rs `Frame`
struct Frame {
    mu: vec3<f32>,
    // axes[k] is column k of R: y_k = axes[k] . (x - mu)
    axes: array<vec3<f32>, 3>,
    sigma: vec3<f32>,
    inv_sigma: vec3<f32>,
    s: f32,
    w: f32,
    ext: vec3<f32>,
    qhat: vec4<f32>,
    qnorm: f32,
    scale_live: vec3<f32>,
}

// kernel.rs `Frame::new`
fn frame_new(p: array<f32, 12>) -> Frame {
    var f: Frame;
    f.mu = vec3<f32>(p[MU], p[MU + 1u], p[MU + 2u]);
    let q = vec4<f32>(p[QUAT], p[QUAT + 1u], p[QUAT + 2u], p[QUAT + 3u]);
    let qn = sqrt(q.x * q.x + q.y * q.y + q.z * q.z + q.w * q.w);
    if qn > 1e-12 {
        f.qhat = q / qn;
        f.qnorm = qn;
    } else {
        f.qhat = vec4<f32>(1.0, 0.0, 0.0, 0.0);
        f.qnorm = 0.0;
    }
    let r = rotation(f.qhat);
    for (var a = 0u; a < 3u; a++) {
        let e = exp(p[LOG_SCALE + a]);
        f.sigma[a] = clamp(e, SIGMA_MIN, SIGMA_MAX);
        f.scale_live[a] = select(0.0, 1.0, e > SIGMA_MIN && e < SIGMA_MAX);
    }
    f.axes = array<vec3<f32>, 3>(
        vec3<f32>(r[0].x, r[1].x, r[2].x),
        vec3<f32>(r[0].y, r[1].y, r[2].y),
        vec3<f32>(r[0].z, r[1].z, r[2].z),
    );
    for (var a = 0u; a < 3u; a++) {
        let v = r[a] * r[a] * f.sigma * f.sigma;
        f.ext[a] = CUTOFF_SIGMAS * sqrt(v.x + v.y + v.z);
    }
    f.inv_sigma = 1.0 / f.sigma;
    f.s = sigmoid(p[ALPHA]);
    f.w = sigmoid(p[BETA]);
    return f;
}

// cpu/lanes.rs `Hot`: what the point passes read of one primitive. a0..a2 are the
// rows of diag(sigma)^-1 R^T (kernel.rs `Frame::scaled_axes`).
struct Hot {
    mu: vec3<f32>,
    w: f32,
    a0: vec3<f32>,
    s: f32,
    a1: vec3<f32>,
    pad0: f32,
    a2: vec3<f32>,
    pad1: f32,
}

// cpu/lanes.rs `Hot::new`
fn hot_new(f: Frame) -> Hot {
    var h: Hot;
    h.mu = f.mu;
    h.w = f.w;
    h.s = f.s;
    h.a0 = f.axes[0] * f.inv_sigma.x;
    h.a1 = f.axes[1] * f.inv_sigma.y;
    h.a2 = f.axes[2] * f.inv_sigma.z;
    h.pad0 = 0.0;
    h.pad1 = 0.0;
    return h;
}

// kernel.rs `Frame::kernel` (as cpu/lanes.rs `block_kernels` computes it from
// `Hot`): the scaled local coordinates y' in xyz and the truncated kernel
// K = exp(-|y'|^2 / 2) in w, 0 at and beyond the cutoff.
fn kernel_at(h: Hot, x: vec3<f32>) -> vec4<f32> {
    let d = x - h.mu;
    let u = vec3<f32>(h.a0.x * d.x + h.a0.y * d.y + h.a0.z * d.z,
                      h.a1.x * d.x + h.a1.y * d.y + h.a1.z * d.z,
                      h.a2.x * d.x + h.a2.y * d.y + h.a2.z * d.z);
    let d2 = u.x * u.x + u.y * u.y + u.z * u.z;
    return vec4<f32>(u, select(0.0, exp_neg_half(d2), d2 < CUTOFF_D2));
}

// The 11 sums of kernel.rs `GradAcc`, as three vec4 (the 12th float unused).
struct Acc {
    a: vec4<f32>, // sum K g_rho, sum K g_n, sum c y'_0, sum c y'_1
    b: vec4<f32>, // sum c y'_2, sum c y'_0^2, sum c y'_1^2, sum c y'_2^2
    c: vec4<f32>, // sum c y'_0 y'_1, sum c y'_0 y'_2, sum c y'_1 y'_2, 0
}

// kernel.rs `GradAcc::add_pair`, with `ky` from `kernel_at`.
fn add_pair(acc: ptr<function, Acc>, h: Hot, ky: vec4<f32>, g_rho: f32, g_n: f32) {
    let k = ky.w;
    let y = ky.xyz;
    let c = -0.5 * k * h.w * (g_rho + h.s * g_n);
    (*acc).a += vec4<f32>(k * g_rho, k * g_n, c * y.x, c * y.y);
    (*acc).b += vec4<f32>(c * y.z, c * y.x * y.x, c * y.y * y.y, c * y.z * y.z);
    (*acc).c += vec4<f32>(c * y.x * y.y, c * y.x * y.z, c * y.y * y.z, 0.0);
}

// kernel.rs `Frame::finalize`: the gradient of the 12 stored parameters.
fn finalize(f: Frame, acc: Acc) -> array<f32, 12> {
    let a_sum = acc.a.x;
    let b_sum = acc.a.y;
    let cy = vec3<f32>(acc.a.z, acc.a.w, acc.b.x);
    // Symmetric M = sum c y y^T.
    let m = array<vec3<f32>, 3>(
        vec3<f32>(acc.b.y, acc.c.x, acc.c.y),
        vec3<f32>(acc.c.x, acc.b.z, acc.c.z),
        vec3<f32>(acc.c.y, acc.c.z, acc.b.w),
    );
    var out: array<f32, 12>;
    out[BETA] = (a_sum + f.s * b_sum) * f.w * (1.0 - f.w);
    out[ALPHA] = f.w * b_sum * f.s * (1.0 - f.s);
    // Centre: dL/dmu = -2 R (P / sigma).
    let z = cy * f.inv_sigma;
    for (var b = 0u; b < 3u; b++) {
        out[MU + b] = -2.0 * (f.axes[0][b] * z.x + f.axes[1][b] * z.y + f.axes[2][b] * z.z);
    }
    // Log-scales.
    for (var k = 0u; k < 3u; k++) {
        out[LOG_SCALE + k] = -2.0 * m[k][k] * f.scale_live[k];
    }
    // Rotation: G_R[b][a] = 2 sum_k R[b][k] sigma_k Q[k][a] / sigma_a.
    var gr: array<vec3<f32>, 3>;
    for (var b = 0u; b < 3u; b++) {
        for (var a = 0u; a < 3u; a++) {
            var rm = 0.0;
            for (var k = 0u; k < 3u; k++) {
                rm += f.axes[k][b] * f.sigma[k] * m[k][a];
            }
            gr[b][a] = 2.0 * rm * f.inv_sigma[a];
        }
    }
    if f.qnorm > 0.0 {
        let w = f.qhat.x;
        let x = f.qhat.y;
        let y = f.qhat.z;
        let zq = f.qhat.w;
        let dr_dw = array<vec3<f32>, 3>(vec3<f32>(0.0, -2.0 * zq, 2.0 * y), vec3<f32>(2.0 * zq, 0.0, -2.0 * x), vec3<f32>(-2.0 * y, 2.0 * x, 0.0));
        let dr_dx = array<vec3<f32>, 3>(vec3<f32>(0.0, 2.0 * y, 2.0 * zq), vec3<f32>(2.0 * y, -4.0 * x, -2.0 * w), vec3<f32>(2.0 * zq, 2.0 * w, -4.0 * x));
        let dr_dy = array<vec3<f32>, 3>(vec3<f32>(-4.0 * y, 2.0 * x, 2.0 * w), vec3<f32>(2.0 * x, 0.0, 2.0 * zq), vec3<f32>(-2.0 * w, 2.0 * zq, -4.0 * y));
        let dr_dz = array<vec3<f32>, 3>(vec3<f32>(-4.0 * zq, -2.0 * w, 2.0 * x), vec3<f32>(2.0 * w, -4.0 * zq, 2.0 * y), vec3<f32>(2.0 * x, 2.0 * y, 0.0));
        let gh = vec4<f32>(contract(gr, dr_dw), contract(gr, dr_dx), contract(gr, dr_dy), contract(gr, dr_dz));
        // Through the normalisation q / |q|.
        let d = gh.x * f.qhat.x + gh.y * f.qhat.y + gh.z * f.qhat.z + gh.w * f.qhat.w;
        for (var i = 0u; i < 4u; i++) {
            out[QUAT + i] = (gh[i] - f.qhat[i] * d) / f.qnorm;
        }
    }
    return out;
}

// The `contract` closure of kernel.rs `Frame::finalize`.
fn contract(g: array<vec3<f32>, 3>, d: array<vec3<f32>, 3>) -> f32 {
    var s = 0.0;
    for (var b = 0u; b < 3u; b++) {
        for (var a = 0u; a < 3u; a++) {
            s += g[b][a] * d[b][a];
        }
    }
    return s;
}

// loss.rs `regularizers`, for one primitive's parameters `p`: adds the
// weighted gradients of L_scale and L_aniso to `grad` and returns their
// (unweighted) values. `w` is `Params.reg`, `aniso_ratio` `Params.objective.z`.
fn regularize(p: array<f32, 12>, w: vec4<f32>, aniso_ratio: f32, grad: ptr<function, array<f32, 12>>) -> vec2<f32> {
    let e = vec3<f32>(exp(p[LOG_SCALE]), exp(p[LOG_SCALE + 1u]), exp(p[LOG_SCALE + 2u]));
    let w_scale = w.x;
    let w_aniso = w.y;
    let inv_3n = w.z;
    let inv_n = w.w;
    var sc = 0.0;
    var an = 0.0;
    for (var a = 0u; a < 3u; a++) {
        if e[a] > 8.0 {
            sc += (e[a] - 8.0) * inv_3n;
            (*grad)[LOG_SCALE + a] += w_scale * e[a] * inv_3n;
        }
        if e[a] < 0.30 {
            sc += 0.05 * (0.30 - e[a]) * inv_3n;
            (*grad)[LOG_SCALE + a] -= w_scale * 0.05 * e[a] * inv_3n;
        }
    }
    var amax = 0u;
    var amin = 0u;
    for (var a = 1u; a < 3u; a++) {
        if e[a] > e[amax] {
            amax = a;
        }
        if e[a] < e[amin] {
            amin = a;
        }
    }
    let ratio = e[amax] / max(e[amin], 1e-3);
    if ratio > aniso_ratio && amax != amin {
        an += (ratio - aniso_ratio) * inv_n;
        (*grad)[LOG_SCALE + amax] += w_aniso * ratio * inv_n;
        if e[amin] > 1e-3 {
            (*grad)[LOG_SCALE + amin] -= w_aniso * ratio * inv_n;
        }
    }
    return vec2<f32>(sc, an);
}

// optim.rs `BETA1`, `BETA2`, `EPS`
const BETA1: f32 = 0.9;
const BETA2: f32 = 0.999;
const EPS: f32 = 1e-8;

// optim.rs `Adam::step` for one parameter: returns (p, m, v) after the step,
// with learning rate `lr` and bias corrections `bc1`, `bc2`.
fn adam_update(p: f32, g: f32, m: f32, v: f32, lr: f32, bc1: f32, bc2: f32) -> vec3<f32> {
    let m1 = BETA1 * m + (1.0 - BETA1) * g;
    let v1 = BETA2 * v + (1.0 - BETA2) * g * g;
    let mh = m1 / bc1;
    let vh = v1 / bc2;
    return vec3<f32>(p - lr * mh / (sqrt(vh) + EPS), m1, v1);
}

// loss.rs `huber`
fn huber(r: f32) -> f32 {
    let a = abs(r);
    if a <= HUBER_DELTA {
        return 0.5 * r * r;
    }
    return HUBER_DELTA * (a - 0.5 * HUBER_DELTA);
}

// loss.rs `huber_grad`
fn huber_grad(r: f32) -> f32 {
    return clamp(r, -HUBER_DELTA, HUBER_DELTA);
}

// loss.rs `v_eval`
fn v_eval(rho: f32, n: f32) -> f32 {
    return clamp(n / max(rho, EVAL_FLOOR), 0.0, 1.0);
}

// loss.rs `fidelity_weight` of an occupied point; `fidelity` is
// `Params.objective.xy`.
fn fidelity_weight(vref: f32, fidelity: vec2<f32>) -> f32 {
    return fidelity.x + fidelity.y * vref;
}

// loss.rs `point_terms`: (val, cov, g_rho, g_n) of one point, given the
// batch's normalisers `inv_weight_sum`, `inv_count`, the weights of L_val
// and L_cov, and the fidelity weight's shape.
fn point_terms(rho: f32, n: f32, vref: f32, inv_weight_sum: f32, inv_count: f32, w_val: f32, w_cov: f32, fidelity: vec2<f32>) -> vec4<f32> {
    if vref <= MASK_REF {
        return vec4<f32>(0.0);
    }
    let omega = fidelity_weight(vref, fidelity);
    let denom = max(rho, TRAIN_FLOOR);
    let r = n / denom - vref;
    let val = omega * huber(r) * inv_weight_sum;
    let dl_dv = w_val * omega * huber_grad(r) * inv_weight_sum;
    var g_rho = select(0.0, -dl_dv * n / (rho * rho), rho > TRAIN_FLOOR);
    let g_n = dl_dv / denom;
    let cov_gap = COVER_RHO - rho;
    var cov = 0.0;
    if cov_gap > 0.0 {
        cov = cov_gap * inv_count;
        g_rho -= w_cov * inv_count;
    }
    return vec4<f32>(val, cov, g_rho, g_n);
}

// What every pass of one backend call reads (gpu/kernels.rs `Params`).
struct Params {
    // xyz: corner of cell (0, 0, 0) of the cell grid; w: 1 / brick edge
    // (training bricks, PointBricks) or unused (lattice bricks).
    grid_lo: vec4<f32>,
    // xyz: lattice step (lattice bricks); w unused.
    grid_step: vec4<f32>,
    // xyz: cells per axis; w: CELLS_* (how a primitive's box maps to cells).
    grid_dims: vec4<u32>,
    // xyz: lattice points per axis (lattice bricks); w: brick edge in points.
    lattice: vec4<u32>,
    // x: primitives; y: cells of this pass; z: capacity of the candidate
    // lists; w: points (training and evaluation).
    counts: vec4<u32>,
    // x: 1 / sum of fidelity weights; y: 1 / points; z: weight of L_val;
    // w: weight of L_cov (loss.rs `PointNorm`, `LossWeights`).
    loss: vec4<f32>,
    // x: which cells a bin pass fills (BIN_*); y: brick layer (lattice
    // bricks); z: first lattice layer of the slab; w: 1 to write the loss terms.
    stage: vec4<u32>,
    // Resident training: x: the learning rate; y, z: Adam's bias
    // corrections 1 - beta1^t, 1 - beta2^t (optim.rs `Adam::step`).
    optim: vec4<f32>,
    // x, y: weights of L_scale and L_aniso; z: 1 / 3N; w: 1 / N
    // (loss.rs `regularizers`).
    reg: vec4<f32>,
    // x: coarse cells; y: capacity of their lists; z: 1 to sum the
    // regularisers' values (loss.wgsl).
    coarse: vec4<u32>,
    // Bin passes (bin.wgsl, scan.wgsl): x: chunks each cell's source list
    // is split into, one workgroup each (0 reads as 1), so the counts and
    // starts hold (cell, chunk) entries, cell-major; y: the same for the
    // pass that made the source lists, so parent p's list runs from
    // src_starts[p * y] to src_starts[(p + 1) * y] (0 reads as 1).
    bin: vec4<u32>,
    // x, y: the fidelity weight's constant and slope in V_ref; z: the axis
    // ratio above which L_aniso acts (loss.rs `LossWeights`).
    objective: vec4<f32>,
    // Point passes: x: pieces of the forward pass (one workgroup each);
    // y: workgroups of the backward pass per brick (0 reads as 1).
    split: vec4<u32>,
    // Binning from bit rows (bin_rows.wgsl): x: parents; y: chunks a
    // parent's list is cut into; z: log2 of a child's edge in bricks; w:
    // the stride of the source starts.
    rows: vec4<u32>,
}

// Params.grid_dims.w
const CELLS_TRAINING: u32 = 0u;
const CELLS_LATTICE: u32 = 1u;
// Params.stage.x
const BIN_LISTED: u32 = 0u;
const BIN_SLAB: u32 = 1u;
const BIN_SLAB_BRICKS: u32 = 2u;
const NONE: u32 = 0xffffffffu;

// Entries [s, e) of a candidate list, clamped to the lists' capacity
// P.counts.z: a level that overflowed is read no further than it was
// written (its totals send the call back to the host, which runs it again).
fn written(s: u32, e: u32) -> vec2<u32> {
    return vec2<u32>(min(s, P.counts.z), min(e, P.counts.z));
}

// A linear workgroup index over a 2D dispatch (at most 65535 a side).
fn group_index(wid: vec3<u32>, nwg: vec3<u32>) -> u32 {
    return wid.x + wid.y * nwg.x;
}
