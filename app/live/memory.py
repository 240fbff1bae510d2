"""Memory freed by a preset switch handed back to the system (glibc's `malloc_trim`).

A switch frees the old session (its MuJoCo and Pinocchio models, the step log, scene meshes), but
glibc keeps freed memory in its arenas, so the server's resident memory crept up switch after switch
with no live data growing: a soak's RSS fell to its level of the first minutes once trimmed. After
each switch the loop asks for a trim in a short thread of its own (ctypes releases the GIL; the loop
thread never waits for it). Elsewhere than glibc it does nothing.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import gc
import threading
from functools import cache
from typing import Any


@cache
def _libc() -> Any:
    """glibc, when this process runs on it (else None)."""
    name = ctypes.util.find_library("c")
    if name is None:
        return None
    try:
        lib = ctypes.CDLL(name)
        lib.malloc_trim.argtypes = [ctypes.c_size_t]
        lib.malloc_trim.restype = ctypes.c_int
    except (OSError, AttributeError):
        return None
    return lib


def trim_heap() -> bool:
    """Return the allocator's free memory to the system now; False where there is no malloc_trim."""
    lib = _libc()
    if lib is None:
        return False
    lib.malloc_trim(0)
    return True


class _MallInfo2(ctypes.Structure):
    _fields_ = [
        (name, ctypes.c_size_t)
        for name in (
            "arena",
            "ordblks",
            "smblks",
            "hblks",
            "hblkhd",
            "usmblks",
            "fsmblks",
            "uordblks",
            "fordblks",
            "keepcost",
        )
    ]


def heap_mb() -> dict[str, float]:
    """glibc's heap over all arenas (mallinfo2): "heap_used" (allocated blocks, mmapped ones included),
    "heap_free" (freed but kept in the arenas) in MB; empty elsewhere than glibc ≥ 2.33."""
    lib = _libc()
    fn = getattr(lib, "mallinfo2", None) if lib is not None else None
    if fn is None:
        return {}
    fn.restype = _MallInfo2
    info = fn()
    mb = 1024.0 * 1024.0
    return {"heap_used": (info.uordblks + info.hblkhd) / mb, "heap_free": info.fordblks / mb}


def trim_heap_soon() -> threading.Thread:
    """`trim_heap` in a daemon thread of its own (started; returned for a caller that waits)."""
    thread = threading.Thread(target=trim_heap, name="torquelab-trim", daemon=True)
    thread.start()
    return thread


def freeze_start_up_objects() -> None:
    """Keep everything built so far out of the collector's passes (`gc.freeze`), then run one pass
    over what is left. CPython starts a full pass only once the objects promoted to the oldest
    generation since the last full pass outnumber a quarter of those that pass left there; without
    a pass after the freeze that count still holds the frozen start-up objects (~200,000), so cyclic
    garbage that had reached the oldest generation stayed for good. After it, a full pass walks only
    what came later (~3,000 objects in a served lab: under a millisecond)."""
    gc.collect()
    gc.freeze()
    gc.collect()
