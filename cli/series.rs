//! `gsenc encode-series`: every step of a particle time series, each
//! warm-started from the previous one (or not), stored as complete models,
//! with a CSV of validation PSNR against iterations for every step.

use crate::args::{one_of, OutputFlags, ParticleInput, TrainingArgs, ValueArgs};
use crate::output::{peak_rss_bytes, print_result, progress_bar};
use gsenc::encode::target::report_json;
use clap::Args;
use gsenc::threads::with_threads;
use gsenc::encode::{WarmStart};
use gsenc::format::{self, model_file_name, Payload};
use gsenc::input::Input;
use gsenc::io::preview::write_preview;
use gsenc::io::{raw, read_model_file, write_atomic, AtomicFile};
use gsenc::render::{ColorMap, View, ViewKind, DEFAULT_OPACITY};
use gsenc::model::metrics::occupied_psnr;
use gsenc::model::Model;
use gsenc::series::{SeriesConfig, SeriesEncoder};
use gsenc::{Error, Result};
use serde_json::json;
use std::path::{Path, PathBuf};
use std::time::Instant;

#[derive(Args)]
pub struct EncodeSeriesArgs {
    /// Per-step arrays: every file holds one row of --count items per step.
    #[command(flatten)]
    input: ParticleInput,
    #[command(flatten)]
    values: ValueArgs,
    /// Steps (rows) to encode: A..B (B excluded), or a comma list; default all.
    #[arg(long)]
    steps: Option<String>,
    /// Encode each step's deposit as a grid (voxel-seeded) instead of seeding
    /// from the particles.
    #[arg(long)]
    as_grid: bool,
    /// Warm start of every step after the first: auto (the previous model,
    /// repaired where it misses, or a fresh seeding, whichever validates
    /// best; stops when the validation PSNR stops rising, within the
    /// schedule's iterations), off (each step on its own), coarse (1000
    /// iterations, no relocation) or dense (1500, relocation on).
    #[arg(long, default_value = "auto", value_parser = one_of(&WarmStart::ALL, WarmStart::name))]
    warm: WarmStart,
    /// Budget and schedule of the first step and of independent steps
    /// (`--no-relocation` there too, as the paper's independent time steps).
    #[command(flatten)]
    train: TrainingArgs,
    /// Validation points (fixed per series) and how often they are scored.
    #[arg(long, default_value_t = 1 << 16)]
    validation_points: usize,
    #[arg(long, default_value_t = 50)]
    validation_every: usize,
    #[arg(long, default_value = "scalar")]
    field: String,
    /// Continue a series that stopped: the first step warm-starts from this
    /// model (the series' last stored step, a .gsm file) on its lattice and
    /// value range, exactly as an unbroken run would (a --range or --log10
    /// other than the model's is refused).
    #[arg(long)]
    resume_from: Option<PathBuf>,
    /// Payload of every step's model: f32, 8bit, 8bit-u16 or packed.
    #[arg(long, default_value = "f32", value_parser = one_of(&Payload::ALL, Payload::name))]
    payload: Payload,
    /// Output: an HDF5 store (.h5, needs the hdf5 feature) or a folder of
    /// FIELD_STEP.gsm files.
    #[arg(short, long)]
    output: PathBuf,
    /// CSV of validation PSNR: field,step,start,iteration,validation_psnr.
    #[arg(long)]
    csv: Option<PathBuf>,
    /// PNG of validation PSNR against step: each step's final PSNR and, for
    /// warm-started steps, the PSNR it started from (the previous model's).
    #[arg(long)]
    plot: Option<PathBuf>,
    /// A picture of every step beside its model (FIELD_STEP.png; beside the
    /// store for .h5): a slice AXIS=FRACTION (as z=0.5), `volume`, or
    /// `volume:AZIMUTH,ELEVATION` in degrees.
    #[arg(long)]
    preview: Option<String>,
    /// Preview size, W or W,H pixels.
    #[arg(long, default_value = "512", value_parser = crate::render::parse_size)]
    preview_size: [usize; 2],
    #[command(flatten)]
    out: OutputFlags,
}

