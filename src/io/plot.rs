//! A line chart drawn into an RGB raster and written as PNG, with no font or
//! graphics library: a built-in 5x7 bitmap font, straight lines and squares.
//! Enough for `gsenc plot-series` (validation PSNR against step), and it
//! draws the same bytes on every machine.

use flate2::write::ZlibEncoder;
use std::io::Write;

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

const LEFT: usize = 90;
const RIGHT: usize = 30;
const TOP: usize = 50;
const BOTTOM: usize = 70;
const SCALE: usize = 2;

/// The data box of a chart and its map to pixels.
#[derive(Clone, Copy, Debug)]
pub struct Axes {
    pub x: (f64, f64),
    pub y: (f64, f64),
    width: usize,
    height: usize,
}

impl Axes {
    /// Pixel (column, row) of a data point.
    pub fn pixel(&self, x: f64, y: f64) -> (f64, f64) {
        let pw = (self.width - LEFT - RIGHT) as f64;
        let ph = (self.height - TOP - BOTTOM) as f64;
        (LEFT as f64 + (x - self.x.0) / (self.x.1 - self.x.0) * pw, TOP as f64 + (self.y.1 - y) / (self.y.1 - self.y.0) * ph)
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
        Axes { x: (x0, x1), y: ((y0 / s).floor() * s, (y1 / s).ceil() * s), width: self.width, height: self.height }
    }

    /// The chart as PNG bytes.
    pub fn to_png(&self) -> Vec<u8> {
        let mut img = Raster::new(self.width.max(LEFT + RIGHT + 50), self.height.max(TOP + BOTTOM + 50));
        let axes = Axes { width: img.w, height: img.h, ..self.axes() };
        let (px0, py1) = axes.pixel(axes.x.0, axes.y.0);
        let (px1, py0) = axes.pixel(axes.x.1, axes.y.1);
        let grey = [210, 210, 210];
        let black = [0, 0, 0];
        // Grid and tick labels.
        let ys = tick_step(axes.y.1 - axes.y.0);
        let mut y = axes.y.0;
        while y <= axes.y.1 + ys * 1e-6 {
            let (_, py) = axes.pixel(axes.x.0, y);
            img.line(px0, py, px1, py, grey, 1);
            let label = if ys < 1.0 { format!("{y:.1}") } else { format!("{y:.0}") };
            img.text(px0 as usize - 8 - text_width(&label), py as usize - 7, &label, black);
            y += ys;
        }
        let xs = tick_step(axes.x.1 - axes.x.0).max(1.0);
        let mut x = (axes.x.0 / xs).ceil() * xs;
        while x <= axes.x.1 + xs * 1e-6 {
            let (px, _) = axes.pixel(x, axes.y.0);
            img.line(px, py0, px, py1, grey, 1);
            let label = format!("{x:.0}");
            img.text(px as usize - text_width(&label) / 2, py1 as usize + 8, &label, black);
            x += xs;
        }
        img.line(px0, py1, px1, py1, black, 1);
        img.line(px0, py0, px0, py1, black, 1);
        img.text(img.w / 2 - text_width(&self.title) / 2, 12, &self.title, black);
        img.text(img.w / 2 - text_width(&self.x_label) / 2, img.h - 28, &self.x_label, black);
        img.text(8, TOP - 30, &self.y_label, black);
        // Lines, markers and the legend.
        for (k, line) in self.lines.iter().enumerate() {
            let pts: Vec<(f64, f64)> = line.points.iter().filter(|p| p.1.is_finite()).map(|&(x, y)| axes.pixel(x, y)).collect();
            for w in pts.windows(2) {
                img.line(w[0].0, w[0].1, w[1].0, w[1].1, line.color, 2);
            }
            for &(x, y) in &pts {
                img.square(x, y, 3, line.color);
            }
            let ly = TOP + 10 + 20 * k;
            img.line(px0 + 12.0, ly as f64 + 7.0, px0 + 40.0, ly as f64 + 7.0, line.color, 3);
            img.text(px0 as usize + 48, ly, &line.label, black);
        }
        img.png()
    }
}

/// An RGB image, white to start with.
struct Raster {
    w: usize,
    h: usize,
    px: Vec<u8>,
}

