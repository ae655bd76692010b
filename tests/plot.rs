//! The PNG line chart: a valid PNG whose pixels put each line where its data
//! says, read back by an independent inflate of the image data.

use gsenc::io::plot::{Chart, Line};
use std::io::Read;

/// Width, height and RGB pixels of an 8-bit RGB PNG with unfiltered rows,
/// checking every chunk's CRC.
fn read_png(bytes: &[u8]) -> (usize, usize, Vec<u8>) {
    assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n");
    let (mut at, mut w, mut h, mut idat) = (8, 0, 0, Vec::new());
    loop {
        let len = u32::from_be_bytes(bytes[at..at + 4].try_into().unwrap()) as usize;
        let kind = &bytes[at + 4..at + 8];
        let data = &bytes[at + 8..at + 8 + len];
        let crc = u32::from_be_bytes(bytes[at + 8 + len..at + 12 + len].try_into().unwrap());
        assert_eq!(crc, crc32fast::hash(&bytes[at + 4..at + 8 + len]), "CRC of {:?}", std::str::from_utf8(kind));
        match kind {
            b"IHDR" => {
                w = u32::from_be_bytes(data[0..4].try_into().unwrap()) as usize;
                h = u32::from_be_bytes(data[4..8].try_into().unwrap()) as usize;
                assert_eq!(&data[8..10], &[8, 2], "8-bit RGB");
            }
            b"IDAT" => idat.extend_from_slice(data),
            b"IEND" => break,
            _ => {}
        }
        at += 12 + len;
    }
    let mut raw = Vec::new();
    flate2::read::ZlibDecoder::new(&idat[..]).read_to_end(&mut raw).unwrap();
    assert_eq!(raw.len(), h * (3 * w + 1));
    let px = raw.chunks_exact(3 * w + 1).flat_map(|row| {
        assert_eq!(row[0], 0, "filter none");
        row[1..].to_vec()
    });
    (w, h, px.collect())
}

#[test]
fn lines_land_where_their_data_says() {
    let a = Line { label: "independent".into(), points: vec![(1.0, 30.0), (2.0, 32.5), (3.0, 31.0)], color: [200, 0, 0] };
    let b = Line { label: "warm dense".into(), points: vec![(1.0, 34.0), (2.0, 35.0), (3.0, 36.0)], color: [0, 0, 200] };
    let chart = Chart { width: 640, height: 400, title: "t".into(), x_label: "step".into(), y_label: "PSNR dB".into(), lines: vec![a.clone(), b.clone()] };
    let (w, h, px) = read_png(&chart.to_png());
    assert_eq!((w, h), (640, 400));
    let axes = chart.axes();
    assert!(axes.y.0 <= 30.0 && axes.y.1 >= 36.0, "{axes:?}");
    let at = |x: f64, y: f64| {
        let (c, r) = axes.pixel(x, y);
        let i = 3 * (r.round() as usize * w + c.round() as usize);
        [px[i], px[i + 1], px[i + 2]]
    };
    for line in [&a, &b] {
        for &(x, y) in &line.points {
            assert_eq!(at(x, y), line.color, "{} at ({x}, {y})", line.label);
        }
        // Half-way between two points, on the segment.
        let (p, q) = (line.points[0], line.points[1]);
        assert_eq!(at((p.0 + q.0) / 2.0, (p.1 + q.1) / 2.0), line.color, "{} segment", line.label);
    }
    // Away from both lines the plot is background or grid, never a line colour.
    let c = at(2.0, 33.7);
    assert!(c != a.color && c != b.color, "{c:?}");
}
