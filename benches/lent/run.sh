#!/usr/bin/env bash
# The one prepared run for a lent GPU machine (an NVIDIA H200, 16 cores, no
# Rust toolchain, no network), from the kit that benches/lent/prepare.sh
# builds here:
#   device run: command "bash benches/lent/run.sh", carry [".lent"], timeout_s 600
# Stages, in order, each only while enough of BUDGET seconds (default 560)
# is left for it:
#   1. the GPU rows (beside them: a step's uploads written buffer by
#      buffer, four steps to a submission, and a host pool of 4 threads),
#      the same rows on all the machine's cores and the in-situ run on the
#      GPU (benches/gpu.sh; the decode of 1024^3, measured on 2026-11-29
#      and 2026-12-04, only with DECODE_WHICH=gpu);
#   2. the CPU backend at 1, 2, 4, 8 and 16 threads (benches/scaling.sh,
#      SCALING_ITERS iterations a row, default 500: the time an iteration
#      takes is what compares), then which CPUs share a core with CPU 0
#      (benches/siblings.sh, about 25 s), then what the machine allows p
#      threads apart from the pool: 1 to 16 one-thread encodes at once
#      (benches/rate.sh, about 45 s);
#   3. where an iteration loses time at 1, 4 and 16 threads (benches/
#      timeline.sh, 300 iterations a row: the pool joining a pass late, a
#      last task running alone, the gaps between passes), what a pass
#      costs beyond its work with rayon and with threads that spin between
#      passes (benches/fork_cost.sh, 2 to 16 threads, about 10 s), then the
#      scaling model's prediction for the same machine
#      (benches/scaling_model.sh), to set beside stage 2;
#   4. the GPU tests (tests/gpu/, one test thread, GSENC_REQUIRE_GPU=1);
#   5. how the point passes are cut into workgroups (benches/gpu_split.sh,
#      at most a minute): the kernels' times with other splits, the same
#      models (checked), for choosing the defaults;
#   6. the in-situ run of stage 1 with the CPU backend (half the iterations,
#      so that one core keeps up with the solver's steps), for the solver's
#      slowdown beside the GPU's on the same machine (+18.7 % with the GPU
#      on 2026-11-29, unexplained; never measured there with the CPU);
#   7. the in-situ run on the GPU again, its encoder waiting for results by
#      polling and sleeping (GSENC_GPU_WAIT=sleep) instead of blocking in the
#      driver, which may spin on a core;
#   8. the same with the solver on CPU 0 and the encoder placed on the CPU
#      that shares least with it by stage 2 (GSENC_ENCODER_CPUS).
# Results land in bench-out/ as they do here. After each stage the text
# results are packed into $OUT/lent.tgz, beside the log $OUT/lent.log (the
# device tool brings back at most 8 files, and whatever is under $OUT when
# a call is cut short). Without OUT (a dry run on any machine) both go to
# bench-out/lent/; GSENC_ADAPTER=llvmpipe then runs the GPU rows on lavapipe.
set -uo pipefail
cd "$(dirname "$0")/../.."
kit=$PWD/.lent
[ -x "$kit/bin/gsenc" ] || { echo "no kit in $kit: run bash benches/lent/prepare.sh here and carry .lent" >&2; exit 2; }
budget=${BUDGET:-560}
dest=${OUT:-bench-out/lent}
mkdir -p "$dest" bench-out
exec > >(tee -a "$dest/lent.log") 2>&1
tee_pid=$!
echo "kit built from $(cat "$kit/built-from" 2>/dev/null || echo 'an unknown commit')"
left() { echo $((budget - SECONDS)); }
insitu() { # NAME ARGS...: benches/insitu.sh ARGS with the caller's variables, its table and runs kept as bench-out/NAME.md and NAME-runs.jsonl
    local name=$1; shift
    timeout $(( $(left) - 5 )) bash benches/insitu.sh "$@" > "bench-out/$name.md" || echo "benches/insitu.sh: exit $?"
    cat "bench-out/$name.md"
    cp bench-out/insitu/runs.jsonl "bench-out/$name-runs.jsonl" 2>/dev/null || true
}
stage() { echo "== $1 (at ${SECONDS} s of ${budget} s)"; }
pack() { # the text results only (no models, raw grids or task profiles)
    find bench-out -maxdepth 2 -type f \( -name '*.jsonl' -o -name '*.md' -o -name '*.json' -o -name '*.txt' -o -name '*.csv' \) \
        -not -path 'bench-out/lent/*' -print0 | tar czf "$dest/lent.tgz" --null -T - || echo "packing the results failed"
}
export GSENC_BIN=$kit/bin/gsenc INSITU_BIN=$kit/bin/insitu GSENC_DATA=$kit/data
# Whether the 16 vCPUs are 16 cores or 8 with two hyperthreads each decides
# what 16 threads can reach (issue 21's 12x) and whether the in-situ
# encoder's thread shares the solver's core; a VM may not say (one thread
# per core shown for what the host runs as siblings).
lscpu | grep -E "Model name|^CPU\(s\)|Thread\(s\) per core|Core\(s\) per socket|Socket\(s\)|NUMA node\(s\)"
lscpu -e=CPU,CORE,SOCKET,NODE > bench-out/cpu-topology.txt 2>&1 || true
echo "vector extensions: $(grep -o -w -E 'avx2|avx512f|avx512vl' /proc/cpuinfo | sort -u | tr '\n' ' ')"
command -v nvidia-smi > /dev/null && nvidia-smi --query-gpu=name,driver_version,clocks.sm,clocks.max.sm --format=csv

