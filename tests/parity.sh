#!/usr/bin/env bash
# The C API and the command-line tool are thin layers over one encode
# pipeline: the same particles (and cells) with the same settings give the
# same model, byte for byte, through both. tests/c/parity.c writes the input
# arrays and encodes them through the C API (schedule `full`: 4,000
# iterations for particles, 3,000 for cells); this script encodes the same
# files with `gsenc encode` and compares. Needs the release build of the
# library and the tool (tests/run-all.sh builds both).
set -euo pipefail
cd "$(dirname "$0")/.."
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
cc -std=c99 -Wall -Werror -Iinclude tests/c/parity.c target/release/libgsenc.a -lpthread -ldl -lm -o "$work/parity"
mkdir -p "$work/capi" "$work/cli"
"$work/parity" "$work"
gsenc=target/release/gsenc
common=(--dims 12 --budget 40 --schedule full --points 256 --step 3 --quiet)
"$gsenc" encode particles --positions "$work/positions.f32" --smoothing-length "$work/h.f32" --mass "$work/mass.f32" \
    --values "$work/pval.f32" --field rho "${common[@]}" -o "$work/cli/rho_000003.gsm" > /dev/null
"$gsenc" encode cells --centers "$work/centres.f32" --sizes "$work/edges.f32" --values "$work/cval.f32" \
    --field temp "${common[@]}" -o "$work/cli/temp_000003.gsm" > /dev/null
fails=0
for m in rho_000003.gsm temp_000003.gsm; do
    if ! cmp "$work/capi/$m" "$work/cli/$m"; then
        echo "FAIL: $m differs between the C API and the command line" >&2
        "$gsenc" info --json "$work/capi/$m" >&2
        "$gsenc" info --json "$work/cli/$m" >&2
        fails=$((fails + 1))
    fi
done
echo "parity: $((2 - fails)) passed, $fails failed"
[ "$fails" = 0 ]
