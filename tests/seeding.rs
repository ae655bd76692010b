//! Seeding from non-grid samples: the importance stream draws without
//! replacement proportional to m^0.6 (statistical tests with fixed seeds), and
//! the peak stream works on sample positions.

use gsenc::input::samples::{Sample, SampleArrays};
use gsenc::encode::seeding::{seed, Stream, PEAK_THRESHOLD};

const MASSES: [f32; 6] = [1.0, 2.0, 4.0, 8.0, 16.0, 32.0];

fn samples(masses: &[f32], value: f32) -> SampleArrays {
    let mut s = SampleArrays::default();
    for (i, &m) in masses.iter().enumerate() {
        s.push(Sample { q: [2.0 * i as f32, 1.0, 1.0], h: 0.5, v: value, m });
    }
    s
}

fn probabilities(exponent: f64) -> Vec<f64> {
    let w: Vec<f64> = MASSES.iter().map(|&m| (m as f64).powf(exponent)).collect();
    let total: f64 = w.iter().sum();
    w.iter().map(|x| x / total).collect()
}

fn chi_square(counts: &[usize], expected: &[f64]) -> f64 {
    let n: usize = counts.iter().sum();
    counts.iter().zip(expected).map(|(&c, &p)| (c as f64 - n as f64 * p).powi(2) / (n as f64 * p)).sum()
}

/// Asserts that the draws `counts` of the six samples follow m^0.6, and
/// that so many draws would tell m^0.5 and m^1 from it.
fn follows_m_to_the_0_6(counts: &[usize; 6]) {
    // Chi-square with 5 degrees of freedom: 25.7 is its 1e-4 upper quantile.
    let chi = chi_square(counts, &probabilities(0.6));
    assert!(chi < 25.7, "chi-square {chi} against m^0.6, counts {counts:?}");
    for wrong in [0.5, 1.0] {
        let c = chi_square(counts, &probabilities(wrong));
        assert!(c > 100.0, "the test cannot tell m^{wrong} from m^0.6 (chi-square {c})");
    }
}

const DRAWS: u64 = 30_000;

/// A budget of 2 has one importance seed: its sample frequencies must follow
/// m^0.6 and must reject the neighbouring exponents 0.5 and 1.
#[test]
fn single_importance_draw_follows_m_to_the_0_6() {
    let s = samples(&MASSES, 0.1);
    let mut counts = [0usize; 6];
    for k in 0..DRAWS {
        let sd = seed(&s, [16, 4, 4], 2, k).unwrap();
        let imp: Vec<usize> = (0..2).filter(|&i| sd.stream[i] == Stream::Importance).map(|i| sd.sample[i]).collect();
        assert_eq!(imp.len(), 1);
        counts[imp[0]] += 1;
    }
    follows_m_to_the_0_6(&counts);
}

/// A budget of 4 has two importance seeds, distinct (without replacement):
/// pair frequencies follow successive sampling, `P{i,j} = p_i p_j / (1 - p_i)
/// + p_j p_i / (1 - p_j)`.
#[test]
fn two_importance_draws_are_without_replacement() {
    let s = samples(&MASSES, 0.1);
    let p = probabilities(0.6);
    let mut pairs = vec![];
    let mut expected = vec![];
    for i in 0..6 {
        for j in i + 1..6 {
            pairs.push((i, j));
            expected.push(p[i] * p[j] / (1.0 - p[i]) + p[j] * p[i] / (1.0 - p[j]));
        }
    }
    let mut counts = vec![0usize; pairs.len()];
    for k in 0..DRAWS {
        let sd = seed(&s, [16, 4, 4], 4, k).unwrap();
        let mut imp: Vec<usize> = (0..4).filter(|&i| sd.stream[i] == Stream::Importance).map(|i| sd.sample[i]).collect();
        imp.sort();
        assert_eq!(imp.len(), 2);
        assert_ne!(imp[0], imp[1], "drawn twice");
        counts[pairs.iter().position(|&x| x == (imp[0], imp[1])).unwrap()] += 1;
    }
    // 14 degrees of freedom: 40.0 is the 1e-4 upper quantile.
    let chi = chi_square(&counts, &expected);
    assert!(chi < 40.0, "chi-square {chi}, counts {counts:?}");
    // With-replacement-style independent draws (p_i p_j twice, renormalised)
    // would be rejected.
    let indep: Vec<f64> = pairs.iter().map(|&(i, j)| 2.0 * p[i] * p[j]).collect();
    let total: f64 = indep.iter().sum();
    let c = chi_square(&counts, &indep.iter().map(|x| x / total).collect::<Vec<_>>());
    assert!(c > 100.0, "cannot tell successive sampling from independent draws ({c})");
}

/// Peak seeds: one per 2x2x2-voxel bin of sample positions, the highest value
/// above 0.55 wins, with the peak scale clip of [0.35, 2.5] applied to `h`.
#[test]
fn peak_stream_bins_sample_positions() {
    let mut s = SampleArrays::default();
    // Bin (0,0,0): two candidates; bin (1,0,0): one; bin (2,0,0): below threshold.
    s.push(Sample { q: [0.2, 0.4, 1.1], h: 3.0, v: 0.7, m: 1.0 });
    s.push(Sample { q: [1.3, 1.2, 0.0], h: 0.1, v: 0.9, m: 1.0 });
    s.push(Sample { q: [2.6, 0.0, 0.0], h: 1.0, v: 0.8, m: 1.0 });
    s.push(Sample { q: [4.5, 0.0, 0.0], h: 1.0, v: 0.5, m: 1.0 });
    for i in 0..36 {
        s.push(Sample { q: [i as f32 * 0.2, 3.0, 3.0], h: 1.0, v: 0.1, m: 1.0 });
    }
    // Budget 20: peak share round(3) = 3, of which two bins qualify.
    let sd = seed(&s, [8, 4, 4], 20, 0).unwrap();
    let peaks: Vec<usize> = (0..20).filter(|&i| sd.stream[i] == Stream::Peak).collect();
    let mut idx: Vec<usize> = peaks.iter().map(|&i| sd.sample[i]).collect();
    idx.sort();
    assert_eq!(idx, vec![1, 2]);
    for &i in &peaks {
        let sigma = sd.params[i][3].exp();
        let want = if sd.sample[i] == 1 { 0.35 } else { 1.0 };
        assert!((sigma - want).abs() < 1e-5, "peak scale {sigma}, want {want}");
    }
    assert_eq!(sd.count(Stream::Uniform), 20 - 9 - 2);
}

