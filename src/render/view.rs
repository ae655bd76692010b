//! What to draw: an axis slice or a volume rendering, the image size and the
//! colour map; checked once, so that a bad camera or size is an error before
//! anything is decoded.

use super::colormap::ColorMap;
use crate::error::{Error, Result};
use crate::field::Grid;

/// A volume's absorption per voxel length of the largest value, unless
/// the caller gives one.
pub const DEFAULT_OPACITY: f64 = 0.05;

/// Smallest and largest image edge in pixels.
pub const MIN_EDGE: usize = 16;
pub const MAX_EDGE: usize = 8192;

#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ViewKind {
    /// The plane `axis = at` (0 x, 1 y, 2 z), `at` a fraction of the
    /// lattice in `[0, 1]` (0 the first voxel centre, 1 the last), seen
    /// from the positive side of the axis, the other two axes in order
    /// (x right and y up for z; x and z for y; y and z for x).
    Slice { axis: usize, at: f64 },
    /// Emission-absorption ray marching of the whole lattice, an
    /// orthographic camera at `azimuth` degrees around z (0: on the +x
    /// side) and `elevation` degrees above the x-y plane, looking at the
    /// centre; `opacity` is the absorption per voxel length of a value 1.
    Volume { azimuth: f64, elevation: f64, opacity: f64 },
}

/// A picture to draw.
#[derive(Clone, Copy, Debug)]
pub struct View {
    pub kind: ViewKind,
    pub width: usize,
    pub height: usize,
    pub colormap: ColorMap,
}

/// An RGB image, rows from the top, 3 bytes a pixel.
#[derive(Clone, Debug, PartialEq)]
pub struct Image {
    pub width: usize,
    pub height: usize,
    pub rgb: Vec<u8>,
}

impl Image {
    pub fn filled(width: usize, height: usize, rgb: [u8; 3]) -> Image {
        Image { width, height, rgb: rgb.repeat(width * height) }
    }

    pub fn pixel(&self, x: usize, y: usize) -> [u8; 3] {
        let i = 3 * (x + self.width * y);
        [self.rgb[i], self.rgb[i + 1], self.rgb[i + 2]]
    }
}

impl ViewKind {
    /// `AXIS=FRACTION`, as in `z=0.5`.
    pub fn parse_slice(s: &str) -> Result<ViewKind> {
        let bad = || Error::arg(format!("slice '{s}': give AXIS=FRACTION with AXIS x, y or z and FRACTION in [0, 1], as in z=0.5"));
        let (axis, at) = s.split_once('=').ok_or_else(bad)?;
        let axis = match axis.trim() {
            "x" => 0,
            "y" => 1,
            "z" => 2,
            _ => return Err(bad()),
        };
        let at: f64 = at.trim().parse().map_err(|_| bad())?;
        let kind = ViewKind::Slice { axis, at };
        kind.check().map_err(|_| bad())?;
        Ok(kind)
    }

    /// A preview's view: `volume`, `volume:AZIMUTH,ELEVATION` (degrees),
    /// or a slice `AXIS=FRACTION`; a volume absorbs `opacity` per voxel.
    pub fn parse_preview(s: &str, opacity: f64) -> Result<ViewKind> {
        let volume = |azimuth, elevation| {
            let kind = ViewKind::Volume { azimuth, elevation, opacity };
            kind.check().map(|_| kind)
        };
        match s.split_once(':') {
            None if s == "volume" => volume(30.0, 25.0),
            Some(("volume", cam)) => {
                let bad = || Error::arg(format!("preview '{s}': give volume:AZIMUTH,ELEVATION in degrees, as in volume:30,25"));
                let (az, el) = cam.split_once(',').ok_or_else(bad)?;
                volume(az.trim().parse().map_err(|_| bad())?, el.trim().parse().map_err(|_| bad())?)
            }
            _ => ViewKind::parse_slice(s),
        }
    }

    fn check(&self) -> Result<()> {
        match *self {
            ViewKind::Slice { axis, at } => {
                if axis > 2 || !(0.0..=1.0).contains(&at) {
                    return Err(Error::arg(format!("slice at {at} along axis {axis}: the axis is 0, 1 or 2 and the fraction in [0, 1]")));
                }
            }
            ViewKind::Volume { azimuth, elevation, opacity } => {
                if !azimuth.is_finite() {
                    return Err(Error::arg(format!("camera azimuth {azimuth}: give a finite angle in degrees")));
                }
                if !(-90.0..=90.0).contains(&elevation) {
                    return Err(Error::arg(format!("camera elevation {elevation}: give degrees in [-90, 90]")));
                }
                if !(opacity.is_finite() && opacity > 0.0) {
                    return Err(Error::arg(format!("opacity {opacity}: give a positive number (absorption per voxel length of a value 1)")));
                }
            }
        }
        Ok(())
    }
}

impl View {
    /// A checked view: the camera or slice, and each edge in
    /// `[MIN_EDGE, MAX_EDGE]` pixels.
    pub fn new(kind: ViewKind, width: usize, height: usize, colormap: ColorMap) -> Result<View> {
        kind.check()?;
        for (what, v) in [("width", width), ("height", height)] {
            if !(MIN_EDGE..=MAX_EDGE).contains(&v) {
                return Err(Error::arg(format!("image {what} {v}: give {MIN_EDGE} to {MAX_EDGE} pixels")));
            }
        }
        Ok(View { kind, width, height, colormap })
    }
}

/// Draws `grid` (values normalised to `[0, 1]`, on the lattice of index
/// coordinates) as `view` says.
pub fn render(grid: &Grid, view: &View) -> Result<Image> {
    view.kind.check()?;
    if grid.values.is_empty() {
        return Err(Error::arg("nothing to render: the grid is empty"));
    }
    Ok(match view.kind {
        ViewKind::Slice { axis, at } => super::slice::slice(grid, axis, at, view),
        ViewKind::Volume { azimuth, elevation, opacity } => super::volume::volume(grid, azimuth, elevation, opacity, view),
    })
}
