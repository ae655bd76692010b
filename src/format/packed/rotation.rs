//! A primitive's rotation in the packed payload: stored in its canonical
//! pose (of the 24 frames that give its kernel, the one nearest the
//! identity), as the three components beside its largest, at fewer bits
//! the nearer it is to a sphere; a rotation this payload decoded keeps its
//! codes when packed again.

use super::{scale_band, scale_code, uniform_code, uniform_value, Precision};
use crate::math::kernel::{layout, rotation, Primitive};

/// Bits of a primitive's rotation components at group precision `bits`,
/// given its scale codes at `scale_bits`; 0 for a sphere (equal codes),
/// whose rotation changes nothing. A rotation error `theta` moves the
/// kernel by about `theta (1 - sigma_min / sigma_max)`, and that factor is
/// below `3 D / levels` for scale codes `D` apart (`ln 20 < 3`): each
/// halving of it gives up one bit, down to one.
pub fn rotation_bits(scale: [u16; 3], scale_bits: u8, bits: u8) -> u8 {
    let d = *scale.iter().max().unwrap() as u64 - *scale.iter().min().unwrap() as u64;
    if d == 0 {
        return 0;
    }
    let levels = (1u64 << scale_bits) - 1;
    let mut spare = 0;
    while spare + 1 < bits && (3 * d) << (spare + 1) <= levels {
        spare += 1;
    }
    bits - spare
}

/// The range of the stored components: beside a unit quaternion's largest
/// component, each of the others lies within ±1/√2.
const ROT_RANGE: f64 = std::f64::consts::FRAC_1_SQRT_2;

/// The dropped component's index and the other three's codes at `bits`
/// bits of a primitive's rotation, in the pose it is given.
pub(super) fn rotation_codes(p: &Primitive, bits: u8) -> (u8, [u16; 3]) {
    let (m, rest) = smallest_three(unit_quaternion(p));
    (m, rest.map(|v| uniform_code(v, -ROT_RANGE, ROT_RANGE, bits)))
}

/// A unit quaternion with its largest component made positive: the index
/// of that component and the other three in order.
fn smallest_three(unit: [f64; 4]) -> (u8, [f64; 3]) {
    let m = (0..4).fold(0, |m, i| if unit[i].abs() > unit[m].abs() { i } else { m });
    let sign = if unit[m] < 0.0 { -1.0 } else { 1.0 };
    (m as u8, stored_components(m).map(|i| sign * unit[i]))
}

/// The three quaternion components stored when component `m` is dropped,
/// in the order the payload keeps their codes.
fn stored_components(m: usize) -> [usize; 3] {
    std::array::from_fn(|j| if j < m { j } else { j + 1 })
}

/// One of the 24 rotations that take the coordinate axes onto one another
/// (the cube's rotations): turning a primitive's frame by `q` and giving
/// its axis `k` the scale of axis `perm[k]` leaves the kernel as it was.
#[derive(Clone, Copy)]
pub(super) struct AxisTurn {
    /// Unit quaternion (w, x, y, z).
    q: [f64; 4],
    perm: [usize; 3],
}

/// The 24 axis turns, the identity first: the identity and the half turns
/// about an axis, the third turns about a cube diagonal, the quarter turns
/// about an axis and the half turns about a face diagonal.
pub(super) fn axis_turns() -> Vec<AxisTurn> {
    let h = std::f64::consts::FRAC_1_SQRT_2;
    let mut qs: Vec<[f64; 4]> = (0..4).map(|i| std::array::from_fn(|k| (k == i) as u8 as f64)).collect();
    qs.extend((0..8).map(|s: usize| [0.5, 0.5 - (s & 1) as f64, 0.5 - (s >> 1 & 1) as f64, 0.5 - (s >> 2 & 1) as f64]));
    for i in 0..4 {
        for j in i + 1..4 {
            for sign in [h, -h] {
                let mut q = [0.0; 4];
                (q[i], q[j]) = (h, sign);
                qs.push(q);
            }
        }
    }
    qs.into_iter()
        .map(|q| {
            // Column k of the turn's matrix is ±(axis perm[k]).
            let r = rotation(q.map(|v| v as f32));
            let perm = [0, 1, 2].map(|k| (0..3).max_by(|&a, &b| r[a][k].abs().total_cmp(&r[b][k].abs())).unwrap());
            AxisTurn { q, perm }
        })
        .collect()
}

/// The Hamilton product `a b` of quaternions (w, x, y, z): the rotation
/// `b`, then `a`.
fn quaternion_product(a: [f64; 4], b: [f64; 4]) -> [f64; 4] {
    [
        a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3],
        a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2],
        a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1],
        a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0],
    ]
}

