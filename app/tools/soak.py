"""`torquelab bench --soak MINUTES`: the server's memory over a long run with switches, drags and a browser.

The web app starts as `serve` starts it (the warm-up first: every kernel loaded, the late imports done)
and runs (polish first) with one headless Chromium showing the page; every SWITCH_EVERY_S the
preset switches to the next one, and every DRAG_EVERY_S a drag grabs the last link, pulls it for a
second and lets go (a drag the loop does not answer within `SimLoop.call`'s timeout is skipped and
counted as a late answer). The server process's resident memory (VmRSS) is sampled every SAMPLE_EVERY_S;
the slope is a least-squares line through the samples after the first WARMUP_S (imports, caches and
the first compiles settle there), in MB per minute; the slope over the run's second half beside it
tells growth that levels off (a cache filling as each preset is met again) from growth that does not.
Not part of the test suite: it takes minutes.

Beside RSS each sample has, to tell where memory grows: its anonymous and file-backed parts, the
thread count, glibc's heap in use and kept free over all its arenas (mallinfo2), and the browser's
RSS over all its processes; each gets a slope too. `--no-switches`, `--no-drags` and `--no-browser`
leave a part out, `--trim-every S` also hands the free heap back every S seconds, `--pages N` opens N
browsers on the page, and `--junk` adds a client that sends junk (`junk_client`): every JUNK_EVERY_S a
new connection with a few malformed frames of each kind, and every JUNK_FLOOD_EVERY_S a flood that gets
its connection dropped. The junk client runs in a process of its own: its connections' threads and
buffers are not the server's memory (in the server's process they were counted as its growth).

The bench fails (exit 1) when the slope after the first minute is MAX_SLOPE_MB_PER_MIN or more.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import multiprocessing
import os
import time
from typing import Any

import msgspec
import numpy as np
import viser
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect
from websockets.typing import Subprotocol

from app.core.commands import DragCommand, SwitchSession
from app.live.memory import cap_arenas, fix_mmap_threshold, heap_mb, trim_heap
from app.live.server import start_app
from app.live.warmup import warm_up
from app.scenarios import SCENARIOS
from app.tools.bench_serve import headless_chromium

SWITCH_EVERY_S = 20.0
DRAG_EVERY_S = 5.0
SAMPLE_EVERY_S = 5.0
WARMUP_S = 60.0
MAX_SLOPE_MB_PER_MIN = 0.1  # the promise: the server's RSS grows less than this after the first WARMUP_S
DRAG_CLIENT = -7  # a client id no page has: the soak's own drags
JUNK_EVERY_S = 2.0  # the junk client opens a connection with a few malformed frames this often
JUNK_FLOOD_EVERY_S = 30.0  # and floods one this often (its connection is dropped)
JUNK_FRAMES: tuple[str | bytes, ...] = (
    "a text frame",
    b"\xc1\xc1 not msgpack",
    msgspec.msgpack.encode({"type": "NoSuchMessage", "x": 1}),
    msgspec.msgpack.encode({"type": "ViewerCameraMessage", "wxyz": "junk"}),
)


def junk_client(url: str, stop: Any, sent: Any) -> None:
    """Until `stop` (an Event) is set: every JUNK_EVERY_S a websocket to `url` sends each of JUNK_FRAMES once
    and closes; every JUNK_FLOOD_EVERY_S one sends 30 malformed frames (its connection is dropped).
    `sent.value` (a shared integer) counts frames. The soak runs it in a process of its own."""
    ws_url = url.replace("http://", "ws://")
    next_flood = time.monotonic() + JUNK_FLOOD_EVERY_S
    while not stop.wait(JUNK_EVERY_S):
        flood = time.monotonic() >= next_flood
        frames = [JUNK_FRAMES[1]] * 30 if flood else list(JUNK_FRAMES)
        if flood:
            next_flood += JUNK_FLOOD_EVERY_S
        try:
            with connect(ws_url, subprotocols=[Subprotocol(f"viser-v{viser.__version__}")], open_timeout=10) as ws:
                for frame in frames:
                    ws.send(frame)
                    sent.value += 1
        except (ConnectionClosed, OSError, TimeoutError):  # dropped for its junk, or the server busy
            pass


def rss_mb() -> float:
    """This process's resident memory (MB), from /proc (0 where there is none)."""
    return proc_status().get("VmRSS", 0.0)


