//! `gsenc decode`: a model, the models of a domain's pieces, or a step
//! index, decoded onto any lattice (or a sub-box of it) and streamed in
//! slabs into a `.vti` or raw float32 file.

use crate::args::{parse_box, parse_dims, BackendArgs, GridOutput};
use crate::output::{is_vti, kernel_seconds, peak_rss_bytes, print_result, Sink};
use crate::write_behind::WriteBehind;
use clap::Args;
use gsenc::threads::with_threads;
use gsenc::field::IndexBox;
use gsenc::io::{read_field, vti};
use gsenc::{Error, Result};
use serde_json::json;
use std::path::PathBuf;
use std::time::Instant;

#[derive(Args)]
pub struct DecodeArgs {
    /// A model; or the models of a domain's pieces (per-rank models of one
    /// step on one lattice), or the step index (`FIELD_STEP.gsi`) that names
    /// them: decoded together as one global field.
    #[arg(required = true)]
    model: Vec<PathBuf>,
    /// With several models or an index: decode only the region of the I-th
    /// (0-based; the rank, for an index) of the global field.
    #[arg(long, conflicts_with = "sub_box")]
    piece: Option<usize>,
    /// With a step index: decode every rank's primitives together
    /// (`sum n / max(sum rho, eps)`) instead of blending each piece's own
    /// decode across the halos; kernels that reach past a piece's box then
    /// leak into its neighbours (for comparison).
    #[arg(long)]
    additive: bool,
    /// Lattice dims X,Y,Z covering the model's box (default: its reference dims).
    #[arg(long, value_parser = parse_dims)]
    dims: Option<[usize; 3]>,
    /// Decode only the voxels X0,Y0,Z0,X1,Y1,Z1 (half-open index ranges of
    /// that lattice); the .vti keeps their world position.
    #[arg(long = "box", value_parser = parse_box)]
    sub_box: Option<[usize; 6]>,
    #[command(flatten)]
    device: BackendArgs,
    /// Voxels decoded at once (memory: 4 bytes each, three times: the
    /// slab decoding, and two in output units, one of them being written).
    #[arg(long, default_value_t = gsenc::model::DEFAULT_SLAB_VOXELS, hide = true)]
    slab_voxels: usize,
    #[command(flatten)]
    output: GridOutput,
}

pub fn decode(a: DecodeArgs) -> Result<()> {
    let t = Instant::now();
    let field = read_field(&a.model)?;
    let model = &field.merged();
    let f = &model.meta.frame;
    let dims = a.dims.unwrap_or(f.dims);
    let region = match (a.sub_box, a.piece) {
        (Some([x0, y0, z0, x1, y1, z1]), _) => IndexBox { lo: [x0, y0, z0], hi: [x1, y1, z1] },
        (None, Some(i)) => {
            if i >= field.pieces().len() {
                return Err(Error::arg(format!("--piece {i}: only {} models given", field.pieces().len())));
            }
            if dims != f.dims {
                return Err(Error::arg("--piece decodes on the models' own lattice; leave out --dims"));
            }
            field.piece_box(i)?
        }
        (None, None) => IndexBox::whole(dims),
    };
    let spacing = [0, 1, 2].map(|i| f.dims[i] as f64 / dims[i] as f64 / f.gamma);
    let origin = [0, 1, 2].map(|i| f.bmin[i] + (region.lo[i] as f64 + 0.5) * spacing[i]);
    let out_path = &a.output.output;
    let is_vti = is_vti(out_path);
    let mut file = Sink::create(out_path)?;
    if is_vti {
        file.write(&vti::vti_prefix(region.dims(), origin, spacing, &model.meta.field))?;
    }
    // Each slab in output units, then written on the writer's thread while
    // the next slab decodes (write_behind.rs).
    let mut writer = WriteBehind::new(file)?;
    let mut write = |slab: &[f32]| {
        let mut values = writer.buffer();
        values.resize(slab.len(), 0.0);
        model.meta.range.output_into(a.output.normalized, slab, &mut values);
        writer.send(values)
    };
    let mut backend = a.device.choice().open()?;
    let backend = backend.as_mut();
    with_threads(a.output.threads, || field.decode_streaming(backend, dims, region, a.additive, a.slab_voxels, &mut write))??;
    let mut file = writer.finish()?;
    if is_vti {
        file.write(vti::VTI_SUFFIX)?;
    }
    file.commit()?;
    let seconds = t.elapsed().as_secs_f64();
    let voxels: usize = region.dims().iter().product();
    print_result(
        a.output.out.json,
        json!({
            "dims": dims,
            "box_min": region.lo,
            "box_max": region.hi,
            "voxels": voxels,
            "seconds": seconds,
            "voxels_per_second": voxels as f64 / seconds.max(1e-9),
            "peak_rss_bytes": peak_rss_bytes(),
            "backend": backend.name(),
            "fell_back": backend.fell_back(),
            "kernel_seconds": kernel_seconds(backend),
            "output": out_path.display().to_string(),
        }),
    );
    Ok(())
}

