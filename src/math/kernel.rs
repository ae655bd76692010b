//! The one mathematical definition of a primitive, its truncated kernel and
//! the kernel's analytic gradients (METHOD.md "Representation").
//!
//! Every backend evaluates exactly these formulas. The gradient is split in
//! two so that it maps onto hardware without float atomics:
//! [`GradAcc::add_pair`] accumulates, per primitive, eleven sums over the points
//! it touches (expressed in the primitive's local frame), and
//! [`Frame::finalize`] turns the sums into the gradient of the twelve stored
//! parameters once per primitive. Summing the pair terms is the only reduction.

/// One primitive: 12 float32 parameters, stored in this order in memory and
/// in model files.
pub type Primitive = [f32; 12];

/// Offsets of the parameter groups inside a [`Primitive`].
pub mod layout {
    /// Centre `mu[3]` in the index frame.
    pub const MU: usize = 0;
    /// Log standard deviations `l[3]` along the primitive's local axes.
    pub const LOG_SCALE: usize = 3;
    /// Rotation quaternion `q[4]` as (w, x, y, z); not necessarily unit length.
    pub const QUAT: usize = 6;
    /// Scalar logit: `s = sigmoid(alpha)`.
    pub const ALPHA: usize = 10;
    /// Weight logit: `w = sigmoid(beta)`.
    pub const BETA: usize = 11;
}

/// Standard deviations are clamped to this band in voxels when evaluating.
pub const SIGMA_MIN: f32 = 0.4;
pub const SIGMA_MAX: f32 = 8.0;
/// Kernels are truncated at five standard deviations: `d2 < 25`.
pub const CUTOFF_D2: f32 = 25.0;
/// The truncation radius in standard deviations.
pub const CUTOFF_SIGMAS: f32 = 5.0;

#[inline]
pub fn sigmoid(x: f32) -> f32 {
    1.0 / (1.0 + (-x).exp())
}

/// Inverse of [`sigmoid`] after clamping `p` to `[1e-4, 1 - 1e-4]`, as seeded
/// values and weights are (METHOD.md "Seeding").
#[inline]
pub fn logit_clamped(p: f32) -> f32 {
    let p = p.clamp(1e-4, 1.0 - 1e-4);
    (p / (1.0 - p)).ln()
}

/// `exp(-d2 / 2)` for `d2` in `[0, 25)`, accurate to about 1 ulp (Cephes
/// `expf` polynomial with Cody-Waite range reduction). Branch-free and made of
/// plain float and integer operations, so loops over it vectorise; every
/// backend uses it so that all evaluate the same function.
// The coefficients are Cephes' as published, as math.wgsl writes them.
#[allow(clippy::excessive_precision)]
#[inline(always)]
pub fn exp_neg_half(d2: f32) -> f32 {
    const LOG2E: f32 = std::f32::consts::LOG2_E;
    const C1: f32 = 0.693_359_4;
    const C2: f32 = -2.121_944_4e-4;
    const ROUND: f32 = 12_582_912.0; // 1.5 * 2^23: adding it rounds to an integer
    let x = (-0.5 * d2).max(-87.0);
    // `shifted` holds round(x log2 e) in its low mantissa bits; reading the
    // integer from the bits (not with a saturating `as` cast) keeps loops
    // over this function vectorisable.
    let shifted = x * LOG2E + ROUND;
    let nf = shifted - ROUND;
    let n = (shifted.to_bits() as i32).wrapping_sub(0x4B40_0000);
    let r = x - nf * C1 - nf * C2;
    let mut p = 1.987_569_1e-4f32;
    p = p * r + 1.398_199_9e-3;
    p = p * r + 8.333_452e-3;
    p = p * r + 4.166_579_6e-2;
    p = p * r + 1.666_666_5e-1;
    p = p * r + 5.000_000_1e-1;
    let e = p * r * r + r + 1.0;
    e * f32::from_bits((n.wrapping_add(127) << 23) as u32)
}

