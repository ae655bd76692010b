#!/usr/bin/env bash
# The SIMD builds of the hot loops (`math/simd.rs` `simd_dispatch!`: each
# `...::avx512` and `...::avx2` function of a binary) must not call core's
# array helpers (`map`, `try_map`, `from_fn`, ...) out of line. Such a call
# is compiled without the function's vector features, takes its arrays
# through memory, and stays in the loop only where LLVM chose not to
# inline it: a build of 2026-12-05 whose decode loop called
# `core::array::try_map` for each pair of rows decoded 2.3 times slower
# than the same source compiled a commit later (docs/BENCHMARKS.md "A
# decode written behind"). Plain loops in those functions never depend on
# that choice; this check finds one that does.
#   bash tests/hot_loops.sh [BINARY...]   (default target/release/gsenc)
# Needs nm and objdump (binutils, which the C compiler brings).
set -euo pipefail
[ "$#" -gt 0 ] || set -- target/release/gsenc
failed=0
for bin in "$@"; do
    [ -f "$bin" ] || { echo "hot_loops: no binary at $bin (build it first)" >&2; exit 1; }
    # Every function's start, in address order: the next one ends it.
    syms=$(nm -n --defined-only "$bin" | awk '$2 ~ /^[tT]$/ {print $1, $3}')
    variants=$(nm -nC --defined-only "$bin" | awk '$2 ~ /^[tT]$/ && ($3 ~ /::avx512$/ || $3 ~ /::avx2$/) {print $1, $3}')
    [ -n "$variants" ] || { echo "hot_loops: no SIMD variants in $bin (stripped?)" >&2; exit 1; }
    checked=0
    bad=0
    while read -r addr name; do
        end=$(awk -v a="$addr" 'f {print $1; exit} $1 == a {f = 1}' <<< "$syms")
        [ -n "$end" ] || continue
        calls=$(objdump -d -C --no-show-raw-insn --start-address="0x$addr" --stop-address="0x$end" "$bin" \
            | grep -E '\scall' | sed -n 's/^[^<]*<\(.*\)>$/\1/p' | grep -E '^core::array::' | sort -u || true)
        checked=$((checked + 1))
        if [ -n "$calls" ]; then
            echo "hot_loops: $bin: $name calls core's array code out of line:" >&2
            echo "$calls" | sed 's/^/    /' >&2
            bad=$((bad + 1))
        fi
    done <<< "$variants"
    echo "hot_loops: $bin: $checked SIMD functions checked, $bad calling core::array out of line"
    [ "$bad" = 0 ] || failed=1
done
exit "$failed"
