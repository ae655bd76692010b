//! VTK XML ImageData (`.vti`): the reader accepts what ParaView and VTK write
//! (ascii, inline base64, appended raw or base64; UInt32 or UInt64 headers;
//! zlib compression; either byte order) for one-component point or cell data;
//! the writer produces binary appended Float32 data that ParaView opens as is.

use crate::error::{Error, Result};
use crate::field::Grid;
use std::io::Read;
use std::path::Path;

/// A grid read from a `.vti` file with its world placement.
#[derive(Clone, Debug)]
pub struct VtiGrid {
    pub grid: Grid,
    /// World position of voxel (0, 0, 0)'s sample point.
    pub origin: [f64; 3],
    pub spacing: [f64; 3],
    pub name: String,
}

fn attr(tag: &str, key: &str) -> Option<String> {
    let mut from = 0;
    while let Some(p) = tag[from..].find(key) {
        let at = from + p;
        let before_ok = at == 0 || tag.as_bytes()[at - 1].is_ascii_whitespace();
        let rest = tag[at + key.len()..].trim_start();
        if before_ok && rest.starts_with('=') {
            let rest = rest[1..].trim_start();
            let q = rest.chars().next()?;
            if q == '"' || q == '\'' {
                let end = rest[1..].find(q)?;
                let raw = &rest[1..1 + end];
                return Some(
                    raw.replace("&quot;", "\"").replace("&apos;", "'").replace("&lt;", "<").replace("&gt;", ">").replace("&amp;", "&"),
                );
            }
        }
        from = at + key.len();
    }
    None
}

/// Finds `<name ...>` at or after `from`; returns (start, end after '>', attribute text).
fn find_tag<'a>(xml: &'a str, name: &str, from: usize) -> Option<(usize, usize, &'a str)> {
    let pat = format!("<{name}");
    let mut at = from;
    loop {
        let p = at + xml[at..].find(&pat)?;
        let after = xml.as_bytes().get(p + pat.len()).copied();
        if matches!(after, Some(b' ' | b'\t' | b'\n' | b'\r' | b'>' | b'/')) {
            let end = p + xml[p..].find('>')? + 1;
            return Some((p, end, &xml[p + pat.len()..end - 1]));
        }
        at = p + pat.len();
    }
}

fn numbers<T: std::str::FromStr>(s: &str, what: &str) -> Result<Vec<T>> {
    s.split_whitespace()
        .map(|t| t.parse::<T>().map_err(|_| Error::format(format!("vti: bad number '{t}' in {what}"))))
        .collect()
}

fn b64_value(c: u8) -> Option<u8> {
    match c {
        b'A'..=b'Z' => Some(c - b'A'),
        b'a'..=b'z' => Some(c - b'a' + 26),
        b'0'..=b'9' => Some(c - b'0' + 52),
        b'+' => Some(62),
        b'/' => Some(63),
        _ => None,
    }
}

/// Decodes base64 in independent 4-character groups, so that separately
/// encoded (and padded) header and data streams decode as one byte stream.
/// Stops at the first character that is neither base64 nor white space.
pub fn base64_decode(text: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(text.len() / 4 * 3);
    let mut group = [0u8; 4];
    let mut n = 0;
    let mut pads = 0;
    for &c in text {
        if c.is_ascii_whitespace() {
            continue;
        }
        let v = if c == b'=' {
            pads += 1;
            0
        } else if let Some(v) = b64_value(c) {
            v
        } else {
            break;
        };
        group[n] = v;
        n += 1;
        if n == 4 {
            let b = [(group[0] << 2) | (group[1] >> 4), (group[1] << 4) | (group[2] >> 2), (group[2] << 6) | group[3]];
            out.extend_from_slice(&b[..3 - pads.min(2)]);
            n = 0;
            pads = 0;
        }
    }
    out
}

struct Layout {
    header64: bool,
    big_endian: bool,
    zlib: bool,
}

impl Layout {
    fn uint(&self, b: &[u8], at: usize) -> Result<usize> {
        let w = if self.header64 { 8 } else { 4 };
        let s = b.get(at..at + w).ok_or_else(|| Error::format("vti: data block header is truncated"))?;
        let mut v = 0u64;
        for i in 0..w {
            let byte = if self.big_endian { s[i] } else { s[w - 1 - i] };
            v = (v << 8) | byte as u64;
        }
        usize::try_from(v).map_err(|_| Error::format("vti: block size overflows"))
    }

    /// Raw bytes of one array from a stream that starts at its header; `need`
    /// is what the array's values take. A compressed array is decompressed
    /// only as far as `need` (the blocks after it are not read), and no block
    /// beyond the size its header gives, so a small file whose header or
    /// zlib stream claims gigabytes is refused instead of filling memory.
    fn payload(&self, b: &[u8], need: usize) -> Result<Vec<u8>> {
        let w: usize = if self.header64 { 8 } else { 4 };
        if !self.zlib {
            let n = self.uint(b, 0)?;
            let data = w.checked_add(n).and_then(|end| b.get(w..end)).ok_or_else(|| Error::format("vti: data array is truncated"))?;
            return Ok(data.to_vec());
        }
        let nblocks = self.uint(b, 0)?;
        let block = self.uint(b, w)?;
        let last = self.uint(b, 2 * w)?;
        if nblocks > b.len() {
            return Err(Error::format("vti: compressed header is corrupted"));
        }
        let mut at = (3 + nblocks) * w;
        let mut out = Vec::new();
        for i in 0..nblocks {
            if out.len() >= need {
                break;
            }
            let csize = self.uint(b, (3 + i) * w)?;
            let comp = at.checked_add(csize).and_then(|end| b.get(at..end)).ok_or_else(|| Error::format("vti: compressed block is truncated"))?;
            let expect = if i + 1 == nblocks && last != 0 { last } else { block };
            // zlib expands at most 1032-fold: a larger claim is a corrupt header.
            if expect > csize.saturating_mul(1032) {
                return Err(Error::format(format!("vti: zlib block {i} claims {expect} bytes from {csize} compressed")));
            }
            let mut dec = Vec::with_capacity(expect);
            flate2::read::ZlibDecoder::new(comp)
                .take(expect as u64 + 1)
                .read_to_end(&mut dec)
                .map_err(|e| Error::format(format!("vti: zlib block {i}: {e}")))?;
            if dec.len() != expect {
                return Err(Error::format(format!("vti: zlib block {i} holds {} bytes or more, header says {expect}", dec.len())));
            }
            out.extend_from_slice(&dec);
            at += csize;
        }
        Ok(out)
    }
}

