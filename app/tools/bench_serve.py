"""`torquelab bench --serve`: the app's real-time factor with one headless Chromium client connected.

Starts the app in-process on a free port (polish scenario, projection executor, W_a, every overlay
on, the self-motion preview scanning), opens the page in a headless Chromium of its own (a plain
process, as a person's browser would be: no automation driver forwarding the page's traffic into
this process), waits until the page is connected, then measures for `--seconds` of wall time: the achieved real-time
factor (simulated / wall seconds), its worst 1 s window, the loop's compute share, and how often
the scene and plots were published; and how long a Signals checkbox waits for a frame's redraw
(the plots redraw under one lock), and how long its whole choice takes.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import fields
from typing import Any

import numpy as np

import robots
from app.core.commands import Play, Reset, SetParam, SetTwin
from app.live.loop import LOOP_NICENESS
from app.live.server import start_app

CHROMIUM = os.environ.get("TORQUELAB_CHROMIUM", "/usr/bin/chromium")
WARMUP_TIMEOUT_S = 300.0  # wall seconds the warm-up may take (compiling the kernels included)
CHROMIUM_ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--no-first-run",
    "--disable-sync",
    # render as a foreground tab does, whatever the headless window's state
    "--disable-background-timer-throttling",
    "--disable-renderer-backgrounding",
    "--disable-backgrounding-occluded-windows",
]


def overlays_on(visual_settings: Any) -> list[str]:
    """Switch every boolean overlay toggle on; returns their names."""
    names = [f.name for f in fields(visual_settings) if isinstance(getattr(visual_settings, f.name), bool)]
    visual_settings.update(**dict.fromkeys(names, True))
    return names


@contextmanager
def headless_chromium(url: str, width: int = 1280, height: int = 800) -> Iterator[subprocess.Popen]:
    """Chromium showing `url` headless, in a fresh profile, for the duration of the block."""
    if not os.path.exists(CHROMIUM):
        raise ValueError(f"no Chromium at {CHROMIUM}; set TORQUELAB_CHROMIUM to a Chromium binary")
    # Chromium's helper processes may still be writing the profile as it is removed: not an error
    with tempfile.TemporaryDirectory(prefix="torquelab-chromium-", ignore_cleanup_errors=True) as profile:
        args = [CHROMIUM, "--headless=new", *CHROMIUM_ARGS, f"--user-data-dir={profile}"]
        args += [f"--window-size={width},{height}", url]
        # a session of its own: its helper processes (zygote, GPU, renderers) end with it
        proc = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
        try:
            yield proc
        finally:
            _end_process_group(proc)


def _end_process_group(proc: subprocess.Popen, timeout: float = 10.0) -> None:
    """Terminate a process started in a session of its own and every process of its group (kill
    what is left after `timeout`), and wait until the group is gone (at most `timeout` more)."""
    _signal_group(proc.pid, signal.SIGTERM)
    try:
        proc.wait(timeout)
    except subprocess.TimeoutExpired:
        pass
    _signal_group(proc.pid, signal.SIGKILL)
    proc.wait()
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and _signal_group(proc.pid, 0):
        time.sleep(0.05)


def _signal_group(pgid: int, sig: int) -> bool:
    """Send `sig` to a process group; False when the group has no process left."""
    try:
        os.killpg(pgid, sig)
    except ProcessLookupError:
        return False
    return True


def _start_stall_probe(seconds: float) -> subprocess.Popen:
    """`app.tools.stall_probe` in a process of its own for `seconds`, at the loop thread's niceness."""
    args = [sys.executable, "-m", "app.tools.stall_probe", str(seconds), str(LOOP_NICENESS)]
    return subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)


def _stall_probe_report(proc: subprocess.Popen) -> dict[str, Any]:
    """The probe's JSON report, or {"error": …} when it gave none."""
    try:
        out, _ = proc.communicate(timeout=30.0)
        return json.loads(out)
    except (subprocess.TimeoutExpired, json.JSONDecodeError) as exc:
        proc.kill()
        proc.wait()
        return {"error": f"stall probe gave no report: {exc!r}"}


