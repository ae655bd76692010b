//! One command line a run, one function a command of the tool: each draws
//! its arguments from what is valid and what is not.

use super::inputs::Inputs;
use crate::common::Draws as Rng;
use std::path::Path;

/// Mostly `usual`, sometimes one of `odd`.
fn value(rng: &mut Rng, usual: &str, odd: &[&str]) -> String {
    match rng.chance(0.8) || odd.is_empty() {
        true => usual.to_string(),
        false => odd[rng.below(odd.len())].to_string(),
    }
}

/// What a run writes into and names: the inputs, the folder its outputs go
/// to, and the file already there.
pub struct Places<'a> {
    pub inp: &'a Inputs,
    pub out: &'a Path,
    pub there: &'a Path,
}

impl Places<'_> {
    fn o(&self, name: &str) -> String {
        self.out.join(name).to_str().unwrap().to_string()
    }

    /// A file to write: mostly a new one, sometimes in a folder that does
    /// not exist, onto a folder, or over the file already there.
    fn output(&self, rng: &mut Rng, ext: &str) -> String {
        match rng.below(10) {
            0 => format!("/nonexistent-gsenc-walk/x.{ext}"),
            1 => self.out.to_str().unwrap().to_string(),
            2 => self.o(&format!("x.{}", ["txt", "gsm", "vti", "raw"][rng.below(4)])),
            _ => self.o(&format!("x.{ext}")),
        }
    }

    /// A folder to write into (made when missing): mostly a new one,
    /// sometimes the file already there, or below it (a folder that cannot
    /// be made, without making anything outside the run's folder).
    fn folder(&self, rng: &mut Rng) -> String {
        let there = self.there.to_str().unwrap();
        match rng.below(10) {
            0 => there.to_string(),
            1 => format!("{there}/sub"),
            _ => self.o("series"),
        }
    }

    /// A model to read: mostly a good one, sometimes a cut, damaged, empty
    /// or foreign file, or none.
    fn model(&self, rng: &mut Rng) -> String {
        let inp = self.inp;
        let all = [&inp.model, &inp.model_8bit, &inp.cut, &inp.damaged, &inp.empty, &inp.field, &inp.index, &inp.bad_index, &inp.store];
        match rng.chance(0.7) {
            true => inp.model.clone(),
            false => match rng.below(all.len() + 1) {
                i if i == all.len() => "/nonexistent-gsenc-walk/m.gsm".into(),
                i => all[i].clone(),
            },
        }
    }

    /// The models of a decode or a render: one, a domain's pieces, or a
    /// step index.
    fn models(&self, rng: &mut Rng) -> Vec<String> {
        match rng.below(10) {
            0 => self.inp.pieces.to_vec(),
            1 => vec![self.inp.index.clone()],
            2 => vec![self.model(rng), self.model(rng)],
            _ => vec![self.model(rng)],
        }
    }

    /// A store to read: mostly the inputs' one, sometimes a file that is
    /// not a store, or none.
    fn store(&self, rng: &mut Rng) -> String {
        let inp = self.inp;
        value(rng, &inp.store, &[&inp.model, &inp.empty, self.there.to_str().unwrap(), "/nonexistent-gsenc-walk/s.h5"])
    }
}

/// Mostly the CPU backend, sometimes the GPU's (Mesa's software adapter,
/// which the walk's runs are pointed at; exit 7 where none is installed)
/// or `auto` (the CPU where there is no hardware GPU).
fn backend(rng: &mut Rng) -> String {
    value(rng, "cpu", &["gpu", "gpu", "auto"])
}

fn push(a: &mut Vec<String>, items: &[&str]) {
    a.extend(items.iter().map(|s| s.to_string()));
}

/// Options each given now and then, with one of its values.
fn some_of(rng: &mut Rng, a: &mut Vec<String>, p: f64, options: &[(&str, &[&str])]) {
    for (option, values) in options {
        if rng.chance(p) {
            push(a, &[option, values[rng.below(values.len())]]);
        }
    }
}

