"""The live figures an environment computes for the page, in a process of their own (`app.scenarios.Offload`).

The polish preset's force-loop margin (σ ten times a simulated second, the K_f^d margin once) is a
few hundred microseconds (σ) to a few milliseconds (K_f^d) of small numpy operations, Python that
holds the GIL: in a thread it would still take the loop thread's turn, so it runs in a spawned
worker process instead (`app.live.workers.Worker`: the loop thread writes a snapshot, the posture's
Λx and the groups, to the worker's pipe itself, and the environment takes the results in order as
they come, a few milliseconds later, with no thread of this process carrying them).

Until the worker is up (its imports done), or after it died until a new one is, `submit` answers None
and the environment keeps the sample for later (a stroke's σ samples are never skipped: the stroke
headroom is the one the run computes inline, only later); when no worker can start (`gave_up`) the
environment computes inline. Work under way when the worker dies ends with an error (the environment
shows NaN for it).
"""

from __future__ import annotations

from app.live.workers import Worker

# the worker runs this much nicer than the app: woken by a job, it must not take the core the loop
# thread (or, headless, the stepping thread) is on; a figure a few milliseconds late costs nothing
WORKER_NICENESS_ABOVE_APP = 10


def import_scenarios() -> None:
    """The worker's warm-up: the presets' modules (MuJoCo, the controller's), so no first figure
    waits for an import."""
    import importlib

    from app.scenarios import SCENARIOS

    for module in SCENARIOS.values():
        importlib.import_module(f"app.scenarios.{module}")


class LiveOffload(Worker):
    """One spawned worker process for the environments' live figures (module docstring)."""

    def __init__(self) -> None:
        super().__init__("torquelab-offload", niceness_above_app=WORKER_NICENESS_ABOVE_APP, warm=import_scenarios)
