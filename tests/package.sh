#!/usr/bin/env bash
# The CMake package from a user's side: build and install gsenc with the
# top-level CMakeLists.txt, check the installed layout and the version check,
# then configure, build and run the C and Fortran examples as separate CMake
# projects that only use find_package(gsenc). The mock solvers' models are
# checked by a program built with pkg-config alone (count, steps, warm starts,
# PSNR above a floor from the mock field); the Fortran module's own test is
# compiled against the installed module; the C mock solver runs under
# valgrind memcheck; and a consumer whose module files do not fit compiles
# the installed gsenc.f90 itself.
#   bash tests/package.sh [STEPS]   (default 10; the mock solvers' own
#   default is 20: ten steps, each warm-started from the one before, check
#   the same in half the time)
set -euo pipefail
cd "$(dirname "$0")/.."
steps=${1:-10}
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
prefix="$work/prefix"
# (grep reads all its input in pipes below: `grep -q` would stop early and, under
# pipefail, fail the pipeline by the writer's SIGPIPE.)
quiet() { "$@" > "$work/log" 2>&1 || { cat "$work/log" >&2; return 1; }; }
fails=0
check() { if eval "$1"; then :; else echo "FAIL: $2" >&2; fails=$((fails + 1)); fi; }

# The two-line install of the README.
quiet cmake -S . -B "$work/build" -DCMAKE_INSTALL_PREFIX="$prefix"
quiet cmake --build "$work/build"
quiet cmake --install "$work/build"
for f in include/gsenc.h include/fortran/gsenc.mod include/fortran/gsenc.f90 lib/libgsenc.so lib/libgsenc.so.0 \
         lib/libgsenc.a lib/libgsenc_fortran.a lib/cmake/gsenc/gsencConfig.cmake \
         lib/cmake/gsenc/gsencConfigVersion.cmake lib/pkgconfig/gsenc.pc; do
    check "test -e '$prefix/$f'" "installed $f"
done
check "cmp -s include/gsenc.h '$prefix/include/gsenc.h'" "the installed header is the checked-in one"
check "objdump -p '$prefix/lib/libgsenc.so' | grep 'SONAME *libgsenc.so.0' > /dev/null" "the shared library's SONAME"

# The system libraries the static library's users link (gsenc::gsenc_static's
# link interface, gsenc.pc's Libs.private) name every one that rustc says it
# needs (libc aside): a list short of one links where that library's symbols
# happen to be in libc (glibc >= 2.34: dl, rt, util, pthread) or the link
# driver adds it (gcc: gcc_s), and fails elsewhere.
rustc_libs=$(cargo rustc --release --locked -q -p gsenc-capi --lib --crate-type staticlib -- --print native-static-libs 2>&1 \
    | sed -n 's/.*native-static-libs: //p' | tr ' ' '\n' | sed -n 's/^-l//p' | grep -vx c | sort -u | tr '\n' ' ')
check "[ -n '$rustc_libs' ]" "rustc lists the static library's system libraries"
cmake_libs=$(sed -n 's/.*INTERFACE_LINK_LIBRARIES "\(.*\)")/\1/p' "$prefix/lib/cmake/gsenc/gsencConfig.cmake" | tr ';' ' ')
pc_libs=$(PKG_CONFIG_PATH="$prefix/lib/pkgconfig" pkg-config --libs-only-l --static gsenc | sed 's/-l//g')
names() { case " $1 " in *" $2 "*) return 0 ;; esac; return 1; }
for lib in $rustc_libs; do
    check "names '$cmake_libs' $lib" "gsenc::gsenc_static links $lib (rustc: $rustc_libs; the package: $cmake_libs)"
    check "names '$pc_libs' $lib" "gsenc.pc's Libs.private names $lib (it has: $pc_libs)"
done

