"""Memory a preset switch frees goes back to the system (`app.live.memory`)."""

from __future__ import annotations

import sys

import pytest

from app.live.memory import trim_heap, trim_heap_soon
from app.tools.soak import rss_mb


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's malloc_trim")
def test_a_trim_returns_what_many_freed_small_blocks_left_in_the_allocator():
    trim_heap()
    base = rss_mb()
    blocks = [bytearray(2000) for _ in range(60_000)]  # ~120 MB of small blocks (the arena, not mmap)
    blocks = blocks[::50]  # 98 % freed in runs of ~100 kB, the rest pins the arena: free() keeps it all
    held = rss_mb()
    assert trim_heap()
    trimmed = rss_mb()
    del blocks
    assert held - base > 80.0, (base, held)
    assert held - trimmed > 30.0, f"RSS {base:.0f} → {held:.0f} → {trimmed:.0f} MB after the trim"


def test_a_trim_runs_in_a_thread_of_its_own():
    thread = trim_heap_soon()
    thread.join(timeout=10.0)
    assert not thread.is_alive() and thread.name == "torquelab-trim"


def test_the_loop_trims_after_a_switch_and_not_after_other_commands(monkeypatch):
    from app.core.commands import Pause, SwitchSession
    from app.live import loop as loop_module

    calls: list[int] = []
    monkeypatch.setattr(loop_module, "trim_heap_soon", lambda: calls.append(1))
    lp = loop_module.SimLoop("free", capture=lambda s: None)
    lp._apply(Pause())
    assert calls == []
    lp._apply(SwitchSession(scenario="compliance"))
    assert calls == [1] and lp.lab.session.scenario.name == "compliance"


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="/proc and glibc's mallinfo2")
def test_the_soaks_columns_see_an_allocation_in_the_heap_and_the_resident_anonymous_memory():
    from app.live.memory import heap_mb
    from app.tools.soak import proc_status

    before, heap_before = proc_status(), heap_mb()
    block = bytearray(64 * 2**20)  # 64 MB, zeroed: resident and anonymous, in glibc's heap (mmapped)
    after, heap_after = proc_status(), heap_mb()
    del block
    assert after["Threads"] >= 1 and after["VmRSS"] > 0
    assert after["RssAnon"] - before["RssAnon"] > 50.0, (before["RssAnon"], after["RssAnon"])
    assert heap_after["heap_used"] - heap_before["heap_used"] > 60.0, (heap_before, heap_after)
