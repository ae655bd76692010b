//! Raw binary arrays: little-endian `u8`, `u16`, `f32` or `f64`, dims and
//! memory order given by the user.

use crate::error::{Error, Result};
use crate::field::Grid;
use std::io::Read;
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
    let want = raw_len(dims, dtype)?;
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
            let mut out = vec![0f32; vals.len()];
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

/// The bytes a grid of `dims` values of `dtype` takes; dims must be positive.
fn raw_len(dims: [usize; 3], dtype: DType) -> Result<usize> {
    let n = dims.iter().try_fold(1usize, |a, &d| a.checked_mul(d)).ok_or_else(|| Error::arg("dims overflow"))?;
    if n == 0 {
        return Err(Error::arg(format!("dims must be positive, got {dims:?}")));
    }
    n.checked_mul(dtype.size()).ok_or_else(|| Error::arg("dims overflow"))
}

/// The bytes of a raw array file; a file named `*.zst` is one or more zstd
/// frames, decompressed here (how the repository's `data/` is stored). The
/// file is read to its end, so a device (`/dev/zero`) is refused unread, and
/// so is content beyond the memory available (a pipe without end, a `.zst`
/// that expands without end: `budget`); see [`read_bytes_at_most`] for a
/// read whose length is known.
pub fn read_bytes(path: impl AsRef<Path>) -> Result<Vec<u8>> {
    read_bytes_within(path.as_ref(), super::budget::whole_read_budget(0)?)
}

/// [`read_bytes`], refusing content beyond `budget` bytes.
fn read_bytes_within(path: &Path, budget: u64) -> Result<Vec<u8>> {
    let file = super::open_to_end(path)?;
    if !is_zst(path) {
        return super::budget::read_within(path, &file, super::file_len(&file), budget, |e| Error::io(path, e));
    }
    let decoder = zstd::stream::read::Decoder::new(file).map_err(|e| not_zstd(path, e))?;
    super::budget::read_within(path, decoder, None, budget, |e| not_zstd(path, e))
}

/// The bytes of a raw array file, as [`read_bytes`], but never more than
/// `limit + 1` of them (of the decompressed content for `*.zst`): enough to
/// tell content of `limit` bytes from longer content without holding it, so
/// that a stream that never ends (`/dev/zero`) or a small zstd file that
/// expands to terabytes is refused instead of filling memory. Pipes work
/// (`--input <(zstdcat a.zst)`).
pub fn read_bytes_at_most(path: impl AsRef<Path>, limit: usize) -> Result<Vec<u8>> {
    let path = path.as_ref();
    let cap = (limit as u64).saturating_add(1);
    let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let mut out = Vec::new();
    if !is_zst(path) {
        out.reserve(usize::try_from(super::file_len(&file).unwrap_or(0).min(cap)).unwrap_or(0));
        file.take(cap).read_to_end(&mut out).map_err(|e| Error::io(path, e))?;
        return Ok(out);
    }
    let not_zstd = |e| not_zstd(path, e);
    zstd::stream::read::Decoder::new(file).map_err(not_zstd)?.take(cap).read_to_end(&mut out).map_err(not_zstd)?;
    Ok(out)
}

/// How many bytes [`read_bytes`] would return, without holding them: a
/// regular file's length, a `.zst` file's decompressed length (decompressed
/// to count it), a pipe's (read to its end, so it is spent).
pub fn content_len(path: impl AsRef<Path>) -> Result<u64> {
    let path = path.as_ref();
    let file = super::open_to_end(path)?;
    if !is_zst(path) {
        match file.metadata() {
            Ok(m) if m.is_file() => return Ok(m.len()),
            _ => return std::io::copy(&mut &file, &mut std::io::sink()).map_err(|e| Error::io(path, e)),
        }
    }
    let not_zstd = |e| not_zstd(path, e);
    std::io::copy(&mut zstd::stream::read::Decoder::new(file).map_err(not_zstd)?, &mut std::io::sink()).map_err(not_zstd)
}

fn not_zstd(path: &Path, e: std::io::Error) -> Error {
    Error::data(format!("{}: not a complete zstd-compressed file ({e})", path.display()))
}

fn is_zst(path: &Path) -> bool {
    path.extension().is_some_and(|e| e.eq_ignore_ascii_case("zst"))
}