/// One command line, and what it needs prepared in the output folder.
pub fn command(rng: &mut Rng, at: &Places) -> Vec<String> {
    match rng.below(13) {
        0 | 1 => encode_grid(rng, at),
        2 => decode(rng, at),
        3 => info(rng, at),
        4 => eval(rng, at),
        5 => convert(rng, at),
        6 => particles(rng, at),
        7 => cells(rng, at),
        8 => render(rng, at),
        9 => encode_series(rng, at),
        10 => plot_series(rng, at),
        11 => store(rng, at),
        _ => decode_series(rng, at),
    }
}

fn encode_grid(rng: &mut Rng, at: &Places) -> Vec<String> {
    let inp = at.inp;
    let mut a = vec![];
    push(&mut a, &["encode", "grid", "--input"]);
    let [flat, spike, huge] = &inp.odd_fields;
    a.push(value(rng, &inp.field, &[&inp.empty, &inp.model, "/nonexistent-gsenc-walk/f.f32", flat, spike, huge]));
    let dims = value(rng, "20,16,12", &["0,16,12", "20,16", "20,16,12,1", "4294967296,1,1", "1,4294967295,1", "a,b,c", "10,16,12", "-1,2,3"]);
    let dtype = value(rng, "f32", &["u8", "u16", "f64", "x"]);
    let budget = value(rng, "10", &["0", "1", "1000000", "99999999999999999999", "-3", "ten"]);
    push(&mut a, &["--dims", &dims, "--dtype", &dtype, "--budget", &budget, "--backend", &backend(rng)]);
    let schedule = value(rng, "short", &["matched", "tuned", "bogus"]);
    let iters = value(rng, "8", &["0", "1", "10000001", "x"]);
    let points = value(rng, "256", &["0", "1", "4294967296"]);
    push(&mut a, &["--schedule", &schedule, "--iters", &iters, "--points", &points]);
    some_of(rng, &mut a, 0.12, &[
        ("--range", &["0,1", "1,0", "nan,1", "0", "2,12"]),
        ("--payload", &["f32", "8bit", "8bit-u16", "packed", "zip"]),
        ("--threads", &["1", "0", "100000"]),
        ("--downsample", &["2", "0", "64"]),
        ("--order", &["zfast", "yfast"]),
        ("--field", &["rho", "", "a/b"]),
        ("--step", &["3", "-1", "x"]),
        ("--time", &["0.5", "nan", "inf"]),
        ("--support", &["none", "stored", "some"]),
        ("--seed", &["7", "-7"]),
    ]);
    if rng.chance(0.1) {
        a.push("--log10".into());
    }
    some_of(rng, &mut a, 0.05, &[("--target-psnr", &["30", "0", "nan", "1000"])]);
    let to = at.output(rng, "gsm");
    push(&mut a, &["-o", &to, "--quiet"]);
    a
}

fn decode(rng: &mut Rng, at: &Places) -> Vec<String> {
    let mut a = vec!["decode".to_string()];
    a.extend(at.models(rng));
    push(&mut a, &["--backend", &backend(rng)]);
    if rng.chance(0.5) {
        let dims = value(rng, "8,6,4", &["0,1,1", "1,2", "4294967296,4,1", "100000,100000,100000", "x"]);
        push(&mut a, &["--dims", &dims]);
    }
    if rng.chance(0.2) {
        let b = value(rng, "0,0,0,4,4,4", &["4,4,4,0,0,0", "0,0,0,100,100,100", "-5,0,0,1,1,1", "0,0,0"]);
        push(&mut a, &["--box", &b]);
    }
    some_of(rng, &mut a, 0.1, &[("--piece", &["0", "1", "2", "x"])]);
    for flag in ["--normalized", "--additive"] {
        if rng.chance(0.15) {
            a.push(flag.into());
        }
    }
    let ext = ["vti", "raw"][rng.below(2)];
    let to = at.output(rng, ext);
    push(&mut a, &["-o", &to]);
    a
}

fn info(rng: &mut Rng, at: &Places) -> Vec<String> {
    let m = match rng.chance(0.2) {
        true => at.store(rng),
        false => at.model(rng),
    };
    let mut a = vec!["info".to_string(), m];
    if rng.chance(0.5) {
        a.push("--json".into());
    }
    a
}