/// Steps to encode out of `rows`: "A..B", "A,B,C" or all.
fn parse_steps(spec: Option<&str>, rows: usize) -> Result<Vec<usize>> {
    let steps: Vec<usize> = match spec {
        None => (0..rows).collect(),
        Some(s) if s.contains("..") => {
            let (a, b) = s.split_once("..").unwrap();
            let parse = |x: &str| x.trim().parse::<usize>().map_err(|_| Error::arg(format!("--steps '{s}' is not A..B")));
            // Steps past the first missing one are not listed: the check
            // below names that one, and a range as long as 2^64 is not held.
            (parse(a)?..parse(b)?.min(rows.saturating_add(1))).collect()
        }
        Some(s) => s
            .split(',')
            .map(|x| x.trim().parse::<usize>().map_err(|_| Error::arg(format!("--steps '{s}' is not a comma list"))))
            .collect::<Result<_>>()?,
    };
    if steps.is_empty() {
        return Err(Error::arg("no steps to encode"));
    }
    if let Some(&s) = steps.iter().find(|&&s| s >= rows) {
        return Err(Error::arg(format!("step {s} is missing: the input holds {rows} steps (rows of --count items)")));
    }
    if steps.windows(2).any(|w| w[1] <= w[0]) {
        return Err(Error::arg("--steps must increase"));
    }
    Ok(steps)
}

/// Where the steps' models go.
enum Sink {
    Folder(PathBuf),
    #[cfg(feature = "hdf5")]
    Store(gsenc::io::store::Store),
}

/// Whether an output path names an HDF5 store (else a folder of models).
fn is_store_path(path: &Path) -> bool {
    path.extension().is_some_and(|e| e.eq_ignore_ascii_case("h5"))
}

#[cfg(not(feature = "hdf5"))]
fn no_hdf5() -> Error {
    Error::arg("an .h5 output needs HDF5 support; rebuild with `cargo build --release --features hdf5` or give a folder")
}

impl Sink {
    /// Whether the steps' models could go to `path`, asked before any step
    /// is encoded (the sink is opened once the first one is, so that a
    /// series that fails at its first step makes nothing): a store there
    /// must be one and hold none of `steps` of `field` (steps are never
    /// rewritten), a new store's folder must be there (a store's folder is
    /// not made), and a folder must be one or could be made.
    fn check(path: &Path, field: &str, steps: &[usize]) -> Result<()> {
        match is_store_path(path) {
            true => Self::check_store(path, field, steps),
            false => Self::check_folder(path),
        }
    }

    #[cfg(feature = "hdf5")]
    fn check_store(path: &Path, field: &str, steps: &[usize]) -> Result<()> {
        if !path.exists() {
            let folder = path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
            return match folder.is_dir() {
                true => Ok(()),
                false => Err(Error::io(path, std::io::Error::new(std::io::ErrorKind::NotFound, format!("no folder {} to make the store in", folder.display())))),
            };
        }
        let store = gsenc::io::store::Store::open_read(path)?;
        match store.entries()?.into_iter().find(|e| e.key.field == field && steps.contains(&(e.key.step as usize))) {
            Some(e) => Err(Error::arg(format!("{}: the store holds {} already (steps are never rewritten)", path.display(), e.key.path()))),
            None => Ok(()),
        }
    }

    #[cfg(not(feature = "hdf5"))]
    fn check_store(_: &Path, _: &str, _: &[usize]) -> Result<()> {
        Err(no_hdf5())
    }

    /// A folder that is there or could be made: the nearest of it and its
    /// ancestors that exists is a folder.
    fn check_folder(path: &Path) -> Result<()> {
        let mut at = path;
        while !at.exists() {
            match at.parent() {
                Some(p) if !p.as_os_str().is_empty() => at = p,
                _ => return Ok(()),
            }
        }
        match at.is_dir() {
            true => Ok(()),
            false => Err(Error::io(path, std::io::Error::new(std::io::ErrorKind::NotADirectory, format!("{} is not a folder", at.display())))),
        }
    }

    fn open(path: &Path) -> Result<Sink> {
        if is_store_path(path) {
            #[cfg(feature = "hdf5")]
            return Ok(Sink::Store(gsenc::io::store::Store::open_append(path)?));
            #[cfg(not(feature = "hdf5"))]
            return Err(no_hdf5());
        }
        std::fs::create_dir_all(path).map_err(|e| Error::io(path, e))?;
        Ok(Sink::Folder(path.to_path_buf()))
    }

    /// Stores `model`; returns where and how many bytes the model file took.
    fn put(&mut self, model: &Model, payload: Payload) -> Result<String> {
        match self {
            Sink::Folder(dir) => {
                let path = dir.join(model_file_name(&model.meta.field, model.meta.step, model.meta.rank));
                write_atomic(&path, &format::write_model_as(model, payload)?)?;
                Ok(path.display().to_string())
            }
            #[cfg(feature = "hdf5")]
            Sink::Store(store) => {
                store.append(model, payload)?;
                Ok(format!("{}:{}", store.path().display(), gsenc::io::store::EntryKey::of(&model.meta).path()))
            }
        }
    }
}