/// Reads a raw grid file (see [`read_bytes`]), no more of it than the grid
/// takes: content longer than that is refused unread.
pub fn read_raw(path: impl AsRef<Path>, dims: [usize; 3], dtype: DType, order: Order) -> Result<Grid> {
    let path = path.as_ref();
    let want = raw_len(dims, dtype)?;
    let bytes = read_bytes_at_most(path, want)?;
    if bytes.len() > want {
        return Err(Error::data(format!(
            "{}: raw input holds more than the {want} bytes that {}x{}x{} values of {} bytes need",
            path.display(),
            dims[0],
            dims[1],
            dims[2],
            dtype.size()
        )));
    }
    parse_raw(&bytes, dims, dtype, order)
}

/// Which rows of a per-item array file to read: `count` items starting at
/// item `row * count` (files holding several steps, one block of `count`
/// items per step), or the whole file when `count` is `None`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Rows {
    pub count: Option<usize>,
    pub row: usize,
}

/// Decodes per-item arrays of `comps` components each (e.g. 3 for positions)
/// into f64, as selected by `rows`.
pub fn parse_items(bytes: &[u8], dtype: DType, comps: usize, rows: Rows, what: &str) -> Result<Vec<f64>> {
    let item_bytes = comps * dtype.size();
    if !bytes.len().is_multiple_of(item_bytes) {
        return Err(Error::data(format!(
            "{what}: {} bytes is not a whole number of {comps}-component {}-byte items",
            bytes.len(),
            dtype.size()
        )));
    }
    let held = bytes.len() / item_bytes;
    let (start, n) = match rows.count {
        None if rows.row > 0 => return Err(Error::arg(format!("{what}: a row index needs an item count per row"))),
        None => (0, held),
        Some(0) => return Err(Error::arg("item count must be at least 1")),
        Some(c) => {
            if !held.is_multiple_of(c) {
                return Err(Error::data(format!("{what}: {held} items are not whole rows of {c}")));
            }
            if rows.row >= held / c {
                return Err(Error::arg(format!("{what}: row {} requested, the file holds {} rows of {c} items", rows.row, held / c)));
            }
            (rows.row * c, c)
        }
    };
    let body = &bytes[start * item_bytes..(start + n) * item_bytes];
    Ok(match dtype {
        DType::U8 => body.iter().map(|&b| b as f64).collect(),
        DType::U16 => body.chunks_exact(2).map(|c| u16::from_le_bytes([c[0], c[1]]) as f64).collect(),
        DType::F32 => body.chunks_exact(4).map(|c| f32::from_le_bytes(c.try_into().unwrap()) as f64).collect(),
        DType::F64 => body.chunks_exact(8).map(|c| f64::from_le_bytes(c.try_into().unwrap())).collect(),
    })
}

/// Reads per-item arrays from a file (see [`parse_items`]). The file is read
/// whole (a regular file, a pipe or a `.zst`); see [`read_items_beside`] for
/// the other arrays of the same items.
pub fn read_items(path: impl AsRef<Path>, dtype: DType, comps: usize, rows: Rows) -> Result<Vec<f64>> {
    Ok(read_items_counted(path.as_ref(), dtype, comps, rows)?.0)
}

/// As [`read_items`], with how many items the whole file holds (every row):
/// what the other arrays of the same items must hold ([`read_items_beside`]).
/// Content beyond the memory available for it and the values parsed from
/// it (8 bytes each) is refused by name ([`read_bytes`]).
pub fn read_items_counted(path: &Path, dtype: DType, comps: usize, rows: Rows) -> Result<(Vec<f64>, usize)> {
    let bytes = read_bytes_within(path, super::budget::whole_read_budget(8 / dtype.size() as u64)?)?;
    let held = bytes.len() / (comps * dtype.size()).max(1);
    Ok((parse_items(&bytes, dtype, comps, rows, &path.display().to_string())?, held))
}

