//! What commands print and write: results as text or JSON, the progress bar,
//! output files (or standard output, `-`), grids written as `.vti` or raw
//! float32, and the process's peak memory.

use gsenc::field::{Grid, ValueRange};
use gsenc::input::Prepared;
use gsenc::io::{raw, vti, AtomicFile};
use gsenc::{Error, Result};
use serde_json::{json, Map, Value};
use std::io::{IsTerminal, Write};
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};

/// Set once a command has written its output file to standard output: the
/// result it prints then goes to standard error, so that the data stay
/// whole (`gsenc decode m.gsm -o - | python ...`).
static DATA_ON_STDOUT: AtomicBool = AtomicBool::new(false);

/// Whether an output path is standard output: `-`, or a path that names the
/// file standard output is (`/dev/stdout`, `/proc/self/fd/1`).
fn is_stdout(path: &Path) -> bool {
    if path.as_os_str() == "-" {
        return true;
    }
    #[cfg(unix)]
    {
        use std::os::fd::AsFd;
        use std::os::unix::fs::MetadataExt;
        let same = || -> std::io::Result<bool> {
            let out = std::fs::File::from(std::io::stdout().as_fd().try_clone_to_owned()?).metadata()?;
            let named = std::fs::metadata(path)?;
            Ok(out.dev() == named.dev() && out.ino() == named.ino())
        };
        return same().unwrap_or(false);
    }
    #[allow(unreachable_code)]
    false
}

/// A command's output file: written under a temporary name and renamed
/// (`AtomicFile`), or to standard output when the path is `-`.
pub enum Sink {
    File(AtomicFile),
    Stdout(std::io::BufWriter<std::io::Stdout>),
}

impl Sink {
    pub fn create(path: &Path) -> Result<Sink> {
        if is_stdout(path) {
            DATA_ON_STDOUT.store(true, Ordering::Relaxed);
            return Ok(Sink::Stdout(std::io::BufWriter::with_capacity(1 << 20, std::io::stdout())));
        }
        Ok(Sink::File(AtomicFile::create(path)?))
    }

    pub fn write(&mut self, bytes: &[u8]) -> Result<()> {
        match self {
            Sink::File(f) => f.write(bytes),
            Sink::Stdout(out) => out.write_all(bytes).map_err(|e| Error::io("standard output", e)),
        }
    }

    pub fn commit(self) -> Result<()> {
        match self {
            Sink::File(f) => f.commit(),
            Sink::Stdout(mut out) => out.flush().map_err(|e| Error::io("standard output", e)),
        }
    }
}

/// Writes a command's output file whole (`-`: standard output).
pub fn write_output(path: &Path, bytes: &[u8]) -> Result<()> {
    let mut sink = Sink::create(path)?;
    sink.write(bytes)?;
    sink.commit()
}

pub fn progress_bar(quiet: bool, len: u64) -> indicatif::ProgressBar {
    if quiet || !std::io::stderr().is_terminal() {
        return indicatif::ProgressBar::hidden();
    }
    let pb = indicatif::ProgressBar::new(len);
    pb.set_style(
        indicatif::ProgressStyle::with_template("{elapsed_precise} [{bar:40}] {pos}/{len} it  loss {msg}  eta {eta}")
            .expect("a valid template")
            .progress_chars("=> "),
    );
    pb
}

/// Prints one JSON object, or its keys as aligned text, to standard output
/// (to standard error when the command's output file went there). A
/// closed pipe (`gsenc info m.gsm | head`) ends the output quietly instead
/// of panicking; other write errors are reported once.
pub fn print_result(json_out: bool, value: Value) {
    let mut text = String::new();
    if json_out {
        text = format!("{value}\n");
    } else if let Value::Object(map) = value {
        for (k, v) in map {
            text += &match v {
                Value::Number(n) if n.is_f64() => format!("{k:>24}: {:.4}\n", n.as_f64().unwrap_or(f64::NAN)),
                Value::String(s) => format!("{k:>24}: {s}\n"),
                other => format!("{k:>24}: {other}\n"),
            };
        }
    }
    let written = if DATA_ON_STDOUT.load(Ordering::Relaxed) {
        std::io::stderr().lock().write_all(text.as_bytes())
    } else {
        let mut out = std::io::stdout().lock();
        out.write_all(text.as_bytes()).and_then(|_| out.flush())
    };
    if let Err(e) = written {
        if e.kind() != std::io::ErrorKind::BrokenPipe {
            eprintln!("gsenc: writing the result: {e}");
        }
    }
}

/// The keys of a JSON object literal.
pub fn keys(value: Value) -> Map<String, Value> {
    match value {
        Value::Object(map) => map,
        _ => unreachable!("keys() takes an object literal"),
    }
}

/// The process's peak resident memory (Linux `VmHWM`), when known.
pub fn peak_rss_bytes() -> Option<u64> {
    gsenc::memory::process_status("VmHWM:")
}

/// The keys particle and cell commands add: what the deposit saw and cost.
pub fn deposit_keys(p: &Prepared) -> Map<String, Value> {
    let d = p.deposit.unwrap_or_default();
    keys(json!({
        "items": d.items,
        "samples": p.samples.as_ref().map_or(0, |s| s.q.len()),
        "outside": d.outside,
        "outside_dropped": d.outside_dropped,
        "nearest_voxel": d.nearest_voxel,
        "empty_voxels": d.empty_voxels,
        "clamped_values": p.clamped_values,
        "deposit_seconds": d.seconds,
        "deposit_peak_bytes": d.peak_bytes,
        "bounds_min": p.frame.bmin,
        "gamma": p.frame.gamma,
        "value_min": p.range.vmin,
        "value_max": p.range.vmax,
    }))
}

/// Normalised values as they are written: kept, or mapped back to data
/// units.
pub fn to_output_unit(range: &ValueRange, normalized: bool, values: &mut [f32]) {
    if !normalized {
        range.denormalize_all(values);
    }
}

/// Whether an output path names a `.vti` file (otherwise raw float32).
pub fn is_vti(path: &Path) -> bool {
    path.extension().is_some_and(|e| e.eq_ignore_ascii_case("vti"))
}

/// Writes a grid as .vti (when the name says so) or raw float32, atomically
/// (`-`: raw to standard output).
pub fn write_grid(path: &Path, grid: &Grid, origin: [f64; 3], spacing: [f64; 3], name: &str) -> Result<()> {
    let bytes = if is_vti(path) { vti::write_vti_bytes(grid, origin, spacing, name) } else { raw::to_f32_bytes(&grid.values) };
    write_output(path, &bytes)
}

/// Device seconds per kernel of a GPU backend (`{kernel: {passes, seconds}}`),
/// null for the CPU's.
pub fn kernel_seconds(backend: &dyn gsenc::backend::Backend) -> Value {
    named_seconds(backend.kernel_seconds(), "passes")
}

/// The host's seconds per phase of a GPU backend's point calls
/// (`{phase: {times, seconds}}`), null for the CPU's.
pub fn gpu_host_seconds(backend: &dyn gsenc::backend::Backend) -> Value {
    named_seconds(backend.host_seconds(), "times")
}

fn named_seconds(k: Vec<(String, u64, f64)>, count: &str) -> Value {
    if k.is_empty() {
        return Value::Null;
    }
    Value::Object(k.into_iter().map(|(name, n, s)| (name, json!({ count: n, "seconds": s }))).collect())
}
