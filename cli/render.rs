//! `gsenc render`: a model (or the global field of a step) decoded onto a
//! lattice and drawn as an axis slice or a volume rendering, with a colour
//! bar in data units; with `--reference`, the reference grid drawn the same
//! way beside it, and the image PSNR and SSIM between the two.

use crate::args::{named, parse_dims, BackendArgs, GridInput};
use crate::output::{print_result, write_output};
use clap::Args;
use gsenc::threads::with_threads;
use gsenc::field::Grid;
use gsenc::io::image::{png_bytes, Figure};
use gsenc::io::{raw, read_field};
use gsenc::render::{image_psnr, render, ssim, ColorMap, View, ViewKind, DEFAULT_OPACITY};
use gsenc::Result;
use serde_json::json;
use std::path::PathBuf;
use std::time::Instant;

#[derive(Args)]
pub struct RenderArgs {
    /// A model, the models of a domain's pieces, or a step index (`.gsi`).
    #[arg(required = true)]
    model: Vec<PathBuf>,
    /// The PNG file to write (`-`: standard output; the results then go to
    /// standard error).
    #[arg(long, short)]
    output: PathBuf,
    /// An axis slice AXIS=FRACTION (x, y or z; 0 the first voxel centre, 1
    /// the last), as in z=0.5. The default view.
    #[arg(long, conflicts_with = "volume")]
    slice: Option<String>,
    /// A volume rendering (emission-absorption ray marching) instead of a slice.
    #[arg(long)]
    volume: bool,
    /// Volume camera: degrees around z from the +x side.
    #[arg(long, default_value_t = 30.0, allow_hyphen_values = true)]
    azimuth: f64,
    /// Volume camera: degrees above the x-y plane, in [-90, 90].
    #[arg(long, default_value_t = 25.0, allow_hyphen_values = true)]
    elevation: f64,
    /// Volume: absorption per voxel length of the largest value.
    #[arg(long, default_value_t = DEFAULT_OPACITY)]
    opacity: f64,
    /// Image size of each panel, W or W,H pixels.
    #[arg(long, default_value = "512", value_parser = parse_size)]
    size: [usize; 2],
    /// Colour map: viridis, magma, inferno, plasma, cividis, turbo, greys.
    #[arg(long, default_value = "viridis", value_parser = named(ColorMap::from_name))]
    colormap: ColorMap,
    /// Decode on a lattice of X,Y,Z voxels over the model's box (default:
    /// its reference dims, or the reference's with --reference).
    #[arg(long, value_parser = parse_dims, conflicts_with = "reference")]
    dims: Option<[usize; 3]>,
    /// A reference grid (raw or .vti) drawn the same way beside the model;
    /// prints the image PSNR and SSIM of the model's picture against it.
    #[arg(long)]
    reference: Option<PathBuf>,
    /// Dims X,Y,Z of a raw reference.
    #[arg(long, value_parser = parse_dims)]
    reference_dims: Option<[usize; 3]>,
    /// Element type of a raw reference: u8, u16, f32, f64.
    #[arg(long, value_parser = named(raw::DType::from_name))]
    dtype: Option<raw::DType>,
    /// Memory order of a raw reference: xfast or zfast.
    #[arg(long, default_value = "xfast", value_parser = named(raw::Order::from_name))]
    order: raw::Order,
    /// Mean-downsample the reference by this factor first (as the encode did).
    #[arg(long, default_value_t = 1)]
    downsample: usize,
    #[arg(long)]
    threads: Option<usize>,
    #[command(flatten)]
    device: BackendArgs,
    /// Print one JSON object instead of text.
    #[arg(long)]
    json: bool,
}

pub fn parse_size(s: &str) -> std::result::Result<[usize; 2], String> {
    let v: Vec<usize> = s.split(',').map(|x| x.trim().parse::<usize>().map_err(|_| format!("size '{s}': give W or W,H pixels"))).collect::<std::result::Result<_, _>>()?;
    match v[..] {
        [w] => Ok([w, w]),
        [w, h] => Ok([w, h]),
        _ => Err(format!("size '{s}': give W or W,H pixels")),
    }
}

pub fn render_cmd(a: RenderArgs) -> Result<()> {
    let t = Instant::now();
    // The view first: a bad camera or size is an error before any decoding.
    let kind = match (&a.slice, a.volume) {
        (Some(s), _) => ViewKind::parse_slice(s)?,
        (None, true) => ViewKind::Volume { azimuth: a.azimuth, elevation: a.elevation, opacity: a.opacity },
        (None, false) => ViewKind::parse_slice("z=0.5")?,
    };
    let view = View::new(kind, a.size[0], a.size[1], a.colormap)?;
    let field = read_field(&a.model)?;
    let model = field.merged();
    let reference = match &a.reference {
        Some(path) => {
            let input = GridInput { input: path.clone(), dims: a.reference_dims, dtype: a.dtype, order: a.order, array: None, downsample: a.downsample };
            let (grid, _) = input.load()?;
            Some(Grid::new(grid.dims, model.meta.range.normalize(&grid.values)?.values)?)
        }
        None => None,
    };
    let dims = reference.as_ref().map(|r| r.dims).or(a.dims).unwrap_or(model.meta.frame.dims);
    let mut backend = a.device.choice().open()?;
    let decoded = with_threads(a.threads, || field.decode(backend.as_mut(), dims, gsenc::field::IndexBox::whole(dims), false))??;
    let ours = with_threads(a.threads, || render(&Grid::new(dims, decoded)?, &view))??;
    let theirs = match &reference {
        Some(r) => Some(with_threads(a.threads, || render(r, &view))??),
        None => None,
    };
    let mut panels = vec![("gsenc model", &ours)];
    if let Some(r) = &theirs {
        panels.push(("reference", r));
    }
    let figure = Figure { panels, colormap: a.colormap, range: model.meta.range, label: &model.meta.field }.draw()?;
    write_output(&a.output, &png_bytes(&figure)?)?;
    let (psnr, similarity) = match &theirs {
        Some(r) => (Some(image_psnr(r, &ours)?), Some(ssim(r, &ours)?)),
        None => (None, None),
    };
    let view_json = match kind {
        ViewKind::Slice { axis, at } => json!({"slice": format!("{}={at}", ["x", "y", "z"][axis])}),
        ViewKind::Volume { azimuth, elevation, opacity } => json!({"volume": {"azimuth": azimuth, "elevation": elevation, "opacity": opacity}}),
    };
    print_result(
        a.json,
        json!({
            "output": a.output,
            "width": figure.width,
            "height": figure.height,
            "view": view_json,
            "colormap": a.colormap.name(),
            "dims": dims,
            "image_psnr": psnr.map(|p| if p.is_finite() { json!(p) } else { json!("inf") }),
            "ssim": similarity,
            "seconds": t.elapsed().as_secs_f64(),
        }),
    );
    Ok(())
}
