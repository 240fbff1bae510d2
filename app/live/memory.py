"""The server's memory across preset switches: freed when dropped, handed back, measured.

A switch drops the old session (its MuJoCo and Pinocchio models, the step log, the scene's meshes).
Nothing of it may sit in a reference cycle (tests/test_faults_memory.py checks every preset case):
`freeze_start_up_objects` keeps the start-up objects out of the collector's passes, and what is left
to a full pass waits up to minutes for one. What is freed, glibc keeps in its arenas: after each
switch the loop asks for a trim (`trim_heap_soon`) in a short thread of its own (ctypes releases the
GIL; the loop thread never waits for it). `heap_mb` reads glibc's heap for `bench --soak`.
Elsewhere than glibc the trim and the heap reading do nothing.

glibc serves a block above its mmap threshold with a mapping of its own, returned when the block is
freed, but raises the threshold to the size of each such block freed (up to 32 MB): after the first
switch freed a step log (~30 MB), every later large block (step logs, scene meshes, the frames viser
serializes for each page) came from the arenas, and what was freed there stayed resident
(`bench --soak 4 --pages 2 --junk`: 516 MB of RSS with 55-68 MB free in the arenas at the end, against
431 MB and 8-9 MB with the threshold fixed). `fix_mmap_threshold` fixes it at MMAP_THRESHOLD_BYTES
(glibc's initial value) before the app allocates its large blocks.

glibc also gives each thread alive at once an arena of its own (up to eight per core), and an arena
keeps what was freed in it: the threads that come and go (a switch's trim among them) made new ones
through a run (8 -> 15 in a 3.5-minute soak, nine tenths of its growth after the first minute).
`cap_arenas` caps them at ARENA_MAX; `arena_count` counts them.

numpy keeps freed data blocks of under ARRAY_CACHE_BYTES bytes for reuse, up to ARRAY_CACHE_DEPTH of each
size (its own cache, in front of malloc; 3.5 MB at most, never handed back). A run's charts make
temporaries of every length as their windows fill again after each switch, so that cache filled over
the first minutes of a run: about half of what `bench --soak 10 --pages 2 --junk` measured after its
first minute (+0.37 MB/min, against +0.19 and +0.23 in two runs with the cache filled at start).
`fill_array_cache` fills it to its bound at start, so the server's memory no longer creeps while it fills.

viser ends a connection by cancelling its sender and receiver tasks: their CancelledError tracebacks hold
the tasks' frames, and through them the connection, its queue of messages not yet sent and their
encodings, in reference cycles (about 300 objects per closed connection, most of them dicts and the
messages' buffers). A full pass of the collector comes only once a quarter as many objects as the
oldest generation holds have reached it, and what a closed connection held waited for it: a junk
client that connects every 2 s kept the server's memory ~4 MB higher and still settling after the
first minute of `bench --soak 10 --pages 2 --junk`. `CollectAfterClose` runs a full pass
COLLECT_AFTER_CLOSE_S after a connection closes, at most once every COLLECT_EVERY_S (a pass walks what
came after the start-up freeze: 6–12 ms measured with one page open and a junk client, the GIL held
meanwhile as in any pass).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import gc
import threading
import time
from functools import cache
from typing import Any

import numpy as np


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


def _mallopt(param: int, value: int) -> bool:
    """glibc's `mallopt(param, value)`; False where there is no mallopt or it refused."""
    lib = _libc()
    fn = getattr(lib, "mallopt", None) if lib is not None else None
    if fn is None:
        return False
    fn.argtypes = [ctypes.c_int, ctypes.c_int]
    fn.restype = ctypes.c_int
    return bool(fn(param, value))


MMAP_THRESHOLD_BYTES = 128 * 1024  # blocks from this size up get a mapping of their own
_M_MMAP_THRESHOLD = -3  # mallopt's parameter number (malloc.h)


def fix_mmap_threshold(nbytes: int = MMAP_THRESHOLD_BYTES) -> bool:
    """Fix glibc's mmap threshold at `nbytes` (no raising it as large blocks are freed; see the module
    docstring); False where there is no mallopt or it refused."""
    return _mallopt(_M_MMAP_THRESHOLD, int(nbytes))


ARENA_MAX = 2  # glibc's malloc arenas: the main one and one that every other thread shares
_M_ARENA_MAX = -8  # mallopt's parameter number (malloc.h)