. benches/lent/gpu_env.sh
"$GSENC_BIN" devices --json
echo "hardware GPUs: $(hardware)"

# Seconds kept for the stages after the GPU rows (the H200 machine's times
# of 2026-12-04: scaling 105 s at 500 iterations, the tests 15 s, in situ
# on the CPU 75 s; estimated: the core probe 25 s, p encodes at once 45 s
# (from its rows' times on the 2-core VM, 1.6x slower), the timeline 25 s, the
# pass cost 10 s, the model 80 s from its one-thread iteration times; the
# split sweep up to 60 s; the last stage runs only if they took less).
reserve=${RESERVE:-430}
stage "1. GPU rows (benches/gpu.sh)"
gpu_time=$(( $(left) - reserve ))
if [ "$gpu_time" -gt 60 ]; then
    # A row's second round only in the first third, so that the in-situ
    # run still starts in time after the 200K row's five runs.
    OUT= REPEAT=${GPU_REPEAT:-2} DEADLINE=$((gpu_time / 3)) ROW_LIMIT=120 STOP_AFTER=$((gpu_time - 30)) DECODE_WHICH=${DECODE_WHICH-} \
        timeout "$gpu_time" bash benches/gpu.sh || echo "benches/gpu.sh: exit $?"
    cp bench-out/insitu/runs.jsonl bench-out/gpu-insitu-runs.jsonl 2>/dev/null || true
fi
pack

stage "2. scaling (benches/scaling.sh)"
iters=${SCALING_ITERS:-500}
[ "$(left)" -gt 200 ] || iters=$((iters / 2))
if [ "$(left)" -gt 60 ]; then
    ITERS=$iters timeout $(( $(left) - 20 )) bash benches/scaling.sh > bench-out/scaling-table.md || echo "benches/scaling.sh: exit $?"
    cat bench-out/scaling-table.md
fi
if [ "$(left)" -gt 150 ]; then
    ITERS=50 timeout 60 bash benches/siblings.sh > bench-out/siblings.md || echo "benches/siblings.sh: exit $?"
    cat bench-out/siblings.md
fi
if [ "$(left)" -gt 240 ]; then
    ALONE=2 SCALING=bench-out/scaling.jsonl timeout 70 bash benches/rate.sh rm128_32k_matched hydrogen_4k_matched > bench-out/rate.md \
        || echo "benches/rate.sh: exit $?"
    cat bench-out/rate.md
