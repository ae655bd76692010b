//! How alike two renderings are: PSNR over the RGB bytes and SSIM (Wang,
//! Bovik, Sheikh and Simoncelli 2004: an 11x11 Gaussian window of sigma
//! 1.5 over the luminance, K1 = 0.01, K2 = 0.03, L = 255, averaged over
//! every position where the window fits).

use super::view::Image;
use crate::error::{Error, Result};

const WINDOW: usize = 11;
const WINDOW_SIGMA: f64 = 1.5;

fn same_size(a: &Image, b: &Image) -> Result<()> {
    if a.width != b.width || a.height != b.height || a.rgb.len() != b.rgb.len() {
        return Err(Error::arg(format!("images of {}x{} and {}x{} pixels: compare images of one size", a.width, a.height, b.width, b.height)));
    }
    Ok(())
}

/// PSNR in dB of `b` against `a` over every byte (infinite when equal).
pub fn image_psnr(a: &Image, b: &Image) -> Result<f64> {
    same_size(a, b)?;
    let se: f64 = a.rgb.iter().zip(&b.rgb).map(|(&x, &y)| (x as f64 - y as f64).powi(2)).sum();
    let mse = se / a.rgb.len() as f64;
    Ok(if mse == 0.0 { f64::INFINITY } else { 10.0 * (255.0f64 * 255.0 / mse).log10() })
}

/// Luminance (ITU-R BT.601 weights) of every pixel.
fn luminance(img: &Image) -> Vec<f64> {
    img.rgb.chunks_exact(3).map(|p| 0.299 * p[0] as f64 + 0.587 * p[1] as f64 + 0.114 * p[2] as f64).collect()
}

/// Mean SSIM of `b` against `a`, in `[-1, 1]` (1 when equal).
pub fn ssim(a: &Image, b: &Image) -> Result<f64> {
    same_size(a, b)?;
    if a.width < WINDOW || a.height < WINDOW {
        return Err(Error::arg(format!("SSIM needs images of at least {WINDOW}x{WINDOW} pixels, not {}x{}", a.width, a.height)));
    }
    let half = (WINDOW / 2) as f64;
    let g: Vec<f64> = (0..WINDOW).map(|i| (-((i as f64 - half).powi(2)) / (2.0 * WINDOW_SIGMA * WINDOW_SIGMA)).exp()).collect();
    let gsum: f64 = g.iter().sum();
    let w: Vec<f64> = (0..WINDOW * WINDOW).map(|k| g[k % WINDOW] * g[k / WINDOW] / (gsum * gsum)).collect();
    let (x, y) = (luminance(a), luminance(b));
    let (c1, c2) = ((0.01f64 * 255.0).powi(2), (0.03f64 * 255.0).powi(2));
    let (nx, ny) = (a.width - WINDOW + 1, a.height - WINDOW + 1);
    let mut total = 0.0;
    for j in 0..ny {
        for i in 0..nx {
            let (mut mx, mut my, mut sxx, mut syy, mut sxy) = (0.0, 0.0, 0.0, 0.0, 0.0);
            for (k, &wk) in w.iter().enumerate() {
                let p = (i + k % WINDOW) + a.width * (j + k / WINDOW);
                mx += wk * x[p];
                my += wk * y[p];
                sxx += wk * x[p] * x[p];
                syy += wk * y[p] * y[p];
                sxy += wk * x[p] * y[p];
            }
            let (vx, vy, cxy) = (sxx - mx * mx, syy - my * my, sxy - mx * my);
            total += ((2.0 * mx * my + c1) * (2.0 * cxy + c2)) / ((mx * mx + my * my + c1) * (vx + vy + c2));
        }
    }
    Ok(total / (nx * ny) as f64)
}
