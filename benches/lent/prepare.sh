#!/usr/bin/env bash
# Builds, on this machine, the kit that benches/lent/run.sh runs on a lent
# GPU machine: that machine has no Rust toolchain, no Vulkan loader and no
# network, and what travels there is the working tree (64 MiB at most)
# plus the ignored folders a call names. Then, in one call of the device
# tool:
#   bash benches/lent/prepare.sh                  (here: builds, about 3 minutes)
#   device run: command "bash benches/lent/run.sh", carry [".lent"], timeout_s 600
# The kit, .lent/ (ignored through .git/info/exclude):
#   bin/gsenc            the release tool (stripped)
#   bin/gsenc-profiled   the same with the feature task-profile (benches/scaling_model.sh)
#   bin/insitu           benches/insitu.c linked against libgsenc.a (benches/insitu.sh)
#   bin/gpu-tests        tests/gpu/ (run there with GSENC_REQUIRE_GPU=1)
#   bin/device_churn     examples/device_churn.rs (benches/lent/tests.sh), with
#                        KIT_CHURN=1 only
#   bin/fork_cost        examples/fork_cost.rs (benches/fork_cost.sh)
#   data/                the corpus files the rows read (RM 256^3, hydrogen)
#   gl/                  Debian 12's Vulkan loader and glvnd packages
#   built-in             this checkout's path, which the test binary looks
#                        for its data/ under (run.sh links it there)
#   built-from           the commit it was built from (run.sh prints it)
set -euo pipefail
cd "$(dirname "$0")/../.."
. benches/corpus.sh
corpus richtmyer_meshkov_t20.uint8 hydrogen_atom.float32
kit=.lent
exclude=$(git rev-parse --git-path info/exclude)
mkdir -p "$(dirname "$exclude")"
grep -qxF "/$kit/" "$exclude" 2>/dev/null || echo "/$kit/" >> "$exclude"
rm -rf "$kit"
mkdir -p "$kit/bin" "$kit/data" "$kit/gl"
target=${CARGO_TARGET_DIR:-target}

cargo build --release --locked --bin gsenc --features gsenc/task-profile >&2
cp "$target/release/gsenc" "$kit/bin/gsenc-profiled"
# The ordinary tool and the C library (the profiled tool's gsenc is
# rebuilt without the feature; the dependencies are shared).
cargo build --release --locked --bin gsenc >&2
cargo build --release --locked -p gsenc-capi >&2
cp "$target/release/gsenc" "$kit/bin/gsenc"
# device_churn (5 MiB) only when asked: the kit is close to what a call may
# carry, and benches/lent/run.sh does not use it.
if [ -n "${KIT_CHURN:-}" ]; then
    cargo build --release --locked --example device_churn >&2
    cp "$target/release/examples/device_churn" "$kit/bin/device_churn"
fi
cargo build --release --locked --example fork_cost >&2
cp "$target/release/examples/fork_cost" "$kit/bin/fork_cost"
cc -std=c99 -O2 -Iinclude -Iexamples_c benches/insitu.c "$target/release/libgsenc.a" -lpthread -ldl -lm -o "$kit/bin/insitu"
tests=$(cargo test --release --locked -p gsenc --test gpu --no-run --message-format=json \
    | python3 -c 'import json, sys
for line in sys.stdin:
    d = json.loads(line)
    if d.get("reason") == "compiler-artifact" and d.get("executable") and d["target"]["name"] == "gpu":
        print(d["executable"])')
cp "$tests" "$kit/bin/gpu-tests"
strip "$kit"/bin/*
pwd > "$kit/built-in"
git describe --always --dirty > "$kit/built-from"

cp "$data/richtmyer_meshkov_t20.uint8" "$data/hydrogen_atom.float32" "$kit/data/"

# The Vulkan loader (and the glvnd libraries NVIDIA's driver loads) as
# Debian 12 packages for x86-64, unpacked there with dpkg -x.
lists=$(mktemp -d)
apt=(-oAPT::Architecture=amd64 -oAPT::Architectures=amd64 "-oDir::State::Lists=$lists")
mkdir -p "$lists/partial"
apt-get "${apt[@]}" update >&2
(cd "$kit/gl" && apt-get "${apt[@]}" download libvulkan1 libegl1 libglvnd0 libopengl0 libgl1 libglx0 libgles2 >&2)
rm -rf "$lists"

# What travels: the tracked and untracked-not-ignored files, and the kit.
tree=$(git ls-files -z --cached --others --exclude-standard | du -cb --files0-from=- 2>/dev/null | tail -1 | cut -f1)
kitsize=$(du -sb "$kit" | cut -f1)
total=$((tree + kitsize))
echo "kit: $kit, $((kitsize / 1048576)) MiB; with the working tree $((total / 1048576)) MiB of the 64 MiB a call may carry" >&2
[ "$total" -lt $((64 * 1048576)) ] || { echo "too large to travel" >&2; exit 1; }
