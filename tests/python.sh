#!/usr/bin/env bash
# The Python package (python/): builds its wheel with maturin in a virtual
# environment (target/pyvenv: maturin, numpy and pytest from PyPI), installs
# it there, and runs its pytest suite (python/tests) against the
# command-line tool and the C mock solver writing an HDF5 store through the
# C API. The wheel is left in target/wheels.
set -euo pipefail
cd "$(dirname "$0")/.."
venv=target/pyvenv
if ! "$venv/bin/maturin" --version >/dev/null 2>&1 || ! "$venv/bin/python" -c "import numpy, pytest" 2>/dev/null; then
    python3 -m venv "$venv"
    "$venv/bin/pip" install -q --disable-pip-version-check "maturin==1.16.0" "numpy==2.4.6" "pytest==9.2.0"
fi
rm -rf target/wheels
"$venv/bin/maturin" build --release --locked -m python/Cargo.toml -o target/wheels
"$venv/bin/pip" install -q --disable-pip-version-check --force-reinstall --no-deps target/wheels/gsenc-*.whl

# The tool the decodes are compared with, and libgsenc with HDF5 for the mock
# solver (the packages and features of the test command's first build, so
# nothing is compiled again there).
cargo build --release --locked --features hdf5
out="$(mktemp -d)"
trap 'rm -rf "$out"' EXIT
# libgsenc.so's soname is libgsenc.so.0, as installed; here a link stands in.
ln -s "$PWD/target/release/libgsenc.so" "$out/libgsenc.so.0"
cc -std=c99 -Wall -Werror -Iinclude -Iexamples_c examples_c/mock_solver.c -Ltarget/release -lgsenc -Wl,-rpath,"$out" -lm -o "$out/mock_solver"
cd python/tests
GSENC_BIN="$OLDPWD/target/release/gsenc" GSENC_MOCK_SOLVER="$out/mock_solver" "../../$venv/bin/python" -m pytest -q -p no:cacheprovider .
