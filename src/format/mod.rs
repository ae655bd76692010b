//! The file formats, bytes in and bytes out (no file system here: `io/`
//! writes them): the model file `.gsm` ([`model_file`], docs/FORMAT.md) and
//! its fields as JSON ([`info`]), its payloads: the 8-bit export
//! ([`quantize`]) and the packed one ([`packed`], its streams coded by
//! [`packed::streams`] on the range coder of [`range`] or zstd, its centres'
//! low bits on the bit stream of [`bits`]), the stored support
//! ([`support_coding`]), the step index `.gsi` of a decomposed step
//! ([`step_index`]), and how models are named on disk ([`names`]).

pub mod bits;
pub mod info;
pub mod model_file;
pub mod names;
pub mod packed;
pub mod quantize;
pub mod range;
pub mod step_index;
pub mod support_coding;

pub use model_file::{read_model, read_model_file, write_model, write_model_as, ModelFile, Payload, BYTES_PER_PRIMITIVE, MAGIC, VERSION_MAJOR, VERSION_MINOR};
pub use names::{check_field_name, model_file_name, step_index_file_name};
pub use step_index::StepIndex;

/// What the format tests share.
#[cfg(test)]
pub(crate) mod test_support {
    use crate::error::{Error, Result};

    /// A zstd frame unpacked to exactly `want` bytes, as the model reader's
    /// `unpack` does (without its bounds).
    pub fn unpack(frame: &[u8], want: usize) -> Result<Vec<u8>> {
        let got = zstd::bulk::decompress(frame, want).map_err(|e| Error::format(e.to_string()))?;
        if got.len() != want {
            return Err(Error::format("length"));
        }
        Ok(got)
    }
}
