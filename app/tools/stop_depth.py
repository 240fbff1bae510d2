"""How deep the page's maximum drag pushes a joint into its hard stop, checked at every step.

`python -m app.tools.stop_depth [PRESETS] [STEPS]`: for every preset (comma-separated, default all)
× executor × direction (±x, ±y, ±z), 500 steps to settle, then the tip pulled 2 m that way with the
drag force limit at its maximum (300 N) for STEPS steps (default 2000); prints the deepest any joint
went into its stop (`World.stop_depth`, every step), the QP's fallback steps (and how many of them
were relaxed: the constraints had no common point and the executor took its least-violation
solution, `control.qp.RELAXED`), and the worst run.
"""

from __future__ import annotations

import itertools
import sys

import numpy as np

from app.core.commands import DragCommand, SetParam
from app.core.executors import EXECUTORS
from app.live.lab import Lab
from app.scenarios import SCENARIOS
from control.qp import RELAXED

DIRECTIONS = {"+x": (1, 0, 0), "-x": (-1, 0, 0), "+y": (0, 1, 0), "-y": (0, -1, 0), "+z": (0, 0, 1), "-z": (0, 0, -1)}
MAX_DRAG_N = 300.0  # the drag force limit's maximum on the page
PULL_M = 2.0


def probe(scenario: str, executor: str, direction: tuple[int, int, int], steps: int) -> tuple[float, int, int, bool]:
    """(deepest into a stop in rad, fallback steps, relaxed ones among them, halted) for one pull."""
    lab = Lab(scenario, executor=executor)
    lab.apply(SetParam("drag", "max_force_n", MAX_DRAG_N))
    lab.advance(500)
    link = lab.session.robot.link_names[-1]
    tip = np.array(lab.session.world.data.xpos[-1], dtype=float)
    lab.apply(DragCommand("grab", 1, body_name=link, point_world=tuple(tip)))
    lab.apply(DragCommand("move", 1, body_name=link, target_world=tuple(tip + PULL_M * np.array(direction))))
    lab.session.world.stop_depth.fill(-np.inf)
    fallback0 = lab.fallback_steps
    relaxed = [0]

    def count(rec) -> bool:
        last = getattr(lab.session.executor, "last_qp", None)
        relaxed[0] += bool(rec.fallback and last is not None and last.status.startswith(RELAXED))
        return False

    result = lab.advance(steps, until=count)
    return float(lab.session.world.stop_depth.max()), lab.fallback_steps - fallback0, relaxed[0], result.halted


def main(argv: list[str]) -> int:
    """Run the probes (see the module docstring)."""
    presets = argv[0].split(",") if argv else list(SCENARIOS)
    steps = int(argv[1]) if len(argv) > 1 else 2000
    rows = []
    for scenario, executor in itertools.product(presets, EXECUTORS):
        for name, direction in DIRECTIONS.items():
            depth, fallback, relaxed, halted = probe(scenario, executor, direction, steps)
            rows.append((depth, scenario, executor, name))
            print(
                f"{scenario:11s} {executor:14s} {name}  {1e3 * depth:8.1f} mrad into a stop"
                f"  QP fallback {fallback:5d}/{steps} ({relaxed} relaxed)  halted {halted}",
                flush=True,
            )
    worst = max(rows)
    past = sum(1 for r in rows if r[0] > 0.02)
    print(f"worst {1e3 * worst[0]:.1f} mrad ({worst[1]} / {worst[2]} {worst[3]}); {past} of {len(rows)} past 20 mrad")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
