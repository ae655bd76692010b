//! Renderings as PNG files: the panels side by side with their titles, a
//! colour bar labelled in data units, text drawn by `plotters` in the
//! bundled DejaVu Sans Mono (`assets/fonts`, its licence beside it), PNG
//! encoded by the `png` crate and written under a temporary name.

use crate::error::{Error, Result};
use crate::field::ValueRange;
use crate::backend::Backend;
use crate::model::Model;
use crate::render::{render, ColorMap, Image, View};
use plotters::prelude::*;
use plotters::style::{register_font, FontStyle};
use std::path::Path;

static FONT: &[u8] = include_bytes!("../../assets/fonts/DejaVuSansMono.ttf");
/// The family name the bundled font is registered under.
pub const FAMILY: &str = "gsenc-mono";
const MARGIN: usize = 8;
const TITLE: usize = 24;
const BAR: usize = 18;
const LABELS: usize = 96;
/// Ticks on the colour bar.
const TICKS: usize = 5;

/// Registers the bundled font with `plotters` (once).
pub fn font() -> Result<()> {
    static REGISTERED: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    if *REGISTERED.get_or_init(|| register_font(FAMILY, FontStyle::Normal, FONT).is_ok()) {
        Ok(())
    } else {
        Err(Error::format("the bundled font could not be read"))
    }
}

/// A value of the colour bar's scale, in data units, with 4 significant digits.
pub fn tick_label(v: f64) -> String {
    if v == 0.0 || (1e-3..1e5).contains(&v.abs()) {
        let digits = (3 - v.abs().log10().floor() as i32).clamp(0, 6) as usize;
        format!("{v:.digits$}")
    } else {
        format!("{v:.3e}")
    }
}

/// One picture: the panels (each with its title) left to right, all of
/// one size, and a colour bar of `map` from `range`'s minimum to its
/// maximum, titled `label`.
pub struct Figure<'a> {
    pub panels: Vec<(&'a str, &'a Image)>,
    pub colormap: ColorMap,
    pub range: ValueRange,
    pub label: &'a str,
}

impl Figure<'_> {
    /// The whole figure as an RGB image.
    pub fn draw(&self) -> Result<Image> {
        let first = self.panels.first().ok_or_else(|| Error::arg("a figure needs at least one panel"))?.1;
        let (pw, ph) = (first.width, first.height);
        if self.panels.iter().any(|(_, p)| p.width != pw || p.height != ph) {
            return Err(Error::arg("the panels of a figure must have one size"));
        }
        let n = self.panels.len();
        let bar_x = MARGIN + n * (pw + MARGIN) + MARGIN;
        let (w, h) = (bar_x + BAR + LABELS, TITLE + ph + MARGIN);
        let mut out = Image::filled(w, h, [255, 255, 255]);
        let mut put = |x: usize, y: usize, c: [u8; 3]| out.rgb[3 * (x + w * y)..3 * (x + w * y) + 3].copy_from_slice(&c);
        for (k, (_, p)) in self.panels.iter().enumerate() {
            let x0 = MARGIN + k * (pw + MARGIN);
            for y in 0..ph {
                for x in 0..pw {
                    put(x0 + x, TITLE + y, p.pixel(x, y));
                }
            }
        }
        for y in 0..ph {
            let t = 1.0 - (y as f32 + 0.5) / ph as f32;
            for x in 0..BAR {
                put(bar_x + x, TITLE + y, self.colormap.rgb(t));
            }
        }
        font()?;
        let text = |s: &str, x: usize, y: usize, buf: &mut [u8]| -> Result<()> {
            let area = BitMapBackend::with_buffer(buf, (w as u32, h as u32)).into_drawing_area();
            let style = TextStyle::from((FAMILY, 13).into_font()).color(&BLACK);
            area.draw(&Text::new(s.to_owned(), (x as i32, y as i32), style)).map_err(|e| Error::format(format!("drawing text: {e}")))?;
            area.present().map_err(|e| Error::format(format!("drawing text: {e}")))
        };
        for (k, (title, _)) in self.panels.iter().enumerate() {
            text(title, MARGIN + k * (pw + MARGIN), 5, &mut out.rgb)?;
        }
        text(self.label, bar_x, 5, &mut out.rgb)?;
        for i in 0..TICKS {
            let t = i as f64 / (TICKS - 1) as f64;
            let y = TITLE + ((1.0 - t) * (ph - 1) as f64) as usize;
            for x in bar_x + BAR..bar_x + BAR + 4 {
                out.rgb[3 * (x + w * y)..3 * (x + w * y) + 3].copy_from_slice(&[0, 0, 0]);
            }
            let label = tick_label(self.range.denormalize(t as f32));
            text(&label, bar_x + BAR + 6, y.saturating_sub(6).max(TITLE - 6), &mut out.rgb)?;
        }
        Ok(out)
    }
}

/// A model decoded on its own lattice and drawn as `view` says, with its
/// colour bar (the picture of `gsenc render` without a reference).
pub fn model_figure(model: &Model, backend: &mut dyn Backend, view: &View) -> Result<Image> {
    let decoded = model.decode(backend, None)?;
    let picture = render(&crate::field::Grid::new(decoded.dims, decoded.values)?, view)?;
    let title = format!("{} step {}", model.meta.field, model.meta.step);
    Figure { panels: vec![(&title, &picture)], colormap: view.colormap, range: model.meta.range, label: &model.meta.field }.draw()
}

/// `img` as PNG bytes (8-bit RGB).
pub fn png_bytes(img: &Image) -> Result<Vec<u8>> {
    let mut bytes = Vec::new();
    let mut enc = png::Encoder::new(&mut bytes, img.width as u32, img.height as u32);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    enc.set_compression(png::Compression::Best);
    enc.set_filter(png::FilterType::Paeth);
    enc.set_adaptive_filter(png::AdaptiveFilterType::Adaptive);
    let err = |e: png::EncodingError| Error::format(format!("encoding PNG: {e}"));
    let mut writer = enc.write_header().map_err(err)?;
    writer.write_image_data(&img.rgb).map_err(err)?;
    writer.finish().map_err(err)?;
    Ok(bytes)
}

/// Writes `img` as a PNG file (under a temporary name, then renamed).
pub fn write_png(path: impl AsRef<Path>, img: &Image) -> Result<()> {
    super::write_atomic(path, &png_bytes(img)?)
}

/// Reads an 8-bit RGB or RGBA PNG (what [`write_png`] writes) back.
pub fn read_png(path: impl AsRef<Path>) -> Result<Image> {
    let path = path.as_ref();
    let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let err = |e: png::DecodingError| Error::format(format!("{}: not a PNG gsenc reads ({e})", path.display()));
    let mut reader = png::Decoder::new(std::io::BufReader::new(file)).read_info().map_err(err)?;
    let mut buf = vec![0; reader.output_buffer_size()];
    let info = reader.next_frame(&mut buf).map_err(err)?;
    let (w, h) = (info.width as usize, info.height as usize);
    let rgb = match (info.color_type, info.bit_depth) {
        (png::ColorType::Rgb, png::BitDepth::Eight) => buf[..3 * w * h].to_vec(),
        (png::ColorType::Rgba, png::BitDepth::Eight) => buf[..4 * w * h].chunks_exact(4).flat_map(|p| [p[0], p[1], p[2]]).collect(),
        (c, d) => return Err(Error::format(format!("{}: a {c:?} PNG of {d:?} bits; gsenc reads 8-bit RGB or RGBA", path.display()))),
    };
    Ok(Image { width: w, height: h, rgb })
}
