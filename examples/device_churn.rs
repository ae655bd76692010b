//! Opens and drops the GPU backend again and again in one process, as a
//! simulation that makes an encoder per output step (or a test binary) does,
//! and reports, each round, whether wgpu still sees an adapter and what the
//! process holds: wgpu instances made, open files, threads, virtual memory.
//! `cargo run --release --example device_churn -- MODE ROUNDS`, MODE one of
//!   enumerate  list the adapters only (a wgpu instance each round);
//!   open       open the device and compile the kernels, then drop them;
//!   work       the same, with one evaluation of 300 primitives at 3,000
//!              points in between (buffers allocated and mapped).
//! The adapter is the first hardware one, else `GSENC_ADAPTER`'s. Stops at
//! the first failure and exits 1, naming the round.
use gsenc::backend::gpu::device::{adapters, instances_made, DeviceRequest};
use gsenc::backend::gpu::GpuBackend;
use gsenc::backend::Backend;
use gsenc::math::kernel::isotropic;
use gsenc::memory::process_status;

fn proc_count(dir: &str) -> usize {
    std::fs::read_dir(dir).map_or(0, |d| d.count())
}

fn main() {
    let a: Vec<String> = std::env::args().collect();
    let mode = a.get(1).map_or("open", |s| s.as_str()).to_string();
    let rounds: usize = a.get(2).map_or(40, |s| s.parse().expect("ROUNDS"));
    let req = DeviceRequest { index: None, name: std::env::var("GSENC_ADAPTER").ok().filter(|s| !s.is_empty()) };
    let params: Vec<_> = (0..300).map(|i| isotropic([(i % 20) as f32 * 2.0, (i / 20) as f32 * 2.0, 5.0], 1.5, 1.0, 0.5)).collect();
    let pos: Vec<[f32; 3]> = (0..3000).map(|i| [(i % 40) as f32, (i / 40 % 30) as f32, (i / 1200) as f32 * 4.0]).collect();
    for round in 0..rounds {
        let seen = adapters().len();
        let outcome = match mode.as_str() {
            "enumerate" => Ok(()),
            "open" | "work" => GpuBackend::new(&req).and_then(|mut g| {
                if mode == "work" {
                    let (mut rho, mut n) = (vec![0.0; pos.len()], vec![0.0; pos.len()]);
                    g.evaluate_points(&params, &pos, &mut rho, &mut n)?;
                }
                Ok(())
            }),
            other => panic!("MODE is enumerate, open or work, not {other}"),
        };
        println!(
            "round {round}: adapters {seen}, wgpu instances made {}, open files {}, threads {}, virtual memory {} MiB{}",
            instances_made(),
            proc_count("/proc/self/fd"),
            proc_count("/proc/self/task"),
            process_status("VmSize:").unwrap_or(0) >> 20,
            outcome.as_ref().err().map_or(String::new(), |e| format!(", failed: {e}"))
        );
        if seen == 0 || outcome.is_err() {
            eprintln!("{mode}: failed at round {round}");
            std::process::exit(1);
        }
    }
    println!("{mode}: {rounds} rounds, the adapter seen every round");
}
