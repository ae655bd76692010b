//! A decoded time series for viewing (cargo feature `hdf5`): every model of
//! one field of a store decoded to a float32 grid in one HDF5 file, plus an
//! XDMF file beside it that ParaView (XDMF reader) or VisIt open as a time
//! series, one uniform grid per rank; a decomposed step whose index the
//! store holds is one grid, its global field (the pieces blended across
//! their halos). `docs/FORMAT.md` describes both.

use crate::backend::Backend;
use crate::error::{Error, Result};
use crate::io::atomic::{write_atomic, Replacement};
use crate::io::xml_escape;
use crate::domain::global::GlobalField;
use crate::io::store::{Entry, EntryKey, Store};
use crate::field::{IndexBox, ValueRange};
use crate::model::Model;
use hdf5::File;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// What to decode and how.
pub struct SeriesOptions<'a> {
    /// The field to decode; may be `None` when the store holds one field.
    pub field: Option<&'a str>,
    /// Output lattice per model: its reference dims times `scale`, rounded.
    pub scale: f64,
    /// Keep values normalised to `[0, 1]` instead of mapping them to data units.
    pub normalized: bool,
    pub slab_voxels: usize,
}

/// One decoded grid of the series: one rank's model, or a step's global
/// field.
#[derive(Clone, Debug)]
pub struct Piece {
    /// The entry (rank 0's, for a global field).
    pub key: EntryKey,
    /// The step's pieces blended by its index, `/<field>/<step>/global`.
    pub global: bool,
    pub time: Option<f64>,
    pub dims: [usize; 3],
    /// World position of voxel (0, 0, 0)'s centre, and voxel size, x first.
    pub origin: [f64; 3],
    pub spacing: [f64; 3],
}

impl Piece {
    /// The grid's name in its step: `rank_<r>`, or `global`.
    pub fn name(&self) -> String {
        if self.global { "global".into() } else { format!("rank_{}", self.key.rank) }
    }

    /// Its dataset in the decoded file: `/<field>/<step>/<name>`.
    pub fn path(&self) -> String {
        format!("/{}/{}/{}", self.key.field, self.key.step, self.name())
    }
}

/// What [`write_decoded_series`] wrote.
#[derive(Debug)]
pub struct SeriesSummary {
    pub field: String,
    pub pieces: Vec<Piece>,
    /// Entries that could not be read (an append cut short), with why.
    pub skipped: Vec<(EntryKey, String)>,
    /// Steps with an index that could not be blended (a rank cut short),
    /// decoded rank by rank instead, with why.
    pub unblended: Vec<(u64, String)>,
    pub voxels: usize,
    pub xdmf: PathBuf,
}

/// The XDMF file written beside `h5`: same name, extension `.xmf`.
pub fn xdmf_path(h5: &Path) -> PathBuf {
    h5.with_extension("xmf")
}

