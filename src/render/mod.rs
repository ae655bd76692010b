//! Pictures of a decoded field: an axis slice or a volume rendering of a grid
//! of normalised values, coloured by a named colour map, and the image
//! metrics (PSNR, SSIM) that compare two renderings. Pure computation on
//! grids and pixels; `io::image` lays the pictures out with a colour bar and
//! writes the PNG.

pub mod colormap;
pub mod compare;
pub mod slice;
pub mod view;
pub mod volume;

pub use colormap::ColorMap;
pub use compare::{image_psnr, ssim};
pub use view::{render, Image, View, ViewKind, DEFAULT_OPACITY};
