# Sourced by the benchmark scripts: where the benchmark corpus lies.
# GSENC_DATA names its folder (default ../shared/data, beside the checkout);
# `corpus FILE...` stops the script with a clear message when the corpus or
# one of its files is absent. The repository's own data/ holds only small
# subsets of it (data/README.md), for the README's encode and the tests.
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