/// Reads another array of items whose first array holds `held` items (every
/// row), as [`read_items`], but no further than `held` items take: a file
/// that holds more (an endless stream, a zstd file that expands beyond them)
/// is refused unread past them. One that holds fewer is read, for the
/// caller's check of the arrays' lengths to name both.
pub fn read_items_beside(path: impl AsRef<Path>, dtype: DType, comps: usize, rows: Rows, held: usize) -> Result<Vec<f64>> {
    let path = path.as_ref();
    let want = held.checked_mul(comps * dtype.size()).ok_or_else(|| Error::arg("item count overflows"))?;
    let bytes = read_bytes_at_most(path, want)?;
    if bytes.len() > want {
        return Err(Error::data(format!(
            "{}: holds more than {held} items of {comps} values of {} bytes, the number the input's first array holds",
            path.display(),
            dtype.size()
        )));
    }
    parse_items(&bytes, dtype, comps, rows, &path.display().to_string())
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

    #[test]
    fn zst_files_read_as_their_content() {
        let dir = std::env::temp_dir().join(format!("gsenc-raw-zst-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let values: Vec<f32> = (0..60).map(|i| (i as f32).sin()).collect();
        let plain = to_f32_bytes(&values);
        let packed = zstd::stream::encode_all(plain.as_slice(), 3).unwrap();
        std::fs::write(dir.join("g.f32.zst"), &packed).unwrap();
        let g = read_raw(dir.join("g.f32.zst"), [5, 4, 3], DType::F32, Order::XFastest).unwrap();
        assert_eq!(g.values, values);
        let items = read_items(dir.join("g.f32.zst"), DType::F32, 3, Rows { count: None, row: 0 }).unwrap();
        assert_eq!(items.len(), 60);
        // A truncated file, and raw bytes under a .zst name, are refused by name.
        std::fs::write(dir.join("cut.f32.zst"), &packed[..packed.len() / 2]).unwrap();
        std::fs::write(dir.join("plain.f32.zst"), &plain).unwrap();
        for bad in ["cut.f32.zst", "plain.f32.zst"] {
            let e = read_raw(dir.join(bad), [5, 4, 3], DType::F32, Order::XFastest).unwrap_err();
            assert!(matches!(&e, Error::InvalidData(m) if m.contains(bad) && m.contains("zstd")), "{e}");
        }
        // Without the name, the compressed bytes are raw data (of the wrong size).
        std::fs::write(dir.join("g.f32"), &packed).unwrap();
        assert!(read_raw(dir.join("g.f32"), [5, 4, 3], DType::F32, Order::XFastest).is_err());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// A grid reads no more than it takes: longer files, endless streams and
    /// zstd files that expand far beyond the grid are refused by name, while
    /// a pipe holding the grid reads like a file.
    #[test]
    fn grids_read_no_more_than_they_take() {
        let dir = std::env::temp_dir().join(format!("gsenc-raw-bound-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let dims = [8, 8, 8];
        let values: Vec<f32> = (0..512).map(|i| (i % 7) as f32).collect();
        let mut long = to_f32_bytes(&values);
        long.extend_from_slice(&[0; 4]);
        std::fs::write(dir.join("long.f32"), &long).unwrap();
        let e = read_raw(dir.join("long.f32"), dims, DType::F32, Order::XFastest).unwrap_err();
        assert!(matches!(&e, Error::InvalidData(m) if m.contains("long.f32") && m.contains("more than the 2048 bytes")), "{e}");
        // 1 GiB of zeros in about 33 KB of zstd: refused after 2 KB of it.
        let mut enc = zstd::stream::write::Encoder::new(Vec::new(), 3).unwrap();
        let zeros = vec![0u8; 1 << 20];
        for _ in 0..1024 {
            std::io::Write::write_all(&mut enc, &zeros).unwrap();
        }
        std::fs::write(dir.join("bomb.f32.zst"), enc.finish().unwrap()).unwrap();
        let e = read_raw(dir.join("bomb.f32.zst"), dims, DType::F32, Order::XFastest).unwrap_err();
        assert!(matches!(&e, Error::InvalidData(m) if m.contains("bomb.f32.zst") && m.contains("more than")), "{e}");
        assert_eq!(read_bytes_at_most(dir.join("bomb.f32.zst"), 10).unwrap().len(), 11);
        #[cfg(unix)]
        {
            let e = read_raw("/dev/zero", dims, DType::F32, Order::XFastest).unwrap_err();
            assert!(matches!(&e, Error::InvalidData(m) if m.contains("/dev/zero") && m.contains("more than")), "{e}");
            let fifo = dir.join("grid.fifo");
            let made = std::process::Command::new("mkfifo").arg(&fifo).status().expect("mkfifo runs");
            assert!(made.success(), "mkfifo failed");
            let bytes = to_f32_bytes(&values);
            let writer = std::thread::spawn({
                let fifo = fifo.clone();
                move || std::fs::write(fifo, bytes).unwrap()
            });
            assert_eq!(read_raw(&fifo, dims, DType::F32, Order::XFastest).unwrap().values, values);
            writer.join().unwrap();
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// The first array of an input is read whole, but not from a device nor
    /// beyond the memory available; the others read no further than the
    /// first's items take, so that longer files, endless streams and zstd
    /// bombs are refused by name, while a shorter one is read for the
    /// caller's length check.
    #[test]
    fn item_arrays_read_no_more_than_their_first() {
        let dir = std::env::temp_dir().join(format!("gsenc-raw-items-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let all = Rows { count: None, row: 0 };
        let pos: Vec<f32> = (0..30).map(|i| i as f32).collect();
        std::fs::write(dir.join("pos.f32"), to_f32_bytes(&pos)).unwrap();
        let (first, held) = read_items_counted(&dir.join("pos.f32"), DType::F32, 3, all).unwrap();
        assert_eq!((first.len(), held), (30, 10));
        // Two rows of five: all ten items count, whichever row is read.
        let (row1, held) = read_items_counted(&dir.join("pos.f32"), DType::F32, 3, Rows { count: Some(5), row: 1 }).unwrap();
        assert_eq!((row1[0], held), (15.0, 10));
        std::fs::write(dir.join("h.f32"), to_f32_bytes(&[0.5; 10])).unwrap();
        assert_eq!(read_items_beside(dir.join("h.f32"), DType::F32, 1, all, 10).unwrap(), vec![0.5; 10]);
        std::fs::write(dir.join("short.f32"), to_f32_bytes(&[0.5; 9])).unwrap();
        assert_eq!(read_items_beside(dir.join("short.f32"), DType::F32, 1, all, 10).unwrap().len(), 9);
        std::fs::write(dir.join("long.f32"), to_f32_bytes(&[0.5; 11])).unwrap();
        let mut enc = zstd::stream::write::Encoder::new(Vec::new(), 3).unwrap();
        let zeros = vec![0u8; 1 << 20];
        for _ in 0..1024 {
            std::io::Write::write_all(&mut enc, &zeros).unwrap();
        }
        std::fs::write(dir.join("bomb.f32.zst"), enc.finish().unwrap()).unwrap();
        let mut longer = vec![dir.join("long.f32"), dir.join("bomb.f32.zst")];
        if cfg!(unix) {
            longer.push("/dev/zero".into());
        }
        for p in &longer {
            let e = read_items_beside(p, DType::F32, 1, all, 10).unwrap_err();
            let name = p.file_name().unwrap().to_string_lossy().into_owned();
            assert!(matches!(&e, Error::InvalidData(m) if m.contains(&name) && m.contains("more than 10 items")), "{e}");
        }
        #[cfg(unix)]
        {
            for e in [read_items("/dev/zero", DType::F32, 3, all).unwrap_err(), content_len("/dev/zero").unwrap_err()] {
                assert!(matches!(&e, Error::InvalidArgument(m) if m.contains("/dev/zero") && m.contains("is a device")), "{e}");
            }
            // A pipe is read to its end, and counted the same way.
            let fifo = dir.join("pos.fifo");
            assert!(std::process::Command::new("mkfifo").arg(&fifo).status().expect("mkfifo runs").success());
            for counted in [false, true] {
                let writer = std::thread::spawn({
                    let (fifo, bytes) = (fifo.clone(), to_f32_bytes(&pos));
                    move || std::fs::write(fifo, bytes).unwrap()
                });
                match counted {
                    false => assert_eq!(read_items(&fifo, DType::F32, 3, all).unwrap(), first),
                    true => assert_eq!(content_len(&fifo).unwrap(), 120),
                }
                writer.join().unwrap();
            }
        }
        // The first array is bounded by the memory available: within a budget
        // of 1 MiB, the 1 GiB bomb and an endless pipe are refused after 1 MiB.
        let over = |e: &Error, name: &str| matches!(e, Error::Io { path, source } if path.contains(name) && source.kind() == std::io::ErrorKind::OutOfMemory);
        assert_eq!(read_bytes_within(&dir.join("pos.f32"), 120).unwrap().len(), 120);
        assert!(over(&read_bytes_within(&dir.join("pos.f32"), 119).unwrap_err(), "pos.f32"));
        let e = read_bytes_within(&dir.join("bomb.f32.zst"), 1 << 20).unwrap_err();
        assert!(over(&e, "bomb.f32.zst"), "{e}");
        #[cfg(unix)]
        {
            let fifo = dir.join("endless.fifo");
            assert!(std::process::Command::new("mkfifo").arg(&fifo).status().expect("mkfifo runs").success());
            let writer = std::thread::spawn({
                let fifo = fifo.clone();
                // Writes until the reader has gone (a broken pipe).
                move || std::io::copy(&mut std::io::repeat(1), &mut std::fs::File::create(fifo).unwrap()).unwrap_err()
            });
            let e = read_bytes_within(&fifo, 1 << 20).unwrap_err();
            assert!(over(&e, "endless.fifo"), "{e}");
            assert_eq!(writer.join().unwrap().kind(), std::io::ErrorKind::BrokenPipe);
        }
        // A file's length without reading it, and a .zst's decompressed length.
        assert_eq!(content_len(dir.join("pos.f32")).unwrap(), 120);
        assert_eq!(content_len(dir.join("bomb.f32.zst")).unwrap(), 1 << 30);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn item_rows_select_one_step() {
        // Two rows of two 3-component f32 items.
        let b: Vec<u8> = (0..12).flat_map(|i| (i as f32).to_le_bytes()).collect();
        let all = parse_items(&b, DType::F32, 3, Rows { count: None, row: 0 }, "x").unwrap();
        assert_eq!(all.len(), 12);
        let r1 = parse_items(&b, DType::F32, 3, Rows { count: Some(2), row: 1 }, "x").unwrap();
        assert_eq!(r1, vec![6.0, 7.0, 8.0, 9.0, 10.0, 11.0]);
        assert!(parse_items(&b, DType::F32, 3, Rows { count: Some(2), row: 2 }, "x").is_err());
        assert!(parse_items(&b, DType::F32, 3, Rows { count: Some(3), row: 0 }, "x").is_err());
        assert!(parse_items(&b[..44], DType::F32, 3, Rows { count: None, row: 0 }, "x").is_err());
    }

    /// A row without a count per row, and a count of 0, are the caller's
    /// mistakes and said so, not data errors.
    #[test]
    fn a_row_needs_a_count_and_a_count_is_positive() {
        let b: Vec<u8> = (0..12).flat_map(|i| (i as f32).to_le_bytes()).collect();
        for (rows, says) in [(Rows { count: None, row: 1 }, "needs an item count"), (Rows { count: Some(0), row: 0 }, "at least 1")] {
            let e = parse_items(&b, DType::F32, 3, rows, "pos").unwrap_err();
            assert!(matches!(&e, Error::InvalidArgument(m) if m.contains(says)), "{rows:?}: {e}");
        }
    }

    /// Integers are little-endian and unsigned, in grids and in item arrays,
    /// and a u8 array keeps its first byte.
    #[test]
    fn integers_are_little_endian() {
        let b = [0x01, 0x02, 0xff, 0x00, 0x00, 0x80];
        let want = [513.0, 255.0, 32768.0];
        assert_eq!(parse_raw(&b, [3, 1, 1], DType::U16, Order::XFastest).unwrap().values, want.map(|v| v as f32));
        assert_eq!(parse_items(&b, DType::U16, 3, Rows { count: None, row: 0 }, "x").unwrap(), want);
        assert_eq!(parse_items(&b, DType::U8, 2, Rows { count: Some(1), row: 0 }, "x").unwrap(), [1.0, 2.0]);
        assert_eq!(parse_items(&b, DType::U8, 2, Rows { count: Some(1), row: 2 }, "x").unwrap(), [0.0, 128.0]);
    }

    /// Dims with a zero are refused by name, before any byte is read.
    #[test]
    fn dims_with_a_zero_are_refused() {
        for dims in [[0, 4, 4], [4, 0, 4], [4, 4, 0]] {
            let e = parse_raw(&[], dims, DType::F32, Order::XFastest).unwrap_err();
            assert!(matches!(&e, Error::InvalidArgument(m) if m.contains("dims must be positive")), "{dims:?}: {e}");
            let e = read_raw("/nonexistent/gsenc-raw", dims, DType::U8, Order::ZFastest).unwrap_err();
            assert!(matches!(&e, Error::InvalidArgument(m) if m.contains("dims must be positive")), "{dims:?}: {e}");
        }
    }

    /// Every name of each type and order, and an unknown one refused with
    /// the names it takes.
    #[test]
    fn dtype_and_order_names() {
        for (names, t, size) in [(["u8", "uint8"], DType::U8, 1), (["u16", "uint16"], DType::U16, 2), (["f32", "float32"], DType::F32, 4), (["f64", "float64"], DType::F64, 8)] {
            for name in names {
                assert_eq!(DType::from_name(name).unwrap(), t);
            }
            assert_eq!(t.size(), size);
        }
        for name in ["xfast", "x", "zyx"] {
            assert_eq!(Order::from_name(name).unwrap(), Order::XFastest);
        }
        for name in ["zfast", "z", "xyz"] {
            assert_eq!(Order::from_name(name).unwrap(), Order::ZFastest);
        }
        assert!(DType::from_name("i32").unwrap_err().to_string().contains("u8, u16, f32, f64"));
        assert!(Order::from_name("yfast").unwrap_err().to_string().contains("zfast"));
    }
}