fn eval(rng: &mut Rng, at: &Places) -> Vec<String> {
    let inp = at.inp;
    let m = at.model(rng);
    let [flat, spike, huge] = &inp.odd_fields;
    let input = value(rng, &inp.field, &[&inp.empty, "/nonexistent-gsenc-walk/f.f32", flat, spike, huge]);
    let dims = value(rng, "20,16,12", &["0,16,12", "10,16,12", "20,16,12,2"]);
    let dtype = value(rng, "f32", &["u8", "f64", "x"]);
    let mut a = vec![];
    push(&mut a, &["eval", &m, "--input", &input, "--dims", &dims, "--dtype", &dtype, "--backend", &backend(rng)]);
    a
}

fn convert(rng: &mut Rng, at: &Places) -> Vec<String> {
    let m = at.model(rng);
    let payload = value(rng, "packed", &["f32", "8bit", "8bit-u16", "zip"]);
    let to = at.output(rng, "gsm");
    let mut a = vec![];
    push(&mut a, &["convert", &m, "--payload", &payload, "-o", &to]);
    a
}

/// Where particles or cells lie: dims or --fit-dims, sometimes bounds.
fn placement(rng: &mut Rng, a: &mut Vec<String>, dims: &str) {
    if rng.chance(0.5) {
        let dims = value(rng, dims, &["0,1,1", "1,4294967295,1", "16,12", "1,1,1"]);
        push(a, &["--dims", &dims]);
    } else {
        let n = value(rng, "16", &["0", "1", "100000"]);
        push(a, &["--fit-dims", &n]);
    }
    if rng.chance(0.15) {
        let b = value(rng, "0,0,0,3,2,1", &["3,2,1,0,0,0", "0,0,0,0,0,0", "nan,0,0,1,1,1"]);
        push(a, &["--bounds", &b]);
    }
}

/// The end of an encode or a deposit (`kind`) of particles or cells: an
/// encode's training options, and the output (a model, or a grid).
fn items_end(rng: &mut Rng, at: &Places, kind: &str, a: &mut Vec<String>) {
    if kind == "encode" {
        let budget = value(rng, "10", &["0", "1000000"]);
        push(a, &["--budget", &budget, "--schedule", "short", "--iters", "8", "--points", "256", "--backend", &backend(rng), "--quiet"]);
    }
    let ext = if kind == "encode" { "gsm" } else { ["vti", "raw"][rng.below(2)] };
    let to = at.output(rng, ext);
    push(a, &["-o", &to]);
}

fn particles(rng: &mut Rng, at: &Places) -> Vec<String> {
    let inp = at.inp;
    let mut a = vec![];
    let kind = value(rng, "encode", &["deposit"]);
    push(&mut a, &[&kind, "particles"]);
    let [pos, h, mass, val] = &inp.particles;
    let positions = value(rng, pos, &[&inp.empty, val, "/nonexistent-gsenc-walk/p.f32"]);
    let smoothing = value(rng, h, &[pos]);
    push(&mut a, &["--positions", &positions, "--smoothing-length", &smoothing, "--values", val]);
    if rng.chance(0.3) {
        push(&mut a, &["--mass", mass]);
    }
    placement(rng, &mut a, "16,12,8");
    if rng.chance(0.5) {
        let count = value(rng, "600", &["0", "601", "1200", "x"]);
        let row = value(rng, "1", &["0", "2", "9"]);
        push(&mut a, &["--count", &count, "--row", &row]);
    }
    items_end(rng, at, &kind, &mut a);
    a
}

