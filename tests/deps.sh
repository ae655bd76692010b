#!/usr/bin/env bash
# Installs what the test suite needs beyond a Rust toolchain, when missing:
# C and C++ compilers (the C tests, libFuzzer), HDF5 (the `hdf5` feature's
# store, and h5dump to read it), valgrind (the C API under memcheck), CMake
# and gfortran (the installed package, the Fortran module and examples),
# Mesa's Vulkan drivers (lavapipe runs the GPU backend's tests on the CPU)
# and h5py (to read the store from Python). Debian
# packages through apt when run as root; otherwise it says what to install.
set -euo pipefail

need_apt=()
command -v cc >/dev/null || need_apt+=(gcc libc6-dev)
command -v c++ >/dev/null || need_apt+=(g++)
command -v pkg-config >/dev/null || need_apt+=(pkg-config)
pkg-config --exists hdf5 2>/dev/null || need_apt+=(libhdf5-dev)
command -v h5dump >/dev/null || need_apt+=(hdf5-tools)
command -v valgrind >/dev/null || need_apt+=(valgrind)
command -v cmake >/dev/null || need_apt+=(cmake make)
command -v gfortran >/dev/null || need_apt+=(gfortran)
command -v mpicc >/dev/null && command -v mpirun >/dev/null || need_apt+=(libopenmpi-dev openmpi-bin)
ls /usr/share/vulkan/icd.d/lvp_icd*.json >/dev/null 2>&1 || need_apt+=(mesa-vulkan-drivers libvulkan1)
python3 -c "import ensurepip, venv" 2>/dev/null || need_apt+=(python3-venv)
[ -e /usr/lib/llvm-14/lib/libclang.so ] || ls /usr/lib/llvm-*/lib/libclang.so >/dev/null 2>&1 || need_apt+=(libclang-dev)
if [ ${#need_apt[@]} -gt 0 ]; then
    if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
        echo "installing ${need_apt[*]}" >&2
        apt-get update -qq
        DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "${need_apt[@]}" >/dev/null
    else
        echo "the tests need: ${need_apt[*]} (Debian package names); install them and rerun" >&2
        exit 1
    fi
fi
if ! python3 -c "import h5py" 2>/dev/null; then
    echo "installing h5py" >&2
    python3 -m pip install -q --disable-pip-version-check h5py 2>&1 | grep -v "Running pip as the 'root' user" >&2 || true
    python3 -c "import h5py" || { echo "the tests need h5py: python3 -m pip install h5py" >&2; exit 1; }
fi
