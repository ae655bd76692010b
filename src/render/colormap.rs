//! Named colour maps (those of matplotlib, through the `colorous` crate).

use crate::error::{Error, Result};

/// A colour map: normalised values in `[0, 1]` to RGB.
#[derive(Clone, Copy)]
pub struct ColorMap {
    name: &'static str,
    gradient: colorous::Gradient,
}

impl std::fmt::Debug for ColorMap {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name)
    }
}

const MAPS: [(&str, colorous::Gradient); 7] = [
    ("viridis", colorous::VIRIDIS),
    ("magma", colorous::MAGMA),
    ("inferno", colorous::INFERNO),
    ("plasma", colorous::PLASMA),
    ("cividis", colorous::CIVIDIS),
    ("turbo", colorous::TURBO),
    ("greys", colorous::GREYS),
];

impl ColorMap {
    pub fn from_name(name: &str) -> Result<ColorMap> {
        MAPS.iter()
            .find(|(n, _)| *n == name)
            .map(|&(name, gradient)| ColorMap { name, gradient })
            .ok_or_else(|| Error::arg(format!("unknown colour map '{name}' ({})", ColorMap::names().join(", "))))
    }

    pub fn names() -> Vec<&'static str> {
        MAPS.iter().map(|(n, _)| *n).collect()
    }

    pub fn name(&self) -> &'static str {
        self.name
    }

    /// The colour of `t` (clamped to `[0, 1]`; NaN reads as 0).
    pub fn rgb(&self, t: f32) -> [u8; 3] {
        let t = if t.is_nan() { 0.0 } else { t.clamp(0.0, 1.0) };
        let c = self.gradient.eval_continuous(t as f64);
        [c.r, c.g, c.b]
    }
}

impl Default for ColorMap {
    fn default() -> Self {
        ColorMap::from_name("viridis").expect("viridis is a known map")
    }
}
