//! The files the walk's runs may name, made once: valid inputs of every
//! command, and the same files cut, damaged, empty or of another kind.

use crate::common::decomposed_step;
use crate::tool::{gsenc, write_f32, write_input, write_particles};
use gsenc::format::{write_model_as, Payload};
use std::path::Path;

pub struct Inputs {
    /// A 20 x 16 x 12 float32 grid; the same lattice constant, with a
    /// single spike, and with values near 1e30.
    pub field: String,
    pub odd_fields: [String; 3],
    /// Models of `field`: float32 and 8-bit payloads, the first cut in
    /// half, with one bit changed, and an empty file.
    pub model: String,
    pub model_8bit: String,
    pub cut: String,
    pub damaged: String,
    pub empty: String,
    /// Positions, smoothing lengths, masses and values: two rows of 600
    /// particles.
    pub particles: [String; 4],
    /// Centres, edge lengths, volumes and values of 64 cells.
    pub cells: [String; 4],
    /// A step index of two pieces (its models beside it), and one that is
    /// not an index.
    pub index: String,
    pub pieces: [String; 2],
    pub bad_index: String,
    /// A CSV as encode-series writes it.
    pub csv: String,
    /// A store holding `model` and the index's step (a file that is not
    /// one without the hdf5 feature).
    pub store: String,
}

fn s(p: &Path) -> String {
    p.to_str().unwrap().to_string()
}

pub fn inputs(dir: &Path) -> Inputs {
    let (field, values) = write_input(dir);
    let odd_fields = [
        ("flat.f32", vec![3.0f32; values.len()]),
        ("spike.f32", (0..values.len()).map(|i| if i == 1234 { 5.0 } else { 0.0 }).collect()),
        ("huge.f32", values.iter().map(|v| v * 1e30).collect()),
    ]
    .map(|(name, v)| {
        write_f32(&dir.join(name), &v);
        s(&dir.join(name))
    });
    let particles = write_particles(dir).map(|p| s(&p));
    let model = dir.join("m.gsm");
    let (code, _, err) = gsenc(&[
        "encode", "grid", "--input", &s(&field), "--dims", "20,16,12", "--dtype", "f32", "--budget", "12", "--schedule", "short",
        "--iters", "10", "--points", "256", "--backend", "cpu", "-o", &s(&model), "--quiet",
    ]);
    assert_eq!(code, 0, "{err}");
    let model_8bit = dir.join("m8.gsm");
    let (code, _, err) = gsenc(&["convert", &s(&model), "--payload", "8bit", "-o", &s(&model_8bit)]);
    assert_eq!(code, 0, "{err}");
    let bytes = std::fs::read(&model).unwrap();
    let (cut, damaged, empty) = (dir.join("cut.gsm"), dir.join("damaged.gsm"), dir.join("empty.f32"));
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
    let mut d = bytes.clone();
    let at = d.len() / 3;
    d[at] ^= 0x10;
    std::fs::write(&damaged, d).unwrap();
    std::fs::write(&empty, b"").unwrap();
    let (index, pieces) = write_index(dir);
    let bad_index = dir.join("bad_000001.gsi");
    std::fs::write(&bad_index, "{}").unwrap();
    let csv = dir.join("series.csv");
    std::fs::write(&csv, "field,step,start,iteration,validation_psnr\nrho,0,independent,10,31.5\nrho,1,previous,10,33.25\n").unwrap();
    let store = dir.join("s.h5");
    if cfg!(feature = "hdf5") {
        let (code, _, err) = gsenc(&["store", "add", &s(&store), &s(&model), &index]);
        assert_eq!(code, 0, "{err}");
    } else {
        std::fs::copy(&model, &store).unwrap();
    }
    Inputs {
        field: s(&field),
        odd_fields,
        model: s(&model),
        model_8bit: s(&model_8bit),
        cut: s(&cut),
        damaged: s(&damaged),
        empty: s(&empty),
        particles,
        cells: write_cells(dir),
        index,
        pieces,
        bad_index: s(&bad_index),
        csv: s(&csv),
        store: s(&store),
    }
}

/// 4 x 4 x 4 cells of edge 0.5 over [0, 2]^3, values in [1, 20].
fn write_cells(dir: &Path) -> [String; 4] {
    let (mut c, mut e, mut vol, mut v) = (vec![], vec![], vec![], vec![]);
    for k in 0..4 {
        for j in 0..4 {
            for i in 0..4 {
                c.extend([i, j, k].map(|a| 0.25 + 0.5 * a as f32));
                e.extend([0.5f32; 3]);
                vol.push(0.125f32);
                v.push(1.0 + (i + 2 * j + 3 * k) as f32);
            }
        }
    }
    let names = ["cc.f32", "ce.f32", "cvol.f32", "cv.f32"].map(|n| dir.join(n));
    for (p, x) in names.iter().zip([&c, &e, &vol, &v]) {
        write_f32(p, x);
    }
    names.map(|p| s(&p))
}

/// Step 4 of field "rho" decomposed in two pieces, as an MPI run writes it.
fn write_index(dir: &Path) -> (String, [String; 2]) {
    let (index, models) = decomposed_step("rho", 4);
    let pieces: Vec<String> = index
        .pieces
        .iter()
        .zip(&models)
        .map(|(p, m)| {
            let path = dir.join(&p.model);
            std::fs::write(&path, write_model_as(m, Payload::Float32).unwrap()).unwrap();
            s(&path)
        })
        .collect();
    let path = dir.join("rho_000004.gsi");
    std::fs::write(&path, index.to_json()).unwrap();
    (s(&path), pieces.try_into().unwrap())
}
