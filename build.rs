//! The build script of the C ABI crate (`capi/Cargo.toml` names it): writes
//! `include/gsenc.h` from the C ABI in `capi/` with cbindgen, and gives the
//! shared library its SONAME.
//!
//! The header is checked in; the test command regenerates it and fails when
//! the checked-in copy differs, so the ABI and its header never drift apart.
use std::path::PathBuf;

fn main() {
    // This package is capi/; the header and cbindgen.toml sit at the top.
    let capi = PathBuf::from(std::env::var("CARGO_MANIFEST_DIR").unwrap());
    let root = capi.parent().expect("capi/ sits inside the repository").to_path_buf();
    println!("cargo:rerun-if-changed={}", capi.display());
    println!("cargo:rerun-if-changed={}", root.join("cbindgen.toml").display());
    // Programs linked against the shared library record its SONAME, not its build path.
    println!("cargo:rustc-cdylib-link-arg=-Wl,-soname,libgsenc.so.0");

    let config = cbindgen::Config::from_file(root.join("cbindgen.toml")).expect("cbindgen.toml");
    // cbindgen follows the `mod` declarations of capi/lib.rs to the other files.
    match cbindgen::Builder::new().with_config(config).with_src(capi.join("lib.rs")).generate() {
        Ok(bindings) => {
            bindings.write_to_file(root.join("include/gsenc.h"));
        }
        Err(e) => panic!("cbindgen failed: {e}"),
    }
}