/// The pose the payload stores a primitive in: of the 24 frames that give
/// its kernel (its frame turned by an [`AxisTurn`], the scales following
/// the axes), the one whose rotation is nearest the identity (the largest
/// `|w|`; the first turn on a tie), with `w >= 0`. Its `w` is then the
/// largest component (the rotation index is always 0) and the other three
/// lie within `(√2 - 1) w`, where the range coder learns to find them
/// (METHOD.md "Payloads"). Readers take any pose.
pub(super) fn canonical_pose(p: &Primitive, turns: &[AxisTurn]) -> Primitive {
    let q = unit_quaternion(p);
    let mut best = (q, turns[0]);
    for &t in turns {
        let turned = quaternion_product(q, t.q);
        if turned[0].abs() > best.0[0].abs() {
            best = (turned, t);
        }
    }
    let (q, turn) = best;
    let sign = if q[0] < 0.0 { -1.0 } else { 1.0 };
    let mut out = *p;
    (0..4).for_each(|k| out[layout::QUAT + k] = (sign * q[k]) as f32);
    (0..3).for_each(|k| out[layout::LOG_SCALE + k] = p[layout::LOG_SCALE + turn.perm[k]]);
    out
}

/// The rotation a reader rebuilds from the dropped component's index `m`
/// and the other three's codes at `bits` bits: those three, and the
/// dropped one, non-negative, from the unit norm.
pub(super) fn rotation_value(m: usize, codes: [u16; 3], bits: u8) -> [f64; 4] {
    let rest = codes.map(|k| uniform_value(k, -ROT_RANGE, ROT_RANGE, bits));
    let mut q = [0.0; 4];
    q[m] = (1.0 - rest.iter().map(|v| v * v).sum::<f64>()).max(0.0).sqrt();
    stored_components(m).into_iter().zip(rest).for_each(|(k, v)| q[k] = v);
    q
}

/// The rotation codes that give `p` back exactly as it is, where `p` is
/// a primitive this payload decoded at `precision` (its log scales on the
/// scale levels, its rotation rebuilt from codes): the dropped
/// component's index and the other three's codes; `None` for any other.
/// Such a primitive is stored again with those codes rather than posed
/// anew: rounding can move a rotation out of the region nearest the
/// identity (or, at few bits, leave its largest component elsewhere than
/// the one dropped), and posing it again would store another frame's
/// codes, so that a model read and packed again would drift.
pub(super) fn codes_as_read(p: &Primitive, precision: &Precision) -> Option<(u8, [u16; 3])> {
    let (lo, hi) = scale_band();
    let scale = [0, 1, 2].map(|a| scale_code(p, a, precision.scale));
    if (0..3).any(|a| uniform_value(scale[a], lo, hi, precision.scale) as f32 != p[layout::LOG_SCALE + a]) {
        return None;
    }
    let q: [f32; 4] = std::array::from_fn(|k| p[layout::QUAT + k]);
    let bits = rotation_bits(scale, precision.scale, precision.rotation);
    if bits == 0 {
        return (q == [1.0, 0.0, 0.0, 0.0]).then_some((0, [0; 3]));
    }
    (0..4).find_map(|m| {
        let codes = stored_components(m).map(|k| uniform_code(q[k] as f64, -ROT_RANGE, ROT_RANGE, bits));
        (rotation_value(m, codes, bits).map(|v| v as f32) == q).then_some((m as u8, codes))
    })
}