pub fn encode_series(a: EncodeSeriesArgs) -> Result<()> {
    let files = &a.input.files;
    let count = files.count.ok_or_else(|| Error::arg("encode-series needs --count (particles per step)"))?;
    let dtype = files.dtype;
    let value_bytes = raw::content_len(&a.input.values)?;
    let rows = usize::try_from(value_bytes / (count * dtype.size()).max(1) as u64).unwrap_or(usize::MAX);
    let steps = parse_steps(a.steps.as_deref(), rows)?;
    let (warm, payload) = (a.warm, a.payload);
    let mut cfg = SeriesConfig::new(a.train.config()?, warm, a.values.spec()?.into());
    cfg.validation_points = a.validation_points;
    cfg.validation_every = a.validation_every;
    cfg.payload = payload;
    cfg.store_support = a.train.support;
    let mut series = SeriesEncoder::new(cfg)?;
    if let Some(path) = &a.resume_from {
        let model = read_model_file(path)?.model;
        if model.meta.field != a.field {
            return Err(Error::arg(format!(
                "--resume-from {} holds field '{}', not --field '{}'",
                path.display(),
                model.meta.field,
                a.field
            )));
        }
        if model.meta.step >= steps[0] as u64 {
            return Err(Error::arg(format!(
                "--resume-from {} is step {}; the steps to encode must come after it (they start at {})",
                path.display(),
                model.meta.step,
                steps[0]
            )));
        }
        series.resume(model)?;
    }
    // A bad preview is an error before any step is encoded.
    let preview = match &a.preview {
        Some(spec) => {
            let kind = ViewKind::parse_preview(spec, DEFAULT_OPACITY)?;
            Some(View::new(kind, a.preview_size[0], a.preview_size[1], ColorMap::default())?)
        }
        None => None,
    };
    let preview_dir = if is_store_path(&a.output) { a.output.parent().map(Path::to_path_buf).unwrap_or_default() } else { a.output.clone() };
    Sink::check(&a.output, &a.field, &steps)?;
    let mut sink = None; // opened once the first step is encoded
    // The CSV and the plot are files to be written before any step is
    // encoded: a place they cannot go is an error now.
    let mut csv = match &a.csv {
        Some(p) => {
            let mut f = AtomicFile::create(p)?;
            f.write(b"field,step,start,iteration,validation_psnr\n")?;
            Some(f)
        }
        None => None,
    };
    let plot = a.plot.as_ref().map(AtomicFile::create).transpose()?;
    let mut rows_out = Vec::new();
    // One backend (one device) for the whole series.
    let mut backend = a.train.device.choice().open()?;
    for &row in &steps {
        let t = Instant::now();
        let arrays = a.input.load(Some(row))?;
        let particles = arrays.particles();
        let placement = a.input.placement.resolve(|| particles.bounds())?;
        let input = if a.as_grid {
            Input::ParticleDeposit { particles: &particles, placement }
        } else {
            Input::Particles { particles: &particles, placement }
        };
        let pb = progress_bar(a.out.quiet, 0);
        let r = with_threads(a.train.threads, || {
            series.encode_step(&a.field, row as u64, None, input, backend.as_mut(), &mut |p| {
                pb.set_length(p.iterations as u64);
                pb.set_position(p.iteration as u64);
            })
        })??;
        pb.finish_and_clear();
        let (e, prepared) = (&r.encoded, &r.prepared);
        let psnr = e.psnr;
        let occupied = occupied_psnr(&e.decoded, &prepared.reference.values);
        if sink.is_none() {
            sink = Some(Sink::open(&a.output)?);
        }
        let stored_at = sink.as_mut().expect("opened above").put(&e.model, payload)?;
        let preview_at = match &preview {
            Some(view) => Some(with_threads(a.train.threads, || write_preview(&preview_dir, &e.model, backend.as_mut(), view))??),
            None => None,
        };
        let start = if e.warm_started { warm.name() } else { "independent" };
        let label = match e.model.meta.warm {
            Some(w) => format!("{start}/{}", w.taken.name()),
            None => start.to_owned(),
        };
        if let Some(f) = csv.as_mut() {
            for (it, p) in &e.output.validation {
                f.write(format!("{},{row},{start},{it},{p:.4}\n", a.field).as_bytes())?;
            }
        }
        let line = json!({
            "step": row,
            "start": start,
            "iterations": e.output.iterations,
            "taken": e.model.meta.warm.map(|w| w.taken.name()),
            "moved": e.model.meta.warm.map(|w| w.moved),
            "voxel_psnr": psnr,
            "primitives": e.model.len(),
            "target": report_json(e.target.as_ref()),
            "occupied_psnr": occupied,
            "validation_psnr": e.output.validation.last().map(|v| v.1),
            "start_validation_psnr": e.output.validation.first().map(|v| v.1),
            "clamped_values": prepared.clamped_values,
            "outside_items": prepared.outside_items(),
            "loop_seconds": e.output.loop_seconds,
            "validation_seconds": e.output.validation_seconds,
            "step_seconds": t.elapsed().as_secs_f64(),
            "stored": stored_at,
            "preview": preview_at,
        });
        if a.out.json {
            println!("{line}");
        } else {
            eprintln!(
                "step {row:>4} {label:<14} {:>5} its  voxel PSNR {psnr:6.2} dB  validation {:6.2} dB  {:6.1} s",
                e.output.iterations,
                e.output.validation.last().map_or(f64::NAN, |v| v.1),
                e.output.loop_seconds
            );
        }
        rows_out.push(line);
    }
    if let Some(f) = csv {
        f.commit()?;
    }
    if let Some(mut f) = plot {
        let finals = rows_out.iter().map(|r| (r["step"].as_f64().unwrap(), r["validation_psnr"].as_f64().unwrap_or(f64::NAN)));
        let starts = rows_out.iter().filter(|r| r["start"] != "independent");
        let mut lines = vec![(format!("final, {}", warm.name()), finals.collect())];
        if warm != WarmStart::Off {
            let start_points = starts.map(|r| (r["step"].as_f64().unwrap(), r["start_validation_psnr"].as_f64().unwrap_or(f64::NAN)));
            lines.push(("start of warm step".into(), start_points.collect()));
        }
        f.write(&series_chart(lines).to_png()?)?;
        f.commit()?;
    }
    let range = series.range(&a.field).expect("at least one step was encoded");
    print_result(
        a.out.json,
        json!({
            "field": a.field,
            "steps": steps.len(),
            "warm": warm.name(),
            "value_min": range.vmin,
            "value_max": range.vmax,
            "mean_voxel_psnr": rows_out.iter().filter_map(|r| r["voxel_psnr"].as_f64()).sum::<f64>() / rows_out.len() as f64,
            "peak_rss_bytes": peak_rss_bytes(),
            "output": a.output.display().to_string(),
            "csv": a.csv.as_ref().map(|p| p.display().to_string()),
        }),
    );
    Ok(())
}

