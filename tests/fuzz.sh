#!/usr/bin/env bash
# Fuzzes the readers of foreign files for a bounded time each: the model
# reader (fuzz/fuzz_targets/model_reader.rs, seeds in fuzz/seeds), the
# .vti reader (vti_reader.rs, seeds in fuzz/vti-seeds) and the step-index
# reader with the decode of what it accepts (step_index_reader.rs, seeds in
# fuzz/gsi-seeds). FUZZ_SECONDS a target,
# default 12, from a fixed libFuzzer seed (FUZZ_SEED, default 1) so that CI
# explores the same inputs every run; set another seed or a longer time to
# explore further. Any panic, hang (10 s an input) or allocation over 2 GiB
# fails the run and leaves the input in fuzz/artifacts/. Runs on stable Rust:
# `--sanitizer none` keeps libFuzzer's coverage guidance without the
# nightly-only sanitizers. Installs cargo-fuzz when it is missing.
set -euo pipefail
cd "$(dirname "$0")/../fuzz"
if ! cargo fuzz --version >/dev/null 2>&1; then
    # Unoptimised: it only runs cargo, and builds in 22 s instead of 40 (2 cores).
    cargo install cargo-fuzz --locked --version 0.13.2 --debug
fi
seconds="${FUZZ_SECONDS:-12}"
for target in model_reader:seeds vti_reader:vti-seeds step_index_reader:gsi-seeds; do
    name="${target%%:*}"
    mkdir -p "corpus/$name"
    cargo fuzz run "$name" --sanitizer none "corpus/$name" "${target#*:}" -- \
        -max_total_time="$seconds" -seed="${FUZZ_SEED:-1}" -timeout=10 -rss_limit_mb=2048 -print_final_stats=1 2>&1 | tail -n 12
    echo "fuzz: $name ran $seconds s without a failure"
done
