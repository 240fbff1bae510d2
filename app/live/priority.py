"""The app's share of the CPU against other sessions' processes (the browser), on Linux.

Linux with autogroup scheduling (`/proc/sys/kernel/sched_autogroup_enabled`) first divides the CPU
between sessions (one autogroup each) and only then between the threads of a session, by their
niceness. A browser started from a desktop or another terminal is another session: however high the
loop thread's own priority, the server's session as a whole gets the same weight as the browser's,
and on two cores shared with software WebGL the loop then waits, runnable, for a CPU. Raising the
autogroup's niceness (`/proc/self/autogroup`) gives the server's session its share first; the
browser keeps the rest. It needs the permission a negative niceness needs (root, or room in
RLIMIT_NICE); refused or unavailable, nothing changes.
"""

from __future__ import annotations

import os

AUTOGROUP = "/proc/self/autogroup"
SERVER_NICENESS = -10  # the server's autogroup niceness where permitted (the loop thread's own is −10 too)


def set_process_niceness(niceness: int) -> int | None:
    """Give the calling process (on Linux: its calling thread) the niceness `niceness` where permitted;
    returns its niceness afterwards (None where priorities are not available)."""
    try:
        os.setpriority(os.PRIO_PROCESS, 0, niceness)
    except OSError:
        pass  # not permitted: the priority stays
    except AttributeError:
        return None
    return os.getpriority(os.PRIO_PROCESS, 0)


def autogroup_niceness(path: str = AUTOGROUP) -> int | None:
    """The niceness of this process's autogroup (e.g. "/autogroup-255 nice 0" → 0); None without one."""
    try:
        with open(path, encoding="ascii") as fh:
            return int(fh.read().split()[-1])
    except (OSError, ValueError, IndexError):
        return None


def set_autogroup_niceness(niceness: int, path: str = AUTOGROUP) -> int | None:
    """Set this process's autogroup niceness; returns it afterwards (None without autogroups; unchanged
    when the system refuses)."""
    try:
        with open(path, "w", encoding="ascii") as fh:
            fh.write(str(int(niceness)))
    except OSError:
        pass
    return autogroup_niceness(path)


def raise_autogroup_priority(niceness: int, path: str = AUTOGROUP) -> int | None:
    """Lower the autogroup's niceness to `niceness` if that raises its priority. Returns the niceness it
    had before when it changed it (give it back with `set_autogroup_niceness` when done), else None
    (no autogroups, refused, or already as high)."""
    before = autogroup_niceness(path)
    if before is None or niceness >= before:
        return None
    return before if set_autogroup_niceness(niceness, path) == niceness else None