def proc_status(pid: int | str = "self") -> dict[str, float]:
    """A process's memory lines of /proc/PID/status in MB (VmRSS, RssAnon, RssFile, ...) and its
    thread count ("Threads"); empty where there is no /proc."""
    out: dict[str, float] = {}
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                key, _, value = line.partition(":")
                parts = value.split()
                if key == "Threads":
                    out[key] = float(parts[0])
                elif len(parts) == 2 and parts[1] == "kB":
                    out[key] = int(parts[0]) / 1024.0
    except OSError:
        pass
    return out


def slope_mb_per_min(t_s: np.ndarray, mb: np.ndarray) -> float:
    """Least-squares slope of memory over time, MB per minute (NaN with fewer than three samples)."""
    if len(t_s) < 3:
        return float("nan")
    return float(np.polyfit(t_s / 60.0, mb, 1)[0])


def late_slope_mb_per_min(t_s: np.ndarray, mb: np.ndarray) -> float:
    """The slope (MB/min) over the second half of the run's duration only (NaN with fewer than three
    samples there)."""
    if len(t_s) == 0:
        return float("nan")
    late = t_s >= t_s[0] + 0.5 * (t_s[-1] - t_s[0])
    return slope_mb_per_min(t_s[late], mb[late])


def _group_rss_mb(pgid: int) -> float:
    """Resident memory (MB) summed over the processes of a process group (Chromium and its helpers)."""
    total = 0.0
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat") as f:
                fields = f.read().rpartition(")")[2].split()
        except OSError:
            continue
        if int(fields[2]) == pgid:  # the process group (after state and ppid)
            total += proc_status(entry).get("VmRSS", 0.0)
    return total


def _sample(t_s: float, browser_pgids: list[int]) -> dict[str, float]:
    """One sample: the server's RSS split into anonymous and file-backed memory, its threads, glibc's
    heap in use and kept free, and the browsers' RSS over all their processes."""
    status = proc_status()
    row = {
        "t": round(t_s, 1),
        "rss": status.get("VmRSS", 0.0),
        "anon": status.get("RssAnon", 0.0),
        "file": status.get("RssFile", 0.0),
        "threads": status.get("Threads", 0.0),
        **heap_mb(),
    }
    if browser_pgids:
        row["browser"] = sum(_group_rss_mb(pgid) for pgid in browser_pgids)
    return {k: round(v, 2) for k, v in row.items()}