impl Raster {
    fn new(w: usize, h: usize) -> Raster {
        Raster { w, h, px: vec![255; w * h * 3] }
    }

    fn set(&mut self, x: i64, y: i64, c: [u8; 3]) {
        if x >= 0 && y >= 0 && (x as usize) < self.w && (y as usize) < self.h {
            let i = 3 * (y as usize * self.w + x as usize);
            self.px[i..i + 3].copy_from_slice(&c);
        }
    }

    fn square(&mut self, x: f64, y: f64, half: i64, c: [u8; 3]) {
        let (x, y) = (x.round() as i64, y.round() as i64);
        for dy in -half..=half {
            for dx in -half..=half {
                self.set(x + dx, y + dy, c);
            }
        }
    }

    /// A line `thick` pixels wide, by stepping along its longer axis.
    fn line(&mut self, x0: f64, y0: f64, x1: f64, y1: f64, c: [u8; 3], thick: i64) {
        let n = (x1 - x0).abs().max((y1 - y0).abs()).ceil().max(1.0) as usize;
        for i in 0..=n {
            let t = i as f64 / n as f64;
            let (x, y) = ((x0 + t * (x1 - x0)).round() as i64, (y0 + t * (y1 - y0)).round() as i64);
            for d in 0..thick {
                let o = d - thick / 2;
                self.set(x + o, y, c);
                self.set(x, y + o, c);
            }
        }
    }

    fn text(&mut self, x: usize, y: usize, s: &str, c: [u8; 3]) {
        for (k, ch) in s.chars().enumerate() {
            let rows = glyph(ch);
            for (r, bits) in rows.iter().enumerate() {
                for col in 0..5 {
                    if bits & (0x10 >> col) != 0 {
                        for sy in 0..SCALE {
                            for sx in 0..SCALE {
                                let px = x + k * 6 * SCALE + col * SCALE + sx;
                                self.set(px as i64, (y + r * SCALE + sy) as i64, c);
                            }
                        }
                    }
                }
            }
        }
    }

    fn png(&self) -> Vec<u8> {
        let mut raw = Vec::with_capacity((self.w * 3 + 1) * self.h);
        for row in self.px.chunks_exact(self.w * 3) {
            raw.push(0); // filter: none
            raw.extend_from_slice(row);
        }
        let mut z = ZlibEncoder::new(Vec::new(), flate2::Compression::default());
        z.write_all(&raw).expect("writing to memory");
        let idat = z.finish().expect("writing to memory");
        let mut out = b"\x89PNG\r\n\x1a\n".to_vec();
        let mut ihdr = Vec::new();
        ihdr.extend_from_slice(&(self.w as u32).to_be_bytes());
        ihdr.extend_from_slice(&(self.h as u32).to_be_bytes());
        ihdr.extend_from_slice(&[8, 2, 0, 0, 0]); // 8-bit RGB
        for (kind, data) in [(b"IHDR", &ihdr), (b"IDAT", &idat), (b"IEND", &Vec::new())] {
            out.extend_from_slice(&(data.len() as u32).to_be_bytes());
            let start = out.len();
            out.extend_from_slice(kind);
            out.extend_from_slice(data);
            let crc = crc32fast::hash(&out[start..]);
            out.extend_from_slice(&crc.to_be_bytes());
        }
        out
    }
}

fn text_width(s: &str) -> usize {
    s.chars().count() * 6 * SCALE
}

