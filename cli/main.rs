//! `gsenc`: the command-line tool, a thin layer over the library. Each
//! command has its file; `args` holds the arguments they share and
//! `output` how they print and write. Every encode goes through the
//! library's pipeline (`gsenc::encode::pipeline`).

mod args;
mod convert;
mod decode;
mod deposit;
mod devices;
mod encode;
mod eval;
mod info;
mod output;
mod render;
mod series;
mod store;
mod write_behind;

use clap::{Parser, Subcommand};
use gsenc::Error;

#[derive(Parser)]
#[command(name = "gsenc", version, about = "Encode 3D scalar fields into fixed budgets of Gaussians, and decode them")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Encode a field into a model file.
    #[command(subcommand)]
    Encode(encode::EncodeInput),
    /// Decode a model to a grid (.raw float32 or .vti).
    Decode(decode::DecodeArgs),
    /// Score a model against a grid: voxel and sampled PSNR.
    Eval(eval::EvalArgs),
    /// Draw a model as an axis slice or a volume rendering (PNG), beside its reference.
    Render(render::RenderArgs),
    /// List the GPU adapters the GPU backend sees (--backend gpu, --gpu-index).
    Devices(devices::DevicesArgs),
    /// Show the metadata of a model file or of every model of a store.
    Info(info::InfoArgs),
    /// Rewrite a model with another payload (float32 to 8-bit and back).
    Convert(convert::ConvertArgs),
    /// Write the reference grid that particles or cells are encoded against.
    #[command(subcommand)]
    Deposit(deposit::DepositInput),
    /// The HDF5 store of a time series (cargo feature `hdf5`).
    #[command(subcommand)]
    Store(store::StoreCommand),
    /// Decode one field of a store to HDF5 plus XDMF, for ParaView (feature `hdf5`).
    DecodeSeries(store::DecodeSeriesArgs),
    /// Encode every step of a particle time series, warm-starting each step
    /// from the previous one, with a CSV of validation PSNR per iteration.
    EncodeSeries(series::EncodeSeriesArgs),
    /// Draw final validation PSNR against step from encode-series CSVs (PNG).
    PlotSeries(series::PlotSeriesArgs),
}

/// The process's exit code for an error (README "Exit codes").
fn exit_code(e: &Error) -> i32 {
    match e {
        Error::InvalidArgument(_) => 2,
        Error::InvalidData(_) => 3,
        Error::Format(_) | Error::Version(_) => 4,
        Error::Io { .. } | Error::Hdf5 { .. } => 5,
        Error::Cancelled(_) | Error::Mpi(_) => 6,
        Error::Device(_) => 7,
    }
}

fn main() {
    tracing_subscriber::fmt()
        .with_env_filter(tracing_subscriber::EnvFilter::from_default_env())
        .with_writer(std::io::stderr)
        .init();
    let r = match Cli::parse().command {
        Command::Encode(input) => encode::encode(input),
        Command::Deposit(input) => deposit::deposit(input),
        Command::Decode(a) => decode::decode(a),
        Command::Eval(a) => eval::eval(a),
        Command::Render(a) => render::render_cmd(a),
        Command::Info(a) => info::info(a),
        Command::Devices(a) => devices::devices(a),
        Command::Convert(a) => convert::convert(a),
        Command::Store(c) => store::store(c),
        Command::DecodeSeries(a) => store::decode_series(a),
        Command::EncodeSeries(a) => series::encode_series(a),
        Command::PlotSeries(a) => series::plot_series(a),
    };
    if let Err(e) = r {
        eprintln!("gsenc: {e}");
        std::process::exit(exit_code(&e));
    }
}
