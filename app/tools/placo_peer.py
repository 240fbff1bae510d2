"""Time placo's DynamicsSolver on one of our URDFs: the compiled peer of the [C] QP executor step.

Runs in its own virtual environment (placo 0.10.2 pins an older Pinocchio than torquelab), so it
imports nothing from torquelab; `torquelab bench --vs-placo PYTHON` calls it as

    PYTHON placo_peer.py URDF FRAME STEPS Q0_JSON

and reads one JSON object from stdout. The problem mirrors our `qp_executor_step` bench: a soft
6-D frame task holding the start pose plus a soft posture task (weights 1 : 1e-4, as the [C] QP's
task : posture), torque, joint and velocity limits on, fixed base, 1 ms step, and the same moving
state q = q0 + 0.05 sin(s), q̇ = 0.2 cos(s), s = 0.01 k + (0..6). A step is
`update_kinematics()` (Pinocchio's dynamics terms) + `solve()` (build and solve the dense QP),
setting the state is not timed.
"""

from __future__ import annotations

import json
import sys
import time
from importlib import metadata

import numpy as np
import placo


def main(argv: list[str]) -> int:
    """Print {"step_us": median, "p95_us", "steps", "placo_version"} for the arguments above."""
    urdf, frame, steps, q0 = argv[1], argv[2], int(argv[3]), np.array(json.loads(argv[4]), dtype=float)
    robot = placo.RobotWrapper(urdf, placo.Flags.ignore_collisions)
    names = list(robot.joint_names())
    if len(names) != len(q0):
        print(json.dumps({"error": f"{urdf} has {len(names)} joints, q0 has {len(q0)}"}))
        return 1
    for name, value in zip(names, q0, strict=True):
        robot.set_joint(name, float(value))
    robot.update_kinematics()
    solver = placo.DynamicsSolver(robot)
    solver.dt = 1e-3
    solver.mask_fbase(True)
    solver.enable_torque_limits(True)
    solver.enable_joint_limits(True)
    solver.enable_velocity_limits(True)
    task = solver.add_frame_task(frame, robot.get_T_world_frame(frame))
    task.configure(frame, "soft", 1.0, 1.0)
    posture = solver.add_joints_task()
    posture.set_joints({name: float(v) for name, v in zip(names, q0, strict=True)})
    posture.configure("posture", "soft", 1e-4)
    warmup = 50
    samples = np.empty(steps)
    phase = np.arange(len(names), dtype=float)
    for k in range(warmup + steps):
        s = 0.01 * k + phase
        q, dq = q0 + 0.05 * np.sin(s), 0.2 * np.cos(s)
        for i, name in enumerate(names):
            robot.set_joint(name, float(q[i]))
            robot.set_joint_velocity(name, float(dq[i]))
        t0 = time.perf_counter()
        robot.update_kinematics()
        solver.solve(False)
        if k >= warmup:
            samples[k - warmup] = time.perf_counter() - t0
    us = samples * 1e6
    out = {
        "step_us": float(np.median(us)),
        "p95_us": float(np.percentile(us, 95)),
        "steps": steps,
        "placo_version": _placo_version(),
    }
    print(json.dumps(out))
    return 0


def _placo_version() -> str:
    """The installed placo's version (the module itself has no `__version__`)."""
    try:
        return metadata.version("placo")
    except metadata.PackageNotFoundError:
        return getattr(placo, "__version__", "unknown")


if __name__ == "__main__":
    sys.exit(main(sys.argv))
