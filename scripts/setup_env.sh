#!/usr/bin/env bash
# Idempotent set-up: system library for open3d (and with --tests a headless browser), then .venv/
# in the repository root with the package.
set -euo pipefail
cd "$(dirname "$0")/.."

if ! ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0'; then
    if [ "$(id -u)" -eq 0 ] && command -v apt-get >/dev/null; then
        echo "setup: installing libusb-1.0-0 (open3d needs it) with apt-get"
        apt-get install -y -q libusb-1.0-0 >/dev/null 2>&1 \
            || { apt-get update -q >/dev/null && apt-get install -y -q libusb-1.0-0 >/dev/null; }
    else
        echo "setup: open3d needs the system library libusb-1.0-0; install it, e.g." >&2
        echo "       sudo apt-get install libusb-1.0-0" >&2
        exit 1
    fi
fi

# --tests (make test): also the headless browser the model-page tests draw WebGL in. Only then:
# it is a large package that `make scan` does not need. Without it those tests are skipped.
if [ "${1:-}" = "--tests" ] && ! command -v chromium >/dev/null; then
    if [ "$(id -u)" -eq 0 ] && command -v apt-get >/dev/null; then
        echo "setup: installing chromium (the browser tests of model.html) with apt-get"
        apt-get install -y -q chromium >/dev/null 2>&1 \
            || { apt-get update -q >/dev/null && apt-get install -y -q chromium >/dev/null; } \
            || echo "setup: chromium could not be installed; the browser tests will be skipped" >&2
    else
        echo "setup: no chromium: the browser tests of model.html will be skipped" \
            "(install it, e.g. sudo apt-get install chromium)" >&2
    fi
fi

PYTHON="${PYTHON:-python3.11}"
command -v "$PYTHON" >/dev/null || PYTHON=python3
if ! "$PYTHON" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))'; then
    echo "setup: Python 3.11 is required (drake 1.51 wheels); found $("$PYTHON" --version 2>&1)" >&2
    exit 1
fi

if [ ! -x .venv/bin/python ]; then
    echo "setup: creating .venv/"
    "$PYTHON" -m venv .venv
fi
stamp=.venv/.installed
# Exactly the versions CI tested (requirements.lock, with hashes); pyproject.toml keeps the ranges
# for people who install the package into an environment of their own.
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ] || [ requirements.lock -nt "$stamp" ]; then
    echo "setup: installing scanner and its locked dependencies into .venv/"
    # Build back-end chatter goes to a log; it is shown only when the install fails.
    if ! { .venv/bin/python -m pip install -q --upgrade pip \
           && .venv/bin/python -m pip install -q --require-hashes --no-deps -r requirements.lock \
           && .venv/bin/python -m pip install -q --no-deps -e . \
           && .venv/bin/python -m pip check; } > .venv/install.log 2>&1; then
        cat .venv/install.log >&2
        echo "setup: installing into .venv/ failed (log above, also in .venv/install.log)" >&2
        exit 1
    fi
    touch "$stamp"
fi
