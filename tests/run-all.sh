#!/usr/bin/env bash
# Every test of the project: the Rust suites of the three crates (library,
# C ABI, command-line tool; with the HDF5 store), the default build without
# system libraries, the generated C header's freshness, clippy and rustdoc
# with warnings as errors, the SIMD loops' compiled code (no out-of-line
# call into core's array helpers), the C API from C
# (under valgrind too), the C API and the tool giving the same models, the
# installed CMake package with C and Fortran, MPI under mpirun, the thread-
# scaling model's scheduler, the store
# read by h5py, the Python package (pytest), the ADIOS2 operator and the
# ParaView reader (pytest, headless), and a bounded fuzzing run of
# the model, .vti and step-index readers. The GPU
# backend's tests run on Mesa's lavapipe when there is no GPU, and fail
# (GSENC_REQUIRE_GPU=1) rather than skip when wgpu sees no adapter at all.
# Needs nothing beyond the repository (tests/deps.sh installs the system packages).
set -euo pipefail
cd "$(dirname "$0")/.."

# Each stage says how long it took (the CI machine allows 30 minutes in all).
stage() {
    local t=$SECONDS
    "$@"
    echo "run-all: '$*' took $((SECONDS - t)) s (at $SECONDS s)" >&2
}
# A stage that keeps one core busy (valgrind runs a program's threads one at
# a time) runs beside the stages after it: `beside CMD...` starts it with its
# output kept aside, `joined` waits for it, prints that output and its time,
# and fails the run when it failed. One at a time.
beside() {
    beside_cmd="$*" beside_t=$SECONDS
    "$@" > "$out/beside.log" 2>&1 &
    beside_pid=$!
}
joined() {
    local rc=0
    wait "$beside_pid" || rc=$?
    beside_pid=
    cat "$out/beside.log"
    echo "run-all: '$beside_cmd' took $((SECONDS - beside_t)) s beside the stages after it (at $SECONDS s)" >&2
    [ "$rc" = 0 ] || { echo "run-all: '$beside_cmd' failed (exit $rc)" >&2; exit 1; }
}
beside_pid=

stage bash tests/deps.sh
export GSENC_REQUIRE_GPU=1
# Mesa's Wayland code complains on stderr without a runtime folder (harmless).
xdg_made=
if [ -z "${XDG_RUNTIME_DIR:-}" ]; then
    export XDG_RUNTIME_DIR="$(mktemp -d)"
    xdg_made=$XDG_RUNTIME_DIR
    trap 'rm -rf "$xdg_made"' EXIT
fi
stage cargo test --release --locked --features hdf5
# A plain build needs no system library: it must still compile, and its tool
# pass the tests that differ without the store (the store commands say how to
# get them) and a round trip; the rest of the tool's suite ran above, with
# the store, and the C API's tests below run on this build. (The packages are
# those CMake builds, gsenc-capi, and the tool, so that the builds below find
# the library compiled: workspace-hack/Cargo.toml.)
stage cargo test --release --locked -p gsenc-capi -p gsenc-cli --test cli -- \
    store_commands_without_hdf5 encode_eval_info_decode_round_trip bad_inputs_fail

# build.rs regenerates include/gsenc.h; the checked-in copy must match.
if ! git diff --quiet -- include/gsenc.h; then
    echo "include/gsenc.h is stale: commit the regenerated header" >&2
    git --no-pager diff -- include/gsenc.h >&2
    exit 1
fi

# Clippy on every crate and target, with the store (the tool's store
# commands and their tests too) and MPI, warnings as
# errors (the workspace's [workspace.lints] says which style lints are off
# and why). About 3 minutes on two cores. A newer toolchain's new lints fail
# here first: fix them, or turn one off there with its reason.
stage cargo clippy --workspace --all-targets --locked --features gsenc/hdf5,gsenc/mpi,gsenc-capi/hdf5,gsenc-capi/mpi,gsenc-cli/hdf5 -- -D warnings
# The library's API documentation, with every feature's items, warnings as
# errors (broken links); it reuses what clippy compiled of the dependencies.
stage env RUSTDOCFLAGS="-D warnings" cargo doc --no-deps --locked --features gsenc/hdf5,gsenc/mpi

