#!/usr/bin/env bash
# The plugins (plugins/): the ADIOS2 operator and the ParaView reader, headless.
# Installs the `adios2` (>= 2.12: its C++ headers and CMake config) and `vtk`
# wheels into the Python package's virtual environment (target/pyvenv, made
# by tests/python.sh, which runs first and installs the gsenc wheel there),
# builds and installs the CMake project with ADIOS2 found in that
# environment (so the operator is built and installed beside libgsenc), and
# runs plugins/tests with pytest: a BP5 file written through the operator
# set in adios2.xml alone and read back by ADIOS2's Python API, and the
# reader on a .gsm, a .gsi and a store against `gsenc decode`.
set -euo pipefail
cd "$(dirname "$0")/.."
venv=target/pyvenv
if ! "$venv/bin/python" -c "import gsenc" 2>/dev/null; then
    echo "plugins: run tests/python.sh first (it builds the gsenc wheel into $venv)" >&2
    exit 1
fi
if ! "$venv/bin/python" -c "import adios2, vtk" 2>/dev/null; then
    "$venv/bin/pip" install -q --disable-pip-version-check "adios2==2.12.1.1001" "vtk==9.7.2"
fi
site=$("$venv/bin/python" -c "import sysconfig; print(sysconfig.get_paths()['purelib'])")

work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
quiet() { "$@" > "$work/log" 2>&1 || { cat "$work/log" >&2; return 1; }; }
quiet cmake -S . -B "$work/build" -DCMAKE_INSTALL_PREFIX="$work/prefix" -DCMAKE_PREFIX_PATH="$site" -DGSENC_FORTRAN=OFF
grep "ADIOS2 operator" "$work/log"
quiet cmake --build "$work/build"
quiet cmake --install "$work/build"
for f in lib/libgsenc_adios2_operator.so share/gsenc/paraview/gsenc_paraview.py; do
    test -e "$work/prefix/$f" || { echo "plugins: $f was not installed" >&2; exit 1; }
done

# The tool that decodes for comparison, and writes the store.
cargo build --release --locked --features hdf5 --bin gsenc
# Mesa's Wayland code complains on stderr without a runtime folder (harmless).
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-$work}"
cd plugins/tests
GSENC_BIN="$OLDPWD/target/release/gsenc" GSENC_PLUGIN_DIR="$work/prefix/lib" GSENC_LIBRARY="$work/prefix/lib/libgsenc.so.0" \
    GSENC_PARAVIEW_DIR="$work/prefix/share/gsenc/paraview" \
    "../../$venv/bin/python" -m pytest -q -p no:cacheprovider .
