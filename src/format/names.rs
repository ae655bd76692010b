//! How models are named on disk: file names in a folder of a series, and
//! the field names that become parts of file names and HDF5 groups.

/// The file name of a model in a folder of a series: `FIELD_STEP.gsm`,
/// with `_rRANK` on ranks other than 0.
pub fn model_file_name(field: &str, step: u64, rank: u32) -> String {
    match rank {
        0 => format!("{field}_{step:06}.gsm"),
        r => format!("{field}_{step:06}_r{r}.gsm"),
    }
}

/// The step index rank 0 writes beside the per-rank models of a step
/// ([`crate::format::step_index::StepIndex`]).
pub fn step_index_file_name(field: &str, step: u64) -> String {
    format!("{field}_{step:06}.gsi")
}

/// Checks a field name: it names an HDF5 group of a store and a part of
/// model file names.
pub fn check_field_name(field: &str) -> crate::Result<()> {
    if field.is_empty() || field == "." || field == ".." || field.contains('/') || field.contains('\\') || field.contains('\0') {
        return Err(crate::Error::arg(format!("field name '{field}' cannot name a file or group (empty, '.', '/', '\\' or NUL)")));
    }
    Ok(())
}
