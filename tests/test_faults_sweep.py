"""Sweeps that survive kill -9: a torn last record is cut off (that cell runs again), workers die with their parent."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
import time

from app.headless.sweep.store import CellStore


def test_a_torn_last_record_is_cut_off_on_resume_and_the_next_one_starts_on_its_own_line(tmp_path):
    path = tmp_path / "cells.jsonl"
    good = [{"key": f"k{i}", "status": "ok", "metrics": {"x": i}} for i in range(3)]
    torn = json.dumps({"key": "k3", "status": "ok", "metrics": {"x": 3}})[:25]  # killed mid-write
    path.write_text("".join(json.dumps(r) + "\n" for r in good) + torn)
    store = CellStore(path)
    assert sorted(store.records) == ["k0", "k1", "k2"] and store.torn == len(torn)
    assert not store.finished("k3", retry_failed=False)  # the torn cell runs again
    store.append({"key": "k3", "status": "ok", "metrics": {"x": 3}})
    lines = path.read_text().splitlines()
    assert [json.loads(line)["key"] for line in lines] == ["k0", "k1", "k2", "k3"]  # every line readable
    again = CellStore(path)
    assert sorted(again.records) == ["k0", "k1", "k2", "k3"] and again.torn == 0


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    try:  # a zombie (exited, not reaped by its dead parent's init yet) counts as gone
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(")")[-1].split()[0] != "Z"
    except OSError:
        return True


def test_pool_workers_exit_when_the_sweep_is_killed():
    script = textwrap.dedent(
        """
        import os, signal, sys, time
        from app.headless.sweep.engine import open_executor

        def spin():
            t = time.time()
            while time.time() - t < 600:
                pass

        if __name__ == "__main__":
            with open_executor(None, 2) as (pool, _):
                pids = [pool.submit(os.getpid).result(timeout=120) for _ in range(4)]
                futures = [pool.submit(spin) for _ in range(2)]  # both workers busy
                print(" ".join(str(p) for p in set(pids)), flush=True)
                time.sleep(1.0)
                os.kill(os.getpid(), signal.SIGKILL)
        """
    )
    proc = subprocess.Popen(
        [sys.executable, "-c", script],
        stdout=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONPATH": os.getcwd()},
    )
    out, _ = proc.communicate(timeout=300)
    workers = [int(p) for p in out.split()]
    assert workers and proc.returncode == -9
    deadline = time.monotonic() + 10.0
    while any(_alive(p) for p in workers) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not any(_alive(p) for p in workers), "a pool worker outlived the killed sweep"