fn cells(rng: &mut Rng, at: &Places) -> Vec<String> {
    let inp = at.inp;
    let mut a = vec![];
    let kind = value(rng, "encode", &["deposit"]);
    push(&mut a, &[&kind, "cells"]);
    let [centres, edges, volumes, values] = &inp.cells;
    let c = value(rng, centres, &[&inp.empty, values, "/nonexistent-gsenc-walk/c.f32"]);
    push(&mut a, &["--centers", &c]);
    match rng.below(10) {
        0 => {}
        1 => push(&mut a, &["--sizes", edges, "--volumes", volumes]),
        2..=5 => push(&mut a, &["--volumes", &value(rng, volumes, &[edges, &inp.empty])]),
        _ => push(&mut a, &["--sizes", &value(rng, edges, &[volumes, centres])]),
    }
    push(&mut a, &["--values", &value(rng, values, &[centres])]);
    placement(rng, &mut a, "8,8,8");
    some_of(rng, &mut a, 0.1, &[("--dtype", &["f64", "u8", "x"]), ("--count", &["64", "0", "32", "65"]), ("--row", &["1", "2"])]);
    items_end(rng, at, &kind, &mut a);
    a
}

fn render(rng: &mut Rng, at: &Places) -> Vec<String> {
    let inp = at.inp;
    let mut a = vec!["render".to_string()];
    a.extend(at.models(rng));
    match rng.below(10) {
        0..=5 => push(&mut a, &["--slice", &value(rng, "z=0.5", &["w=0.5", "z=2", "z=nan", "z", "x=-0.1", "y=1"])]),
        6..=8 => {
            a.push("--volume".into());
            some_of(rng, &mut a, 0.3, &[
                ("--azimuth", &["-720", "nan", "inf", "45"]),
                ("--elevation", &["-90", "91", "nan", "10"]),
                ("--opacity", &["0", "-1", "nan", "1e300"]),
            ]);
        }
        _ => {}
    }
    push(&mut a, &["--size", &value(rng, "32,24", &["0", "32,0", "1", "100000", "x", "32,24,1"])]);
    some_of(rng, &mut a, 0.2, &[("--colormap", &["magma", "greys", "rainbow", ""])]);
    match rng.below(10) {
        0..=3 => {
            let [flat, spike, huge] = &inp.odd_fields;
            let r = value(rng, &inp.field, &[&inp.empty, &inp.model, flat, spike, huge]);
            let dims = value(rng, "20,16,12", &["10,16,12", "0,1,1"]);
            let dtype = value(rng, "f32", &["u8", "x"]);
            push(&mut a, &["--reference", &r, "--reference-dims", &dims, "--dtype", &dtype]);
            some_of(rng, &mut a, 0.2, &[("--downsample", &["2", "0", "7"])]);
        }
        4..=6 => push(&mut a, &["--dims", &value(rng, "16,12,8", &["0,1,1", "100000,100000,100000", "x"])]),
        _ => {}
    }
    push(&mut a, &["--backend", &backend(rng)]);
    if rng.chance(0.2) {
        a.push("--json".into());
    }
    let to = match rng.chance(0.1) {
        true => "-".to_string(),
        false => at.output(rng, "png"),
    };
    push(&mut a, &["-o", &to]);
    a
}

fn encode_series(rng: &mut Rng, at: &Places) -> Vec<String> {
    let inp = at.inp;
    let mut a = vec![];
    let [pos, h, _, val] = &inp.particles;
    let positions = value(rng, pos, &[&inp.empty, val]);
    push(&mut a, &["encode-series", "--positions", &positions, "--smoothing-length", h, "--values", val]);
    push(&mut a, &["--count", &value(rng, "600", &["0", "601", "1200"])]);
    placement(rng, &mut a, "12,8,6");
    let budget = value(rng, "8", &["0"]);
    let iters = value(rng, "8", &["0"]);
    push(&mut a, &["--budget", &budget, "--schedule", "short", "--iters", &iters, "--points", "256", "--backend", &backend(rng), "--quiet"]);
    push(&mut a, &["--validation-points", &value(rng, "256", &["0", "1"]), "--validation-every", &value(rng, "4", &["0"])]);
    some_of(rng, &mut a, 0.15, &[
        ("--steps", &["0..2", "0..5", "1,0", "x", "5", "0..0", "1"]),
        ("--warm", &["coarse", "off", "dense", "auto", "bogus"]),
        ("--payload", &["packed", "8bit", "zip"]),
        ("--field", &["rho", "", "a/b"]),
        ("--preview", &["z=0.5", "w=0.5", "volume", "volume:30,100", "volume:x"]),
        ("--preview-size", &["24", "0", "x"]),
    ]);
    if rng.chance(0.1) {
        a.push("--as-grid".into());
    }
    if rng.chance(0.1) {
        push(&mut a, &["--resume-from", &at.model(rng)]);
    }
    if rng.chance(0.15) {
        push(&mut a, &["--csv", &at.output(rng, "csv")]);
    }
    if rng.chance(0.1) {
        push(&mut a, &["--plot", &at.output(rng, "png")]);
    }
    let to = match rng.below(10) {
        0 => at.o("series.h5"),
        _ => at.folder(rng),
    };
    push(&mut a, &["-o", &to]);
    a
}

