#!/usr/bin/env bash
# Set up and run the whole test suite on a fresh machine: the system packages the viewer tests need
# (Mesa's software Vulkan driver for headless screenshots, Chromium for the web viewer, Xvfb as a
# display for the native viewer), a virtual environment, the lint, format and type checks, then
# pytest (its arguments are this script's) in two passes.
set -euo pipefail
cd "$(dirname "$0")/.."
if command -v apt-get >/dev/null && command -v dpkg >/dev/null; then
    missing=()
    for package in libvulkan1 mesa-vulkan-drivers chromium xvfb; do
        dpkg -s "$package" >/dev/null 2>&1 || missing+=("$package")
    done
    if [ ${#missing[@]} -gt 0 ]; then
        sudo=""
        [ "$(id -u)" -ne 0 ] && sudo="sudo"
        $sudo apt-get update -qq
        DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq "${missing[@]}" >/dev/null
    fi
fi
python3 -m venv .venv
.venv/bin/pip install -q -e '.[test]'
.venv/bin/ruff check .
.venv/bin/ruff format --check .
.venv/bin/pyright
# Two passes: the tests that a loaded machine cannot upset on every core (pytest-xdist, each test
# given to the next free worker), then alone the realtime ones (wall-clock timing) and the viewer
# ones (a software renderer's timeouts). Exit status 5 (no test selected, as when the arguments
# name only tests of the other pass) is not a failure.
pytest() { .venv/bin/python -m pytest "$@" || [ $? -eq 5 ]; }
pytest -n auto --dist worksteal -m "not (realtime or viewer)" "$@"
pytest -m "realtime or viewer" "$@"