/// With fewer samples than the budget, every sample is first a uniform seed,
/// once and in order, at its own position and with the spread scale of one
/// sample per primitive (never smaller: the spread factor is at least 1);
/// the other slots are copies drawn with replacement in proportion to
/// m^0.6, each jittered within half a voxel of its sample on every axis.
#[test]
fn fewer_samples_than_the_budget_are_each_taken_once_then_copied() {
    let s = samples(&MASSES, 0.1);
    let n = 50;
    let mut counts = [0usize; 6];
    let mut moved = 0;
    for k in 0..400 {
        let sd = seed(&s, [16, 4, 4], n, k).unwrap();
        assert_eq!((sd.params.len(), sd.stream.len(), sd.sample.len()), (n, n, n));
        for i in 0..6 {
            assert_eq!((sd.stream[i], sd.sample[i]), (Stream::Uniform, i), "seed {k}: slot {i}");
            assert_eq!(sd.params[i][..3], [2.0 * i as f32, 1.0, 1.0], "seed {k}: a uniform seed sits at its sample");
        }
        for i in 0..n {
            assert!((sd.params[i][3].exp() - 0.5).abs() < 1e-6, "seed {k}: scale {} of slot {i}, not the sample's 0.5", sd.params[i][3].exp());
        }
        for i in 6..n {
            assert_eq!(sd.stream[i], Stream::Importance, "seed {k}: slot {i}");
            let j = sd.sample[i];
            let q = [2.0 * j as f32, 1.0, 1.0];
            for a in 0..3 {
                let d = sd.params[i][a] - q[a];
                assert!((-0.5..0.5).contains(&d), "seed {k}: copy {i} of sample {j} is {d} from it on axis {a}");
                moved += (d != 0.0) as usize;
            }
            counts[j] += 1;
        }
    }
    assert!(moved > 400 * 44 * 3 * 9 / 10, "only {moved} coordinates of the copies were jittered");
    follows_m_to_the_0_6(&counts);
}

/// Importances that are negative or not finite are refused, in either
/// branch; so are importances that are all zero when copies must be drawn
/// in proportion to them.
#[test]
fn importances_that_cannot_weigh_a_draw_are_refused() {
    for bad in [f32::INFINITY, f32::NAN, -1.0] {
        let mut masses = MASSES;
        masses[2] = bad;
        for n in [4, 50] {
            let e = seed(&samples(&masses, 0.1), [16, 4, 4], n, 0).err().unwrap_or_else(|| panic!("mass {bad} with budget {n} was taken"));
            assert!(e.to_string().contains("negative or not finite"), "{bad}, budget {n}: {e}");
        }
    }
    let e = seed(&samples(&[0.0; 6], 0.1), [16, 4, 4], 50, 0).expect_err("zero importances weighed copies");
    assert!(e.to_string().contains("all sample importances are zero"), "{e}");
}

/// The peak stream's edge cases: a value exactly at the threshold does not
/// exceed it, the lower sample index wins a tie within a bin, and between
/// bins whose winners tie, the lower sample index comes first, whatever
/// the bins' order.
#[test]
fn peak_ties_go_to_the_lower_sample_and_the_threshold_is_exceeded() {
    let peaks = |s: &SampleArrays, n: usize| -> Vec<usize> {
        let sd = seed(s, [8, 4, 4], n, 3).unwrap();
        (0..n).filter(|&i| sd.stream[i] == Stream::Peak).map(|i| sd.sample[i]).collect()
    };
    // Samples 0 and 1 at (x, value) on the y = z = 0 row, then 40 below
    // the threshold elsewhere.
    let two = |[(x0, v0), (x1, v1)]: [(f32, f32); 2]| {
        let mut s = SampleArrays::default();
        s.push(Sample { q: [x0, 0.0, 0.0], h: 1.0, v: v0, m: 1.0 });
        s.push(Sample { q: [x1, 0.0, 0.0], h: 1.0, v: v1, m: 1.0 });
        for i in 0..40 {
            s.push(Sample { q: [i as f32 * 0.15, 3.0, 3.0], h: 1.0, v: 0.1, m: 1.0 });
        }
        s
    };
    // Budget 7: a peak share of 1. Bins x = 2 and 0, then both in bin 0.
    assert_eq!(peaks(&two([(4.0, 0.9), (0.0, 0.9)]), 7), vec![0]);
    assert_eq!(peaks(&two([(0.0, 0.9), (1.0, 0.9)]), 7), vec![0]);
    // Budget 20: a share of 3, of which one bin exceeds the threshold.
    assert_eq!(peaks(&two([(0.0, PEAK_THRESHOLD), (4.0, PEAK_THRESHOLD.next_up())]), 20), vec![1]);
}