/// Rotation matrix (row-major) of the unit quaternion (w, x, y, z).
#[inline]
pub fn rotation(q: [f32; 4]) -> [[f32; 3]; 3] {
    let [w, x, y, z] = q;
    [
        [1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y)],
        [2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x)],
        [2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y)],
    ]
}

/// Everything about one primitive that evaluation needs, computed once per
/// iteration from its stored parameters.
#[derive(Clone, Copy, Debug, Default)]
pub struct Frame {
    pub mu: [f32; 3],
    /// Rows are the columns of R: `y_k = axes[k] . (x - mu)` is the local coordinate.
    pub axes: [[f32; 3]; 3],
    /// Clamped standard deviations.
    pub sigma: [f32; 3],
    pub inv_sigma: [f32; 3],
    /// `s = sigmoid(alpha)`.
    pub s: f32,
    /// `w = sigmoid(beta)`.
    pub w: f32,
    /// Half-extents of the 5-sigma ellipsoid's tight axis-aligned box:
    /// `ext_a = 5 sqrt(Sigma_aa)` with `Sigma = R diag(sigma^2) R^T`.
    pub ext: [f32; 3],
    /// Unit quaternion used for R, and the norm of the stored one.
    pub qhat: [f32; 4],
    pub qnorm: f32,
    /// Per axis: 1 where the sigma clamp is inactive (gradient flows to `l`), else 0.
    pub scale_live: [f32; 3],
}

