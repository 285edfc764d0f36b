#!/usr/bin/env bash
# The test suite under a CPU hog: does it hold on a busy machine?
#
# Starts `stress-ng --cpu N` (one busy worker per core by default, from Debian's
# stress-ng: listed in .ci/install-system-packages) and runs the README's test
# command RUNS times in a row, printing each run's result and duration, then a
# summary. The hog is stopped at the end, on failure and on Ctrl-C.
#
#   bash benchmarks/suite_under_load.sh [RUNS] [-- pytest arguments]
#
#   RUNS=3 by default; HOG_CPUS=2 by default (the workers the hog starts).
#   After `--`, the arguments replace the README's `-n 2` (e.g. a few files:
#   `-- -p no:randomly tests/drivers/test_modbus.py`).
#
# Each run's output goes to ${TMPDIR:-/tmp}/compd-suite-under-load/run-<k>.log; the
# exit status is that of the worst run (0 when all passed).
set -uo pipefail
cd "$(dirname "$0")/.."

runs=${1:-3}
shift || true
if [[ ${1:-} == "--" ]]; then
    shift
    args=("$@")
else
    args=(-n 2)  # the README's test command: python -m pytest -n 2
fi
hog_cpus=${HOG_CPUS:-2}
python=${PYTHON:-python}
[[ -x .venv/bin/python && -z ${PYTHON:-} ]] && python=.venv/bin/python

if ! command -v stress-ng >/dev/null; then
    echo "stress-ng is missing: run 'bash .ci/install-system-packages' as root (Debian package stress-ng)" >&2
    exit 2
fi

out=${TMPDIR:-/tmp}/compd-suite-under-load
mkdir -p "$out"
hog_pid=""
stop_hog() {
    if [[ -n $hog_pid ]] && kill -0 "$hog_pid" 2>/dev/null; then
        kill -TERM "$hog_pid" 2>/dev/null
        wait "$hog_pid" 2>/dev/null
    fi
    hog_pid=""
}
trap 'stop_hog' EXIT
trap 'echo; echo "interrupted: stopping the hog"; stop_hog; exit 130' INT TERM

stress-ng --cpu "$hog_cpus" --timeout 0 --quiet &
hog_pid=$!
echo "== hog: stress-ng --cpu $hog_cpus (pid $hog_pid) on $(nproc) cores; $runs run(s) of: $python -m pytest ${args[*]}"

worst=0
summary=()
for ((k = 1; k <= runs; k++)); do
    log="$out/run-$k.log"
    start=$(date +%s)
    "$python" -m pytest "${args[@]}" >"$log" 2>&1
    rc=$?
    took=$(($(date +%s) - start))
    result=$(grep -E '(passed|failed|error).* in [0-9.]+s' "$log" | tail -1 | sed -E 's/^=+ //; s/ =+$//')
    line=$(printf 'run %d: exit %d, %dm%02ds: %s' "$k" "$rc" $((took / 60)) $((took % 60)) "${result:-no summary (see $log)}")
    echo "$line"
    summary+=("$line")
    grep -E '^(FAILED|ERROR) ' "$log" | sed 's/^/    /'
    ((rc > worst)) && worst=$rc
done
stop_hog
echo "== under stress-ng --cpu $hog_cpus:"
printf '%s\n' "${summary[@]}"
exit "$worst"
