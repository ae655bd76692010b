//! Empty on purpose: `Cargo.toml` says why this crate exists.
