"""How often the machine itself stalls a waiting thread: `python -m app.tools.stall_probe SECONDS [NICENESS]`.

A process of its own (no interpreter shared with the app) sleeps 1 ms at a time for SECONDS and
prints, as JSON, how often and how long its wake-ups came late. `torquelab bench --serve` runs it
beside the app, in the app's session, at the loop thread's niceness: what it meets, any thread of
the server meets from the rest of the machine (other sessions such as the browser, the host), so a
frame the loop misses while the probe was stalled too was not lost to the app's own work.

`python -m app.tools.stall_probe SECONDS NICENESS --stream MS` prints instead, as it happens, one
line "START END" (CLOCK_MONOTONIC seconds, the clock `time.monotonic` reads in every process) per
wake-up later than MS milliseconds (`stream_stalls`): a test that times a loop's gaps subtracts the
spans the machine stalled the probe too.
"""

from __future__ import annotations

import json
import sys
import time
from typing import TextIO

from app.live.priority import set_process_niceness

SLEEP_S = 1e-3


def probe(seconds: float, frame_period_s: float = 1.0 / 30.0) -> dict[str, float]:
    """Sleep SLEEP_S at a time for `seconds`; statistics of the oversleep (wake-up delay)."""
    delays = []
    end = time.perf_counter() + seconds
    while (t0 := time.perf_counter()) < end:
        time.sleep(SLEEP_S)
        delays.append(time.perf_counter() - t0 - SLEEP_S)
    delays.sort()
    n = len(delays)
    long = [d for d in delays if d > frame_period_s]
    return {
        "seconds": seconds,
        "wakeups": n,
        "delay_p99_ms": 1e3 * delays[min(n - 1, int(0.99 * n))] if n else float("nan"),
        "delay_max_ms": 1e3 * delays[-1] if n else float("nan"),
        "stalls_over_10ms": sum(d > 0.010 for d in delays),
        "stalls_over_frame_period": len(long),
        "stalled_s_over_frame_period": sum(long),
    }


def stream_stalls(seconds: float, over_s: float, out: TextIO) -> int:
    """Sleep SLEEP_S at a time for `seconds`; write "START END" (monotonic s, from when the wake-up was
    due to when it came) for every wake-up later than `over_s`, flushed at once; how many."""
    count = 0
    end = time.monotonic() + seconds
    while (t0 := time.monotonic()) < end:
        time.sleep(SLEEP_S)
        t1 = time.monotonic()
        if t1 - t0 - SLEEP_S > over_s:
            out.write(f"{t0 + SLEEP_S:.6f} {t1:.6f}\n")
            out.flush()
            count += 1
    return count


def main(argv: list[str]) -> int:
    """Entry point: SECONDS [NICENESS] [--stream MS]; prints the JSON report, or with --stream the
    stalls longer than MS as they happen."""
    stream = None
    if "--stream" in argv:
        i = argv.index("--stream")
        stream, argv = float(argv[i + 1]) * 1e-3, argv[:i] + argv[i + 2 :]
    seconds = float(argv[0])
    niceness = set_process_niceness(int(argv[1])) if len(argv) > 1 else None
    if stream is not None:
        stream_stalls(seconds, stream, sys.stdout)
        return 0
    print(json.dumps({**probe(seconds), "niceness": niceness}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
