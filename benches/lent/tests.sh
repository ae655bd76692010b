#!/usr/bin/env bash
# The GPU tests on a lent GPU machine, and why some may fail there: on the
# H200 of 2026-12-04 the last 3 of 18 tests in one process found no adapter
# (docs/BENCHMARKS.md "A lent H200, 2026-12-04"). From the kit of
# benches/lent/prepare.sh:
#   device run: command "bash benches/lent/tests.sh", carry [".lent"], timeout_s 300
# (step 1 needs the kit built with KIT_CHURN=1).
# 1. examples/device_churn: rounds that list the adapters, open and drop the
#    backend, and open, evaluate and drop it, each reporting whether the
#    adapter is still seen and the process's open files, threads, memory;
# 2. tests/gpu/ in one process, one test thread, the process's open files
#    and threads sampled as the tests run;
# 3. each test in a process of its own.
# Output in $OUT/tests.log (bench-out/lent/ without OUT).
set -uo pipefail
cd "$(dirname "$0")/../.."
kit=$PWD/.lent
[ -x "$kit/bin/gsenc" ] || { echo "no kit in $kit: run bash benches/lent/prepare.sh here and carry .lent" >&2; exit 2; }
dest=${OUT:-bench-out/lent}
mkdir -p "$dest"
exec > >(tee -a "$dest/tests.log") 2>&1
echo "kit built from $(cat "$kit/built-from" 2>/dev/null || echo 'an unknown commit')"
. benches/lent/gpu_env.sh
echo "hardware GPUs: $(hardware); open files allowed: $(ulimit -n) (hard $(ulimit -Hn))"
command -v nvidia-smi > /dev/null && nvidia-smi --query-gpu=name,driver_version,memory.used --format=csv

echo "== 1. device_churn"
if [ -x "$kit/bin/device_churn" ]; then
    for mode in enumerate open work; do
        timeout 40 "$kit/bin/device_churn" "$mode" 40 | awk 'NR % 5 == 1 || /rounds|failed/'
        echo "device_churn $mode: exit ${PIPESTATUS[0]}"
    done
else
    echo "not in the kit: KIT_CHURN=1 bash benches/lent/prepare.sh builds it"
fi

echo "== 2. tests/gpu/ in one process"
export GSENC_REQUIRE_GPU=1
"$kit/bin/gpu-tests" --test-threads 1 > "$dest/gpu-tests-one.txt" 2>&1 &
pid=$!
while kill -0 "$pid" 2> /dev/null; do
    echo "tests finished $(grep -c ' \.\.\. ' "$dest/gpu-tests-one.txt"), open files $(ls /proc/$pid/fd 2>/dev/null | wc -l), threads $(ls /proc/$pid/task 2>/dev/null | wc -l)"
    sleep 0.5
done | uniq
wait "$pid"
echo "tests/gpu/ in one process: exit $?"
grep -E '\.\.\. |test result' "$dest/gpu-tests-one.txt"

echo "== 3. each test in a process of its own"
for t in $("$kit/bin/gpu-tests" --list --format terse 2>/dev/null | sed -n 's/: test$//p'); do
    timeout 60 "$kit/bin/gpu-tests" --exact "$t" > /tmp/one.txt 2>&1
    echo "$t: exit $? ($(grep 'test result' /tmp/one.txt))"
done
echo "== done at ${SECONDS} s"
