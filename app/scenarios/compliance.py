"""Compliance modes [C] §IV-E (Fig. 6): the same scripted pushes on the Gen3 under three settings
of the explicit compliance Γ [C9]: stiff (Γ = 0 on both tasks), nullspace-compliant (Γ₀ = I) and
fully compliant (Γ = I on the pose task too).

Constants, chosen once, not tuned afterwards:
- posture `home` (the paper's "default configuration");
- TCP pose task K_p = 100 s⁻², K_d = 20 s⁻¹ (10 rad/s, critically damped), weight 1e4; posture task
  K_p = 1 s⁻², K_d = 2 s⁻¹, weight 1 ("significantly lower weight", [C] §IV-E);
- pushes: 5 N along +y for 0.5 s, first at the TCP (t = 0.5 s, seen by the F/T sensor), then at the
  elbow (origin of the forearm link, t = 2.0 s, seen only by the momentum observer) — a firm hand
  push that a person can give; the paper's rope-hung weight is left out so all modes get the same input;
- estimator: fusion [C26], K_I = 50 s⁻¹; F/T noise σ = 0.1 N / 0.005 N m;
- run length 4 s.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from app.scenarios import Environment, PhaseMark, Scenario, Sensor
from app.scenarios.mass_drop import wrist_ft_sensor
from app.scenarios.metrics import PUSH_AFTER_S, WindowPeaks, push_windows
from app.sim.world import World
from control.compliance_qp import ComplianceQPExecutor, PoseTask
from control.executor import Executor
from control.gains import EstimatorGains, PoseTaskGains, PostureTaskGains
from control.params import ParamGroup, replaced
from robots import RobotDescription

MODES = ("stiff", "nullspace", "full")
GAMMAS = {"stiff": (0.0, 0.0), "nullspace": (0.0, 1.0), "full": (1.0, 1.0)}  # (Γ task, Γ₀)
PUSH_N = 5.0
PUSH_DIRECTION = np.array([0.0, 1.0, 0.0])
PUSHES = (("tcp", 0.5, 1.0), ("elbow", 2.0, 2.5))  # (where, start s, end s)
ELBOW_BODY = "forearm_link"
DURATION_S = 4.0
OBSERVER_GAIN = 50.0


class ScriptedPushes(Environment):
    """5 N pushes at the TCP and then at the elbow, at fixed times."""

    def __init__(self, world: World):
        self.tcp_body = world.wrist_body
        try:
            self.elbow_body = int(world.model.body(ELBOW_BODY).id)
        except KeyError:  # another arm: the body carrying joint 4
            self.elbow_body = int(world.model.jnt_bodyid[world.model.joint(world.robot.joint_names[3]).id])
        self.active = ""

    def apply(self, world: World, t: float) -> dict[str, float]:
        self.active = ""
        for where, start, end in PUSHES:
            if start <= t < end:
                self.active = where
                if where == "tcp":
                    point = world.site_pose(world.tcp_site)[0]
                    body = self.tcp_body
                else:
                    point = world.data.xpos[self.elbow_body].copy()
                    body = self.elbow_body
                world.apply_force(body, point, PUSH_N * PUSH_DIRECTION)
        return {"push_tcp": float(self.active == "tcp"), "push_elbow": float(self.active == "elbow")}


class ComplianceScenario(Scenario):
    name = "compliance"
    cases = MODES
    case_arg = "mode"
    title = "Compliance modes [C]"
    description = (
        "One pose task and one posture task; only Γ changes. Stiff (Γ = 0): the arm resists pushes. "
        "Nullspace-compliant (Γ₀ = I): the TCP holds, the elbow yields. Fully compliant (Γ = I): the "
        "whole arm moves with the hand."
    )
    default_robot = "gen3"
    default_executor = "compliance-qp"
    logs_deflection = True
    plot_layout = ("deflection", "torque")
    phase_marks = (PhaseMark("push_tcp", "TCP push"), PhaseMark("push_elbow", "elbow push"))
    tune_first = ("Compliance", "Safety")
    claim_keys = ("pose_task.compliance", "posture_task.compliance")

    def __init__(self, mode: str = "nullspace"):
        if mode not in MODES:
            raise ValueError(f"mode must be one of {', '.join(MODES)}, got {mode!r}")
        self.mode = mode

    def make_environment(self, world: World, rng: np.random.Generator) -> Environment:
        return ScriptedPushes(world)

    def readout_fold(self) -> WindowPeaks:
        """The TCP's and the elbow's largest deflection (mm) over each push and the PUSH_AFTER_S after it
        ("tcp_push_tcp_mm", "elbow_push_elbow_mm", …; the experiment's figures too)."""
        return WindowPeaks(push_windows(PUSHES), ("tcp_dev_mm", "elbow_dev_mm"))

    def readout_text(self, values: Mapping[str, float]) -> list[str]:
        """How far the TCP and the elbow moved under each push."""
        return [
            f"Push at the {'TCP' if push == 'tcp' else 'elbow'} (peak over the push and the "
            f"{PUSH_AFTER_S:g} s after it): TCP moved {values[f'{push}_push_tcp_mm']:.1f} mm, "
            f"elbow {values[f'{push}_push_elbow_mm']:.1f} mm"
            for push in ("tcp", "elbow")
            if f"{push}_push_tcp_mm" in values
        ]

    def make_sensor(self, rng: np.random.Generator) -> Sensor:
        return wrist_ft_sensor(rng)

    @property
    def chosen_case(self) -> str:
        """The compliance mode (`MODES`)."""
        return self.mode

    def prepare_executor(self, executor: Executor, robot: RobotDescription) -> None:
        """One pose task (the [C] QP executor; other executors are left as they are)."""
        if isinstance(executor, ComplianceQPExecutor):
            executor.set_tasks([PoseTask()])

    def executor_changes(self, groups: Mapping[str, ParamGroup], robot: RobotDescription) -> dict[str, ParamGroup]:
        """This mode's Γ on the pose and posture tasks, the fusion estimate, feedback on (the [C] QP
        executor's groups; none for another executor)."""
        if "compliance_qp" not in groups:
            return {}
        g_task, g_posture = GAMMAS[self.mode]
        return {
            "pose_task": PoseTaskGains(stiffness=100.0, damping=20.0, weight=1e4, compliance=g_task),
            "posture_task": PostureTaskGains(stiffness=1.0, damping=2.0, weight=1.0, compliance=g_posture),
            "estimator": EstimatorGains(source="fusion", observer_gain=OBSERVER_GAIN),
            "compliance_qp": replaced(groups["compliance_qp"], "feedback", True),
        }


SCENARIO = ComplianceScenario()
