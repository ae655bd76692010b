//! Line charts (`gsenc plot-series`, `encode-series --plot`: validation PSNR
//! against step) drawn by `plotters` with the bundled font of
//! [`super::image`], and written as PNG by the `png` crate.

use super::image::{font, png_bytes, FAMILY};
use crate::error::{Error, Result};
use crate::render::Image;
use plotters::prelude::*;

/// One named polyline.
#[derive(Clone, Debug)]
pub struct Line {
    pub label: String,
    pub points: Vec<(f64, f64)>,
    pub color: [u8; 3],
}

/// Distinct colours for up to six lines (then they repeat).
pub const PALETTE: [[u8; 3]; 6] = [[31, 119, 180], [255, 127, 14], [44, 160, 44], [214, 39, 40], [148, 103, 189], [23, 23, 23]];

pub struct Chart {
    pub width: usize,
    pub height: usize,
    pub title: String,
    pub x_label: String,
    pub y_label: String,
    pub lines: Vec<Line>,
}

/// The data box of a chart.
#[derive(Clone, Copy, Debug)]
pub struct Axes {
    pub x: (f64, f64),
    pub y: (f64, f64),
}

/// A drawn chart and where its data land: `pixel(x, y)` is the (column,
/// row) of a data point.
pub struct Drawn {
    pub image: Image,
    pixels: Vec<((f64, f64), (i32, i32))>,
    axes: Axes,
    plot: ((i32, i32), (i32, i32)),
}

impl Drawn {
    /// The pixel of data point `(x, y)` inside the plotting area (linear
    /// in each axis, as plotters maps it).
    pub fn pixel(&self, x: f64, y: f64) -> (i32, i32) {
        let ((l, t), (r, b)) = self.plot;
        let (ax, ay) = (self.axes.x, self.axes.y);
        let fx = (x - ax.0) / (ax.1 - ax.0);
        let fy = (ay.1 - y) / (ay.1 - ay.0);
        ((l as f64 + fx * (r - l) as f64).round() as i32, (t as f64 + fy * (b - t) as f64).round() as i32)
    }

    /// The pixels plotters gave the data points themselves.
    pub fn data_pixels(&self) -> &[((f64, f64), (i32, i32))] {
        &self.pixels
    }
}

/// A tick interval of 1, 2 or 5 times a power of ten giving 4 to 10 ticks.
fn tick_step(span: f64) -> f64 {
    let raw = span / 6.0;
    let p = 10f64.powf(raw.log10().floor());
    [1.0, 2.0, 5.0, 10.0].into_iter().map(|m| m * p).find(|s| span / s <= 10.0).unwrap_or(10.0 * p)
}

impl Chart {
    /// The data box: the lines' extent, y padded and rounded to ticks.
    pub fn axes(&self) -> Axes {
        let pts = self.lines.iter().flat_map(|l| l.points.iter()).filter(|p| p.0.is_finite() && p.1.is_finite());
        let (mut x0, mut x1, mut y0, mut y1) = (f64::INFINITY, f64::NEG_INFINITY, f64::INFINITY, f64::NEG_INFINITY);
        for &(x, y) in pts {
            (x0, x1, y0, y1) = (x0.min(x), x1.max(x), y0.min(y), y1.max(y));
        }
        if x0 > x1 {
            (x0, x1, y0, y1) = (0.0, 1.0, 0.0, 1.0);
        }
        if x1 - x0 < 1e-9 {
            (x0, x1) = (x0 - 0.5, x1 + 0.5);
        }
        if y1 - y0 < 1e-9 {
            (y0, y1) = (y0 - 0.5, y1 + 0.5);
        }
        let s = tick_step(y1 - y0);
        Axes { x: (x0, x1), y: ((y0 / s).floor() * s, (y1 / s).ceil() * s) }
    }

    /// The chart drawn: title, axes with ticks and labels, a grid, each
    /// line with square markers, a legend.
    pub fn draw(&self) -> Result<Drawn> {
        font()?;
        let (w, h) = (self.width.max(200), self.height.max(160));
        let axes = self.axes();
        let y_step = tick_step(axes.y.1 - axes.y.0);
        let mut img = Image::filled(w, h, [255, 255, 255]);
        let err = |e: String| Error::format(format!("drawing the chart: {e}"));
        let (pixels, plot) = {
            let root = BitMapBackend::with_buffer(&mut img.rgb, (w as u32, h as u32)).into_drawing_area();
            let mut chart = ChartBuilder::on(&root)
                .caption(&self.title, (FAMILY, 20))
                .margin(12)
                .x_label_area_size(48)
                .y_label_area_size(64)
                .build_cartesian_2d(axes.x.0..axes.x.1, axes.y.0..axes.y.1)
                .map_err(|e| err(e.to_string()))?;
            chart
                .configure_mesh()
                .x_desc(&self.x_label)
                .y_desc(&self.y_label)
                .label_style((FAMILY, 13))
                .axis_desc_style((FAMILY, 14))
                .light_line_style(WHITE)
                .bold_line_style(RGBColor(215, 215, 215))
                .x_label_formatter(&|x| format!("{x:.0}"))
                .y_label_formatter(&|y| if y_step >= 1.0 { format!("{y:.0}") } else { format!("{y:.1}") })
                .draw()
                .map_err(|e| err(e.to_string()))?;
            let mut pixels = Vec::new();
            for line in &self.lines {
                let c = RGBColor(line.color[0], line.color[1], line.color[2]);
                let pts: Vec<(f64, f64)> = line.points.iter().copied().filter(|p| p.0.is_finite() && p.1.is_finite()).collect();
                chart
                    .draw_series(LineSeries::new(pts.clone(), c.stroke_width(2)))
                    .map_err(|e| err(e.to_string()))?
                    .label(line.label.clone())
                    .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 24, y)], c.stroke_width(3)));
                chart
                    .draw_series(pts.iter().map(|&p| EmptyElement::at(p) + Rectangle::new([(-3, -3), (3, 3)], c.filled())))
                    .map_err(|e| err(e.to_string()))?;
                pixels.extend(pts.iter().map(|&p| (p, chart.backend_coord(&p))));
            }
            if !self.lines.is_empty() {
                chart
                    .configure_series_labels()
                    .position(SeriesLabelPosition::UpperRight)
                    .label_font((FAMILY, 13))
                    .background_style(WHITE.mix(0.85))
                    .border_style(BLACK)
                    .draw()
                    .map_err(|e| err(e.to_string()))?;
            }
            let plot = (chart.backend_coord(&(axes.x.0, axes.y.1)), chart.backend_coord(&(axes.x.1, axes.y.0)));
            root.present().map_err(|e| err(e.to_string()))?;
            (pixels, plot)
        };
        Ok(Drawn { image: img, pixels, axes, plot })
    }

    /// The chart as PNG bytes.
    pub fn to_png(&self) -> Result<Vec<u8>> {
        png_bytes(&self.draw()?.image)
    }
}
