//! Renderings against independent computations: a slice of one analytic
//! Gaussian pixel by pixel, the volume rendering of a constant field
//! against the closed-form absorption, PSNR and SSIM against their
//! definitions, the PNG figure, and the errors of bad views.

use gsenc::backend::cpu::CpuBackend;
use gsenc::field::{Grid, IndexFrame, Transform, ValueRange};
use gsenc::io::image::{png_bytes, read_png, write_png, Figure};
use gsenc::math::kernel::isotropic;
use gsenc::model::{Model, ModelMeta};
use gsenc::render::{image_psnr, render, ssim, ColorMap, Image, View, ViewKind};

const D: usize = 32;

fn close(a: [u8; 3], b: [u8; 3], tol: i32) -> bool {
    (0..3).all(|c| (a[c] as i32 - b[c] as i32).abs() <= tol)
}

/// One isotropic Gaussian in the middle of a 32^3 lattice: its slice
/// through the middle layer, drawn one pixel a voxel, is the colour map of
/// `V = s w K / max(w K, 0.05)` computed here from the formula.
#[test]
fn a_slice_of_one_gaussian_matches_the_formula_pixel_by_pixel() {
    let (mu, sigma, s, w) = ([15.5f32, 14.0, 16.0], 4.0f32, 0.7f32, 0.9f32);
    let model = Model {
        meta: ModelMeta::new(IndexFrame::for_grid([D; 3], [0.0; 3], 1.0).unwrap(), ValueRange::new(0.0, 1.0, Transform::Linear).unwrap()),
        params: vec![isotropic(mu, sigma, s, w)],
        support: None,
    };
    let decoded = model.decode(&mut CpuBackend::new(), None).unwrap();
    let grid = Grid::new([D; 3], decoded.values).unwrap();
    let map = ColorMap::from_name("magma").unwrap();
    let k = 16;
    let view = View::new(ViewKind::Slice { axis: 2, at: k as f64 / (D - 1) as f64 }, D, D, map).unwrap();
    let img = render(&grid, &view).unwrap();
    let mut varied = std::collections::BTreeSet::new();
    for j in 0..D {
        for i in 0..D {
            // Row j from the top is y = D - 1 - j.
            let p = [i as f32, (D - 1 - j) as f32, k as f32];
            let d2: f32 = (0..3).map(|a| ((p[a] - mu[a]) / sigma).powi(2)).sum();
            let kern = if d2 < 25.0 { (-0.5 * d2).exp() } else { 0.0 };
            let v = (s * w * kern / (w * kern).max(0.05)).clamp(0.0, 1.0);
            let got = img.pixel(i, j);
            assert!(close(got, map.rgb(v), 1), "pixel ({i}, {j}): {got:?}, want {:?} (V = {v})", map.rgb(v));
            varied.insert(got);
        }
    }
    assert!(varied.len() > 20, "the slice should cross the Gaussian's edge: {} colours", varied.len());
}

/// A constant field `v` seen from +x at elevation 0: the centre pixel's ray
/// crosses the lattice's cells over a length of D, so it shows
/// `colour(v) (1 - exp(-opacity v D))` over black.
#[test]
fn the_volume_rendering_of_a_constant_field_is_the_closed_form_absorption() {
    let v = 0.6f32;
    let grid = Grid::new([D, 20, 12], vec![v; D * 20 * 12]).unwrap();
    let map = ColorMap::default();
    for (opacity, az) in [(0.05, 0.0), (0.2, 180.0)] {
        let view = View::new(ViewKind::Volume { azimuth: az, elevation: 0.0, opacity }, 64, 64, map).unwrap();
        let img = render(&grid, &view).unwrap();
        let a = 1.0 - (-opacity * v as f64 * D as f64).exp();
        let want = map.rgb(v).map(|c| (c as f64 * a).round() as u8);
        let got = img.pixel(32, 32);
        assert!(close(got, want, 1), "opacity {opacity}: {got:?}, want {want:?}");
        // The corners look past the lattice: background.
        assert_eq!(img.pixel(0, 0), [0, 0, 0]);
    }
    // Looking straight down the z axis, the lattice's 12 cells.
    let view = View::new(ViewKind::Volume { azimuth: 0.0, elevation: 90.0, opacity: 0.1 }, 64, 64, map).unwrap();
    let a = 1.0 - (-0.1 * v as f64 * 12.0).exp();
    assert!(close(render(&grid, &view).unwrap().pixel(32, 32), map.rgb(v).map(|c| (c as f64 * a).round() as u8), 1));
}

fn gradient_image(w: usize, h: usize, shift: usize) -> Image {
    let mut img = Image::filled(w, h, [0, 0, 0]);
    for y in 0..h {
        for x in 0..w {
            let t = (((x + shift) * 7 + y * 3) % 256) as u8;
            img.rgb[3 * (x + w * y)..3 * (x + w * y) + 3].copy_from_slice(&[t, 255 - t, t / 2]);
        }
    }
    img
}

