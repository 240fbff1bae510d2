#!/usr/bin/env bash
# The test command: bash scripts/test.sh [pytest args]
# Creates or reuses .venv, installs torquelab with its test extras, makes sure a Chromium is
# available for the browser tests, then runs ruff, mypy, the import contracts, the documentation build
# (mkdocs.yml, docs/), pytest and the wheel smoke test
# (scripts/wheel_smoke.sh: the built wheel installed in a throw-away venv; only without pytest
# arguments). Exits non-zero on any failure. pytest runs on TORQUELAB_TEST_WORKERS processes
# (pytest-xdist, default 2: the machine's two cores; a module's tests stay on one worker, so its
# module fixtures start once; `-n 0` among the pytest arguments runs them in this process). The full
# run takes the browser tests (`-m browser`: the page in a software-WebGL Chromium, timed against the
# 1 kHz loop) and the loop's wall-clock tests (`-m alone`) on their own afterwards, with the machine
# to themselves as the other tests are not.
set -euo pipefail
cd "$(dirname "$0")/.."

PYTHON=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
    echo "== creating .venv"
    "$PYTHON" -m venv .venv
fi
echo "== installing torquelab[test,robots,docs] into .venv"
# through the venv's real path: pip writes the interpreter it runs under into the first line of the
# scripts it installs (mypy, lint-imports, ...), and .venv may be a link (.ci/run's kept venv) made in
# a checkout that is gone by the next run
"$(cd .venv && pwd -P)/bin/python" -m pip install -q --disable-pip-version-check -e '.[test,robots,docs]'

find_chromium() {
    for c in "${TORQUELAB_CHROMIUM:-}" /usr/bin/chromium /usr/bin/chromium-browser /usr/bin/google-chrome; do
        if [ -n "$c" ] && [ -x "$c" ]; then echo "$c"; return 0; fi
    done
    return 1
}
if ! CHROMIUM=$(find_chromium); then
    if [ "$(id -u)" = "0" ] && command -v apt-get >/dev/null 2>&1; then
        echo "== installing Debian's chromium for the browser tests"
        apt-get update -qq
        DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null
        CHROMIUM=$(find_chromium) || { echo "error: chromium install failed" >&2; exit 1; }
    else
        echo "error: no Chromium found for the browser tests. Install one (Debian: sudo apt-get install chromium)" >&2
        echo "       or point TORQUELAB_CHROMIUM at a Chromium/Chrome binary." >&2
        exit 1
    fi
fi
export TORQUELAB_CHROMIUM="$CHROMIUM"
echo "== chromium: $CHROMIUM"

echo "== ruff"
.venv/bin/ruff check .
.venv/bin/ruff format --check .
echo "== mypy"
.venv/bin/mypy
echo "== import contracts (docs/architecture.md)"
.venv/bin/lint-imports
echo "== docs (mkdocs build --strict: warnings, broken links and anchors fail it)"
NO_MKDOCS_2_WARNING=1 .venv/bin/mkdocs build --strict
echo "== pytest"
mkdir -p test-artifacts
PARALLEL=(-n "${TORQUELAB_TEST_WORKERS:-2}" --dist loadfile --no-loadscope-reorder)
if [ "$#" -gt 0 ]; then  # a subset: as given; the wheel is not built
    .venv/bin/python -m pytest "${PARALLEL[@]}" --durations=30 "$@"
    exit 0
fi
.venv/bin/python -m pytest "${PARALLEL[@]}" --durations=30 -m "not browser and not alone"
echo "== pytest: the tests timed against the wall clock (loop, workers, the page), alone"
.venv/bin/python -m pytest --durations=15 -m "browser or alone"
echo "== wheel smoke test"
bash scripts/wheel_smoke.sh
