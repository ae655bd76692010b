//! Seeded random runs of the tool, as a careless user might type them:
//! every command (encodes of grids, particles and cells, deposits,
//! decodes of models, pieces and step indexes, eval, info, convert,
//! render, encode-series, plot-series, the store's commands and
//! decode-series) with its options drawn from what is valid and what is
//! not (missing, foreign, cut and damaged files, fields constant, of one
//! spike or of values near 1e30, dims of zero, of the
//! wrong count or past 2^32, unknown names, huge or non-numeric counts,
//! outputs in folders that do not exist, onto folders, or over a file
//! already there), on the CPU backend or now and then the GPU's (on
//! Mesa's software adapter, which the runs' `GSENC_ADAPTER` names; exit 7
//! where there is none). Nothing is expected of a run but what the tool
//! promises of every run: it never panics or dies of a signal, it exits 0
//! or with one of its codes (README "Exit codes"; 2 for what clap
//! refuses), a failure says why on the standard error and leaves every
//! file of the output folder byte for byte as it was (adding none), no
//! temporary file is left behind, no folder is made where none was asked
//! for, no run changes what it read, and what a run wrote reads back as
//! what it is (`check_written`).
//!
//! `GSENC_TOOL_WALKS` sets the number of runs (default 120, about 7 s on
//! two cores), `GSENC_TOOL_WALK_SEED` the first seed (default 1); a
//! failure names its seed and its command line. `GSENC_TOOL_WALK_TRACE`
//! prints every run's command line and exit code.

#[path = "../../tests/common/mod.rs"]
mod common;
mod tool;
#[path = "walk/commands.rs"]
mod commands;
#[path = "walk/inputs.rs"]
mod inputs;
use common::{tmpdir, Draws as Rng};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use tool::gsenc_env;

/// Runs, unless `GSENC_TOOL_WALKS` says.
const RUNS: u64 = 120;

/// Where the runs' outputs name a folder that does not exist; no run may
/// make it.
const NOWHERE: &str = "/nonexistent-gsenc-walk";

/// Every file below `dir`, with its bytes.
fn files(dir: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    let mut all = BTreeMap::new();
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            all.extend(files(&p));
        } else {
            all.insert(p.clone(), std::fs::read(&p).unwrap());
        }
    }
    all
}

/// What a run that succeeded wrote reads back as what it is, told by its
/// first bytes (an output's name need not say: `-o x.txt`): a model with
/// finite parameters, a step index, a `.vti` grid or raw float32 values
/// all finite, a PNG image, a CSV of encode-series, a store whose every
/// entry verifies (`command` decode-series writes a field's HDF5 file, not
/// a store), XDMF text.
fn check_written(command: &str, path: &Path, bytes: &[u8]) -> Result<(), String> {
    let text = || std::str::from_utf8(bytes).map_err(|e| e.to_string());
    let finite = |v: &[f32]| match v.iter().all(|x| x.is_finite()) {
        true => Ok(()),
        false => Err("values that are not finite".to_string()),
    };
    if bytes.starts_with(gsenc::format::MAGIC) {
        let m = gsenc::format::read_model(bytes).map_err(|e| e.to_string())?;
        return finite(&m.params.iter().flatten().copied().collect::<Vec<f32>>());
    }
    if bytes.starts_with(b"\x89PNG") {
        return gsenc::io::image::read_png(path).map(|_| ()).map_err(|e| e.to_string());
    }
    if bytes.starts_with(b"\x89HDF") {
        #[cfg(feature = "hdf5")]
        if command != "decode-series" {
            let checked = gsenc::io::store::Store::open_read(path).and_then(|s| s.verify()).map_err(|e| e.to_string())?;
            return match checked.iter().find(|(_, r)| r.is_err()) {
                Some((what, r)) => Err(format!("{what}: {r:?}")),
                None => Ok(()),
            };
        }
        return match command {
            "decode-series" => Ok(()),
            _ => Err("an HDF5 file from a build without HDF5".into()),
        };
    }
    if bytes.starts_with(b"field,step,start,iteration,validation_psnr\n") {
        return match text()?.lines().skip(1).all(|l| l.split(',').count() == 5) {
            true => Ok(()),
            false => Err("a CSV line that is not five columns".into()),
        };
    }
    if bytes.starts_with(b"{") {
        return gsenc::format::step_index::StepIndex::from_json(text()?).map(|_| ()).map_err(|e| e.to_string());
    }
    if bytes.starts_with(b"<") {
        return match bytes.windows(8).any(|w| w == b"<VTKFile") {
            true => finite(&gsenc::io::vti::parse_vti(bytes, None).map_err(|e| e.to_string())?.grid.values),
            false => text().map(|_| ()), // XDMF beside decode-series' HDF5 file
        };
    }
    if bytes.is_empty() || !bytes.len().is_multiple_of(4) {
        return Err(format!("{} bytes: not float32 values", bytes.len()));
    }
    finite(&bytes.chunks_exact(4).map(|b| f32::from_le_bytes(b.try_into().unwrap())).collect::<Vec<f32>>())
}

