"""The loop thread does only steps and ready commands: a settings file is parsed and checked elsewhere."""

from __future__ import annotations

import subprocess
import sys
import threading
import time

import pytest

from app.live.loop import LOOP_NICENESS, SimLoop
from app.live.settings_io import load_settings_text
from tests.test_faults_workers import PROBE_OVER_MS, _effective_gaps

# the loop's gaps are timed against the wall clock: the module runs alone (the `alone` marker)
pytestmark = [pytest.mark.alone, pytest.mark.usefixtures("warm_kernels")]

MAX_GAP_S = 0.1  # the bound on the loop's longest gap between two steps through a settings upload
SETTINGS_BOUND = 64 * 1024  # the documented size bound of a settings file (bytes)


def unknown_tables(count: int) -> str:
    """A TOML text of `count` tables no session has (15 bytes each: 100,000 of them are 1.5 MB)."""
    return "".join(f"[t{i:05d}]\nx = 1\n" for i in range(count))


def _load_beside_the_running_loop(tmp_path, text: str) -> dict:
    """`load_settings_text` from another thread (as the page's upload callback runs) while the loop runs
    paced: the refused lines, the longest gap between two steps over the load (raw and less the spans a
    stall probe in another process at the loop's niceness was stalled too, see
    `tests/test_faults_workers.py`) and the loop thread's largest CPU time in one pass over its queue."""
    lp = SimLoop("free", capture=lambda s: None)
    stamps: list[float] = []
    drains: list[float] = []
    advance, drain = lp.lab.advance, lp._drain

    def stamped_advance(n, until=None):
        def stamp(rec):
            stamps.append(time.monotonic())
            return until is not None and until(rec)

        return advance(n, until=stamp)

    def timed_drain():
        t0 = time.thread_time()
        try:
            drain()
        finally:
            drains.append(time.thread_time() - t0)

    log = tmp_path / "stalls.txt"
    probe = subprocess.Popen(
        [sys.executable, "-m", "app.tools.stall_probe", "600", str(LOOP_NICENESS), "--stream", str(PROBE_OVER_MS)],
        stdout=log.open("w"),
    )
    lp.start(running=True)
    out: dict = {}
    try:
        lp.sync(timeout=300.0)
        lp.lab.advance = stamped_advance  # type: ignore[method-assign]
        lp._drain = timed_drain  # type: ignore[method-assign]
        time.sleep(0.3)
        begun = time.monotonic()

        def load() -> None:
            out["refused"] = load_settings_text(lp, text)

        thread = threading.Thread(target=load)
        thread.start()
        thread.join(120.0)
        ended = time.monotonic()
        time.sleep(0.2)
    finally:
        lp.stop()
        probe.terminate()
        probe.wait(timeout=30.0)
    stalls = [(float(a), float(b)) for a, b in (line.split() for line in log.read_text().splitlines())]
    during = [s for s in stamps if begun - 0.05 <= s <= ended + 0.1]
    assert len(during) > 10, "the loop did not step over the load"
    gaps = _effective_gaps(during, stalls)
    out |= {"raw_s": max(g for g, _ in gaps), "effective_s": max(e for _, e in gaps), "drain_cpu_s": max(drains)}
    print(
        f"{len(text) / 1e6:.2f} MB loaded in {ended - begun:.2f} s: {len(out['refused'])} refused; longest gap "
        f"{1e3 * out['raw_s']:.0f} ms raw, {1e3 * out['effective_s']:.0f} ms less machine stalls; the loop "
        f"thread's CPU in one pass over its queue at most {1e3 * out['drain_cpu_s']:.1f} ms"
    )
    return out


@pytest.mark.parametrize("tables", [100_000, SETTINGS_BOUND // 15])
def test_a_settings_upload_of_unknown_tables_leaves_no_100_ms_gap_between_steps(tmp_path, tables):
    """1.5 MB of 100,000 unknown tables (refused whole: over the size bound) and the largest text the bound
    lets through (4,369 unknown tables, each refused): parsed and checked off the loop thread, which
    takes no pass over its queue of more than MAX_GAP_S of CPU and leaves no gap over MAX_GAP_S between
    two steps beyond the machine's own stalls (parsed on the loop thread, the 1.5 MB stopped it for
    over a second)."""
    text = unknown_tables(tables)
    out = _load_beside_the_running_loop(tmp_path, text)
    assert out["drain_cpu_s"] < MAX_GAP_S, f"one pass over the queue took {out['drain_cpu_s']:.3f} s of CPU"
    assert out["effective_s"] < MAX_GAP_S, f"the loop paused {1e3 * out['effective_s']:.0f} ms"
    refused = out["refused"]
    if len(text) > SETTINGS_BOUND:
        assert len(refused) == 1 and "at most 64 kB" in refused[0] and "nothing applied" in refused[0]
    else:
        assert len(refused) == tables and all("no parameter group" in line for line in refused)
