#!/usr/bin/env bash
# Every test of the project: the Rust suites (unit, integration, CLI), the
# generated C header's freshness, a C program linked against the library, and
# a bounded fuzzing run of the model reader.
set -euo pipefail
cd "$(dirname "$0")/.."

cargo test --release --locked

# build.rs regenerates include/gsenc.h; the checked-in copy must match.
if ! git diff --quiet -- include/gsenc.h; then
    echo "include/gsenc.h is stale: commit the regenerated header" >&2
    git --no-pager diff -- include/gsenc.h >&2
    exit 1
fi

cargo build --release --locked --lib
out="$(mktemp -d)"
trap 'rm -rf "$out"' EXIT
cc -std=c99 -Wall -Werror -Iinclude examples_c/version.c target/release/libgsenc.a -lpthread -ldl -lm -o "$out/version"
"$out/version"
echo "c: 1 passed, 0 failed"

# The model reader under libFuzzer for a bounded time.
bash tests/fuzz.sh