/// The bytes one value of a DataArray `type` takes.
fn type_size(ty: &str) -> Result<usize> {
    Ok(match ty {
        "Int8" | "UInt8" => 1,
        "Int16" | "UInt16" => 2,
        "Int32" | "UInt32" | "Float32" => 4,
        "Int64" | "UInt64" | "Float64" => 8,
        _ => return Err(Error::format(format!("vti: unsupported data type {ty}"))),
    })
}

fn convert(bytes: &[u8], ty: &str, big_endian: bool, n: usize) -> Result<Vec<f32>> {
    let size = type_size(ty)?;
    if bytes.len() < n * size {
        return Err(Error::format(format!("vti: array holds {} bytes, {n} values of {ty} need {}", bytes.len(), n * size)));
    }
    let mut out = Vec::with_capacity(n);
    for c in bytes[..n * size].chunks_exact(size) {
        let mut b = [0u8; 8];
        b[..size].copy_from_slice(c);
        if big_endian {
            b[..size].reverse();
        }
        let v = match ty {
            "Int8" => b[0] as i8 as f32,
            "UInt8" => b[0] as f32,
            "Int16" => i16::from_le_bytes([b[0], b[1]]) as f32,
            "UInt16" => u16::from_le_bytes([b[0], b[1]]) as f32,
            "Int32" => i32::from_le_bytes(b[..4].try_into().unwrap()) as f32,
            "UInt32" => u32::from_le_bytes(b[..4].try_into().unwrap()) as f32,
            "Float32" => f32::from_le_bytes(b[..4].try_into().unwrap()),
            "Int64" => i64::from_le_bytes(b) as f32,
            "UInt64" => u64::from_le_bytes(b) as f32,
            _ => f64::from_le_bytes(b) as f32,
        };
        out.push(v);
    }
    Ok(out)
}

