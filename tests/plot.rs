//! The PNG line chart: a PNG whose pixels put each line where its data say,
//! and plotters' placement of the data matches the chart's linear axes.

use gsenc::io::plot::{Chart, Line};

#[test]
fn lines_land_where_their_data_says() {
    let a = Line { label: "independent".into(), points: vec![(1.0, 30.0), (2.0, 32.5), (3.0, 31.0)], color: [200, 0, 0] };
    let b = Line { label: "warm dense".into(), points: vec![(1.0, 34.0), (2.0, 35.0), (3.0, 36.0)], color: [0, 0, 200] };
    let chart = Chart { width: 640, height: 400, title: "t".into(), x_label: "step".into(), y_label: "PSNR dB".into(), lines: vec![a.clone(), b.clone()] };
    let axes = chart.axes();
    assert!(axes.y.0 <= 30.0 && axes.y.1 >= 36.0, "{axes:?}");
    let drawn = chart.draw().unwrap();
    let img = &drawn.image;
    assert_eq!((img.width, img.height), (640, 400));
    // The PNG holds the same pixels.
    let dir = std::env::temp_dir().join(format!("gsenc_plot_{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join("c.png"), chart.to_png().unwrap()).unwrap();
    assert_eq!(&gsenc::io::image::read_png(dir.join("c.png")).unwrap(), img);
    std::fs::remove_dir_all(&dir).ok();
    let at = |(c, r): (i32, i32)| img.pixel(c as usize, r as usize);
    // Plotters put every data point where the chart's axes say (to a pixel).
    assert_eq!(drawn.data_pixels().len(), 6);
    for &((x, y), (c, r)) in drawn.data_pixels() {
        let (c2, r2) = drawn.pixel(x, y);
        assert!((c - c2).abs() <= 1 && (r - r2).abs() <= 1, "({x}, {y}): plotters ({c}, {r}), axes ({c2}, {r2})");
    }
    for line in [&a, &b] {
        for &(x, y) in &line.points {
            assert_eq!(at(drawn.pixel(x, y)), line.color, "{} at ({x}, {y})", line.label);
        }
        // Half-way between two points, on the segment.
        let (p, q) = (line.points[0], line.points[1]);
        assert_eq!(at(drawn.pixel((p.0 + q.0) / 2.0, (p.1 + q.1) / 2.0)), line.color, "{} segment", line.label);
    }
    // Away from both lines the plot is background or grid, never a line colour.
    let c = at(drawn.pixel(2.0, 33.7));
    assert!(c != a.color && c != b.color, "{c:?}");
    // Text was drawn (title, ticks, labels, legend): dark pixels outside the plot.
    let (l, _) = drawn.pixel(axes.x.0, axes.y.0);
    assert!((0..img.height).any(|y| (0..l as usize - 2).any(|x| img.pixel(x, y)[0] < 80)), "no tick labels");
}

#[test]
fn an_empty_chart_still_draws() {
    let chart = Chart { width: 300, height: 200, title: "nothing yet".into(), x_label: "step".into(), y_label: "PSNR dB".into(), lines: vec![] };
    let png = chart.to_png().unwrap();
    assert_eq!(&png[..8], b"\x89PNG\r\n\x1a\n");
}