/// Decodes every readable model of one field of `store` into `out_h5`
/// (`/<field>/<step>/rank_<r>`, float32, z slowest; a step with its index,
/// `/<field>/<step>/global`) and writes the XDMF beside it. Both files
/// appear whole or not at all.
pub fn write_decoded_series(
    store: &Store,
    out_h5: &Path,
    opts: &SeriesOptions,
    backend: &mut dyn Backend,
) -> Result<SeriesSummary> {
    if !(opts.scale.is_finite() && opts.scale > 0.0) {
        return Err(Error::arg(format!("scale must be positive, got {}", opts.scale)));
    }
    // HDF5 prints no error stack while the series is written (as for the store's calls).
    let _quiet = super::store::host_errors::quiet();
    let entries = store.entries()?;
    let mut fields: Vec<&str> = entries.iter().map(|e| e.key.field.as_str()).collect();
    fields.dedup();
    let field = match (opts.field, fields.as_slice()) {
        (Some(f), _) if fields.contains(&f) => f.to_owned(),
        (Some(f), _) => return Err(Error::arg(format!("the store holds no field '{f}' (it holds {fields:?})"))),
        (None, [one]) => (*one).to_owned(),
        (None, []) => return Err(Error::arg("the store holds no models")),
        (None, many) => return Err(Error::arg(format!("the store holds several fields {many:?}; choose one"))),
    };
    let mut pieces = Vec::new();
    let (mut skipped, mut unblended) = (Vec::new(), Vec::new());
    let mut voxels = 0;
    let out = Replacement::new(out_h5)?;
    let h5err = |e: hdf5::Error| Error::Hdf5 { path: out_h5.display().to_string(), message: e.to_string() };
    let written = (|| -> Result<()> {
        let file = File::create(&out.tmp).map_err(h5err)?;
        let of_field: Vec<&Entry> = entries.iter().filter(|e| e.key.field == field).collect();
        // Entries are sorted: each run of one step's ranks, in turn.
        for step_entries in of_field.chunk_by(|a, b| a.key.step == b.key.step) {
            let first = &step_entries[0].key;
            // The step's global field, where it has an index.
            let global = store.step_index(&field, first.step).and_then(|index| match index {
                Some(index) => {
                    let models = store.pieces_of(&index)?.into_iter().map(|(m, _)| m).collect();
                    GlobalField::of_step(index, models).map(Some)
                }
                None => Ok(None),
            });
            match global {
                Ok(Some(g)) => {
                    let piece = decode_global(&file, &g, first, opts, backend)?;
                    voxels += piece.dims.iter().product::<usize>();
                    pieces.push(piece);
                    continue;
                }
                Ok(None) => {}
                Err(why) => unblended.push((first.step, why.to_string())),
            }
            for e in step_entries {
                if let Err(why) = &e.content {
                    skipped.push((e.key.clone(), why.to_string()));
                    continue;
                }
                let model = match store.read(&e.key) {
                    Ok((m, _)) => m,
                    Err(why) => {
                        skipped.push((e.key.clone(), why.to_string()));
                        continue;
                    }
                };
                let piece = decode_piece(&file, &model, &e.key, opts, backend)?;
                voxels += piece.dims.iter().product::<usize>();
                pieces.push(piece);
            }
        }
        file.close().map_err(h5err)
    })();
    if let Err(e) = written {
        out.discard();
        return Err(e);
    }
    out.commit()?;
    let h5_name = out_h5.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let xdmf = xdmf_path(out_h5);
    write_atomic(&xdmf, xdmf_text(&field, &h5_name, &pieces).as_bytes())?;
    Ok(SeriesSummary { field, pieces, skipped, unblended, voxels, xdmf })
}

fn decode_piece(out: &File, model: &Model, key: &EntryKey, opts: &SeriesOptions, backend: &mut dyn Backend) -> Result<Piece> {
    write_grid(out, model, key, false, opts, &mut |dims, sink| model.decode_streaming(backend, dims, IndexBox::whole(dims), opts.slab_voxels, sink))
}

/// A step's global field, its pieces blended, on its global lattice.
fn decode_global(out: &File, global: &GlobalField, key: &EntryKey, opts: &SeriesOptions, backend: &mut dyn Backend) -> Result<Piece> {
    write_grid(out, global.merged(), key, true, opts, &mut |dims, sink| {
        global.decode_streaming(backend, dims, IndexBox::whole(dims), false, opts.slab_voxels, sink)
    })
}