#[test]
fn psnr_and_ssim_follow_their_definitions() {
    let a = gradient_image(40, 30, 0);
    assert_eq!(image_psnr(&a, &a).unwrap(), f64::INFINITY);
    assert!((ssim(&a, &a).unwrap() - 1.0).abs() < 1e-12);
    let shifted = gradient_image(40, 30, 3);
    let (p, s) = (image_psnr(&a, &shifted).unwrap(), ssim(&a, &shifted).unwrap());
    assert!(p.is_finite() && p > 0.0 && s < 0.99 && s > -1.0, "{p} {s}");
    // PSNR of a uniform difference of 10 in every byte: 20 log10(255 / 10).
    let b = Image { rgb: a.rgb.iter().map(|&x| x.saturating_add(10)).collect(), ..a.clone() };
    let exact = Image { rgb: vec![100; a.rgb.len()], ..a.clone() };
    let plus = Image { rgb: vec![110; a.rgb.len()], ..a.clone() };
    assert!((image_psnr(&exact, &plus).unwrap() - 20.0 * (255.0f64 / 10.0).log10()).abs() < 1e-9);
    assert!(image_psnr(&a, &b).unwrap() > image_psnr(&exact, &plus).unwrap() - 1e-9);
    // Two flat images of luminance x and y: SSIM = (2xy + C1) / (x^2 + y^2 + C1).
    let (x, y) = (100.0f64, 140.0f64);
    let c1 = (0.01f64 * 255.0).powi(2);
    let grey = |g: u8| Image { rgb: vec![g; a.rgb.len()], ..a.clone() };
    let want = (2.0 * x * y + c1) / (x * x + y * y + c1);
    assert!((ssim(&grey(100), &grey(140)).unwrap() - want).abs() < 1e-9);
    // Sizes must agree, and SSIM needs an 11x11 window.
    assert!(image_psnr(&a, &gradient_image(41, 30, 0)).unwrap_err().to_string().contains("one size"));
    let tiny = gradient_image(10, 10, 0);
    assert!(ssim(&tiny, &tiny).unwrap_err().to_string().contains("at least 11x11"));
}

#[test]
fn the_figure_holds_the_panels_and_round_trips_through_png() {
    let (a, b) = (gradient_image(48, 40, 0), gradient_image(48, 40, 5));
    let map = ColorMap::default();
    let range = ValueRange::new(2.0, 12.0, Transform::Linear).unwrap();
    let fig = Figure { panels: vec![("gsenc model", &a), ("reference", &b)], colormap: map, range, label: "density" }.draw().unwrap();
    assert!(fig.width > 2 * 48 && fig.height > 40);
    // Each panel's pixels lie unchanged below the title band, side by side.
    let find = |p: &Image| (0..fig.width - 48).find(|&x0| (0..40).all(|y| (0..48).all(|x| fig.pixel(x0 + x, 24 + y) == p.pixel(x, y))));
    let (xa, xb) = (find(&a).expect("first panel"), find(&b).expect("second panel"));
    assert!(xb > xa + 48);
    // The titles and labels put dark text on the white margins.
    assert!((0..fig.width).any(|x| (0..20).any(|y| fig.pixel(x, y)[0] < 100)), "no text drawn");
    let dir = std::env::temp_dir().join(format!("gsenc_render_{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("fig.png");
    write_png(&path, &fig).unwrap();
    assert_eq!(read_png(&path).unwrap(), fig);
    assert_eq!(std::fs::read(&path).unwrap(), png_bytes(&fig).unwrap());
    // A truncated file is an error, not a panic.
    std::fs::write(&path, &png_bytes(&fig).unwrap()[..60]).unwrap();
    assert!(read_png(&path).is_err());
    std::fs::remove_dir_all(&dir).ok();
    assert!(Figure { panels: vec![("a", &a), ("b", &gradient_image(20, 20, 0))], colormap: map, range, label: "x" }.draw().is_err());
}

#[test]
fn bad_views_are_clear_errors() {
    let map = ColorMap::default();
    let err = |k: ViewKind, w: usize, h: usize| View::new(k, w, h, map).unwrap_err().to_string();
    let vol = |azimuth, elevation, opacity| ViewKind::Volume { azimuth, elevation, opacity };
    assert!(err(vol(0.0, 0.0, 0.1), 0, 64).contains("image width 0"));
    assert!(err(vol(0.0, 0.0, 0.1), 64, 100_000).contains("image height 100000"));
    assert!(err(vol(f64::NAN, 0.0, 0.1), 64, 64).contains("azimuth"));
    assert!(err(vol(0.0, 91.0, 0.1), 64, 64).contains("elevation"));
    assert!(err(vol(0.0, 0.0, 0.0), 64, 64).contains("opacity"));
    assert!(err(vol(0.0, 0.0, f64::INFINITY), 64, 64).contains("opacity"));
    for bad in ["w=0.5", "z=1.5", "z", "z=-0.1", "z=nan", ""] {
        assert!(ViewKind::parse_slice(bad).unwrap_err().to_string().contains("AXIS=FRACTION"), "{bad}");
    }
    assert_eq!(ViewKind::parse_slice("y=0.25").unwrap(), ViewKind::Slice { axis: 1, at: 0.25 });
    assert!(ColorMap::from_name("rainbow").unwrap_err().to_string().contains("viridis"));
    let empty = Grid { dims: [0, 0, 0], values: vec![] };
    let view = View::new(ViewKind::Slice { axis: 2, at: 0.5 }, 32, 32, map).unwrap();
    assert!(render(&empty, &view).is_err());
}
