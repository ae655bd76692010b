//! A long run's HDF5 store (docs/BENCHMARKS.md "A long series' HDF5
//! store"): one store kept open, as an in-situ encoder keeps its own, and
//! STEPS small models (50 primitives, float32) appended to it one after
//! another. Every eighth of the run it prints the appends so far, the
//! milliseconds an append took over that eighth, the metadata cache's
//! kilobytes and the process's resident memory:
//! `cargo run --release --features hdf5 --example store_growth -- [STEPS [FILE]]`
//! (defaults 8,000 and a temporary file).
use gsenc::field::{IndexFrame, Transform, ValueRange};
use gsenc::format::Payload;
use gsenc::io::store::Store;
use gsenc::math::rng::Rng;
use gsenc::model::{Model, ModelMeta};
use std::time::Instant;

fn resident_kb() -> u64 {
    let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    status.lines().find_map(|l| l.strip_prefix("VmRSS:")).and_then(|v| v.split_whitespace().next()?.parse().ok()).unwrap_or(0)
}

fn model(step: u64) -> Model {
    let dims = [24, 16, 12];
    let mut meta = ModelMeta::new(IndexFrame { dims, bmin: [0.0; 3], gamma: 1.0 }, ValueRange::new(0.0, 1.0, Transform::Linear).unwrap());
    meta.field = "rho".into();
    meta.step = step;
    let mut rng = Rng::new(step);
    let params = (0..50).map(|_| std::array::from_fn(|k| if k < 3 { rng.range(0.0, dims[k] as f64) } else { rng.range(-1.0, 1.0) } as f32)).collect();
    Model { meta, params, support: None }
}

fn main() {
    let a: Vec<String> = std::env::args().collect();
    let steps: u64 = a.get(1).map_or(8000, |s| s.parse().expect("steps"));
    let dir = std::env::temp_dir().join(format!("gsenc-store-growth-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = a.get(2).map_or_else(|| dir.join("s.h5"), std::path::PathBuf::from);
    let _ = std::fs::remove_file(&path);
    let mut store = Store::open_append(&path).unwrap();
    let eighth = (steps / 8).max(1);
    let mut t = Instant::now();
    for step in 0..steps {
        store.append(&model(step), Payload::Float32).unwrap();
        if (step + 1) % eighth == 0 {
            let ms = t.elapsed().as_secs_f64() * 1e3 / eighth as f64;
            println!("{} appends: {ms:.3} ms an append, cache {} KB, resident {} KB", step + 1, store.cache_size().0 / 1024, resident_kb());
            t = Instant::now();
        }
    }
    drop(store);
    let _ = std::fs::remove_dir_all(&dir);
}
