//! Raw binary arrays: little-endian `u8`, `u16`, `f32` or `f64`, dims and
//! memory order given by the user.

use crate::error::{Error, Result};
use crate::field::Grid;
use std::path::Path;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DType {
    U8,
    U16,
    F32,
    F64,
}

impl DType {
    pub fn from_name(s: &str) -> Result<DType> {
        match s {
            "u8" | "uint8" => Ok(DType::U8),
            "u16" | "uint16" => Ok(DType::U16),
            "f32" | "float32" => Ok(DType::F32),
            "f64" | "float64" => Ok(DType::F64),
            _ => Err(Error::arg(format!("unknown dtype '{s}' (u8, u16, f32, f64)"))),
        }
    }
    pub fn size(self) -> usize {
        match self {
            DType::U8 => 1,
            DType::U16 => 2,
            DType::F32 => 4,
            DType::F64 => 8,
        }
    }
}

/// Memory order of a raw array.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Order {
    /// x varies fastest: C order `[z][y][x]` (VTK, most simulation output).
    XFastest,
    /// z varies fastest: C order `[x][y][z]` (a numpy array indexed `[x, y, z]`).
    ZFastest,
}

impl Order {
    pub fn from_name(s: &str) -> Result<Order> {
        match s {
            "xfast" | "x" | "zyx" => Ok(Order::XFastest),
            "zfast" | "z" | "xyz" => Ok(Order::ZFastest),
            _ => Err(Error::arg(format!("unknown order '{s}' (xfast: x varies fastest; zfast: z varies fastest)"))),
        }
    }
}

/// Decodes raw bytes into a grid (x fastest, float32).
pub fn parse_raw(bytes: &[u8], dims: [usize; 3], dtype: DType, order: Order) -> Result<Grid> {
    let n = dims.iter().try_fold(1usize, |a, &d| a.checked_mul(d)).ok_or_else(|| Error::arg("dims overflow"))?;
    if n == 0 {
        return Err(Error::arg(format!("dims must be positive, got {dims:?}")));
    }
    let want = n.checked_mul(dtype.size()).ok_or_else(|| Error::arg("dims overflow"))?;
    if bytes.len() != want {
        return Err(Error::data(format!(
            "raw input has {} bytes; {}x{}x{} values of {} bytes need {want}",
            bytes.len(),
            dims[0],
            dims[1],
            dims[2],
            dtype.size()
        )));
    }
    let vals: Vec<f32> = match dtype {
        DType::U8 => bytes.iter().map(|&b| b as f32).collect(),
        DType::U16 => bytes.chunks_exact(2).map(|c| u16::from_le_bytes([c[0], c[1]]) as f32).collect(),
        DType::F32 => bytes.chunks_exact(4).map(|c| f32::from_le_bytes(c.try_into().unwrap())).collect(),
        DType::F64 => bytes.chunks_exact(8).map(|c| f64::from_le_bytes(c.try_into().unwrap()) as f32).collect(),
    };
    let vals = match order {
        Order::XFastest => vals,
        Order::ZFastest => {
            let mut out = vec![0f32; n];
            for x in 0..dims[0] {
                for y in 0..dims[1] {
                    for z in 0..dims[2] {
                        out[x + dims[0] * (y + dims[1] * z)] = vals[z + dims[2] * (y + dims[1] * x)];
                    }
                }
            }
            out
        }
    };
    Grid::new(dims, vals)
}

pub fn read_raw(path: impl AsRef<Path>, dims: [usize; 3], dtype: DType, order: Order) -> Result<Grid> {
    let path = path.as_ref();
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    parse_raw(&bytes, dims, dtype, order)
}

/// A grid as little-endian float32, x fastest.
pub fn to_f32_bytes(values: &[f32]) -> Vec<u8> {
    values.iter().flat_map(|v| v.to_le_bytes()).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn orders_and_types_decode() {
        // 2x1x3, z fastest: element (x, z) at z + 3 x.
        let zfast: Vec<u8> = vec![0, 1, 2, 10, 11, 12];
        let g = parse_raw(&zfast, [2, 1, 3], DType::U8, Order::ZFastest).unwrap();
        assert_eq!(g.values, vec![0.0, 10.0, 1.0, 11.0, 2.0, 12.0]);
        let b: Vec<u8> = [1.5f64, -2.0].iter().flat_map(|v| v.to_le_bytes()).collect();
        assert_eq!(parse_raw(&b, [2, 1, 1], DType::F64, Order::XFastest).unwrap().values, vec![1.5, -2.0]);
        let err = parse_raw(&b, [3, 1, 1], DType::F64, Order::XFastest).unwrap_err();
        assert!(err.to_string().contains("16 bytes"), "{err}");
    }
}
