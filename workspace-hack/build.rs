//! Nothing to build: this script exists so that the `[build-dependencies]` of
//! Cargo.toml take part in every build's feature resolution (see there).
fn main() {}
