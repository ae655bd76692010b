//! `gsenc devices`: the adapters the GPU backend sees, and what `auto`
//! would take.

use crate::output::print_result;
use clap::Args;
use gsenc::backend::select::{adapters, HAS_GPU_BACKEND};
use gsenc::Result;
use serde_json::json;

#[derive(Args)]
pub struct DevicesArgs {
    #[arg(long)]
    json: bool,
}

pub fn devices(a: DevicesArgs) -> Result<()> {
    let all = adapters();
    let hardware = all.iter().filter(|d| !d.software()).count();
    if !a.json {
        if !HAS_GPU_BACKEND {
            println!("this gsenc was built without the GPU backend (cargo feature gpu)");
        }
        for d in &all {
            let index = d.index.map_or("software (GSENC_ADAPTER selects it)".to_string(), |i| format!("gpu {i}"));
            println!("{index}: {} [{}, {}, {}]", d.name, d.api, d.device_type, d.driver);
        }
        println!("auto takes: {}", if hardware > 0 { "gpu 0" } else { "the CPU" });
        return Ok(());
    }
    let list: Vec<_> = all
        .iter()
        .map(|d| json!({ "gpu_index": d.index, "name": d.name, "api": d.api, "type": d.device_type, "driver": d.driver, "software": d.software() }))
        .collect();
    print_result(true, json!({ "gpu_backend": HAS_GPU_BACKEND, "adapters": list, "hardware_gpus": hardware, "auto": if hardware > 0 { "gpu" } else { "cpu" } }));
    Ok(())
}