#[derive(Args)]
pub struct PlotSeriesArgs {
    /// CSV files written by `encode-series --csv` (one line each).
    #[arg(required = true)]
    csv: Vec<PathBuf>,
    /// Output PNG.
    #[arg(short, long)]
    output: PathBuf,
}

/// Final validation PSNR per step of one `encode-series` CSV, and its label:
/// the warm start of its warm-started steps, or "independent".
fn read_series_csv(path: &Path) -> Result<(String, Vec<(f64, f64)>)> {
    let bytes = gsenc::io::read_whole(path)?;
    let text = String::from_utf8_lossy(&bytes);
    let mut lines = text.lines();
    if lines.next() != Some("field,step,start,iteration,validation_psnr") {
        return Err(Error::format(format!("{}: not a CSV written by encode-series --csv", path.display())));
    }
    let mut last: std::collections::BTreeMap<u64, (u64, f64)> = Default::default();
    let mut label = "independent".to_owned();
    for (i, line) in lines.enumerate() {
        let bad = || Error::format(format!("{}: line {} is not field,step,start,iteration,psnr", path.display(), i + 2));
        let cols: Vec<&str> = line.split(',').collect();
        let [_, step, start, it, psnr] = cols[..] else { return Err(bad()) };
        let (step, it, psnr) = (step.parse::<u64>().map_err(|_| bad())?, it.parse::<u64>().map_err(|_| bad())?, psnr.parse::<f64>().map_err(|_| bad())?);
        if start != "independent" {
            label = format!("warm {start}");
        }
        let e = last.entry(step).or_insert((it, psnr));
        if it >= e.0 {
            *e = (it, psnr);
        }
    }
    Ok((label, last.into_iter().map(|(s, (_, p))| (s as f64, p)).collect()))
}

fn series_chart(lines: Vec<(String, Vec<(f64, f64)>)>) -> gsenc::io::plot::Chart {
    use gsenc::io::plot::{Chart, Line, PALETTE};
    Chart {
        width: 960,
        height: 560,
        title: "final validation PSNR per step".into(),
        x_label: "step".into(),
        y_label: "PSNR dB".into(),
        lines: lines
            .into_iter()
            .enumerate()
            .map(|(k, (label, points))| Line { label, points, color: PALETTE[k % PALETTE.len()] })
            .collect(),
    }
}

pub fn plot_series(a: PlotSeriesArgs) -> Result<()> {
    let lines = a.csv.iter().map(|p| read_series_csv(p)).collect::<Result<Vec<_>>>()?;
    write_atomic(&a.output, &series_chart(lines).to_png()?)?;
    println!("{}", a.output.display());
    Ok(())
}
