"""Registry of executors by name: factory(robot, model) -> Executor.

Each paper executor adds one entry to `EXECUTORS` below, as a small factory function that
imports its module lazily; the Session, the web app and the experiments pick executors by name.
"""

from __future__ import annotations

from collections.abc import Callable

from control.executor import Executor
from control.joint_hold import JointHold
from control.model import RobotModel
from robots import RobotDescription

ExecutorFactory = Callable[[RobotDescription, RobotModel], Executor]

EXECUTORS: dict[str, ExecutorFactory] = {
    "joint-hold": lambda robot, model: JointHold(),
    "projection": lambda robot, model: _projection(robot, model),
    "compliance-qp": lambda robot, model: _compliance_qp(robot, model),
}


def register(name: str, factory: ExecutorFactory) -> None:
    """Make an executor available by name."""
    EXECUTORS[name] = factory


def make_executor(name: str, robot: RobotDescription, model: RobotModel) -> Executor:
    """Build a registered executor; ValueError with the known names otherwise."""
    if name not in EXECUTORS:
        raise ValueError(f"unknown executor {name!r}; choose one of {', '.join(EXECUTORS)}")
    return EXECUTORS[name](robot, model)


def _projection(robot: RobotDescription, model: RobotModel) -> Executor:
    from control.motion_force import make_projection_executor

    return make_projection_executor(robot, model)


def _compliance_qp(robot: RobotDescription, model: RobotModel) -> Executor:
    from control.compliance_qp import make_compliance_qp

    return make_compliance_qp(robot, model)