/// Parses a `.vti` file's bytes; `array` picks a data array by name (default:
/// the active scalars, else the first point array, else the first cell array).
pub fn parse_vti(bytes: &[u8], array: Option<&str>) -> Result<VtiGrid> {
    // The XML part ends where raw appended data begins.
    let xml_end = find_bytes(bytes, b"<AppendedData").map(|p| {
        find_bytes(&bytes[p..], b">").map(|q| p + q + 1).unwrap_or(bytes.len())
    });
    let xml = String::from_utf8_lossy(&bytes[..xml_end.unwrap_or(bytes.len())]).into_owned();
    let (_, _, file_attrs) = find_tag(&xml, "VTKFile", 0).ok_or_else(|| Error::format("not a VTK XML file"))?;
    if attr(file_attrs, "type").as_deref() != Some("ImageData") {
        return Err(Error::format("vti: VTKFile type is not ImageData"));
    }
    let layout = Layout {
        header64: attr(file_attrs, "header_type").as_deref() == Some("UInt64"),
        big_endian: attr(file_attrs, "byte_order").as_deref() == Some("BigEndian"),
        zlib: match attr(file_attrs, "compressor").as_deref() {
            None | Some("") => false,
            Some("vtkZLibDataCompressor") => true,
            Some(other) => return Err(Error::format(format!("vti: compressor {other} is not supported (use zlib or none)"))),
        },
    };
    let (_, img_end, img) = find_tag(&xml, "ImageData", 0).ok_or_else(|| Error::format("vti: no ImageData element"))?;
    let extent: Vec<i64> = numbers(&attr(img, "WholeExtent").ok_or_else(|| Error::format("vti: no WholeExtent"))?, "WholeExtent")?;
    if extent.len() != 6 || (0..3).any(|a| extent[2 * a + 1] < extent[2 * a]) {
        return Err(Error::format("vti: WholeExtent must hold 6 ordered numbers"));
    }
    let origin: Vec<f64> = numbers(&attr(img, "Origin").unwrap_or_else(|| "0 0 0".into()), "Origin")?;
    let spacing: Vec<f64> = numbers(&attr(img, "Spacing").unwrap_or_else(|| "1 1 1".into()), "Spacing")?;
    if origin.len() != 3 || spacing.len() != 3 {
        return Err(Error::format("vti: Origin and Spacing need 3 numbers"));
    }
    // VTK 9 writes the axes' directions (the identity, unless the image is
    // rotated); gsenc's lattices are axis-aligned.
    if let Some(d) = attr(img, "Direction") {
        let d: Vec<f64> = numbers(&d, "Direction")?;
        if d != [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0] {
            return Err(Error::format(format!("vti: Direction {d:?} is not the identity; gsenc reads axis-aligned images only (resample it first)")));
        }
    }
    let too_large = || Error::format(format!("vti: WholeExtent {extent:?} is too large"));
    let mut point_dims = [0usize; 3];
    for a in 0..3 {
        let d = extent[2 * a + 1].checked_sub(extent[2 * a]).and_then(|d| d.checked_add(1));
        point_dims[a] = d.and_then(|d| usize::try_from(d).ok()).ok_or_else(too_large)?;
    }
    if find_bytes(xml.as_bytes(), b"<Piece").is_some() {
        let pieces = xml.matches("<Piece").count();
        if pieces > 1 {
            return Err(Error::format("vti: files with several pieces are not supported"));
        }
    }

    // Candidate arrays in PointData, then CellData.
    let mut chosen: Option<(String, usize, usize, bool)> = None; // (attrs, start, end, is_cell)
    for (section, is_cell) in [("PointData", false), ("CellData", true)] {
        let Some((_, s_end, s_attrs)) = find_tag(&xml, section, img_end) else { continue };
        if s_attrs.trim_end().ends_with('/') {
            continue;
        }
        let close = xml[s_end..].find(&format!("</{section}>")).map(|p| s_end + p).unwrap_or(xml.len());
        let active = attr(s_attrs, "Scalars");
        let mut at = s_end;
        let mut first = None;
        while let Some((_, e, a)) = find_tag(&xml, "DataArray", at) {
            if e > close {
                break;
            }
            let name = attr(a, "Name").unwrap_or_default();
            let data_end = if a.trim_end().ends_with('/') { e } else { e + xml[e..].find("</DataArray>").unwrap_or(0) };
            let entry = (a.to_string(), e, data_end, is_cell);
            let wanted = match array {
                Some(w) => name == w,
                None => active.as_deref() == Some(name.as_str()),
            };
            if wanted {
                chosen = Some(entry);
                break;
            }
            if first.is_none() {
                first = Some(entry);
            }
            at = e;
        }
        if chosen.is_none() && array.is_none() {
            chosen = first;
        }
        if chosen.is_some() {
            break;
        }
    }
    let (a, dstart, dend, is_cell) = chosen.ok_or_else(|| match array {
        Some(w) => Error::format(format!("vti: no data array named '{w}'")),
        None => Error::format("vti: no point or cell data array"),
    })?;
    let dims = if is_cell { point_dims.map(|d| d.saturating_sub(1).max(1)) } else { point_dims };
    let n = dims.iter().try_fold(1usize, |a, &d| a.checked_mul(d)).ok_or_else(too_large)?;
    let comps: usize = attr(&a, "NumberOfComponents").map(|c| c.parse().unwrap_or(0)).unwrap_or(1);
    if comps != 1 {
        return Err(Error::format(format!("vti: array has {comps} components; gsenc encodes scalars (extract one component first)")));
    }
    let ty = attr(&a, "type").ok_or_else(|| Error::format("vti: DataArray without type"))?;
    let need = n.checked_mul(type_size(&ty)?).ok_or_else(too_large)?;
    let name = attr(&a, "Name").unwrap_or_else(|| "scalars".into());
    let values = match attr(&a, "format").as_deref().unwrap_or("ascii") {
        "ascii" => {
            let v: Vec<f64> = numbers(&xml[dstart..dend], "ascii DataArray")?;
            if v.len() != n {
                return Err(Error::format(format!("vti: ascii array holds {} values, extent needs {n}", v.len())));
            }
            v.into_iter().map(|x| x as f32).collect()
        }
        "binary" => {
            let raw = base64_decode(&xml.as_bytes()[dstart..dend]);
            convert(&layout.payload(&raw, need)?, &ty, layout.big_endian, n)?
        }
        "appended" => {
            let off: usize = attr(&a, "offset").and_then(|o| o.parse().ok()).ok_or_else(|| Error::format("vti: appended array without offset"))?;
            let (_, _, app) = find_tag(&xml, "AppendedData", 0).ok_or_else(|| Error::format("vti: no AppendedData"))?;
            let base64 = attr(app, "encoding").as_deref() == Some("base64");
            let tag_end = xml_end.unwrap();
            let underscore = bytes[tag_end..].iter().position(|&c| c == b'_').ok_or_else(|| Error::format("vti: AppendedData without '_'"))?;
            let beyond = || Error::format("vti: appended offset beyond end of file");
            let start = (tag_end + underscore + 1).checked_add(off).ok_or_else(beyond)?;
            let stream = bytes.get(start..).ok_or_else(beyond)?;
            let decoded;
            let stream = if base64 {
                decoded = base64_decode(stream);
                &decoded[..]
            } else {
                stream
            };
            convert(&layout.payload(stream, need)?, &ty, layout.big_endian, n)?
        }
        other => return Err(Error::format(format!("vti: unknown DataArray format '{other}'"))),
    };
    // `Origin` is the position of point index (0, 0, 0), which an extent
    // need not start at (ParaView keeps a subset's extent); a cell's sample
    // point is its centre, half a spacing on along every axis the cells
    // span (none along an axis of one point: a flat image's cells are flat
    // there).
    let first = |a: usize| {
        let half = if is_cell && point_dims[a] > 1 { 0.5 } else { 0.0 };
        origin[a] + (extent[2 * a] as f64 + half) * spacing[a]
    };
    Ok(VtiGrid {
        grid: Grid::new(dims, values)?,
        origin: [first(0), first(1), first(2)],
        spacing: [spacing[0], spacing[1], spacing[2]],
        name,
    })
}

fn find_bytes(hay: &[u8], needle: &[u8]) -> Option<usize> {
    hay.windows(needle.len()).position(|w| w == needle)
}