impl Frame {
    #[inline(always)]
    pub fn new(p: &Primitive) -> Frame {
        use layout::*;
        let mu = [p[MU], p[MU + 1], p[MU + 2]];
        let q = [p[QUAT], p[QUAT + 1], p[QUAT + 2], p[QUAT + 3]];
        let qn = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]).sqrt();
        // A zero quaternion has no direction; read it as the identity (and its
        // gradient is then zero, see `finalize`).
        let (qhat, qnorm) = if qn > 1e-12 {
            ([q[0] / qn, q[1] / qn, q[2] / qn, q[3] / qn], qn)
        } else {
            ([1.0, 0.0, 0.0, 0.0], 0.0)
        };
        let r = rotation(qhat);
        let mut sigma = [0.0; 3];
        let mut scale_live = [0.0; 3];
        for a in 0..3 {
            let e = p[LOG_SCALE + a].exp();
            sigma[a] = e.clamp(SIGMA_MIN, SIGMA_MAX);
            // NaN-safe: only a finite value inside the band is live.
            scale_live[a] = if e > SIGMA_MIN && e < SIGMA_MAX { 1.0 } else { 0.0 };
        }
        let axes = [
            [r[0][0], r[1][0], r[2][0]],
            [r[0][1], r[1][1], r[2][1]],
            [r[0][2], r[1][2], r[2][2]],
        ];
        let mut ext = [0.0; 3];
        for a in 0..3 {
            let var: f32 = (0..3).map(|k| r[a][k] * r[a][k] * sigma[k] * sigma[k]).sum();
            ext[a] = CUTOFF_SIGMAS * var.sqrt();
        }
        Frame {
            mu,
            axes,
            sigma,
            inv_sigma: [1.0 / sigma[0], 1.0 / sigma[1], 1.0 / sigma[2]],
            s: sigmoid(p[ALPHA]),
            w: sigmoid(p[BETA]),
            ext,
            qhat,
            qnorm,
            scale_live,
        }
    }

    /// Scaled local coordinates `y' = diag(sigma)^-1 R^T (x - mu)` and the
    /// truncated kernel `K = exp(-|y'|^2 / 2)` for `|y'|^2 < 25`; `None` outside.
    #[inline(always)]
    pub fn kernel(&self, x: [f32; 3]) -> Option<(f32, [f32; 3])> {
        let d = [x[0] - self.mu[0], x[1] - self.mu[1], x[2] - self.mu[2]];
        let mut y = [0.0f32; 3];
        let mut d2 = 0.0f32;
        for k in 0..3 {
            let a = &self.axes[k];
            y[k] = (a[0] * d[0] + a[1] * d[1] + a[2] * d[2]) * self.inv_sigma[k];
            d2 += y[k] * y[k];
        }
        if d2 < CUTOFF_D2 {
            Some((exp_neg_half(d2), y))
        } else {
            None
        }
    }

    /// Rows of `diag(sigma)^-1 R^T`: `y'_k = scaled_axes()[k] . (x - mu)`.
    pub fn scaled_axes(&self) -> [[f32; 3]; 3] {
        let mut a = self.axes;
        for k in 0..3 {
            for b in 0..3 {
                a[k][b] *= self.inv_sigma[k];
            }
        }
        a
    }

    /// Gradient of the loss with respect to the 12 stored parameters, from the
    /// accumulated pair sums of this primitive.
    #[inline(always)]
    pub fn finalize(&self, acc: &GradAcc) -> Primitive {
        use layout::*;
        let g = &acc.0;
        let (a_sum, b_sum) = (g[0], g[1]);
        let cy = [g[2], g[3], g[4]];
        // Symmetric M = sum c y y^T.
        let m = [[g[5], g[8], g[9]], [g[8], g[6], g[10]], [g[9], g[10], g[7]]];
        let mut out = [0.0f32; 12];

        // Weight and value logits.
        out[BETA] = (a_sum + self.s * b_sum) * self.w * (1.0 - self.w);
        out[ALPHA] = self.w * b_sum * self.s * (1.0 - self.s);

        // With y' = y / sigma the pair sums are P = sum c y' and Q = sum c y' y'^T,
        // and d2 = |y'|^2.
        // Centre: dd2/dmu = -2 R diag(1/sigma) y', so dL/dmu = -2 R (P / sigma).
        let z = [cy[0] * self.inv_sigma[0], cy[1] * self.inv_sigma[1], cy[2] * self.inv_sigma[2]];
        for b in 0..3 {
            out[MU + b] = -2.0 * (self.axes[0][b] * z[0] + self.axes[1][b] * z[1] + self.axes[2][b] * z[2]);
        }

        // Log-scales: dd2/dsigma_k = -2 y'_k^2 / sigma_k and dsigma/dl = sigma (where live).
        for k in 0..3 {
            out[LOG_SCALE + k] = -2.0 * m[k][k] * self.scale_live[k];
        }

        // Rotation: dd2/dR[b][a] = 2 d_b y'_a / sigma_a with d = R diag(sigma) y', so
        // G_R[b][a] = 2 sum_k R[b][k] sigma_k Q[k][a] / sigma_a.
        let mut gr = [[0.0f32; 3]; 3];
        for b in 0..3 {
            for a in 0..3 {
                let rm: f32 = (0..3).map(|k| self.axes[k][b] * self.sigma[k] * m[k][a]).sum();
                gr[b][a] = 2.0 * rm * self.inv_sigma[a];
            }
        }
        if self.qnorm > 0.0 {
            let [w, x, y, z] = self.qhat;
            let dr_dw = [[0.0, -2.0 * z, 2.0 * y], [2.0 * z, 0.0, -2.0 * x], [-2.0 * y, 2.0 * x, 0.0]];
            let dr_dx = [[0.0, 2.0 * y, 2.0 * z], [2.0 * y, -4.0 * x, -2.0 * w], [2.0 * z, 2.0 * w, -4.0 * x]];
            let dr_dy = [[-4.0 * y, 2.0 * x, 2.0 * w], [2.0 * x, 0.0, 2.0 * z], [-2.0 * w, 2.0 * z, -4.0 * y]];
            let dr_dz = [[-4.0 * z, -2.0 * w, 2.0 * x], [2.0 * w, -4.0 * z, 2.0 * y], [2.0 * x, 2.0 * y, 0.0]];
            let contract = |d: [[f32; 3]; 3]| -> f32 {
                let mut s = 0.0;
                for b in 0..3 {
                    for a in 0..3 {
                        s += gr[b][a] * d[b][a];
                    }
                }
                s
            };
            let gh = [contract(dr_dw), contract(dr_dx), contract(dr_dy), contract(dr_dz)];
            // Through the normalisation q / |q|.
            let dot: f32 = (0..4).map(|i| gh[i] * self.qhat[i]).sum();
            for i in 0..4 {
                out[QUAT + i] = (gh[i] - self.qhat[i] * dot) / self.qnorm;
            }
        }
        out
    }
}