/// Rows of a 5x7 glyph, top first, bit 4 the leftmost column. Characters
/// without a glyph draw as a blank.
fn glyph(c: char) -> [u8; 7] {
    match c {
        '0' => [0x0E, 0x11, 0x13, 0x15, 0x19, 0x11, 0x0E],
        '1' => [0x04, 0x0C, 0x04, 0x04, 0x04, 0x04, 0x0E],
        '2' => [0x0E, 0x11, 0x01, 0x02, 0x04, 0x08, 0x1F],
        '3' => [0x1F, 0x02, 0x04, 0x02, 0x01, 0x11, 0x0E],
        '4' => [0x02, 0x06, 0x0A, 0x12, 0x1F, 0x02, 0x02],
        '5' => [0x1F, 0x10, 0x1E, 0x01, 0x01, 0x11, 0x0E],
        '6' => [0x06, 0x08, 0x10, 0x1E, 0x11, 0x11, 0x0E],
        '7' => [0x1F, 0x01, 0x02, 0x04, 0x08, 0x08, 0x08],
        '8' => [0x0E, 0x11, 0x11, 0x0E, 0x11, 0x11, 0x0E],
        '9' => [0x0E, 0x11, 0x11, 0x0F, 0x01, 0x02, 0x0C],
        '.' => [0, 0, 0, 0, 0, 0x0C, 0x0C],
        '-' => [0, 0, 0, 0x1F, 0, 0, 0],
        ',' => [0, 0, 0, 0, 0x0C, 0x04, 0x08],
        '(' => [0x02, 0x04, 0x08, 0x08, 0x08, 0x04, 0x02],
        ')' => [0x08, 0x04, 0x02, 0x02, 0x02, 0x04, 0x08],
        '%' => [0x18, 0x19, 0x02, 0x04, 0x08, 0x13, 0x03],
        'B' => [0x1E, 0x11, 0x11, 0x1E, 0x11, 0x11, 0x1E],
        'N' => [0x11, 0x11, 0x19, 0x15, 0x13, 0x11, 0x11],
        'P' => [0x1E, 0x11, 0x11, 0x1E, 0x10, 0x10, 0x10],
        'R' => [0x1E, 0x11, 0x11, 0x1E, 0x14, 0x12, 0x11],
        'S' => [0x0F, 0x10, 0x10, 0x0E, 0x01, 0x01, 0x1E],
        'a' => [0, 0, 0x0E, 0x01, 0x0F, 0x11, 0x0F],
        'b' => [0x10, 0x10, 0x16, 0x19, 0x11, 0x11, 0x1E],
        'c' => [0, 0, 0x0E, 0x10, 0x10, 0x11, 0x0E],
        'd' => [0x01, 0x01, 0x0D, 0x13, 0x11, 0x11, 0x0F],
        'e' => [0, 0, 0x0E, 0x11, 0x1F, 0x10, 0x0E],
        'f' => [0x06, 0x09, 0x08, 0x1C, 0x08, 0x08, 0x08],
        'g' => [0, 0x0F, 0x11, 0x11, 0x0F, 0x01, 0x0E],
        'h' => [0x10, 0x10, 0x16, 0x19, 0x11, 0x11, 0x11],
        'i' => [0x04, 0, 0x0C, 0x04, 0x04, 0x04, 0x0E],
        'j' => [0x02, 0, 0x06, 0x02, 0x02, 0x12, 0x0C],
        'k' => [0x10, 0x10, 0x12, 0x14, 0x18, 0x14, 0x12],
        'l' => [0x0C, 0x04, 0x04, 0x04, 0x04, 0x04, 0x0E],
        'm' => [0, 0, 0x1A, 0x15, 0x15, 0x11, 0x11],
        'n' => [0, 0, 0x16, 0x19, 0x11, 0x11, 0x11],
        'o' => [0, 0, 0x0E, 0x11, 0x11, 0x11, 0x0E],
        'p' => [0, 0, 0x1E, 0x11, 0x1E, 0x10, 0x10],
        'q' => [0, 0, 0x0D, 0x13, 0x0F, 0x01, 0x01],
        'r' => [0, 0, 0x16, 0x19, 0x10, 0x10, 0x10],
        's' => [0, 0, 0x0E, 0x10, 0x0E, 0x01, 0x1E],
        't' => [0x08, 0x08, 0x1C, 0x08, 0x08, 0x09, 0x06],
        'u' => [0, 0, 0x11, 0x11, 0x11, 0x13, 0x0D],
        'v' => [0, 0, 0x11, 0x11, 0x11, 0x0A, 0x04],
        'w' => [0, 0, 0x11, 0x11, 0x15, 0x15, 0x0A],
        'x' => [0, 0, 0x11, 0x0A, 0x04, 0x0A, 0x11],
        'y' => [0, 0, 0x11, 0x11, 0x0F, 0x01, 0x0E],
        'z' => [0, 0, 0x1F, 0x02, 0x04, 0x08, 0x1F],
        c if c.is_ascii_uppercase() => glyph(c.to_ascii_lowercase()),
        _ => [0; 7],
    }
}
