#!/usr/bin/env bash
# A packed model written packed again (docs/FORMAT.md "The packed
# payload"): each row encodes a dataset with `--payload packed` (the
# precision measured), then rewrites the model packed three times with
# `gsenc convert`; every generation's bytes and voxel PSNR (`gsenc eval`
# against the data) go into the table. Nothing is timed.
#   bash benches/repack.sh
#   BASE_BIN=/path/to/other/gsenc bash benches/repack.sh   # both builds, side by side
#   ROWS="hydrogen_4k_tuned" bash benches/repack.sh
# Env: ROWS selects rows by name; GSENC_BIN a build to run instead of this
# checkout's (benches/corpus.sh). JSON lines go to bench-out/repack.jsonl.
set -euo pipefail
cd "$(dirname "$0")/.."
. benches/corpus.sh
corpus richtmyer_meshkov_t20.uint8 hydrogen_atom.float32 enzo_amr_cells.centers.float32
out=bench-out
mkdir -p "$out"
gsenc_bin
log="$out/repack.jsonl"
rm -f "$log"
row() { # name eval-args -- encode-args...
    local name=$1 b exe g eval_args=() psnr bytes; shift
    while [ "$1" != -- ]; do eval_args+=("$1"); shift; done
    shift
    want "$name" || return 0
    for b in "${builds[@]}"; do
        exe=$(build_bin "$b")
        echo "[$name] $b build" >&2
        "$exe" encode "$@" --backend cpu --payload packed -o "$out/repack_${b}_0.gsm" --json --quiet > /dev/null
        for g in 0 1 2 3; do
            if [ "$g" -gt 0 ]; then
                "$exe" convert "$out/repack_${b}_$((g - 1)).gsm" --payload packed -o "$out/repack_${b}_$g.gsm" --json > /dev/null
            fi
            psnr=$("$exe" eval "$out/repack_${b}_$g.gsm" "${eval_args[@]}" --backend cpu --json --quiet | python3 -c "import json, sys; print(json.load(sys.stdin)['voxel_psnr'])")
            bytes=$(stat -c %s "$out/repack_${b}_$g.gsm")
            echo "{\"row\": \"$name\", \"build\": \"$b\", \"generation\": $g, \"bytes\": $bytes, \"voxel_psnr\": $psnr, \"same_as_before\": $([ "$g" -gt 0 ] && cmp -s "$out/repack_${b}_$((g - 1)).gsm" "$out/repack_${b}_$g.gsm" && echo true || echo false)}" >> "$log"
        done
    done
}
row hydrogen_4k_tuned --input "$data/hydrogen_atom.float32" --dims 64,64,64 --dtype f32 -- "${hyd[@]}" --budget 4096 --schedule tuned
row rm128_32k_matched --input "$data/richtmyer_meshkov_t20.uint8" --dims 256,256,256 --dtype u8 --downsample 2 -- "${rm128[@]}" --range 0,255 --budget 32000 --schedule matched
# The Enzo cells' model scored against their deposit, normalised.
if want enzo_8k_tuned; then
    "$bin" deposit "${enzo[@]}" --normalized -o "$out/repack_enzo.raw" --quiet > /dev/null
fi
row enzo_8k_tuned --input "$out/repack_enzo.raw" --dims 128,128,128 --dtype f32 --normalized -- "${enzo[@]}" --budget 8000 --schedule tuned

python3 - "$log" <<'EOF'
import json, sys
runs = [json.loads(l) for l in open(sys.argv[1])]
print("| row | build | encoded: bytes, dB | repacked once | twice | three times |")
print("|---|---|---|---|---|---|")
for key in dict.fromkeys((r["row"], r["build"]) for r in runs):
    gens = sorted((r for r in runs if (r["row"], r["build"]) == key), key=lambda r: r["generation"])
    cells = [f"{g['bytes']:,} B, {g['voxel_psnr']:.4f}" + (" (same bytes)" if g["same_as_before"] else "") for g in gens]
    print(f"| {key[0]} | {key[1]} | " + " | ".join(cells) + " |")
EOF
