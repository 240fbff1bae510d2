#!/usr/bin/env bash
# Wheel smoke test: build the wheel, install it (with its dependencies, no editable install) into a
# throw-away venv, and run `torquelab check` and one experiment from it, outside the source tree.
# Usage: bash scripts/wheel_smoke.sh   (PYTHON picks the interpreter). With TORQUELAB_SMOKE_VENV set
# (.ci/run sets it, keyed by pyproject.toml) that venv is kept between runs: made and filled by this
# script alone (the wheel and its dependencies, nothing else), a later run replaces the wheel in it
# and installs what `pip check` finds missing.
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$(pwd)
PYTHON=${PYTHON:-python3}
WORK=$(mktemp -d "${TMPDIR:-/tmp}/torquelab-wheel.XXXXXX")
trap 'rm -rf "$WORK"' EXIT

echo "== building the wheel"
"$PYTHON" -m pip wheel -q --disable-pip-version-check --no-deps -w "$WORK/dist" "$ROOT"
WHEEL=$(ls "$WORK"/dist/torquelab-*.whl)
VENV=${TORQUELAB_SMOKE_VENV:-$WORK/venv}
if "$VENV/bin/python" -m pip --version >/dev/null 2>&1; then  # (not one a stopped run left without pip)
    echo "== installing $(basename "$WHEEL") into the kept venv $VENV (its dependencies are there)"
    "$VENV/bin/python" -m pip install -q --disable-pip-version-check --no-compile --force-reinstall --no-deps "$WHEEL"
    if ! "$VENV/bin/python" -m pip check >/dev/null; then  # (a run stopped mid-install): complete it
        "$VENV/bin/python" -m pip install -q --disable-pip-version-check --no-compile "$WHEEL"
    fi
else
    echo "== installing $(basename "$WHEEL") into a fresh venv"
    rm -rf "$VENV"
    "$PYTHON" -m venv "$VENV"
    "$VENV/bin/python" -m pip install -q --disable-pip-version-check --no-compile "$WHEEL"
fi
cd "$WORK"  # nothing from the source tree on the path
echo "== torquelab check --robot gen3 (from the wheel)"
"$VENV/bin/torquelab" check --robot gen3
echo "== torquelab experiment compliance (from the wheel)"
"$VENV/bin/torquelab" experiment compliance --out "$WORK/compliance"
test -s "$WORK/compliance/report.html"
echo "== the first served step comes within seconds of the URL (kernels compiled before it)"
"$VENV/bin/python" - <<'PY'
import time
from app.live.server import start_app
from app.live.warmup import warm_up
took = warm_up(None, lambda line: print("==", line, flush=True))
app = start_app(port=0, scenario="free", running=True)
at_url = time.monotonic()  # where `serve` prints the URL
try:
    while app.loop.sync(timeout=60.0).steps == 0:
        time.sleep(0.01)
    first = time.monotonic() - at_url
finally:
    app.stop()
print(f"== first served step {first:.2f} s after the URL (warm-up {took:.1f} s before it)")
assert first < 5.0, f"the first step came {first:.1f} s after the URL"
PY
"$VENV/bin/python" - <<'PY'
import app, pathlib, robots, static
for mod in (app, robots, static):
    path = pathlib.Path(mod.__file__).resolve()
    assert "site-packages" in path.parts, f"{mod.__name__} imported from {path}, not from the wheel"
print("== the wheel runs:", pathlib.Path(app.__file__).parent)
PY