pub fn read_vti(path: impl AsRef<Path>, array: Option<&str>) -> Result<VtiGrid> {
    let path = path.as_ref();
    let bytes = super::read_whole(path)?;
    parse_vti(&bytes, array).map_err(|e| match e {
        Error::Format(m) => Error::Format(format!("{}: {m}", path.display())),
        other => other,
    })
}

/// Serialises a grid as binary appended Float32 point data (UInt64 headers).
pub fn write_vti_bytes(grid: &Grid, origin: [f64; 3], spacing: [f64; 3], name: &str) -> Vec<u8> {
    let mut out = vti_prefix(grid.dims, origin, spacing, name);
    for v in &grid.values {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out.extend_from_slice(VTI_SUFFIX);
    out
}

/// Everything of a `.vti` file before its Float32 values, x fastest: the XML
/// and the UInt64 byte count of the appended block. Values, then
/// [`VTI_SUFFIX`], complete it, so that a decode can stream into the file.
pub fn vti_prefix(d: [usize; 3], origin: [f64; 3], spacing: [f64; 3], name: &str) -> Vec<u8> {
    let name = super::xml_escape(name);
    let xml = format!(
        "<?xml version=\"1.0\"?>\n<VTKFile type=\"ImageData\" version=\"1.0\" byte_order=\"LittleEndian\" header_type=\"UInt64\">\n  <ImageData WholeExtent=\"0 {} 0 {} 0 {}\" Origin=\"{} {} {}\" Spacing=\"{} {} {}\">\n    <Piece Extent=\"0 {} 0 {} 0 {}\">\n      <PointData Scalars=\"{name}\">\n        <DataArray type=\"Float32\" Name=\"{name}\" format=\"appended\" offset=\"0\"/>\n      </PointData>\n      <CellData>\n      </CellData>\n    </Piece>\n  </ImageData>\n  <AppendedData encoding=\"raw\">\n   _",
        d[0] - 1, d[1] - 1, d[2] - 1, origin[0], origin[1], origin[2], spacing[0], spacing[1], spacing[2],
        d[0] - 1, d[1] - 1, d[2] - 1,
    );
    let mut out = xml.into_bytes();
    out.extend_from_slice(&((d[0] * d[1] * d[2] * 4) as u64).to_le_bytes());
    out
}

/// The end of a `.vti` file after its values.
pub const VTI_SUFFIX: &[u8] = b"\n  </AppendedData>\n</VTKFile>\n";

#[cfg(test)]
mod tests {
    use super::*;

    fn b64(bytes: &[u8]) -> String {
        const T: &[u8] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
        let mut s = String::new();
        for c in bytes.chunks(3) {
            let b = [c[0], *c.get(1).unwrap_or(&0), *c.get(2).unwrap_or(&0)];
            let idx = [b[0] >> 2, ((b[0] & 3) << 4) | (b[1] >> 4), ((b[1] & 15) << 2) | (b[2] >> 6), b[2] & 63];
            for (i, &x) in idx.iter().enumerate() {
                s.push(if i <= c.len() { T[x as usize] as char } else { '=' });
            }
        }
        s
    }

    fn grid() -> Grid {
        Grid::new([3, 2, 2], (0..12).map(|i| i as f32 * 0.5 - 1.0).collect()).unwrap()
    }

    #[test]
    fn written_file_reads_back() {
        let g = grid();
        let bytes = write_vti_bytes(&g, [1.0, 2.0, 3.0], [0.5, 0.5, 0.5], "rho");
        let r = parse_vti(&bytes, None).unwrap();
        assert_eq!(r.grid, g);
        assert_eq!(r.origin, [1.0, 2.0, 3.0]);
        assert_eq!(r.spacing, [0.5; 3]);
        assert_eq!(r.name, "rho");
    }

    fn wrap(file_attrs: &str, array: &str, appended: &str) -> Vec<u8> {
        format!(
            "<?xml version=\"1.0\"?><VTKFile type=\"ImageData\" version=\"0.1\" {file_attrs}><ImageData WholeExtent=\"0 2 0 1 0 1\" Origin=\"0 0 0\" Spacing=\"1 1 1\"><Piece Extent=\"0 2 0 1 0 1\"><PointData Scalars=\"b\"><DataArray type=\"Float32\" Name=\"a\" format=\"ascii\">9 9 9 9 9 9 9 9 9 9 9 9</DataArray>{array}</PointData></Piece></ImageData>{appended}</VTKFile>"
        )
        .into_bytes()
    }

    #[test]
    fn ascii_base64_zlib_and_named_arrays() {
        let g = grid();
        let data: Vec<u8> = g.values.iter().flat_map(|v| v.to_le_bytes()).collect();
        // ascii, active scalars "b" chosen over the first array "a".
        let txt: Vec<String> = g.values.iter().map(|v| v.to_string()).collect();
        let f = wrap("", &format!("<DataArray type=\"Float32\" Name=\"b\" format=\"ascii\">{}</DataArray>", txt.join(" ")), "");
        assert_eq!(parse_vti(&f, None).unwrap().grid, g);
        assert_eq!(parse_vti(&f, Some("a")).unwrap().grid.values, vec![9.0; 12]);
        assert!(parse_vti(&f, Some("zz")).is_err());
        // An empty compressor attribute means none.
        let none = String::from_utf8(f.clone()).unwrap().replace("version=\"0.1\"", "version=\"0.1\" compressor=\"\"");
        assert_eq!(parse_vti(none.as_bytes(), None).unwrap().grid, g);
        // inline base64, UInt32 header encoded separately from the data.
        let f = wrap(
            "byte_order=\"LittleEndian\"",
            &format!("<DataArray type=\"Float32\" Name=\"b\" format=\"binary\">{}{}</DataArray>", b64(&(data.len() as u32).to_le_bytes()), b64(&data)),
            "",
        );
        assert_eq!(parse_vti(&f, None).unwrap().grid, g);
        // appended raw, zlib-compressed in two blocks, UInt64 header.
        let enc = |chunk: &[u8]| {
            use std::io::Write;
            let mut e = flate2::write::ZlibEncoder::new(vec![], flate2::Compression::default());
            e.write_all(chunk).unwrap();
            e.finish().unwrap()
        };
        let (c1, c2) = (enc(&data[..32]), enc(&data[32..]));
        let mut blob = vec![];
        for v in [2u64, 32, 16, c1.len() as u64, c2.len() as u64] {
            blob.extend_from_slice(&v.to_le_bytes());
        }
        blob.extend_from_slice(&c1);
        blob.extend_from_slice(&c2);
        let mut f = wrap(
            "header_type=\"UInt64\" compressor=\"vtkZLibDataCompressor\"",
            "<DataArray type=\"Float32\" Name=\"b\" format=\"appended\" offset=\"0\"/>",
            "<AppendedData encoding=\"raw\">_",
        );
        let tail = f.split_off(f.len() - "</VTKFile>".len());
        f.extend_from_slice(&blob);
        f.extend_from_slice(b"</AppendedData>");
        f.extend_from_slice(&tail);
        assert_eq!(parse_vti(&f, None).unwrap().grid, g);
        // appended base64, uncompressed.
        let f = wrap(
            "",
            "<DataArray type=\"Float32\" Name=\"b\" format=\"appended\" offset=\"0\"/>",
            &format!("<AppendedData encoding=\"base64\">_{}{}</AppendedData>", b64(&(data.len() as u32).to_le_bytes()), b64(&data)),
        );
        assert_eq!(parse_vti(&f, None).unwrap().grid, g);
    }

    #[test]
    fn truncated_and_foreign_files_fail_cleanly() {
        let bytes = write_vti_bytes(&grid(), [0.0; 3], [1.0; 3], "v");
        for cut in [10, 200, bytes.len() - 40] {
            assert!(parse_vti(&bytes[..cut], None).is_err(), "cut at {cut}");
        }
        assert!(parse_vti(b"hello", None).is_err());
        assert!(parse_vti(b"<VTKFile type=\"PolyData\">", None).is_err());
    }

    /// Each file the reader cannot take is refused with a message naming
    /// what is wrong: every change below, of a file that reads, is one.
    #[test]
    fn unreadable_files_are_refused_with_the_reason() {
        let base = String::from_utf8(wrap("", "", "")).unwrap();
        assert_eq!(parse_vti(base.as_bytes(), None).unwrap().grid.values, vec![9.0; 12]);
        let refused = |f: &str, what: &str| {
            let e = parse_vti(f.as_bytes(), None).unwrap_err();
            assert!(matches!(&e, Error::Format(m) if m.contains(what)), "wanted '{what}', got {e}");
        };
        let array = "<DataArray type=\"Float32\" Name=\"a\" format=\"ascii\">9 9 9 9 9 9 9 9 9 9 9 9</DataArray>";
        for (from, to, what) in [
            ("version=\"0.1\"", "version=\"0.1\" compressor=\"vtkLZ4DataCompressor\"", "compressor vtkLZ4DataCompressor is not supported"),
            ("<ImageData ", "<ImageDatum ", "no ImageData element"),
            ("WholeExtent=\"0 2 0 1 0 1\"", "", "no WholeExtent"),
            ("WholeExtent=\"0 2 0 1 0 1\"", "WholeExtent=\"0 2 0 1 0\"", "6 ordered numbers"),
            ("WholeExtent=\"0 2 0 1 0 1\"", "WholeExtent=\"0 2 1 0 0 1\"", "6 ordered numbers"),
            ("Origin=\"0 0 0\"", "Origin=\"0 0\"", "Origin and Spacing need 3 numbers"),
            ("Spacing=\"1 1 1\"", "Spacing=\"1 x 1\"", "bad number 'x' in Spacing"),
            ("Spacing=\"1 1 1\"", "Spacing=\"1 1 1\" Direction=\"0 1 0 1 0 0 0 0 1\"", "Direction [0.0, 1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0] is not the identity"),
            ("</Piece>", "</Piece><Piece Extent=\"0 2 0 1 0 1\"></Piece>", "several pieces"),
            (array, "", "no point or cell data array"),
            ("Name=\"a\"", "Name=\"a\" NumberOfComponents=\"3\"", "array has 3 components"),
            ("type=\"Float32\" Name=\"a\"", "Name=\"a\"", "DataArray without type"),
            ("type=\"Float32\" Name=\"a\"", "type=\"Bit\" Name=\"a\"", "unsupported data type Bit"),
            ("9 9 9 9 9 9 9 9 9 9 9 9", "9 9 9 9 9 9 9 9 9 9 9", "ascii array holds 11 values, extent needs 12"),
            ("9 9 9 9 9 9 9 9 9 9 9 9", "9 9 9 9 9 9 9 9 9 9 9 z", "bad number 'z' in ascii DataArray"),
            ("format=\"ascii\"", "format=\"hex\"", "unknown DataArray format 'hex'"),
        ] {
            assert_eq!(base.matches(from).count(), 1, "{from}");
            refused(&base.replace(from, to), what);
        }
        let appended = |tag: &str, data: &str| {
            let a = format!("<DataArray type=\"Float32\" Name=\"b\" format=\"appended\"{tag}/>");
            String::from_utf8(wrap("", &a, data)).unwrap()
        };
        refused(&appended("", "<AppendedData encoding=\"raw\">_</AppendedData>"), "appended array without offset");
        refused(&appended(" offset=\"0\"", "<AppendedData encoding=\"raw\"></AppendedData>"), "AppendedData without '_'");
        refused(&appended(" offset=\"0\"", ""), "no AppendedData");
    }

    /// Attributes and elements are matched by their whole names: `type`
    /// is not read out of a `header_type` before it, nor `ImageData` out of
    /// an element whose name begins so; the arrays of a section are those
    /// before its end (an empty `PointData`, as VTK writes beside cell data,
    /// does not take the `CellData` array after it); and a name the writer
    /// escapes reads back as given.
    #[test]
    fn names_are_matched_whole() {
        let cells = "<VTKFile header_type=\"UInt32\" type=\"ImageData\"><ImageDataX/><ImageData WholeExtent=\"0 2 0 1 0 1\"><Piece Extent=\"0 2 0 1 0 1\"><PointData>\n</PointData><CellData><DataArray type=\"Float32\" Name=\"c\" format=\"ascii\">1 2</DataArray></CellData></Piece></ImageData></VTKFile>";
        let v = parse_vti(cells.as_bytes(), None).unwrap();
        assert_eq!((v.grid.dims, v.grid.values, v.name.as_str()), ([2, 1, 1], vec![1.0, 2.0], "c"));
        let name = "a<b & \"c\" 'd'>";
        let bytes = write_vti_bytes(&grid(), [0.0; 3], [1.0; 3], name);
        assert_eq!(parse_vti(&bytes, None).unwrap().name, name);
        assert_eq!(parse_vti(&bytes, Some(name)).unwrap().grid, grid());
    }

    /// Point data sit at the points (`Origin` + index x `Spacing`, from
    /// where the extent starts), cell data at their cells' centres, half a
    /// spacing on, except along an axis of one point, where cells are flat.
    #[test]
    fn samples_sit_where_vtk_places_them() {
        let at = |section: &str, extent: &str, n: usize| {
            let values = vec!["1"; n].join(" ");
            let f = format!("<VTKFile type=\"ImageData\"><ImageData WholeExtent=\"{extent}\" Origin=\"1 2 3\" Spacing=\"0.5 0.5 0.25\"><{section}><DataArray type=\"Float32\" Name=\"v\" format=\"ascii\">{values}</DataArray></{section}></ImageData></VTKFile>");
            let v = parse_vti(f.as_bytes(), None).unwrap();
            (v.grid.dims, v.origin)
        };
        assert_eq!(at("PointData", "0 2 0 1 0 1", 12), ([3, 2, 2], [1.0, 2.0, 3.0]));
        assert_eq!(at("CellData", "0 2 0 1 0 1", 2), ([2, 1, 1], [1.25, 2.25, 3.125]));
        assert_eq!(at("CellData", "0 2 0 1 0 0", 2), ([2, 1, 1], [1.25, 2.25, 3.0]));
        assert_eq!(at("PointData", "4 6 0 1 -2 -1", 12), ([3, 2, 2], [3.0, 2.0, 2.5]));
        assert_eq!(at("CellData", "4 6 0 1 -2 -1", 2), ([2, 1, 1], [3.25, 2.25, 2.625]));
        // VTK 9's identity Direction changes nothing.
        let f = String::from_utf8(wrap("", "", "")).unwrap().replace("Spacing=\"1 1 1\"", "Spacing=\"1 1 1\" Direction=\"1 0 0 0 1 0 0 0 1\"");
        assert_eq!(parse_vti(f.as_bytes(), None).unwrap().grid.values, vec![9.0; 12]);
        // What gsenc writes reads back where it was.
        let g = grid();
        let back = parse_vti(&write_vti_bytes(&g, [-1.5, 0.25, 7.0], [0.5; 3], "v"), None).unwrap();
        assert_eq!(back.origin, [-1.5, 0.25, 7.0]);
    }

    /// The fuzzing seeds (`fuzz/vti-seeds`, written by Python's zlib and
    /// base64, not by this module) read as the grids they were made from, so
    /// that the fuzzer starts from files that reach every layout's decoder.
    /// Their first byte is the fuzz target's flag: odd picks the array "v" by name.
    #[test]
    fn fuzz_seeds_read_as_made() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("fuzz/vti-seeds");
        let halves: Vec<f32> = (0..12).map(|i| i as f32 * 0.5 - 1.0).collect();
        let mut seen = 0;
        for entry in std::fs::read_dir(&dir).unwrap() {
            let path = entry.unwrap().path();
            let bytes = std::fs::read(&path).unwrap();
            let name = path.file_name().unwrap().to_string_lossy().into_owned();
            let v = parse_vti(&bytes[1..], (bytes[0] & 1 == 1).then_some("v")).unwrap_or_else(|e| panic!("{name}: {e}"));
            let (dims, values) = match name.split('.').next().unwrap() {
                "cell-bigendian-f64" => ([2, 1, 1], halves[..2].to_vec()),
                "binary-zlib-u8" => ([3, 2, 2], (0..12).map(|i| i as f32).collect()),
                _ => ([3, 2, 2], halves.clone()),
            };
            assert_eq!((v.grid.dims, v.grid.values), (dims, values), "{name}");
            seen += 1;
        }
        assert_eq!(seen, 14, "seven layouts, each with both flags");
    }

    /// Every integer and float type reads as its value, signed or not, in
    /// either byte order and with either header width: the bytes here come
    /// from Rust's own `to_le_bytes`/`to_be_bytes` of typed values.
    #[test]
    fn every_data_type_in_either_byte_order() {
        macro_rules! typed {
            ($name:expr, $t:ty, [$($v:expr),*]) => {{
                let v: [$t; 6] = [$($v),*];
                let le: Vec<u8> = v.iter().flat_map(|x| x.to_le_bytes()).collect();
                let be: Vec<u8> = v.iter().flat_map(|x| x.to_be_bytes()).collect();
                ($name, le, be, v.map(|x| x as f32).to_vec())
            }};
        }
        let cases = [
            typed!("Int8", i8, [-128, -1, 0, 1, 127, -7]),
            typed!("UInt8", u8, [0, 1, 127, 128, 200, 255]),
            typed!("Int16", i16, [-32768, -2, 0, 3, 32767, -300]),
            typed!("UInt16", u16, [0, 1, 255, 256, 40000, 65535]),
            typed!("Int32", i32, [i32::MIN, -3, 0, 1 << 24, i32::MAX - 127, -70000]),
            typed!("UInt32", u32, [0, 1, 1 << 24, 3_000_000_000, u32::MAX - 255, 70000]),
            typed!("Int64", i64, [i64::MIN, -5, 0, 1 << 40, -(1 << 50), 9]),
            typed!("UInt64", u64, [0, 5, 1 << 40, 1 << 63, (1 << 63) + (1 << 50), 9]),
            typed!("Float32", f32, [-1.5, 0.0, 3.25, 1e30, -1e-30, 7.0]),
            typed!("Float64", f64, [-1.5, 0.0, 3.25, 1e30, -1e-30, 7.0]),
        ];
        for (ty, le, be, want) in &cases {
            for (order, data) in [("LittleEndian", le), ("BigEndian", be)] {
                for header64 in [false, true] {
                    let header = match (header64, order == "BigEndian") {
                        (false, false) => (data.len() as u32).to_le_bytes().to_vec(),
                        (false, true) => (data.len() as u32).to_be_bytes().to_vec(),
                        (true, false) => (data.len() as u64).to_le_bytes().to_vec(),
                        (true, true) => (data.len() as u64).to_be_bytes().to_vec(),
                    };
                    let width = if header64 { "UInt64" } else { "UInt32" };
                    let f = format!(
                        "<VTKFile type=\"ImageData\" byte_order=\"{order}\" header_type=\"{width}\"><ImageData WholeExtent=\"0 2 0 1 0 0\"><PointData><DataArray type=\"{ty}\" Name=\"v\" format=\"binary\">{}{}</DataArray></PointData></ImageData></VTKFile>",
                        b64(&header),
                        b64(data)
                    );
                    let v = parse_vti(f.as_bytes(), None).unwrap_or_else(|e| panic!("{ty} {order} {width}: {e}"));
                    assert_eq!((v.grid.dims, &v.grid.values), ([3, 2, 1], want), "{ty} {order} {width}");
                }
            }
        }
    }

    /// What VTK also writes, read alike: single-quoted attributes, a
    /// self-closing empty `PointData` before the cell data, and a zlib array
    /// whose length is a whole number of blocks (the header's last size is 0).
    #[test]
    fn other_spellings_of_the_same_file() {
        let quoted = "<VTKFile type='ImageData'><ImageData WholeExtent='0 2 0 1 0 1' Spacing='2 2 2'><PointData Scalars='b'><DataArray type='Float32' Name='a' format='ascii'>1 1 1 1 1 1 1 1 1 1 1 1</DataArray><DataArray type='Float32' Name='b' format='ascii'>2 2 2 2 2 2 2 2 2 2 2 2</DataArray></PointData></ImageData></VTKFile>";
        let v = parse_vti(quoted.as_bytes(), None).unwrap();
        assert_eq!((v.grid.values, v.spacing, v.name.as_str()), (vec![2.0; 12], [2.0; 3], "b"));
        let cells = "<VTKFile type=\"ImageData\"><ImageData WholeExtent=\"0 2 0 1 0 1\"><PointData/><CellData><DataArray type=\"Float32\" Name=\"c\" format=\"ascii\">1 2</DataArray></CellData></ImageData></VTKFile>";
        let v = parse_vti(cells.as_bytes(), None).unwrap();
        assert_eq!((v.grid.dims, v.grid.values, v.name.as_str()), ([2, 1, 1], vec![1.0, 2.0], "c"));
        let data: Vec<u8> = (0..24).collect();
        let whole_blocks = zlib_file(&data, 12, None, "0 3 0 2 0 1");
        let at = appended_at(&whole_blocks);
        assert_eq!(u64::from_le_bytes(whole_blocks[at + 16..at + 24].try_into().unwrap()), 0, "the last block is whole");
        assert_eq!(parse_vti(&whole_blocks, None).unwrap().grid.values, data.iter().map(|&b| b as f32).collect::<Vec<_>>());
        // A component count that is not a number is refused, not taken for 1.
        let f = String::from_utf8(wrap("", "", "")).unwrap().replace("Name=\"a\"", "Name=\"a\" NumberOfComponents=\"one\"");
        let e = parse_vti(f.as_bytes(), None).unwrap_err();
        assert!(matches!(&e, Error::Format(m) if m.contains("components")), "{e}");
    }

    /// A zlib-compressed appended array of `data`, in blocks of `block` bytes,
    /// with header words `header` (block count, block size, last size, then
    /// each compressed size) in place of the true ones where given.
    fn zlib_file(data: &[u8], block: usize, header: Option<Vec<u64>>, extent: &str) -> Vec<u8> {
        use std::io::Write;
        let blocks: Vec<Vec<u8>> = data
            .chunks(block)
            .map(|c| {
                let mut e = flate2::write::ZlibEncoder::new(vec![], flate2::Compression::default());
                e.write_all(c).unwrap();
                e.finish().unwrap()
            })
            .collect();
        let mut words = vec![blocks.len() as u64, block as u64, (data.len() % block) as u64];
        words.extend(blocks.iter().map(|b| b.len() as u64));
        let mut f = format!(
            "<VTKFile type=\"ImageData\" header_type=\"UInt64\" compressor=\"vtkZLibDataCompressor\"><ImageData WholeExtent=\"{extent}\"><PointData><DataArray type=\"UInt8\" Name=\"v\" format=\"appended\" offset=\"0\"/></PointData></ImageData><AppendedData encoding=\"raw\">_"
        )
        .into_bytes();
        for v in header.unwrap_or(words) {
            f.extend_from_slice(&v.to_le_bytes());
        }
        blocks.iter().for_each(|b| f.extend_from_slice(b));
        f.extend_from_slice(b"</AppendedData></VTKFile>");
        f
    }

    /// Where the appended data of a file begin (after its '_').
    fn appended_at(f: &[u8]) -> usize {
        let tag = find_bytes(f, b"<AppendedData").unwrap();
        tag + f[tag..].iter().position(|&c| c == b'_').unwrap() + 1
    }

    /// Sizes a file claims (its extent, offsets, block headers, zlib streams)
    /// are checked against what it holds before anything is allocated or
    /// decompressed for them: each crafted file is refused with a message, and
    /// a compressed array is decompressed no further than its values need.
    #[test]
    fn claimed_sizes_are_bounded() {
        let refused = |f: &[u8], what: &str| {
            let e = parse_vti(f, None).unwrap_err();
            assert!(matches!(&e, Error::Format(m) if m.contains(what)), "wanted '{what}', got {e}");
        };
        let data: Vec<u8> = (0..24).collect();
        let extent = "0 3 0 2 0 1";
        assert_eq!(parse_vti(&zlib_file(&data, 10, None, extent), None).unwrap().grid.values, data.iter().map(|&b| b as f32).collect::<Vec<_>>());
        // Extents whose point counts overflow, alone or multiplied.
        refused(&zlib_file(&data, 10, None, "-9223372036854775808 9223372036854775807 0 0 0 0"), "too large");
        refused(&zlib_file(&data, 10, None, "0 4294967296 0 4294967296 0 4294967296"), "too large");
        // An extent far larger than the file: the values are not there.
        refused(&zlib_file(&data, 10, None, "0 99999 0 99999 0 9"), "values of UInt8 need");
        // A block header claiming 2^60 bytes, and one claiming more than zlib
        // can expand its compressed block to.
        let real = zlib_file(&data, 10, None, extent);
        let csizes: Vec<u64> = {
            let at = appended_at(&real) + 24;
            (0..3).map(|i| u64::from_le_bytes(real[at + 8 * i..at + 8 * i + 8].try_into().unwrap())).collect()
        };
        refused(&zlib_file(&data, 10, Some([vec![3, 1 << 60, 4], csizes.clone()].concat()), extent), "claims");
        refused(&zlib_file(&data, 10, Some([vec![3, 10, 4], vec![csizes[0], u64::MAX - 8, csizes[2]]].concat()), extent), "truncated");
        // A block count whose header alone would outgrow the file (and whose
        // header size, 8 bytes a block, overflows).
        refused(&zlib_file(&data, 10, Some([vec![1 << 61, 10, 4], csizes.clone()].concat()), extent), "compressed header is corrupted");
        // A block whose stream expands beyond its header's size stops there.
        let bomb = vec![7u8; 1 << 20];
        let f = zlib_file(&bomb, 1 << 20, Some(vec![1, 24, 24, 0]), extent);
        let csize = (f.len() - appended_at(&f) - 32 - b"</AppendedData></VTKFile>".len()) as u64;
        refused(&zlib_file(&bomb, 1 << 20, Some(vec![1, 24, 24, csize]), extent), "holds 25 bytes or more, header says 24");
        // Blocks past the values are not read: of a stream of four 10-byte
        // blocks whose fourth is corrupt, a 24-value array reads the first three.
        let long: Vec<u8> = (0..40).collect();
        let good = zlib_file(&long, 10, None, extent);
        let at = appended_at(&good);
        let mut words: Vec<u64> = (0..7).map(|i| u64::from_le_bytes(good[at + 8 * i..at + 8 * i + 8].try_into().unwrap())).collect();
        words[6] = u64::MAX;
        let more = zlib_file(&long, 10, Some(words), extent);
        assert_eq!(parse_vti(&more, None).unwrap().grid.values, data.iter().map(|&b| b as f32).collect::<Vec<_>>());
        // An uncompressed header, and an appended offset, near 2^64.
        let mut g = write_vti_bytes(&grid(), [0.0; 3], [1.0; 3], "v");
        let at = appended_at(&g);
        g[at..at + 8].copy_from_slice(&(u64::MAX - 4).to_le_bytes());
        refused(&g, "truncated");
        let g = String::from_utf8_lossy(&write_vti_bytes(&grid(), [0.0; 3], [1.0; 3], "v")).replace("offset=\"0\"", "offset=\"18446744073709551615\"");
        refused(g.as_bytes(), "beyond end of file");
    }
}
