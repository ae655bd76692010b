//! `gsenc info`: every header field of a model file, or every entry of an
//! HDF5 store.

use crate::output::print_result;
use crate::store;
use clap::Args;
use gsenc::{Error, Result};
use gsenc::format::info::model_info;
use std::path::PathBuf;

#[derive(Args)]
pub struct InfoArgs {
    model: PathBuf,
    #[arg(long)]
    json: bool,
}

pub fn info(a: InfoArgs) -> Result<()> {
    if gsenc::io::is_hdf5_file(&a.model) {
        return store::info(&a.model, a.json);
    }
    let file = gsenc::io::read_model_file(&a.model)?;
    let bytes = std::fs::metadata(&a.model).map_err(|e| Error::io(&a.model, e))?.len();
    print_result(a.json, model_info(&file, bytes));
    Ok(())
}
