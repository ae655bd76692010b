//! Emission-absorption volume rendering: orthographic rays through the
//! lattice, front to back. A sample of value `v` emits the colour map's
//! colour of `v` and absorbs `opacity * v` per voxel length, so empty space
//! is clear and the largest values are the most opaque.

use super::view::{Image, View};
use crate::field::Grid;
use rayon::prelude::*;

/// Behind the volume.
pub const VOLUME_BACKGROUND: [u8; 3] = [0, 0, 0];
/// Ray samples per voxel length (at least).
pub const SAMPLES_PER_VOXEL: f64 = 2.0;

/// The camera: the direction it looks in, the image's right and up axes,
/// and index-space units per pixel, for a lattice of `dims` voxels.
pub struct Camera {
    pub centre: [f64; 3],
    pub look: [f64; 3],
    pub right: [f64; 3],
    pub up: [f64; 3],
    pub units_per_pixel: f64,
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}

fn unit(a: [f64; 3]) -> [f64; 3] {
    let n = (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt();
    a.map(|x| x / n)
}

impl Camera {
    /// Looking at the lattice's centre from `azimuth` degrees around z
    /// (0: from +x) and `elevation` degrees up; the lattice's bounding
    /// sphere fills the shorter image edge.
    pub fn new(dims: [usize; 3], azimuth: f64, elevation: f64, view: &View) -> Camera {
        let (a, e) = (azimuth.to_radians(), elevation.to_radians());
        let look = [-e.cos() * a.cos(), -e.cos() * a.sin(), -e.sin()];
        // z up in the picture, unless the camera looks along z.
        let right = if e.cos().abs() < 1e-6 { [a.sin(), -a.cos(), 0.0] } else { unit(cross(look, [0.0, 0.0, 1.0])) };
        let up = cross(right, look);
        let ext = dims.map(|d| d as f64);
        let radius = 0.5 * (ext[0] * ext[0] + ext[1] * ext[1] + ext[2] * ext[2]).sqrt();
        Camera {
            centre: dims.map(|d| (d as f64 - 1.0) / 2.0),
            look,
            right,
            up,
            units_per_pixel: 2.0 * radius / view.width.min(view.height) as f64,
        }
    }

    /// The ray through pixel `(i, j)` (row from the top): a point on the
    /// plane through the centre, and the direction.
    pub fn ray(&self, i: usize, j: usize, view: &View) -> ([f64; 3], [f64; 3]) {
        let x = (i as f64 + 0.5 - view.width as f64 / 2.0) * self.units_per_pixel;
        let y = (view.height as f64 / 2.0 - (j as f64 + 0.5)) * self.units_per_pixel;
        (std::array::from_fn(|a| self.centre[a] + x * self.right[a] + y * self.up[a]), self.look)
    }
}

/// Where the line `o + t d` is inside the box `[-0.5, D - 0.5]` of each
/// axis (the lattice's cells): `(t0, t1)` with `t0 < t1`, or `None`.
pub fn clip(o: [f64; 3], d: [f64; 3], dims: [usize; 3]) -> Option<(f64, f64)> {
    let (mut t0, mut t1) = (f64::NEG_INFINITY, f64::INFINITY);
    for a in 0..3 {
        let (lo, hi) = (-0.5, dims[a] as f64 - 0.5);
        if d[a].abs() < 1e-12 {
            if o[a] < lo || o[a] > hi {
                return None;
            }
        } else {
            let (ta, tb) = ((lo - o[a]) / d[a], (hi - o[a]) / d[a]);
            t0 = t0.max(ta.min(tb));
            t1 = t1.min(ta.max(tb));
        }
    }
    (t0 < t1).then_some((t0, t1))
}

/// The pixel of one ray: `n` samples at the midpoints of equal steps over
/// the clipped segment (at least [`SAMPLES_PER_VOXEL`] a voxel length),
/// composited front to back, over the background.
pub fn march(grid: &Grid, o: [f64; 3], d: [f64; 3], opacity: f64, view: &View) -> [u8; 3] {
    let Some((t0, t1)) = clip(o, d, grid.dims) else { return VOLUME_BACKGROUND };
    let n = ((t1 - t0) * SAMPLES_PER_VOXEL).ceil().max(1.0) as usize;
    let h = (t1 - t0) / n as f64;
    let (mut c, mut transmit) = ([0.0f64; 3], 1.0f64);
    for k in 0..n {
        let t = t0 + (k as f64 + 0.5) * h;
        let p = std::array::from_fn(|a| (o[a] + t * d[a]) as f32);
        let v = grid.trilinear(p) as f64;
        let alpha = 1.0 - (-opacity * v * h).exp();
        let rgb = view.colormap.rgb(v as f32);
        for ch in 0..3 {
            c[ch] += transmit * alpha * rgb[ch] as f64;
        }
        transmit *= 1.0 - alpha;
        if transmit < 1e-4 {
            break;
        }
    }
    std::array::from_fn(|ch| (c[ch] + transmit * VOLUME_BACKGROUND[ch] as f64).round().clamp(0.0, 255.0) as u8)
}

pub fn volume(grid: &Grid, azimuth: f64, elevation: f64, opacity: f64, view: &View) -> Image {
    let cam = Camera::new(grid.dims, azimuth, elevation, view);
    let mut img = Image::filled(view.width, view.height, VOLUME_BACKGROUND);
    img.rgb.par_chunks_mut(3 * view.width).enumerate().for_each(|(j, row)| {
        for i in 0..view.width {
            let (o, d) = cam.ray(i, j, view);
            row[3 * i..3 * i + 3].copy_from_slice(&march(grid, o, d, opacity, view));
        }
    });
    img
}