def _preview_on(app: Any) -> Any:
    """Switch the Nullspace panel's self-motion preview on (a scan a second, ghost arm); returns it."""
    from app.live.ui.panels.nullspace import NullspacePanel

    for panel in app.panels:
        if isinstance(panel, NullspacePanel):
            panel.preview.set_enabled(True)
            return panel.preview
    return None


def _toggle_first_torque(plots: Any) -> float:
    """Hide τ1 in the torque chart if it is drawn, else draw it again, as its checkbox does (the
    chart redrawn at once); returns the seconds that took, waiting for a frame's redraw included."""
    keys = [key for key, _ in plots.signals.specs["torque"]]
    shown = plots.signals.shown("torque", keys[0])
    t0 = time.perf_counter()
    plots.choose_signals("torque", keys[1:] if shown else keys)
    return time.perf_counter() - t0


def _spread_ms(seconds: list[float]) -> dict[str, float]:
    """Median, 99th percentile and largest of `seconds`, in ms (NaN when there are none)."""
    if not seconds:
        return {"median": float("nan"), "p99": float("nan"), "max": float("nan"), "n": 0}
    ms = np.asarray(seconds) * 1e3
    return {"median": float(np.median(ms)), "p99": float(np.percentile(ms, 99)), "max": float(ms.max()), "n": len(ms)}


def run_serve_bench(
    scenario: str = "polish",
    seconds: float = 20.0,
    warmup: float = 3.0,  # simulated seconds run before measuring
    objective: str = "a",
    robot: str | None = None,
    twin: str | None = None,
) -> dict[str, Any]:
    """Measure the real-time factor of the running app with one browser; returns a report dict."""
    app = start_app(port=0, scenario=scenario, robot=robot, running=False)
    try:
        toggles = overlays_on(app.visual_settings) if app.visual_settings is not None else []
        preview = _preview_on(app)
        if "nullspace" in app.loop.settings.groups:
            app.loop.submit(SetParam("nullspace", "objective", objective))
        with headless_chromium(app.url) as browser:
            deadline = time.monotonic() + 60.0
            while not app.server.get_clients() and time.monotonic() < deadline:
                if browser.poll() is not None:
                    raise RuntimeError(f"Chromium exited with code {browser.returncode} before the page connected")
                time.sleep(0.1)
            if not app.server.get_clients():
                raise RuntimeError("the browser did not connect within 60 s")
            if twin is not None:
                app.loop.submit(SetTwin(twin))
            app.loop.submit(Reset())
            app.loop.submit(Play())
            app.loop.sync()
            # warm up for `warmup` simulated seconds, however long the first steps take (a cold numba
            # cache compiles the kernels on the first step: many seconds, during which the loop
            # answers nothing)
            deadline = time.monotonic() + WARMUP_TIMEOUT_S
            while app.loop.sync(timeout=WARMUP_TIMEOUT_S).t < warmup:
                if time.monotonic() > deadline:
                    raise RuntimeError(f"the simulation did not run {warmup} s within {WARMUP_TIMEOUT_S:.0f} s")
                time.sleep(0.2)
            windows = []
            probe = _start_stall_probe(seconds)
            s0 = app.loop.sync()
            w0, frames0, scene0 = time.perf_counter(), app.publisher.frames_shown, app.publisher.scene_updates
            times0 = os.times()
            scans0 = preview.scans if preview is not None else 0
            loads = []
            plots = app.publisher.plots
            redraw_waits: list[float] = []  # s a redraw asked for from this thread waited, about 10 a second
            jitter = random.Random(0)
            signal_choices: list[float] = []  # s to draw τ1 again or not (what a Signals checkbox does), 1 a second
            prev_t, prev_w = s0.t, w0
            while time.perf_counter() - w0 < seconds:
                for _ in range(10):
                    time.sleep(jitter.uniform(0.05, 0.15))  # not in step with the frames (every 33 ms)
                    if plots is not None:
                        redraw_waits.append(plots.redraw_wait_s())
                if plots is not None:
                    signal_choices.append(_toggle_first_torque(plots))
                st = app.loop.sync()
                now = time.perf_counter()
                windows.append((st.t - prev_t) / (now - prev_w))
                loads.append(st.load)
                prev_t, prev_w = st.t, now
            s1 = app.loop.sync()
            wall = time.perf_counter() - w0
            times1 = os.times()
            process_cpu = (times1.user + times1.system) - (times0.user + times0.system)
            frames = app.publisher.frames_shown - frames0
            scenes = app.publisher.scene_updates - scene0
            clients = len(app.server.get_clients())
            stalls = _stall_probe_report(probe)
        return {
            "scenario": scenario,
            "robot": s1.robot,
            "executor": s1.executor,
            "objective": app.loop.settings.values.get("nullspace", {}).get("objective"),
            "overlays_on": toggles,
            "browser_clients": clients,
            "wall_s": wall,
            "sim_s": s1.t - s0.t,
            "real_time_factor": (s1.t - s0.t) / wall,
            "worst_1s_real_time_factor": min(windows) if windows else float("nan"),
            "loop_compute_share": sum(loads) / len(loads) if loads else float("nan"),
            "step_cpu_per_sim_s": (s1.step_cpu_s - s0.step_cpu_s) / max(s1.t - s0.t, 1e-9),
            "server_process_cores": process_cpu / wall,
            "frames_per_s": frames / wall,
            "scene_updates_per_s": scenes / wall,
            "twin": s1.twin,
            "self_motion_scans_per_s": (preview.scans - scans0) / wall if preview is not None else 0.0,
            "halted": s1.halted,
            "plots_redraw_wait_ms": _spread_ms(redraw_waits),
            "plots_signal_choice_ms": _spread_ms(signal_choices),
            "machine_stalls": stalls,
            "cpu_count": os.cpu_count(),
            "load_average_1min": os.getloadavg()[0],
        }
    finally:
        app.stop()