fn plot_series(rng: &mut Rng, at: &Places) -> Vec<String> {
    let inp = at.inp;
    let mut a = vec!["plot-series".to_string()];
    for _ in 0..1 + rng.below(2) {
        a.push(value(rng, &inp.csv, &[&inp.empty, &inp.field, &inp.model, "/nonexistent-gsenc-walk/s.csv"]));
    }
    push(&mut a, &["-o", &at.output(rng, "png")]);
    a
}

/// `store add`, `extract` or `verify` (each refused, with how to get it,
/// without the hdf5 feature).
fn store(rng: &mut Rng, at: &Places) -> Vec<String> {
    let inp = at.inp;
    let mut a = vec!["store".to_string()];
    match rng.below(3) {
        0 => {
            a.push("add".into());
            let target = match rng.below(4) {
                0 => at.o("s.h5"),
                1 => at.there.to_str().unwrap().to_string(),
                _ => {
                    // A store that holds some of what is added: the
                    // inputs' one, copied.
                    let copy = at.out.join("held.h5");
                    std::fs::copy(&inp.store, &copy).unwrap();
                    copy.to_str().unwrap().to_string()
                }
            };
            a.push(target);
            let all = [&inp.model, &inp.model_8bit, &inp.cut, &inp.damaged, &inp.empty, &inp.index, &inp.bad_index, &inp.pieces[0], &inp.pieces[1]];
            for _ in 0..1 + rng.below(2) {
                a.push(match rng.chance(0.5) {
                    true => inp.model.clone(),
                    false => all[rng.below(all.len())].clone(),
                });
            }
            some_of(rng, &mut a, 0.2, &[("--payload", &["8bit", "zip", "f32"])]);
            if rng.chance(0.3) {
                a.push("--json".into());
            }
        }
        1 => {
            a.push("extract".into());
            a.push(at.store(rng));
            a.push(value(rng, "scalar/0/0", &["rho/4", "rho/4/1", "rho/9", "x", "scalar/0/7", "/", "scalar/-1/0", "rho/4/0/0"]));
            let to = match rng.below(4) {
                0 => at.folder(rng),
                1 => "-".to_string(),
                _ => at.output(rng, "gsm"),
            };
            push(&mut a, &["-o", &to]);
            some_of(rng, &mut a, 0.2, &[("--payload", &["8bit", "zip", "f32"])]);
        }
        _ => {
            a.push("verify".into());
            a.push(value(rng, &inp.store, &[&inp.model, &inp.empty, &inp.cut]));
            if rng.chance(0.3) {
                a.push("--json".into());
            }
        }
    }
    a
}

fn decode_series(rng: &mut Rng, at: &Places) -> Vec<String> {
    let mut a = vec!["decode-series".to_string(), at.store(rng)];
    let to = at.output(rng, "h5");
    push(&mut a, &["-o", &to, "--backend", &backend(rng), "--quiet"]);
    // The inputs' store holds two fields: without --field, a refusal.
    if rng.chance(0.85) {
        push(&mut a, &["--field", &value(rng, "rho", &["scalar", "nope"])]);
    }
    some_of(rng, &mut a, 0.3, &[("--scale", &["0.5", "0", "-1", "nan", "1000"])]);
    if rng.chance(0.2) {
        a.push("--normalized".into());
    }
    a
}
