"""Run a function in a forked copy of this process and get its result back.

A fork is a copy-on-write snapshot of everything the process holds: a simulation stepped to some
state (MuJoCo's data, the controller's filters and integrators, the sensor's noise generator, the
delay lines) continues in the copy exactly as it would have here, while the original stays at that
state for the next copy. The sweeps use it to run many cells from one settled posture
(`app.headless.experiments.polish_map`). The copy ends with its parent (`engine.die_with_parent`); its
CPU time is the parent's children's time (`children_cpu_s`), which `runner.run_cell` adds to the cell.
"""

from __future__ import annotations

import os
import pickle
import resource
import traceback
from collections.abc import Callable
from typing import Any

from app.headless.sweep.engine import die_with_parent


class ForkedError(RuntimeError):
    """The function raised in the copy (its one-line message), or the copy died without an answer."""


def can_fork() -> bool:
    """True where the process can fork (not on Windows)."""
    return hasattr(os, "fork")


def children_cpu_s() -> float:
    """User + system CPU seconds of this process's children that have been waited for."""
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return float(usage.ru_utime + usage.ru_stime)


def call_forked(fn: Callable[..., Any], *args: Any) -> Any:
    """fn(*args) in a forked copy of this process; its (picklable) result, or ForkedError with the
    copy's exception in one line. Nothing fn changes reaches this process."""
    parent = os.getpid()
    read_fd, write_fd = os.pipe()
    pid = os.fork()
    if pid == 0:  # the copy: answer through the pipe, then leave without running the parent's exit code
        code = 0
        try:
            os.close(read_fd)
            die_with_parent(parent)
            try:
                payload = pickle.dumps(("ok", fn(*args)))
            except Exception as exc:
                line = traceback.format_exception_only(type(exc), exc)[-1].strip()
                payload = pickle.dumps(("error", line))
            with os.fdopen(write_fd, "wb") as pipe:
                pipe.write(payload)
        except BaseException:
            code = 1
        finally:
            os._exit(code)
    os.close(write_fd)
    with os.fdopen(read_fd, "rb") as pipe:
        data = pipe.read()
    _, status = os.waitpid(pid, 0)
    if not data:
        raise ForkedError(f"the forked copy ended without an answer (exit status {status})")
    kind, value = pickle.loads(data)
    if kind == "error":
        raise ForkedError(value)
    return value
