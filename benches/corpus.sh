# Sourced by the benchmark scripts: where the benchmark corpus lies, and the
# gsenc tool they run.
# GSENC_DATA names its folder (default ../shared/data, beside the checkout);
# `corpus FILE...` stops the script with a clear message when the corpus or
# one of its files is absent. The repository's own data/ holds only small
# subsets of it (data/README.md), for the README's encode and the tests.
# `gsenc_bin [CARGO BUILD ARGS...]` sets `bin`: GSENC_BIN, a gsenc built
# elsewhere (for a machine without a Rust toolchain; nothing is built then),
# or else this checkout's, built with those arguments (default `--bin
# gsenc`) into CARGO_TARGET_DIR (default target).
data=${GSENC_DATA:-../shared/data}
corpus() {
    local f
    for f in "$@"; do
        if [ ! -f "$data/$f" ]; then
            echo "benchmark corpus: $data/$f is missing." >&2
            echo "Set GSENC_DATA to the folder of the benchmark corpus (richtmyer_meshkov_t20.uint8, hydrogen_atom.float32," >&2
            echo "dm_halo_particles.*, enzo_amr_cells.*, dambreak3d_particles.*); default ../shared/data." >&2
            exit 1
        fi
    done
}

# The encode arguments of the corpus's datasets, as the benchmarks run them:
# RM at 128^3 (downsampled) and 256^3, hydrogen, the dam break's step 21
# (particles), the halo and the Enzo cells (log10, deposited at 128^3).
rm128=(grid --input "$data/richtmyer_meshkov_t20.uint8" --dims 256,256,256 --dtype u8 --downsample 2)
rm256=(grid --input "$data/richtmyer_meshkov_t20.uint8" --dims 256,256,256 --dtype u8)
hyd=(grid --input "$data/hydrogen_atom.float32" --dims 64,64,64 --dtype f32)
dam=(particles --positions "$data/dambreak3d_particles.positions.float32"
     --smoothing-length "$data/dambreak3d_particles.smoothing_length.float32"
     --mass "$data/dambreak3d_particles.mass.float32"
     --values "$data/dambreak3d_particles.speed.float32" --count 42042 --row 21 --fit-dims 128)
halo=(particles --positions "$data/dm_halo_particles.positions.float32"
      --smoothing-length "$data/dm_halo_particles.smoothing_length.float32"
      --mass "$data/dm_halo_particles.mass.float32"
      --values "$data/dm_halo_particles.density.float32" --log10 --dims 128)
enzo=(cells --centers "$data/enzo_amr_cells.centers.float32" --sizes "$data/enzo_amr_cells.sizes.float32"
      --values "$data/enzo_amr_cells.density.float32" --log10 --dims 128)

gsenc_bin() {
    if [ -n "${GSENC_BIN:-}" ]; then
        bin=$GSENC_BIN
        return
    fi
    [ "$#" -gt 0 ] || set -- --bin gsenc
    cargo build --release --locked "$@" >&2
    bin=${CARGO_TARGET_DIR:-target}/release/gsenc
}

# `want NAME`: whether the row NAME runs, by the names ROWS lists (every
# row when ROWS is unset or empty). core.sh and inputs.sh take their rows
# as arguments and define their own.
want() { [ -z "${ROWS:-}" ] || [[ " $ROWS " == *" $1 "* ]]; }

# Back to back against another build: with BASE_BIN set, `builds` is
# (base new) and each run of a row runs both, else (new); `build_bin B`
# prints the tool of build B (after `gsenc_bin`). Used by precision.sh and
# decode.sh, which then compare the two builds' outputs.
builds=(new)
if [ -n "${BASE_BIN:-}" ]; then
    builds=(base new)
fi
build_bin() {
    if [ "$1" = base ]; then
        echo "$BASE_BIN"
    else
        echo "$bin"
    fi
}
