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
//! for, and no run changes what it read.
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
