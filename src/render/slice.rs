//! An axis slice: the grid sampled trilinearly at each pixel centre of the
//! plane, the lattice fitted into the image with square pixels.

use super::view::{Image, View};
use crate::field::Grid;
use rayon::prelude::*;

/// Where the slice has no data (outside the lattice's extent).
pub const SLICE_BACKGROUND: [u8; 3] = [255, 255, 255];

/// The in-plane axes of a slice across `axis`: (right, up).
pub fn plane_axes(axis: usize) -> (usize, usize) {
    match axis {
        0 => (1, 2),
        1 => (0, 2),
        _ => (0, 1),
    }
}

/// The index coordinates (right, up) of pixel `(i, j)`'s centre (row `j`
/// from the top), or `None` outside the lattice's extent: the lattice's
/// `nu x nv` voxels fill the image with square pixels, centred.
pub fn pixel_to_plane(i: usize, j: usize, nu: usize, nv: usize, view: &View) -> Option<(f32, f32)> {
    let scale = (view.width as f64 / nu as f64).min(view.height as f64 / nv as f64);
    let (ox, oy) = ((view.width as f64 - scale * nu as f64) / 2.0, (view.height as f64 - scale * nv as f64) / 2.0);
    let x = (i as f64 + 0.5 - ox) / scale;
    let y = (view.height as f64 - (j as f64 + 0.5) - oy) / scale;
    if !(0.0..nu as f64).contains(&x) || !(0.0..nv as f64).contains(&y) {
        return None;
    }
    Some(((x - 0.5) as f32, (y - 0.5) as f32))
}

pub fn slice(grid: &Grid, axis: usize, at: f64, view: &View) -> Image {
    let (ru, rv) = plane_axes(axis);
    let (nu, nv) = (grid.dims[ru], grid.dims[rv]);
    let c = (at * (grid.dims[axis] - 1) as f64) as f32;
    let mut img = Image::filled(view.width, view.height, SLICE_BACKGROUND);
    img.rgb.par_chunks_mut(3 * view.width).enumerate().for_each(|(j, row)| {
        for i in 0..view.width {
            if let Some((u, v)) = pixel_to_plane(i, j, nu, nv, view) {
                let mut p = [0.0f32; 3];
                p[axis] = c;
                p[ru] = u;
                p[rv] = v;
                row[3 * i..3 * i + 3].copy_from_slice(&view.colormap.rgb(grid.trilinear(p)));
            }
        }
    });
    img
}