fi
pack

stage "3. where time is lost at 16 threads (benches/timeline.sh), what a pass costs (benches/fork_cost.sh), then the scaling model (benches/scaling_model.sh)"
if [ "$(left)" -gt 120 ]; then
    GSENC_PROFILED_BIN=$kit/bin/gsenc-profiled THREADS="1 4 16" ITERS=300 timeout 45 bash benches/timeline.sh > bench-out/timeline.md \
        || echo "benches/timeline.sh: exit $?"
    cat bench-out/timeline.md
fi
if [ "$(left)" -gt 100 ]; then
    GSENC_FORK_COST_BIN=$kit/bin/fork_cost timeout 40 bash benches/fork_cost.sh 2 4 8 16 > bench-out/fork-cost.md \
        || echo "benches/fork_cost.sh: exit $?"
    cat bench-out/fork-cost.md
fi
if [ "$(left)" -gt 90 ]; then
    GSENC_PROFILED_BIN=$kit/bin/gsenc-profiled timeout $(( $(left) - 10 )) bash benches/scaling_model.sh > bench-out/scaling-model.md \
        || echo "benches/scaling_model.sh: exit $?"
    cat bench-out/scaling-model.md
fi
pack

stage "4. the GPU tests (tests/gpu/)"
if [ "$(left)" -gt 30 ]; then
    GSENC_REQUIRE_GPU=1 timeout $(( $(left) - 5 )) "$kit/bin/gpu-tests" --test-threads 1 > bench-out/gpu-tests.txt 2>&1
    echo "tests/gpu/: exit $?"
    tail -5 bench-out/gpu-tests.txt
fi
pack

stage "5. the work split sweep (benches/gpu_split.sh)"
# At most a minute, and only while the in-situ stage keeps its time.
sweep=$(( $(left) - 150 ))
[ "$sweep" -le 60 ] || sweep=60
if [ "$sweep" -gt 20 ]; then
    STOP_AFTER=$((sweep - 10)) timeout "$sweep" bash benches/gpu_split.sh || echo "benches/gpu_split.sh: exit $?"
fi
pack

stage "6. in situ with the CPU backend (benches/insitu.sh)"
if [ "$(left)" -gt 80 ]; then
    GSENC_BACKEND=cpu insitu cpu-insitu 1 8 600 4000 100 30
fi
pack

stage "7. in situ on the GPU, waiting by sleeping (GSENC_GPU_WAIT=sleep)"
if [ "$(left)" -gt 60 ]; then
    GSENC_BACKEND=gpu GSENC_GPU_WAIT=sleep insitu gpu-sleep-insitu 1 8 600
fi
pack
stage "8. in situ on the GPU, the encoder placed away from the solver (GSENC_ENCODER_CPUS)"
# The solver on CPU 0 and the encoder's thread on the CPU that slowed CPU 0
# least in stage 2 (benches/siblings.sh), so that no hyperthread sibling,
# as the VM may show one as a core, is shared: whether the solver's
# slowdown of stages 1 and 7 is its neighbour's doing.
apart=$(python3 -c '
import sys
rows = [l.split("|")[1:4] for l in open(sys.argv[1]) if l.startswith("| ") and l.split("|")[1].strip().isdigit()]
print(min(rows, key=lambda r: max(float(r[1]), float(r[2])))[0].strip() if rows else "")
' bench-out/siblings.md 2>/dev/null || true)
if [ -n "$apart" ] && [ "$(left)" -gt 60 ]; then
    echo "encoder on CPU $apart, solver on CPU 0"
    INSITU_CPUS=0,$apart GSENC_ENCODER_CPUS=$apart GSENC_BACKEND=gpu GSENC_GPU_WAIT=sleep insitu gpu-apart-insitu 1 8 600
fi
pack
stage "done"
exec >&- 2>&-
wait "$tee_pid" 2>/dev/null || true
