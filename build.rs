//! Generates `include/gsenc.h` from the C ABI in `capi/` with cbindgen.
//!
//! The header is checked in; `.ci/run` regenerates it and fails when the
//! checked-in copy differs, so the ABI and its header never drift apart.
use std::path::PathBuf;

fn main() {
    let root = PathBuf::from(std::env::var("CARGO_MANIFEST_DIR").unwrap());
    println!("cargo:rerun-if-changed=capi");
    println!("cargo:rerun-if-changed=cbindgen.toml");
    // Programs linked against the shared library record its SONAME, not its build path.
    println!("cargo:rustc-cdylib-link-arg=-Wl,-soname,libgsenc.so.0");

    let config = cbindgen::Config::from_file(root.join("cbindgen.toml")).expect("cbindgen.toml");
    let mut builder = cbindgen::Builder::new().with_config(config);
    // cbindgen follows the `mod` declarations of capi/mod.rs to the other files.
    builder = builder.with_src(root.join("capi/mod.rs"));
    match builder.generate() {
        Ok(bindings) => {
            bindings.write_to_file(root.join("include/gsenc.h"));
        }
        Err(e) => panic!("cbindgen failed: {e}"),
    }
}
