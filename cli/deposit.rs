//! `gsenc deposit particles|cells`: the reference grid that particles or
//! cells are encoded against, written as `.vti` or raw float32.

use crate::args::{CellInput, GridOutput, ParticleInput, ValueArgs};
use crate::output::{deposit_keys, peak_rss_bytes, print_result, to_output_unit, write_grid};
use clap::{Args, Subcommand};
use gsenc::threads::with_threads;
use gsenc::field::Grid;
use gsenc::input::{prepare, Input, Prepared};
use gsenc::Result;
use serde_json::json;

#[derive(Subcommand)]
pub enum DepositInput {
    /// The M4-spline, Shepard-normalised, mass-weighted particle deposit.
    Particles(DepositParticlesArgs),
    /// The volume-weighted cell deposit (the paper's Eq. 6).
    Cells(DepositCellsArgs),
}

#[derive(Args)]
pub struct DepositParticlesArgs {
    #[command(flatten)]
    input: ParticleInput,
    #[command(flatten)]
    values: ValueArgs,
    #[command(flatten)]
    output: GridOutput,
}

#[derive(Args)]
pub struct DepositCellsArgs {
    #[command(flatten)]
    input: CellInput,
    #[command(flatten)]
    values: ValueArgs,
    #[command(flatten)]
    output: GridOutput,
}

pub fn deposit(input: DepositInput) -> Result<()> {
    match input {
        DepositInput::Particles(a) => {
            let arrays = a.input.load(None)?;
            let particles = arrays.particles();
            let placement = a.input.placement.resolve(|| particles.bounds())?;
            let range = a.values.spec()?;
            let p = with_threads(a.output.threads, || prepare(&Input::Particles { particles: &particles, placement }, &range))??;
            write(p, &a.output)
        }
        DepositInput::Cells(a) => {
            let arrays = a.input.load()?;
            let cells = arrays.cells();
            let placement = a.input.placement.resolve(|| cells.bounds())?;
            let range = a.values.spec()?;
            let p = with_threads(a.output.threads, || prepare(&Input::Cells { cells: &cells, placement }, &range))??;
            write(p, &a.output)
        }
    }
}

fn write(p: Prepared, o: &GridOutput) -> Result<()> {
    let mut values = p.reference.values.clone();
    to_output_unit(&p.range, o.normalized, &mut values);
    let spacing = 1.0 / p.frame.gamma;
    write_grid(&o.output, &Grid::new(p.reference.dims, values)?, p.frame.bmin.map(|b| b + 0.5 * spacing), [spacing; 3], "deposit")?;
    let mut result = serde_json::Map::new();
    result.insert("dims".into(), json!(p.reference.dims));
    result.insert("voxels".into(), json!(p.reference.len()));
    result.extend(deposit_keys(&p));
    result.insert("peak_rss_bytes".into(), json!(peak_rss_bytes()));
    result.insert("output".into(), json!(o.output.display().to_string()));
    print_result(o.out.json, serde_json::Value::Object(result));
    Ok(())
}