def cmd_bench_serve(args: argparse.Namespace) -> int:
    """Print the serve benchmark; exit 1 if the real-time factor stays below 1.0."""
    report = run_serve_bench(
        scenario=args.scenario,
        seconds=args.seconds,
        robot=robots.spec_from_args(args),
        twin=getattr(args, "twin", None),
    )
    if args.json:
        print(json.dumps(report, indent=2))
    else:
        print(
            f"{report['scenario']} on {report['robot']} with {report['executor']} (W_{report['objective']}), "
            f"{report['browser_clients']} browser, overlays on: {len(report['overlays_on'])}, "
            f"self-motion preview {report['self_motion_scans_per_s']:.1f} scans/s"
            + (f", twin arm W_{report['twin']}" if report["twin"] else "")
        )
        print(f"  real-time factor        {report['real_time_factor']:.3f}  over {report['wall_s']:.1f} s of wall time")
        print(f"  worst 1 s window        {report['worst_1s_real_time_factor']:.3f}")
        print(f"  loop compute share      {100 * report['loop_compute_share']:.0f} % of wall time")
        print(
            f"  CPU per simulated s     {report['step_cpu_per_sim_s']:.2f} s in steps; server process "
            f"{report['server_process_cores']:.2f} cores (real time needs the steps' share below 1)"
        )
        print(
            f"  frames published        {report['frames_per_s']:.1f} /s (scene {report['scene_updates_per_s']:.1f} /s)"
        )
        wait, choice = report["plots_redraw_wait_ms"], report["plots_signal_choice_ms"]
        print(
            f"  plots redraw wait       median {wait['median']:.2f} ms, p99 {wait['p99']:.2f}, max {wait['max']:.2f} "
            f"(a checkbox's redraw waiting for a frame's); a Signals choice takes median {choice['median']:.1f} ms, "
            f"max {choice['max']:.1f}"
        )
        print(f"  machine                 {report['cpu_count']} cores, load average {report['load_average_1min']:.2f}")
        stalls = report["machine_stalls"]
        if "error" in stalls:
            print(f"  machine stalls          {stalls['error']}")
        else:
            print(
                f"  machine stalls          {stalls['stalls_over_frame_period']} wake-ups over a frame period late "
                f"(max {stalls['delay_max_ms']:.0f} ms) in a probe process of the loop's priority, beside the app"
            )
    return 0 if report["real_time_factor"] >= 0.99 and not report["halted"] else 1