/// Per-primitive sums over the points it touches, in its scaled local frame
/// `y' = diag(sigma)^-1 R^T (x - mu)`:
/// `[sum K g_rho, sum K g_n, sum c y' (3), sum c y' y'^T (xx, yy, zz, xy, xz, yz)]`
/// with `c = dL/d(d2) = -K w (g_rho + s g_n) / 2`. Eleven floats, padded to 12.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[repr(C)]
pub struct GradAcc(pub [f32; 12]);

impl GradAcc {
    /// Adds the contribution of one point at which this primitive's kernel is
    /// `k` with scaled local coordinates `y`, given the loss's sensitivity to the
    /// point's density (`g_rho`) and numerator (`g_n`).
    #[inline(always)]
    pub fn add_pair(&mut self, f: &Frame, k: f32, y: [f32; 3], g_rho: f32, g_n: f32) {
        let g = &mut self.0;
        g[0] += k * g_rho;
        g[1] += k * g_n;
        let c = -0.5 * k * f.w * (g_rho + f.s * g_n);
        g[2] += c * y[0];
        g[3] += c * y[1];
        g[4] += c * y[2];
        g[5] += c * y[0] * y[0];
        g[6] += c * y[1] * y[1];
        g[7] += c * y[2] * y[2];
        g[8] += c * y[0] * y[1];
        g[9] += c * y[0] * y[2];
        g[10] += c * y[1] * y[2];
    }

    #[inline(always)]
    pub fn add(&mut self, other: &GradAcc) {
        for i in 0..11 {
            self.0[i] += other.0[i];
        }
    }
}

/// Morton (z-order) key of a primitive's centre at voxel resolution. Keeping
/// primitives sorted by it makes neighbours in memory neighbours in space, so
/// the CPU backend's blocks of candidates are compact and can be skipped whole.
pub fn morton_key(p: &Primitive) -> u64 {
    // Saturating float-to-int: NaN and negatives map to 0.
    let c = |a: usize| p[layout::MU + a].clamp(0.0, 2_000_000.0) as u64;
    morton([c(0), c(1), c(2)])
}

/// The Morton key of three 21-bit codes: bit `j` of code `a` at bit `3j + a`.
pub fn morton(c: [u64; 3]) -> u64 {
    spread(c[0]) | spread(c[1]) << 1 | spread(c[2]) << 2
}

/// The codes of a Morton key ([`morton`]'s inverse).
pub fn unmorton(k: u64) -> [u64; 3] {
    [compact(k), compact(k >> 1), compact(k >> 2)]
}

/// Spreads the 21 low bits of `v` to every third bit.
fn spread(v: u64) -> u64 {
    let mut x = v & 0x1f_ffff;
    x = (x | x << 32) & 0x1f_0000_0000_ffff;
    x = (x | x << 16) & 0x1f_0000_ff00_00ff;
    x = (x | x << 8) & 0x100f_00f0_0f00_f00f;
    x = (x | x << 4) & 0x10c3_0c30_c30c_30c3;
    (x | x << 2) & 0x1249_2492_4924_9249
}

/// Gathers every third bit of `x` into the 21 low bits ([`spread`]'s inverse).
fn compact(x: u64) -> u64 {
    let mut x = x & 0x1249_2492_4924_9249;
    x = (x | x >> 2) & 0x10c3_0c30_c30c_30c3;
    x = (x | x >> 4) & 0x100f_00f0_0f00_f00f;
    x = (x | x >> 8) & 0x1f_0000_ff00_00ff;
    x = (x | x >> 16) & 0x1f_0000_0000_ffff;
    (x | x >> 32) & 0x1f_ffff
}

