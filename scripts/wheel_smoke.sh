#!/usr/bin/env bash
# Wheel smoke test: build the wheel, install it (with its dependencies, no editable install) into a
# throw-away venv, and run `torquelab check`, one experiment and a cold first start of `serve` (an empty
# numba cache: the seconds to the URL and to the arm's first step are printed) from it, outside the source tree.
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
echo "== a cold first start: torquelab serve on an empty numba cache (the URL, then the arm's first step)"
NUMBA_CACHE_DIR="$WORK/numba-cache" "$VENV/bin/python" - "$VENV/bin/torquelab" <<'PY'
import os, signal, subprocess, sys, time
t0 = time.monotonic()
proc = subprocess.Popen([sys.argv[1], "serve", "--port", "0"], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
seen = {}
try:
    for line in proc.stdout:
        now = time.monotonic() - t0
        print(f"== {now:6.1f} s  {line.rstrip()}", flush=True)
        for key, words in (("url", "open http://"), ("ready", "kernels ready in"), ("step", "the arm is running")):
            if words in line and key not in seen:
                seen[key] = now
        if "the arm" in line or "error" in line:  # running, or not within serve's 120 s
            break
finally:
    stop = time.monotonic()
    # SIGTERM, not Ctrl-C's SIGINT: a job a non-interactive shell starts in the background (as a CI runner
    # may start this script) ignores SIGINT, and so does every process it starts; serve stops on either
    proc.send_signal(signal.SIGTERM)
    try:  # its output read to the end meanwhile (a full pipe would hold the process)
        rest, _ = proc.communicate(timeout=60)
        print(f"== serve stopped {time.monotonic() - stop:.1f} s after SIGTERM (exit code {proc.returncode})", flush=True)
    except subprocess.TimeoutExpired:
        proc.kill()
        rest, _ = proc.communicate()
        print("== serve did not stop within 60 s of SIGTERM; killed. Its last output:", flush=True)
        print("\n".join(rest.splitlines()[-20:]), flush=True)
load = open("/proc/loadavg").read().split()[0] if os.path.exists("/proc/loadavg") else "?"
assert {"url", "ready", "step"} <= set(seen) and seen["url"] < seen["ready"] < seen["step"], seen
print(f"== cold first start: URL after {seen['url']:.1f} s, the arm's first step after {seen['step']:.1f} s "
      f"(kernels ready at {seen['ready']:.1f} s; load average {load}, {os.cpu_count()} cores)")
PY
"$VENV/bin/python" - <<'PY'
import app, pathlib, robots, static
for mod in (app, robots, static):
    path = pathlib.Path(mod.__file__).resolve()
    assert "site-packages" in path.parts, f"{mod.__name__} imported from {path}, not from the wheel"
print("== the wheel runs:", pathlib.Path(app.__file__).parent)
PY