#[test]
fn random_runs_of_the_tool_keep_its_promises() {
    let runs: u64 = std::env::var("GSENC_TOOL_WALKS").ok().and_then(|s| s.parse().ok()).unwrap_or(RUNS);
    let first: u64 = std::env::var("GSENC_TOOL_WALK_SEED").ok().and_then(|s| s.parse().ok()).unwrap_or(1);
    let trace = std::env::var_os("GSENC_TOOL_WALK_TRACE").is_some();
    assert!(!Path::new(NOWHERE).exists(), "{NOWHERE} exists: remove it");
    let dir = tmpdir("tool-walk");
    let inp = inputs::inputs(&dir);
    let kept_inputs = files(&dir);
    let out = dir.join("out");
    std::fs::create_dir_all(&out).unwrap();
    // A file already there, which a failed run must leave as it was.
    let there = out.join("x.gsm");
    let at = commands::Places { inp: &inp, out: &out, there: &there };
    let mut codes = BTreeMap::new();
    for seed in first..first + runs {
        std::fs::copy(&inp.model, &there).unwrap();
        let mut rng = Rng::new(seed);
        let args = commands::command(&mut rng, &at);
        let before = files(&out);
        let refs: Vec<&str> = args.iter().map(String::as_str).collect();
        let (code, _, err) = gsenc_env(&refs, &[("GSENC_ADAPTER", "llvmpipe")]);
        let line = format!("run {seed}: gsenc {}", args.join(" "));
        *codes.entry(code).or_insert(0) += 1;
        if trace {
            eprintln!("{line}\n  exit {code}: {}", err.lines().last().unwrap_or(""));
        }
        assert!([0, 2, 3, 4, 5, 6, 7].contains(&code), "{line}\nexit code {code}: {err}");
        let after = files(&out);
        if code != 0 {
            assert!(!err.trim().is_empty(), "{line}\nexit code {code} without a word on the standard error");
            assert!(after == before, "{line}\nfailed (exit {code}: {err}) and changed, removed or added files: before {:?}, after {:?}", before.keys(), after.keys());
        }
        for (path, bytes) in after.iter().filter(|(p, b)| before.get(*p) != Some(b)) {
            if let Err(e) = check_written(&args[0], path, bytes) {
                panic!("{line}\nwrote {} that does not read back: {e}", path.display());
            }
        }
        let left: Vec<&PathBuf> = after.keys().filter(|p| p.to_string_lossy().contains(".tmp")).collect();
        assert!(left.is_empty(), "{line}\nleft temporary files behind: {left:?}");
        assert!(!Path::new(NOWHERE).exists(), "{line}\nmade {NOWHERE}");
        for e in std::fs::read_dir(&out).unwrap() {
            let p = e.unwrap().path();
            if p != there {
                let _ = std::fs::remove_file(&p).or_else(|_| std::fs::remove_dir_all(&p));
            }
        }
    }
    eprintln!("{runs} runs; exit codes: {codes:?}");
    // No run changed what it read.
    std::fs::remove_dir_all(&out).unwrap();
    assert!(files(&dir) == kept_inputs, "the inputs changed");
    // The runs reached what they are for: some succeeded, some failed.
    assert!(runs < RUNS || (codes.get(&0).is_some_and(|&n| n > runs as usize / 10) && codes.len() > 2), "exit codes {codes:?}");
    let _ = std::fs::remove_dir_all(&dir);
}