/// A primitive's parameters for an isotropic, unrotated Gaussian.
pub fn isotropic(mu: [f32; 3], sigma: f32, value: f32, weight: f32) -> Primitive {
    use layout::*;
    let mut p = [0.0f32; 12];
    p[MU..MU + 3].copy_from_slice(&mu);
    let l = sigma.ln();
    p[LOG_SCALE..LOG_SCALE + 3].copy_from_slice(&[l, l, l]);
    p[QUAT] = 1.0;
    p[ALPHA] = logit_clamped(value);
    p[BETA] = logit_clamped(weight);
    p
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn morton_keys_interleave_and_invert() {
        let mut rng = crate::math::rng::Rng::new(5);
        for _ in 0..1000 {
            let c = [rng.below(1 << 21), rng.below(1 << 21), rng.below(1 << 21)];
            assert_eq!(unmorton(morton(c)), c);
        }
        assert_eq!(morton([1, 0, 0]), 1);
        assert_eq!(morton([0, 1, 0]), 2);
        assert_eq!(morton([0, 0, 1]), 4);
        assert_eq!(morton([3, 0, 0]), 0b1001);
    }


    #[test]
    fn box_is_tight_for_rotated_ellipsoid() {
        // A needle along x rotated 45 degrees about z: its box must follow the
        // rotated ellipsoid, not the corners of the rotated box.
        let mut p = isotropic([0.0; 3], 1.0, 0.5, 0.5);
        p[layout::LOG_SCALE] = 4.0f32.ln();
        let h = (std::f32::consts::FRAC_PI_8).cos();
        p[layout::QUAT..layout::QUAT + 4].copy_from_slice(&[h, 0.0, 0.0, (std::f32::consts::FRAC_PI_8).sin()]);
        let f = Frame::new(&p);
        // Sigma_xx = (16 + 1)/2 for a 45-degree rotation of diag(16, 1).
        let expect = 5.0 * (8.5f32).sqrt();
        assert!((f.ext[0] - expect).abs() < 1e-4 && (f.ext[1] - expect).abs() < 1e-4, "{:?}", f.ext);
        assert!((f.ext[2] - 5.0).abs() < 1e-5);
        // The farthest point of the ellipsoid along x lies on the box face.
        let mut far = 0.0f32;
        for i in 0..20000 {
            let t = i as f32 / 20000.0 * std::f32::consts::TAU;
            let local = [4.0 * 5.0 * t.cos(), 5.0 * t.sin(), 0.0];
            let world_x = f.axes[0][0] * local[0] + f.axes[1][0] * local[1];
            far = far.max(world_x.abs());
        }
        assert!((far - f.ext[0]).abs() < 1e-2, "{far} vs {}", f.ext[0]);
    }

    #[test]
    fn kernel_truncates_at_five_sigma() {
        let f = Frame::new(&isotropic([0.0; 3], 2.0, 0.5, 0.5));
        assert!(f.kernel([9.99, 0.0, 0.0]).is_some());
        assert!(f.kernel([10.01, 0.0, 0.0]).is_none());
        let (k, _) = f.kernel([2.0, 0.0, 0.0]).unwrap();
        assert!((k - (-0.5f32).exp()).abs() < 1e-6);
    }

    #[test]
    fn fast_exp_matches_libm() {
        let mut worst = 0.0f64;
        for i in 0..250_000 {
            let d2 = i as f32 * 1e-4;
            let exact = (-0.5 * d2 as f64).exp();
            let rel = ((exp_neg_half(d2) as f64 - exact) / exact).abs();
            worst = worst.max(rel);
        }
        assert!(worst < 3e-7, "worst relative error {worst}");
    }
}
