# Shared by benches/scaling_model.sh and benches/timeline.sh (sourced after
# benches/corpus.sh): the tool built with the feature task-profile, and the
# arguments of the scaling rows.

# profiled_bin DIR: copies GSENC_PROFILED_BIN (a binary built elsewhere,
# as benches/lent/prepare.sh builds it) into DIR, or builds one there (only
# gsenc and the tool recompile; the ordinary binary is linked again
# afterwards); prints its path.
profiled_bin() {
    local dir=$1
    if [ -n "${GSENC_PROFILED_BIN:-}" ]; then
        cp "$GSENC_PROFILED_BIN" "$dir/gsenc"
    else
        cargo build --release --locked --bin gsenc --features gsenc/task-profile >&2
        cp "${CARGO_TARGET_DIR:-target}/release/gsenc" "$dir/gsenc"
        cargo build --release --locked --bin gsenc >&2
    fi
    echo "$dir/gsenc"
}

# scaling_row_args ROW: the encode's arguments for ROW (rm128_32k_matched,
# rm128_32k_full, hydrogen_4k_matched) in the array `args`.
scaling_row_args() {
    local rm=(--input "$data/richtmyer_meshkov_t20.uint8" --dims 256,256,256 --dtype u8 --range 0,255 --downsample 2 --budget 32000)
    local h=(--input "$data/hydrogen_atom.float32" --dims 64,64,64 --dtype f32 --budget 4096)
    case $1 in
        rm128_32k_matched) args=("${rm[@]}" --schedule matched) ;;
        rm128_32k_full) args=("${rm[@]}" --schedule full) ;;
        hydrogen_4k_matched) args=("${h[@]}" --schedule matched) ;;
        *) echo "unknown row $1" >&2; return 2 ;;
    esac
}