/// `q / |q|` of a primitive; the identity where the kernel reads one (a
/// norm of 1e-12 or less, `math::kernel::Frame::new`).
fn unit_quaternion(p: &Primitive) -> [f64; 4] {
    let q: [f64; 4] = std::array::from_fn(|i| p[layout::QUAT + i] as f64);
    let norm = q.iter().map(|v| v * v).sum::<f64>().sqrt();
    if norm > 1e-12 && norm.is_finite() {
        q.map(|v| v / norm)
    } else {
        [1.0, 0.0, 0.0, 0.0]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::rng::Rng;

    /// A rotation's bits: none for a sphere; otherwise the group's bits,
    /// less one for each halving of `3 D / levels` below 1 (computed here
    /// as a logarithm), down to one bit and never to none.
    #[test]
    fn rotation_bits_fall_by_one_a_halving_down_to_one() {
        for scale_bits in 2..=16u8 {
            let levels = (1u64 << scale_bits) - 1;
            for bits in 1..=16u8 {
                for d in (0..=levels).step_by((levels as usize / 97).max(1)).chain([1, 2, 3, levels / 3, levels / 6 + 1, levels]) {
                    let scale = [(d / 2) as u16, d as u16, 0];
                    let want = match d {
                        0 => 0,
                        _ => {
                            let halvings = (levels as f64 / (3 * d) as f64).log2().floor().max(0.0) as u8;
                            bits - halvings.min(bits - 1)
                        }
                    };
                    assert_eq!(rotation_bits(scale, scale_bits, bits), want, "scale codes {scale:?} at {scale_bits} bits, rotation at {bits}");
                }
            }
        }
        assert_eq!(rotation_bits([7, 7, 7], 12, 10), 0);
        assert_eq!(rotation_bits([100, 100, 101], 12, 10), 1);
    }

    #[test]
    fn smallest_three_rebuilds_the_rotation_up_to_sign() {
        let mut rng = Rng::new(9);
        for _ in 0..500 {
            let q: [f64; 4] = std::array::from_fn(|_| rng.normal());
            let n = q.iter().map(|v| v * v).sum::<f64>().sqrt();
            let unit = q.map(|v| v / n);
            let (m, rest) = smallest_three(unit);
            let big = (1.0 - rest.iter().map(|v| v * v).sum::<f64>()).sqrt();
            assert!((big - unit[m as usize].abs()).abs() < 1e-9);
            assert!(rest.iter().all(|v| v.abs() <= ROT_RANGE + 1e-12));
        }
    }

    /// The 24 axis turns are 24 different rotations, each taking the axes
    /// onto one another as its permutation says.
    #[test]
    fn the_axis_turns_are_the_cubes_24_rotations() {
        let turns = axis_turns();
        assert_eq!(turns.len(), 24);
        for (i, t) in turns.iter().enumerate() {
            let r = rotation(t.q.map(|v| v as f32));
            for k in 0..3 {
                for a in 0..3 {
                    let want = if a == t.perm[k] { 1.0 } else { 0.0 };
                    assert!((r[a][k].abs() - want).abs() < 1e-6, "turn {i}: column {k} is not ±axis {}", t.perm[k]);
                }
            }
            for u in &turns[..i] {
                let dot: f64 = (0..4).map(|k| t.q[k] * u.q[k]).sum();
                assert!(dot.abs() < 1.0 - 1e-9, "two turns are one rotation: {:?} {:?}", t.q, u.q);
            }
        }
    }

    /// A primitive in its canonical pose has the same kernel everywhere,
    /// and its rotation lies in the region nearest the identity:
    /// `|x|, |y|, |z| <= (√2 - 1) w` and `|x| + |y| + |z| <= w`.
    #[test]
    fn the_canonical_pose_keeps_the_kernel_and_lies_nearest_the_identity() {
        use crate::math::kernel::Frame;
        let mut rng = Rng::new(31);
        let turns = axis_turns();
        let mut moved = 0;
        for _ in 0..400 {
            let mut p: Primitive = [0.0; 12];
            for a in 0..3 {
                p[layout::MU + a] = rng.range(-2.0, 2.0) as f32;
                p[layout::LOG_SCALE + a] = rng.range(0.5f64.ln(), 4f64.ln()) as f32;
            }
            for k in 0..4 {
                p[layout::QUAT + k] = (2.0 * rng.normal()) as f32;
            }
            let c = canonical_pose(&p, &turns);
            moved += (c[layout::LOG_SCALE..layout::LOG_SCALE + 3] != p[layout::LOG_SCALE..layout::LOG_SCALE + 3]) as usize;
            let q: [f64; 4] = std::array::from_fn(|k| c[layout::QUAT + k] as f64);
            let tan = std::f64::consts::SQRT_2 - 1.0;
            assert!((q.iter().map(|v| v * v).sum::<f64>() - 1.0).abs() < 1e-6);
            assert!(q[1..].iter().all(|v| v.abs() <= tan * q[0] + 1e-6), "{q:?}");
            assert!(q[1..].iter().map(|v| v.abs()).sum::<f64>() <= q[0] + 1e-6, "{q:?}");
            let (f, g) = (Frame::new(&p), Frame::new(&c));
            for _ in 0..20 {
                let x = [0, 1, 2].map(|a| p[layout::MU + a] + rng.range(-6.0, 6.0) as f32);
                let (kf, kg) = (f.kernel(x).map_or(0.0, |k| k.0), g.kernel(x).map_or(0.0, |k| k.0));
                assert!((kf - kg).abs() <= 1e-5, "kernel {kf} posed {kg}");
            }
        }
        // The scales follow the axes: most random rotations need a turn
        // that permutes them.
        assert!(moved > 200, "{moved} of 400 permuted");
    }
}
