//! The decode against the CPU decode, and slabs whose lists overflow.

use super::*;

#[test]
fn decode_matches_the_cpu_decode() {
    let Some(mut g) = gpu() else { return };
    let mut rng = Rng::new(15);
    let params = random_model(&mut rng, 250, 20.0);
    // The reference lattice, a finer resampling with sizes not a multiple of
    // the decode brick, a shifted window, and slabs of more than a megabyte
    // (copied out of the mapped buffer in runs of one: the last run short).
    for lat in [
        Lattice::reference([20, 20, 20]),
        Lattice::resampled([20, 20, 20], [37, 29, 19]),
        Lattice { dims: [9, 17, 25], origin: [3.5, -2.0, 1.25], step: [0.75, 1.0, 0.5] },
        Lattice::resampled([20, 20, 20], [181, 190, 11]),
    ] {
        let mut a = vec![0.0; lat.len()];
        let mut b = vec![f32::NAN; lat.len()];
        CpuBackend::new().decode_lattice(&params, &lat, &mut a).unwrap();
        g.decode_lattice(&params, &lat, &mut b).unwrap();
        for i in 0..a.len() {
            assert!((a[i] - b[i]).abs() <= 2e-5, "{lat:?} voxel {i}: cpu {} gpu {}", a[i], b[i]);
        }
    }
}

#[test]
fn decode_slabs_that_overflow_run_again() {
    let Some(mut g) = gpu() else { return };
    let mut rng = Rng::new(16);
    let params = random_model(&mut rng, 300, 24.0);
    let lat = Lattice::reference([24, 24, 24]);
    let mut a = vec![0.0; lat.len()];
    g.decode_lattice(&params, &lat, &mut a).unwrap();
    let mut tight = gpu().unwrap();
    tight.set_capacity(3);
    let mut b = vec![0.0; lat.len()];
    tight.decode_lattice(&params, &lat, &mut b).unwrap();
    assert!(tight.reruns >= 1);
    assert!(a.iter().zip(&b).all(|(x, y)| x.to_bits() == y.to_bits()));
}

/// Slabs go to the device two at a time, so a slab's lists are found to
/// have overflowed while the next slab is already on the queue: that one is
/// kept if its lists fitted and runs again with the first if not. Here the
/// slabs along z hold 16, 4, 64, 8 and 256 primitives, none reaching past
/// its own, so the lists overflow
/// on the first slab with the second behind it overflowing too, on the third
/// with the fourth fitting behind it, and on the last with none behind it.
#[test]
fn a_later_slab_that_overflows_runs_again_with_the_one_behind_it() {
    let Some(mut g) = gpu() else { return };
    let mut rng = Rng::new(17);
    let mut params = vec![];
    for (slab, count) in [16, 4, 64, 8, 256].into_iter().enumerate() {
        for mut p in random_model(&mut rng, count, 16.0) {
            p[2] = (8 * slab) as f32 + rng.range(3.0, 5.0) as f32;
            for a in 3..6 {
                p[a] = rng.range(0.3f64.ln(), 0.5f64.ln()) as f32;
            }
            params.push(p);
        }
    }
    let lat = Lattice::reference([16, 16, 40]);
    let mut cpu = vec![0.0; lat.len()];
    CpuBackend::new().decode_lattice(&params, &lat, &mut cpu).unwrap();
    let mut roomy = vec![f32::NAN; lat.len()];
    g.decode_lattice(&params, &lat, &mut roomy).unwrap();
    let mut tight = gpu().unwrap();
    tight.set_capacity(3);
    let mut b = vec![f32::NAN; lat.len()];
    tight.decode_lattice(&params, &lat, &mut b).unwrap();
    assert!(tight.reruns >= 3, "the lists overflowed {} times, not slab after slab", tight.reruns);
    for i in 0..b.len() {
        assert!(b[i].to_bits() == roomy[i].to_bits(), "voxel {i}: {} with reruns, {} without", b[i], roomy[i]);
        assert!((cpu[i] - b[i]).abs() <= 2e-5, "voxel {i}: cpu {} gpu {}", cpu[i], b[i]);
    }
}