# The library, libgsenc (.so and .a) and the tool, without features.
stage cargo build --release --locked -p gsenc-capi -p gsenc-cli
# Their SIMD loops call none of core's array helpers out of line (a build
# whose decode loop did ran 2.3 times slower).
stage bash tests/hot_loops.sh target/release/gsenc target/release/libgsenc.so
out="$(mktemp -d)"
trap '[ -z "$beside_pid" ] || kill "$beside_pid" 2>/dev/null; rm -rf "$out" ${xdg_made:+"$xdg_made"}' EXIT
cc -std=c99 -Wall -Werror -Iinclude examples_c/version.c target/release/libgsenc.a -lpthread -ldl -lm -o "$out/version"
"$out/version"
echo "c: 1 passed, 0 failed"
# The 30-line example must build warning-free against the header.
cc -std=c99 -Wall -Werror -Iinclude examples_c/minimal.c target/release/libgsenc.a -lpthread -ldl -lm -o "$out/minimal"
# The C API from C: a warm-started series, models read back, every error path.
cc -std=c99 -Wall -Werror -Iinclude tests/c/capi.c target/release/libgsenc.a -lpthread -ldl -lm -o "$out/capi"
stage env GSENC_CAPI_TMP="$out" "$out/capi"
# The log for C hosts: a warning when GSENC_LOG asks, nothing when unset.
cc -std=c99 -Wall -Werror -Iinclude tests/c/log.c target/release/libgsenc.a -lpthread -ldl -lm -o "$out/log"
GSENC_CAPI_TMP="$out" "$out/log" on
GSENC_CAPI_TMP="$out" "$out/log" bad
GSENC_CAPI_TMP="$out" "$out/log" off
# ...and under valgrind memcheck: no invalid reads or writes, no leaks. With
# no Vulkan driver (VK_ICD_FILENAMES names none): memcheck is for gsenc, and
# glibc's loader and Mesa's driver report their own (suppressible) findings.
# GSENC_CAPI_MEMCHECK leaves the target-PSNR search (eight encodes behind
# the calls of one) to the native run above. It takes one core for a
# minute, beside the parity check and the package.
cc -std=c99 -g -Wall -Werror -Iinclude tests/c/capi.c target/release/libgsenc.a -lpthread -ldl -lm -o "$out/capi-g"
beside env VK_ICD_FILENAMES=/nonexistent.json GSENC_CAPI_MEMCHECK=1 GSENC_CAPI_TMP="$out" valgrind -q --leak-check=full --show-leak-kinds=definite,indirect --errors-for-leak-kinds=definite,indirect --error-exitcode=3 "$out/capi-g"
# The C API and the tool: the same particles and cells, the same models.
stage bash tests/parity.sh

# The installed CMake package: C and Fortran mock solvers as a separate project.
stage bash tests/package.sh
joined

# The MPI layer under mpirun -n 1, 2, 4: C, Fortran, CLI and the mock solver.
stage bash tests/mpi.sh

# The thread-scaling model's scheduler, and the timeline's account of
# where a pass loses time, each on a profile whose answer is known.
stage python3 benches/scaling_model.py --check
stage python3 benches/timeline.py --check
# The benchmark scripts need the corpus or a lent GPU machine, so CI does
# not run them; they must at least parse.
stage bash -c 'for f in benches/*.sh benches/lent/*.sh; do bash -n "$f" || exit 1; done'

# The store read with h5py alone, against the models gsenc extracts from it.
stage cargo build --release --locked --features hdf5 --bin gsenc
stage python3 tests/store_h5py.py target/release/gsenc

# The Python package: its wheel built by maturin, then pytest (decodes bit
# for bit against the tool, a store written through the C API).
stage bash tests/python.sh

# The plugins: the ADIOS2 operator (set in adios2.xml alone) and the ParaView
# reader, with the adios2 and vtk wheels.
stage bash tests/plugins.sh

# The readers of foreign files under libFuzzer for a bounded time.
stage bash tests/fuzz.sh
