#!/usr/bin/env bash
# Wheel smoke test: build the wheel, install it (with its dependencies, no editable install) into a
# throw-away venv, and run `torquelab check` and one experiment from it, outside the source tree.
# Usage: bash scripts/wheel_smoke.sh   (PYTHON picks the interpreter; pip's cache makes reruns quick)
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$(pwd)
PYTHON=${PYTHON:-python3}
WORK=$(mktemp -d "${TMPDIR:-/tmp}/torquelab-wheel.XXXXXX")
trap 'rm -rf "$WORK"' EXIT

echo "== building the wheel"
"$PYTHON" -m pip wheel -q --disable-pip-version-check --no-deps -w "$WORK/dist" "$ROOT"
WHEEL=$(ls "$WORK"/dist/torquelab-*.whl)
echo "== installing $(basename "$WHEEL") into a throw-away venv"
"$PYTHON" -m venv "$WORK/venv"
"$WORK/venv/bin/python" -m pip install -q --disable-pip-version-check --no-compile "$WHEEL"
cd "$WORK"  # nothing from the source tree on the path
echo "== torquelab check --robot gen3 (from the wheel)"
"$WORK/venv/bin/torquelab" check --robot gen3
echo "== torquelab experiment compliance (from the wheel)"
"$WORK/venv/bin/torquelab" experiment compliance --out "$WORK/compliance"
test -s "$WORK/compliance/report.html"
"$WORK/venv/bin/python" - <<'PY'
import app, pathlib, robots, static
for mod in (app, robots, static):
    path = pathlib.Path(mod.__file__).resolve()
    assert "site-packages" in path.parts, f"{mod.__name__} imported from {path}, not from the wheel"
print("== the wheel runs:", pathlib.Path(app.__file__).parent)
PY