def cap_arenas(n: int = ARENA_MAX) -> bool:
    """Cap glibc's malloc arenas at `n`: a thread that starts later shares one (glibc's default gives each
    thread alive at once an arena of its own, up to eight per core, each keeping what was freed in it:
    the arenas made by the threads that come and go were nine tenths of the soak's growth after its
    first minute, docs/failures.md); False where there is no mallopt or it refused."""
    return _mallopt(_M_ARENA_MAX, int(n))


def arena_count() -> int:
    """glibc's malloc arenas in this process (the `<heap>` entries of malloc_info); 0 elsewhere."""
    lib = _libc()
    info = getattr(lib, "malloc_info", None) if lib is not None else None
    if info is None:
        return 0
    lib.open_memstream.restype = ctypes.c_void_p
    lib.open_memstream.argtypes = [ctypes.POINTER(ctypes.c_char_p), ctypes.POINTER(ctypes.c_size_t)]
    lib.fclose.argtypes = [ctypes.c_void_p]
    info.argtypes = [ctypes.c_int, ctypes.c_void_p]
    text, size = ctypes.c_char_p(), ctypes.c_size_t()
    stream = lib.open_memstream(ctypes.byref(text), ctypes.byref(size))
    if not stream:
        return 0
    info(0, stream)
    lib.fclose(stream)
    xml = ctypes.string_at(text, size.value).decode()
    lib.free.argtypes = [ctypes.c_void_p]
    lib.free(ctypes.cast(text, ctypes.c_void_p))
    return xml.count("<heap nr=")


ARRAY_CACHE_BYTES = 1024  # numpy caches freed data blocks smaller than this (its NBUCKETS)...
ARRAY_CACHE_DEPTH = 7  # ...up to this many of each size (its NCACHE)


def fill_array_cache() -> None:
    """Fill numpy's cache of freed small data blocks to its bound now (see the module docstring): every
    size under ARRAY_CACHE_BYTES, ARRAY_CACHE_DEPTH blocks each, allocated at once and freed."""
    blocks = [np.empty(size, dtype=np.uint8) for size in range(1, ARRAY_CACHE_BYTES) for _ in range(ARRAY_CACHE_DEPTH)]
    del blocks


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


COLLECT_AFTER_CLOSE_S = 1.0  # a closed connection's cycles are collected this long after it closes...
COLLECT_EVERY_S = 5.0  # ...by a full pass at most this often (a flood of connections gets one per period)


class CollectAfterClose:
    """A full pass of the collector soon after a connection closes (see the module docstring), in one
    daemon thread of its own that lives as long as the app (a thread per pass would come and go every
    few seconds under a flood of connections); requests while one is pending, or within COLLECT_EVERY_S
    of the last pass, are folded into the next one."""

    def __init__(self, after_s: float = COLLECT_AFTER_CLOSE_S, every_s: float = COLLECT_EVERY_S):
        self.after_s, self.every_s = after_s, every_s
        self.passes = 0  # full passes run
        self.collected = 0  # objects they found unreachable
        self._wake = threading.Condition()
        self._due: float | None = None  # when the pending pass runs (monotonic s); None: none pending
        self._last = -float("inf")
        self._stopped = False
        self._thread: threading.Thread | None = None

    def request(self, *_: Any) -> None:
        """Ask for a pass (a connection closed); any arguments are ignored (a callback's)."""
        with self._wake:
            if self._due is not None or self._stopped:
                return
            self._due = max(time.monotonic() + self.after_s, self._last + self.every_s)
            if self._thread is None:
                self._thread = threading.Thread(target=self._run, name="torquelab-collect", daemon=True)
                self._thread.start()
            self._wake.notify()

    def _run(self) -> None:
        while True:
            with self._wake:
                while not self._stopped and (self._due is None or time.monotonic() < self._due):
                    self._wake.wait(None if self._due is None else self._due - time.monotonic())
                if self._stopped:
                    return
                self._due, self._last = None, time.monotonic()  # a request during the pass waits for the next
            found = gc.collect()
            with self._wake:
                self.passes += 1
                self.collected += found

    def stop(self) -> None:
        """No pass from now on (the pending one is dropped; the thread ends)."""
        with self._wake:
            self._stopped = True
            self._wake.notify()
