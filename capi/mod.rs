//! The C ABI: a thin layer over the Rust API. Every function is `extern "C"`,
//! never unwinds into C, and reports through its return value.
//!
//! This first version holds the version query only; the encoder handles,
//! status codes and array descriptions come with the C API issue.

/// Major version of the library (changes break the ABI).
pub const GSENC_VERSION_MAJOR: u32 = 0;
/// Minor version (append-only additions).
pub const GSENC_VERSION_MINOR: u32 = 1;
/// Patch version.
pub const GSENC_VERSION_PATCH: u32 = 0;

/// The run-time library version as `major * 10000 + minor * 100 + patch`, to
/// compare with the compile-time `GSENC_VERSION_*` macros. Thread-safe.
#[no_mangle]
pub extern "C" fn gsenc_version() -> u32 {
    GSENC_VERSION_MAJOR * 10000 + GSENC_VERSION_MINOR * 100 + GSENC_VERSION_PATCH
}

/// The run-time library version as a static NUL-terminated string
/// ("0.1.0"); owned by the library, never freed by the caller. Thread-safe.
#[no_mangle]
pub extern "C" fn gsenc_version_string() -> *const std::os::raw::c_char {
    concat!(env!("CARGO_PKG_VERSION"), "\0").as_ptr().cast()
}

#[cfg(test)]
mod tests {
    #[test]
    fn version_macros_match_the_crate_version() {
        let v: Vec<u32> = env!("CARGO_PKG_VERSION").split('.').map(|x| x.parse().unwrap()).collect();
        assert_eq!(super::gsenc_version(), v[0] * 10000 + v[1] * 100 + v[2]);
        let s = unsafe { std::ffi::CStr::from_ptr(super::gsenc_version_string()) };
        assert_eq!(s.to_str().unwrap(), env!("CARGO_PKG_VERSION"));
    }
}