# Version checking: this release satisfies 0.1, not 0.2 or 1.0.
for want in 0.1:found 0.2:missing 1.0:missing; do
    v=${want%%:*}
    mkdir -p "$work/v$v"
    printf 'cmake_minimum_required(VERSION 3.16)\nproject(v LANGUAGES C)\nfind_package(gsenc %s CONFIG)\nmessage(STATUS "gsenc_FOUND=${gsenc_FOUND}")\n' "$v" \
        > "$work/v$v/CMakeLists.txt"
    found=$(cmake -S "$work/v$v" -B "$work/v$v/build" -DCMAKE_PREFIX_PATH="$prefix" 2>/dev/null | grep -c "gsenc_FOUND=1" || true)
    check "[ '$found' = '$([ "${want#*:}" = found ] && echo 1 || echo 0)' ]" "find_package(gsenc $v) is ${want#*:}"
done

# The C examples: shared (minimal, version, restart) and static (mock solver).
quiet cmake -S examples_c -B "$work/exc" -DCMAKE_PREFIX_PATH="$prefix"
quiet cmake --build "$work/exc"
check "'$work/exc/version' > /dev/null" "version: header and library agree"
check "ldd '$work/exc/minimal' | grep '$prefix/lib/libgsenc.so.0' > /dev/null" "minimal links the installed shared library"
check "! ldd '$work/exc/mock_solver' | grep libgsenc > /dev/null" "mock_solver links the static library"
mkdir -p "$work/minimal"
check "(cd '$work/minimal' && '$work/exc/minimal' > out.txt) && [ \$(ls '$work/minimal'/field_*.gsm | wc -l) = 3 ]" "minimal writes 3 models"
# Two runs of the restart example: the second resumes from the first's checkpoint.
check "'$work/exc/restart' '$work/restart.ckpt' > '$work/restart1.txt' && '$work/exc/restart' '$work/restart.ckpt' > '$work/restart2.txt' \
    && ! grep -q resumed '$work/restart1.txt' && grep -qx 'resumed from step 2' '$work/restart2.txt' && grep -q '^step 5: ' '$work/restart2.txt'" \
    "restart resumes from its checkpoint"

# The Fortran mock solver, with the installed module.
quiet cmake -S examples_fortran -B "$work/exf" -DCMAKE_PREFIX_PATH="$prefix"
quiet cmake --build "$work/exf"

# Both mock solvers into one folder, then every model checked.
models="$work/models"
mkdir -p "$models"
"$work/exc/mock_solver" "$models" "$steps" 1000 300 150
"$work/exf/mock_solver_f" "$models" "$steps" 1000 300 150
export PKG_CONFIG_PATH="$prefix/lib/pkgconfig"
# shellcheck disable=SC2046
cc -std=c99 -O2 -Wall -Wextra -Werror -D_DEFAULT_SOURCE $(pkg-config --cflags gsenc) -Iexamples_c tests/c/check_mock_models.c \
    -L"$prefix/lib" -Wl,-Bstatic -lgsenc -Wl,-Bdynamic $(pkg-config --libs-only-l --static gsenc | sed 's/-lgsenc//') \
    -o "$work/check"
check "'$work/check' '$models' '$steps' 1000 grid:10 tracers:10 amr:8 fortran_grid:10" "mock solver models"

# The Fortran module's own test, against the installed module files.
gfortran -std=f2008 -Wall -Werror -I"$prefix/include/fortran" tests/fortran/module_test.f90 \
    -L"$prefix/lib" -lgsenc_fortran -lgsenc -Wl,-rpath,"$prefix/lib" -o "$work/module_test"
mkdir -p "$work/ftest"
check "'$work/module_test' '$work/ftest'" "the Fortran module test"

# A consumer whose compiler cannot use the installed module compiles gsenc.f90.
cp -a "$prefix" "$work/prefix2"
rm "$work/prefix2/lib/libgsenc_fortran.a" "$work/prefix2/include/fortran/gsenc.mod"
cmake -S examples_fortran -B "$work/exf2" -DCMAKE_PREFIX_PATH="$work/prefix2" > "$work/exf2.log"
check "grep -q 'compiling the Fortran module' '$work/exf2.log'" "the package compiles the module source"
quiet cmake --build "$work/exf2"
mkdir -p "$work/models2"
check "'$work/exf2/mock_solver_f' '$work/models2' 2 200 40 20 > /dev/null" "the mock solver with a consumer-built module"

# The C mock solver under valgrind memcheck: two steps (the second warm), all
# three forms; with no Vulkan driver, as for tests/c/capi.c in run-all.sh.
mkdir -p "$work/vg"
check "VK_ICD_FILENAMES=/nonexistent.json valgrind -q --leak-check=full --show-leak-kinds=definite,indirect --errors-for-leak-kinds=definite,indirect --error-exitcode=3 \
    '$work/exc/mock_solver' '$work/vg' 2 200 20 10 > /dev/null" "valgrind: mock solver"

if [ "$fails" -gt 0 ]; then
    echo "package: $fails failed" >&2
    exit 1
fi
echo "package: ok"
