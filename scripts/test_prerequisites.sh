#!/usr/bin/env bash
# What the test suite needs from the system, beyond .venv: ./run test calls this (and so does CI, through
# ./run test). Silent when everything is there. Otherwise it installs the missing Debian packages with
# apt-get when it can (as root, or through sudo without a password; never reading stdin), or says what is
# missing and the command that installs it. Without them the tests that need them skip, naming what they
# miss; with CI=true they would fail, so this exits 1 first.
#
#   scripts/test_prerequisites.sh [PYTHON]    PYTHON: the suite's interpreter (default .venv/bin/python)
#
# The needs (Debian package: what for):
#   chromium      the browser tests (tests/e2e) drive it through Playwright; nothing is downloaded
#                 (EIGENSCOPE_TEST_CHROMIUM names another build)
#   libusb-1.0-0  pyrealsense2 (a dev dependency where it installs) loads it for the RealSense tests
#   nodejs, npm   the spec lint and TypeScript checks (tests/contract/test_spec_tools.py)
set -euo pipefail

python=${1:-.venv/bin/python}

has_chromium() {
    if [ -n "${EIGENSCOPE_TEST_CHROMIUM:-}" ]; then
        [ -f "$EIGENSCOPE_TEST_CHROMIUM" ]
    else
        [ -f /usr/bin/chromium ] || command -v chromium >/dev/null 2>&1
    fi
}

needs_libusb() {
    "$python" -c 'import importlib.util, sys; sys.exit(importlib.util.find_spec("pyrealsense2") is None)' \
        2>/dev/null
}

has_libusb() {
    # ldconfig lives in /sbin, which a user's PATH often lacks.
    local ldconfig
    ldconfig=$(command -v ldconfig || echo /sbin/ldconfig)
    "$ldconfig" -p 2>/dev/null | grep -q 'libusb-1\.0\.so\.0'
}

missing=()
why=()
if ! has_chromium; then
    missing+=(chromium)
    why+=("chromium (the browser tests)")
fi
if needs_libusb && ! has_libusb; then
    missing+=(libusb-1.0-0)
    why+=("libusb-1.0-0 (pyrealsense2, the RealSense tests)")
fi
if ! command -v npm >/dev/null 2>&1; then
    command -v node >/dev/null 2>&1 || missing+=(nodejs)
    missing+=(npm)
    why+=("node and npm (the spec lint and TypeScript checks)")
fi
[ ${#missing[@]} -eq 0 ] && exit 0

as_root=()
if [ "$(id -u)" != 0 ]; then
    as_root=(sudo -n)
fi
if command -v apt-get >/dev/null 2>&1 && { [ ${#as_root[@]} -eq 0 ] || sudo -n true 2>/dev/null; }; then
    echo "== installing ${missing[*]} (apt-get) for the tests"
    log=$(mktemp)
    if { "${as_root[@]}" env DEBIAN_FRONTEND=noninteractive apt-get update -qq \
        && "${as_root[@]}" env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${missing[@]}"; } \
        </dev/null >"$log" 2>&1; then
        rm -f "$log"
        exit 0
    fi
    tail -n 30 "$log" >&2
    rm -f "$log"
    echo "test_prerequisites: apt-get could not install ${missing[*]}" >&2
fi
joined=$(printf '%s, ' "${why[@]}")
echo "missing for the tests: ${joined%, }" >&2
echo "install with: sudo apt-get install -y ${missing[*]}" >&2
case "${CI:-}" in
    1 | true | yes)
        echo "(CI=true: the tests that need them would fail)" >&2
        exit 1
        ;;
esac
echo "(until then the tests that need them are skipped, each naming what it misses)" >&2
exit 0