def run_soak(
    minutes: float,
    browser: bool = True,
    progress: bool = True,
    switches: bool = True,
    drags: bool = True,
    trim_every_s: float = 0.0,
    pages: int = 1,
    junk: bool = False,
) -> dict[str, Any]:
    """Run the soak (see the module docstring); the samples, counts and slopes. `switches` / `drags` /
    `browser` False leave that part out; `trim_every_s` > 0 also trims the heap that often; `pages`
    browsers show the page; `junk` adds the junk client."""
    fix_mmap_threshold()  # as `serve` does, before the warm-up
    cap_arenas()
    warm_up(None, progress=print if progress else lambda line: None)
    app = start_app(port=0, scenario="polish", running=True)
    junk_guard, collector = app.junk_guard, app.collector
    names = list(SCENARIOS)
    samples: list[dict[str, float]] = []
    n_switches = n_drags = late = 0
    t0 = time.monotonic()
    end = t0 + 60.0 * minutes
    never = float("inf")
    next_switch = t0 + SWITCH_EVERY_S if switches else never
    next_drag = t0 + DRAG_EVERY_S if drags else never
    next_trim = t0 + trim_every_s if trim_every_s > 0 else never
    next_sample = t0
    spawn = multiprocessing.get_context("spawn")  # a fresh interpreter: no copy of the server's threads
    stop_junk = spawn.Event()
    junk_sent = spawn.Value("q", 0)
    try:
        browsers = contextlib.ExitStack()
        procs = [browsers.enter_context(headless_chromium(app.url)) for _ in range(pages if browser else 0)]
        junk_process = spawn.Process(target=junk_client, args=(app.url, stop_junk, junk_sent), daemon=True)
        if junk:
            junk_process.start()
        try:
            while (now := time.monotonic()) < end:
                if now >= next_sample:
                    samples.append(_sample(now - t0, [p.pid for p in procs]))
                    next_sample += SAMPLE_EVERY_S
                    if progress:
                        print("soak: " + "  ".join(f"{k} {v:g}" for k, v in samples[-1].items()), flush=True)
                if now >= next_switch:
                    n_switches += 1
                    app.loop.submit(SwitchSession(scenario=names[n_switches % len(names)]))
                    next_switch += SWITCH_EVERY_S
                if now >= next_drag:
                    try:
                        _drag(app)
                        n_drags += 1
                    except TimeoutError:  # the loop answered late (a switch on a loaded machine): counted
                        late += 1
                    next_drag += DRAG_EVERY_S
                if now >= next_trim:
                    trim_heap()
                    next_trim += trim_every_s
                if not app.loop.alive:
                    raise RuntimeError(f"the simulation loop stopped: {app.loop.failure}")
                time.sleep(0.2)
        finally:
            stop_junk.set()
            if junk:
                junk_process.join(30.0)
                if junk_process.is_alive():
                    junk_process.kill()
                    junk_process.join()
            browsers.close()
    finally:
        app.stop()
    t = np.array([s["t"] for s in samples])
    after = t >= WARMUP_S
    columns = [k for k in samples[0] if k != "t" and all(k in s for s in samples)] if samples else []
    slopes = {k: slope_mb_per_min(t[after], np.array([s[k] for s in samples])[after]) for k in columns}
    mb = np.array([s["rss"] for s in samples])
    return {
        "minutes": minutes,
        "browser": browser,
        "pages": pages if browser else 0,
        "junk_frames_sent": int(junk_sent.value),
        "junk_received": junk_guard.log.received if junk_guard is not None else 0,
        "junk_log_lines": junk_guard.log.lines if junk_guard is not None else 0,
        "junk_connections_dropped": junk_guard.dropped if junk_guard is not None else 0,
        "collections_after_close": collector.passes if collector is not None else 0,
        "objects_collected_after_close": collector.collected if collector is not None else 0,
        "switches": n_switches,
        "drags": n_drags,
        "late_answers": late,
        "trim_every_s": trim_every_s,
        "malloc_arena_max": os.environ.get("MALLOC_ARENA_MAX", ""),
        "samples": len(samples),
        "rss_start_mb": float(mb[0]) if len(mb) else float("nan"),
        "rss_end_mb": float(mb[-1]) if len(mb) else float("nan"),
        "slope_mb_per_min": slopes.get("rss", float("nan")),
        "max_slope_mb_per_min": MAX_SLOPE_MB_PER_MIN,
        "slope_all_mb_per_min": slope_mb_per_min(t, mb),
        "slope_second_half_mb_per_min": late_slope_mb_per_min(t, mb),
        "slopes_per_min": slopes,
        "warmup_s": WARMUP_S,
        "series": samples,
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
    report = run_soak(
        args.soak,
        browser=not getattr(args, "no_browser", False),
        progress=not args.json,
        switches=not getattr(args, "no_switches", False),
        drags=not getattr(args, "no_drags", False),
        trim_every_s=getattr(args, "trim_every", 0.0) or 0.0,
        pages=getattr(args, "pages", 1) or 1,
        junk=getattr(args, "junk", False),
    )
    slope = report["slope_mb_per_min"]
    held = bool(slope < MAX_SLOPE_MB_PER_MIN)  # NaN (too short a run) does not hold
    report["promise_held"] = held
    if args.json:
        print(json.dumps(report, indent=2))
    else:
        others = ", ".join(f"{k} {v:+.3f}" for k, v in report["slopes_per_min"].items() if k != "rss")
        print(
            f"soak {report['minutes']:g} min, {report['switches']} switches, {report['drags']} drags "
            f"({report['late_answers']} late), "
            f"{report['pages']} page(s), junk client {'on' if report['junk_frames_sent'] else 'off'} "
            f"({report['junk_frames_sent']} frames sent, {report['junk_received']} counted in "
            f"{report['junk_log_lines']} log lines, {report['junk_connections_dropped']} connections dropped; "
            f"{report['collections_after_close']} collections after a connection closed found "
            f"{report['objects_collected_after_close']} objects): "
            f"RSS {report['rss_start_mb']:.1f} → "
            f"{report['rss_end_mb']:.1f} MB, slope {report['slope_mb_per_min']:+.3f} MB/min after the first "
            f"{report['warmup_s']:g} s ({report['slope_all_mb_per_min']:+.3f} over the whole run, "
            f"{report['slope_second_half_mb_per_min']:+.3f} over its second half); "
            f"per minute after it: {others}"
        )
        print(
            f"soak: the promise (< {MAX_SLOPE_MB_PER_MIN:g} MB/min after the first {WARMUP_S:g} s) "
            f"{'held' if held else 'NOT held'}: {slope:+.3f} MB/min"
        )
    return 0 if held else 1
