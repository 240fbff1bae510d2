"""`torquelab bench --soak MINUTES`: the server's memory over a long run with switches, drags and a browser.

The web app runs (polish first) with one headless Chromium showing the page; every SWITCH_EVERY_S the
preset switches to the next one, and every DRAG_EVERY_S a drag grabs the last link, pulls it for a
second and lets go (a drag the loop does not answer within `SimLoop.call`'s timeout is skipped and
counted as a late answer). The server process's resident memory (VmRSS) is sampled every SAMPLE_EVERY_S;
the slope is a least-squares line through the samples after the first WARMUP_S (imports, caches and
the first compiles settle there), in MB per minute. Not part of the test suite: it takes minutes.
"""

from __future__ import annotations

import argparse
import json
import time
from typing import Any

import numpy as np

from app.core.commands import DragCommand, SwitchSession
from app.live.server import start_app
from app.scenarios import SCENARIOS
from app.tools.bench_serve import headless_chromium

SWITCH_EVERY_S = 20.0
DRAG_EVERY_S = 5.0
SAMPLE_EVERY_S = 5.0
WARMUP_S = 60.0
DRAG_CLIENT = -7  # a client id no page has: the soak's own drags


def rss_mb() -> float:
    """This process's resident memory (MB), from /proc (0 where there is none)."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return 0.0


def slope_mb_per_min(t_s: np.ndarray, mb: np.ndarray) -> float:
    """Least-squares slope of memory over time, MB per minute (NaN with fewer than three samples)."""
    if len(t_s) < 3:
        return float("nan")
    return float(np.polyfit(t_s / 60.0, mb, 1)[0])


def run_soak(minutes: float, browser: bool = True, progress: bool = True) -> dict[str, Any]:
    """Run the soak (see the module docstring); the samples, counts and slopes."""
    app = start_app(port=0, scenario="polish", running=True)
    names = list(SCENARIOS)
    samples: list[tuple[float, float]] = []
    switches = drags = late = 0
    t0 = time.monotonic()
    end = t0 + 60.0 * minutes
    next_switch, next_drag, next_sample = t0 + SWITCH_EVERY_S, t0 + DRAG_EVERY_S, t0
    try:
        ctx = headless_chromium(app.url) if browser else None
        if ctx is not None:
            ctx.__enter__()
        try:
            while (now := time.monotonic()) < end:
                if now >= next_sample:
                    samples.append((now - t0, rss_mb()))
                    next_sample += SAMPLE_EVERY_S
                    if progress:
                        print(f"soak: {now - t0:7.0f} s  {samples[-1][1]:8.1f} MB", flush=True)
                if now >= next_switch:
                    switches += 1
                    app.loop.submit(SwitchSession(scenario=names[switches % len(names)]))
                    next_switch += SWITCH_EVERY_S
                if now >= next_drag:
                    try:
                        _drag(app)
                        drags += 1
                    except TimeoutError:  # the loop answered late (a switch on a loaded machine): counted
                        late += 1
                    next_drag += DRAG_EVERY_S
                if not app.loop.alive:
                    raise RuntimeError(f"the simulation loop stopped: {app.loop.failure}")
                time.sleep(0.2)
        finally:
            if ctx is not None:
                ctx.__exit__(None, None, None)
    finally:
        app.stop()
    t = np.array([s[0] for s in samples])
    mb = np.array([s[1] for s in samples])
    after = t >= WARMUP_S
    return {
        "minutes": minutes,
        "browser": browser,
        "switches": switches,
        "drags": drags,
        "late_answers": late,
        "samples": len(samples),
        "rss_start_mb": float(mb[0]) if len(mb) else float("nan"),
        "rss_end_mb": float(mb[-1]) if len(mb) else float("nan"),
        "slope_mb_per_min": slope_mb_per_min(t[after], mb[after]),
        "slope_all_mb_per_min": slope_mb_per_min(t, mb),
        "warmup_s": WARMUP_S,
        "series": [[round(a, 1), round(b, 2)] for a, b in samples],
    }


def _drag(app: Any) -> None:
    """Grab the last link, pull it 10 cm sideways for a second, let go."""
    link = app.loop.call(lambda s: s.robot.link_names[-1])
    app.loop.submit(DragCommand("grab", DRAG_CLIENT, body_name=link, point_world=(0.4, 0.0, 0.6)))
    for i in range(10):
        app.loop.submit(DragCommand("move", DRAG_CLIENT, body_name=link, target_world=(0.4, 0.01 * i, 0.6)))
        time.sleep(0.1)
    app.loop.submit(DragCommand("release", DRAG_CLIENT, body_name=link))


def cmd_soak(args: argparse.Namespace) -> int:
    """`bench --soak MINUTES`: print the slope (and the samples with --json)."""
    report = run_soak(args.soak, browser=not getattr(args, "no_browser", False), progress=not args.json)
    if args.json:
        print(json.dumps(report, indent=2))
    else:
        print(
            f"soak {report['minutes']:g} min, {report['switches']} switches, {report['drags']} drags "
            f"({report['late_answers']} late), "
            f"browser {'on' if report['browser'] else 'off'}: RSS {report['rss_start_mb']:.1f} → "
            f"{report['rss_end_mb']:.1f} MB, slope {report['slope_mb_per_min']:+.3f} MB/min after the first "
            f"{report['warmup_s']:g} s ({report['slope_all_mb_per_min']:+.3f} over the whole run)"
        )
    return 0
