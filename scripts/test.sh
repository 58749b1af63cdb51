#!/usr/bin/env bash
# The whole test suite: lint, format check, types, then every tier of tests in one run on pytest-xdist
# workers (the fuzz tier beside them, in a pytest of its own). Prints the 15 slowest tests, each tier's
# tests and serial time, and the wall time at the end (with --tier, the tiers run one after another and
# each gets its own wall time).
#
#   scripts/test.sh                          everything (what `./run test` and CI run)
#   scripts/test.sh --tier unit [--tier e2e] only these tiers, no lint (tiers: unit accuracy contract
#                                            integration e2e fuzz; see pyproject's markers)
#   scripts/test.sh -m unit tests/unit/cli   any pytest arguments: one pytest run, no lint
#
# EIGENSCOPE_TEST_WORKERS sets the number of xdist workers (default 2, one per core; 0 runs serially).
# EIGENSCOPE_FUZZ_SECONDS sets the fuzzer's time (default 60).
set -euo pipefail
cd "$(dirname "$0")/.."
. .venv/bin/activate

ALL_TIERS=(unit accuracy contract integration e2e fuzz)
tiers=()
args=()
while [ $# -gt 0 ]; do
    case "$1" in
        --tier) tiers+=("$2"); shift 2 ;;
        --tier=*) tiers+=("${1#--tier=}"); shift ;;
        *) args+=("$1"); shift ;;
    esac
done
for tier in "${tiers[@]}"; do
    case " ${ALL_TIERS[*]} " in
        *" $tier "*) ;;
        *) echo "test.sh: unknown tier '$tier'; the tiers are: ${ALL_TIERS[*]}" >&2; exit 2 ;;
    esac
done

workers=${EIGENSCOPE_TEST_WORKERS:-2}
xdist=()
if [ "$workers" != 0 ]; then
    # Tests of a module that starts services stay on one worker, and those that share the Redis test
    # database share one (xdist_group marks, set in tests/conftest.py).
    xdist=(-n "$workers" --dist loadgroup)
fi

if [ ${#tiers[@]} -eq 0 ] && [ ${#args[@]} -gt 0 ]; then
    exec pytest "${xdist[@]}" --durations=15 "${args[@]}"
fi
reports=$(mktemp -d)
trap 'rm -rf "$reports"' EXIT
status=0
if [ ${#tiers[@]} -eq 0 ]; then
    # Lint and types fail the run as a test does (after the tests, so that one run shows everything).
    lint=0
    echo "== ruff"; { ruff check . && ruff format --check .; } || lint=1
    echo "== mypy"; mypy api_schemas backend workers service eigenscope client/src/eigenscope_client || lint=1
    # The fuzz tier runs in a pytest of its own, started first and beside the others: the fuzzer's memory
    # limit is checked against its peak resident set, which Linux carries over from the process that
    # starts it (fork and exec keep the high-water mark), so under a test worker grown by whole analyses
    # it would start above its limit. It fuzzes for a set time on one core; run after the other tiers it
    # added its whole minute and more to the wall time, with the other core idle, while the service
    # tiers leave time on both cores (waiting on processes they start). Its output is shown after theirs.
    echo "== pytest: the fuzz tier (a process of its own, beside the others; its output follows theirs)"
    fuzz_started=$(date +%s.%N)
    (
        fuzz_rc=0
        pytest -m fuzz --basetemp="$reports/fuzz-tmp" --junitxml="$reports/fuzz.xml" "${args[@]}" \
            > "$reports/fuzz.log" 2>&1 || fuzz_rc=$?
        echo "fuzz $fuzz_started $(date +%s.%N) $fuzz_rc" > "$reports/fuzz.wall"
    ) &
    fuzz_pid=$!
    # Every other tier in one pytest run: the workers share out all the tests, so neither waits at the
    # end of a tier for the other's last long test (the report still gives each tier's tests and serial
    # time).
    echo "== pytest: every other tier (${ALL_TIERS[*]/fuzz})"
    started=$(date +%s.%N)
    rc=0
    pytest "${xdist[@]}" -m "not fuzz" --junitxml="$reports/all.xml" "${args[@]}" || rc=$?
    ended=$(date +%s.%N)
    echo "all $started $ended $rc" >> "$reports/walls"
    wait "$fuzz_pid" || true
    echo "== pytest: the fuzz tier's output"
    cat "$reports/fuzz.log"
    fuzz_rc=1
    if [ -f "$reports/fuzz.wall" ]; then
        cat "$reports/fuzz.wall" >> "$reports/walls"
        fuzz_rc=$(cut -d' ' -f4 "$reports/fuzz.wall")
    fi
    [ "$rc" = 0 ] && rc=$fuzz_rc
    python scripts/test_report.py "$reports" --slowest 15
    if [ "$rc" = 0 ] && [ "$lint" != 0 ]; then
        echo "== ruff or mypy found problems (above): the run fails"
        rc=1
    fi
    exit $rc
fi
for tier in "${tiers[@]}"; do
    echo "== pytest: the $tier tier"
    started=$(date +%s.%N)
    rc=0
    pytest -m "$tier" "${xdist[@]}" --junitxml="$reports/$tier.xml" "${args[@]}" || rc=$?
    [ "$rc" = 5 ] && rc=0  # no test was selected
    ended=$(date +%s.%N)
    [ "$rc" != 0 ] && status=$rc
    echo "$tier $started $ended $rc" >> "$reports/walls"
done
python scripts/test_report.py "$reports" --slowest 15
exit $status