/// Decodes the lattice of `model`'s box (its dims times the scale) by
/// `decode` into the grid's dataset ([`Piece::path`]), in slabs.
fn write_grid(
    out: &File,
    model: &Model,
    key: &EntryKey,
    global: bool,
    opts: &SeriesOptions,
    decode: &mut dyn FnMut([usize; 3], &mut dyn FnMut(&[f32]) -> Result<()>) -> Result<()>,
) -> Result<Piece> {
    let f = &model.meta.frame;
    let dims = f.dims.map(|d| ((d as f64 * opts.scale).round() as usize).max(1));
    // A lattice the decode refuses is refused before HDF5 is asked for it.
    model.lattice_dims(Some(dims))?;
    let spacing = [0, 1, 2].map(|a| f.dims[a] as f64 / dims[a] as f64 / f.gamma);
    let origin = [0, 1, 2].map(|a| f.bmin[a] + 0.5 * spacing[a]);
    let piece = Piece { key: key.clone(), global, time: model.meta.time, dims, origin, spacing };
    let h5err = |e: hdf5::Error| Error::Hdf5 { path: out.filename(), message: e.to_string() };
    let ds = out.new_dataset::<f32>().shape((dims[2], dims[1], dims[0])).create(piece.path().as_str()).map_err(h5err)?;
    let range: ValueRange = model.meta.range;
    let mut z = 0;
    let mut values = Vec::new();
    decode(dims, &mut |slab| {
        let layers = slab.len() / (dims[0] * dims[1]);
        values.resize(slab.len(), 0.0);
        range.output_into(opts.normalized, slab, &mut values);
        let view = ndarray::ArrayView3::from_shape((layers, dims[1], dims[0]), &values)
            .map_err(|e| Error::arg(format!("slab shape: {e}")))?;
        ds.write_slice(view, (z..z + layers, .., ..)).map_err(h5err)?;
        z += layers;
        Ok(())
    })?;
    let attr = |name: &str, v: &[f64]| ds.new_attr::<f64>().shape(v.len()).create(name).and_then(|a| a.write_raw(v));
    attr("origin", &origin).map_err(h5err)?;
    attr("spacing", &spacing).map_err(h5err)?;
    attr("time", &[model.meta.time.unwrap_or(f64::NAN)]).map_err(h5err)?;
    Ok(piece)
}

/// An XDMF 3 temporal collection with one spatial collection per step.
/// A step without a simulation time gets its step number as time.
pub fn xdmf_text(field: &str, h5_name: &str, pieces: &[Piece]) -> String {
    let name = xml_escape(field);
    let mut s = String::new();
    s.push_str("<?xml version=\"1.0\" ?>\n<Xdmf Version=\"3.0\">\n <Domain>\n");
    let _ = writeln!(s, "  <Grid Name=\"{name}\" GridType=\"Collection\" CollectionType=\"Temporal\">");
    let mut i = 0;
    while i < pieces.len() {
        let step = pieces[i].key.step;
        let j = i + pieces[i..].iter().take_while(|p| p.key.step == step).count();
        let time = pieces[i].time.unwrap_or(step as f64);
        let _ = writeln!(s, "   <Grid Name=\"step_{step}\" GridType=\"Collection\" CollectionType=\"Spatial\">");
        let _ = writeln!(s, "    <Time Value=\"{time:e}\"/>");
        for p in &pieces[i..j] {
            let [nx, ny, nz] = p.dims;
            let _ = writeln!(s, "    <Grid Name=\"{}\" GridType=\"Uniform\">", p.name());
            let _ = writeln!(s, "     <Topology TopologyType=\"3DCoRectMesh\" Dimensions=\"{nz} {ny} {nx}\"/>");
            s.push_str("     <Geometry GeometryType=\"ORIGIN_DXDYDZ\">\n");
            let _ = writeln!(
                s,
                "      <DataItem Dimensions=\"3\" NumberType=\"Float\" Precision=\"8\" Format=\"XML\">{:e} {:e} {:e}</DataItem>",
                p.origin[2], p.origin[1], p.origin[0]
            );
            let _ = writeln!(
                s,
                "      <DataItem Dimensions=\"3\" NumberType=\"Float\" Precision=\"8\" Format=\"XML\">{:e} {:e} {:e}</DataItem>",
                p.spacing[2], p.spacing[1], p.spacing[0]
            );
            s.push_str("     </Geometry>\n");
            let _ = writeln!(s, "     <Attribute Name=\"{name}\" AttributeType=\"Scalar\" Center=\"Node\">");
            let _ = writeln!(
                s,
                "      <DataItem Dimensions=\"{nz} {ny} {nx}\" NumberType=\"Float\" Precision=\"4\" Format=\"HDF\">{}:{}</DataItem>",
                xml_escape(h5_name),
                xml_escape(&p.path())
            );
            s.push_str("     </Attribute>\n    </Grid>\n");
        }
        s.push_str("   </Grid>\n");
        i = j;
    }
    s.push_str("  </Grid>\n </Domain>\n</Xdmf>\n");
    s
}
