"""Joint-limit drop [C] §IV-B–C (Figs. 2–4): Gen3 in an L-shape with a 1.25 kg mass at the TCP
(in the simulation, not in the controller model); joint 4 alone is compliant (Γ₀ = e₄) and falls
into its position limit or a lowered velocity limit; the dampers must stop it.

Constants, chosen once from the paper and not tuned afterwards:
- posture `l_shape` (robots/gen3.toml): the paper's L-shape, only joint 4 loaded by the mass; on
  another arm its sidecar's `l_shape` (robots/panda.toml says how the Panda's was chosen), or for an
  arm without a sidecar the start `app.scenarios.drop_postures.limit_drop_start` finds;
- the limit joint 4 falls into: the one the mass's torque at the start points to (`fall`, the Gen3's
  upper limit, the Panda's lower one);
- payload 1.25 kg at the TCP: the paper's weight "fixed to the end-effector";
- posture task only (no Cartesian task): the drop is a joint-level test, the other joints are
  kept by Γ = 0 and feedback ("kept the other joints non-compliant");
- posture gains K_p = 1 s⁻², K_d = 2 s⁻¹: a soft, critically damped posture task (the default
  stiffness of mc_rtc's posture task, the paper's framework), so that gravity wins and joint 4 falls;
- estimator: fusion [C26] with K_I = 50 s⁻¹ (the paper's external-force source; K_I is not given),
  ideal F/T sensor (the drop is about the dampers, not about sensor noise);
- lowered velocity limit for case (b): 0.5 rad/s on joint 4, about a third of its 1.40 rad/s
  limit, so the velocity damper acts well before the position damper;
- run length: until joint 4 has stopped, at most 6 s (`app.headless.experiments.limit_drop`), so that no
  curve ends mid-motion; the fall takes about 1 s.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any, ClassVar

import mujoco
import numpy as np

from app.scenarios import Environment, PhaseMark, Scenario
from app.scenarios.drop_postures import FALLING_JOINT, Fall, fall_from, guess_posture, limit_drop_start
from app.scenarios.payload import PayloadEnvironment, PayloadParams, add_payload_body
from app.sim.world import World
from control.compliance_qp import ComplianceQPExecutor
from control.executor import Executor, TaskTarget
from control.gains import EstimatorGains, PostureTaskGains
from control.model import Dynamics, RobotModel
from control.params import ParamGroup, replaced
from robots import RobotDescription

PAYLOAD_KG = 1.25  # [C] §IV-B
POSTURE_STIFFNESS = 1.0  # 1/s², mc_rtc posture-task default
POSTURE_DAMPING = 2.0  # 1/s, critical damping for K_p = 1
OBSERVER_GAIN = 50.0  # 1/s
LOWERED_VELOCITY_LIMIT = 0.5  # rad/s, case (b)
REST_SPEED_RAD_S = 0.02  # a falling joint slower than this counts as at rest (the phase line)
DURATION_S = 6.0  # s: the cap; the experiment stops a drop once joint 4 is at rest


def _searched_start(robot: RobotDescription) -> tuple[np.ndarray, str]:
    """The limit drop's start found by `limit_drop_start`, and how, in words."""
    q, fall = limit_drop_start(robot, PAYLOAD_KG)
    side = "upper" if fall.direction > 0 else "lower"
    return q, (
        f"the limit drop starts at joint 4 = {q[FALLING_JOINT]:.3f} rad, joint 2 = {q[1]:.3f} rad, falling toward"
        f" its {side} limit {fall.limit:.3f} rad under {fall.torque.min():.1f}–{fall.torque.max():.1f} N m of the"
        f" {PAYLOAD_KG:g} kg load (a search, app/scenarios/drop_postures.py, not [C]'s L-shape): the speed at"
        " which it meets the dampers depends on that torque"
    )


class LimitDropScenario(Scenario):
    name = "limit-drop"
    cases = ("position", "velocity")
    case_arg = "limit"
    title = "Joint-limit drop [C]"
    description = (
        "Gen3 in an L-shape (another arm: its own limit-drop start) carries 1.25 kg the controller does not "
        "know about. Only joint 4 is compliant (Γ₀ = e₄), so the weight drops it into the position limit its "
        "torque points to (or a lowered velocity "
        "limit). Change λ, M, the damper form and the external-force feedback and watch the phase plot."
    )
    default_robot = "gen3"
    default_executor = "compliance-qp"
    focus_joint = FALLING_JOINT
    starts_paused = True  # the drop is over in seconds
    groups: ClassVar[Mapping[str, type[ParamGroup]]] = {"payload": PayloadParams}
    plot_layout = ("phase", "torque")
    phase_marks = (PhaseMark("payload_attached", "release", rising=False),)
    tune_first = ("Safety", "Latency", "Compliance")
    claim_keys = ("damper.lambda_", "world.torque_delay_ms")

    def __init__(self, limit: str = "position"):
        if limit not in ("position", "velocity"):
            raise ValueError(f"limit must be 'position' or 'velocity', got {limit!r}")
        self.limit = limit

    @property
    def chosen_case(self) -> str:
        """Which limit the drop meets: "position" or "velocity" (lowered)."""
        return self.limit

    def initial_q(self, robot: RobotDescription) -> np.ndarray:
        return self.named_posture(robot, "l_shape")

    def prepare_robot(self, robot: RobotDescription) -> None:
        """For an arm without sidecar postures, find its start (`drop_postures.limit_drop_start`) and
        say so among the guessed values."""
        guess_posture(robot, "l_shape", "limit_drop", lambda: _searched_start(robot))

    def phase_text(self, status: Any, scene: Any, memory: dict[str, Any]) -> str:
        """The drop while the falling joint moves, at rest once it has stopped (its speed, from the
        posture of successive frames, kept in `memory`)."""
        joint = status.focus_joint
        q = getattr(scene, "q", None)
        if joint is None or q is None:
            return "drop"
        now = (float(status.t), float(q[joint]))
        last, memory["last_q"] = memory.get("last_q"), now
        if last is None or now[0] <= last[0]:
            memory["moved"] = False
            return f"drop: joint {joint + 1} falls" if status.t < 0.05 else "drop"
        speed = abs(now[1] - last[1]) / (now[0] - last[0])
        memory["moved"] = memory.get("moved", False) or speed > REST_SPEED_RAD_S
        if speed > REST_SPEED_RAD_S or not memory["moved"]:
            return f"drop: joint {joint + 1} falls ({speed:.2f} rad/s)"
        return f"done: joint {joint + 1} at rest"

    def fall(self, robot: RobotDescription) -> Fall:
        """Where joint 4 falls from the start: toward the limit the payload's torque points to there
        (computed once per robot and start)."""
        q0 = self.initial_q(robot)
        key = (robot.spec or robot.name, tuple(q0))
        cache = self.__dict__.setdefault("_falls", {})
        if key not in cache:
            cache[key] = fall_from(robot, RobotModel(robot.model), q0, PAYLOAD_KG, FALLING_JOINT)
        return cache[key]

    def customize_world(self, spec: mujoco.MjSpec, robot: RobotDescription) -> None:
        add_payload_body(spec, robot, PAYLOAD_KG)

    def make_environment(self, world: World, rng: np.random.Generator) -> Environment:
        return PayloadEnvironment(world, PAYLOAD_KG, release_time_s=None)

    def make_target(
        self, robot: RobotDescription, model: RobotModel, dyn0: Dynamics, gains: Mapping[str, ParamGroup]
    ) -> Callable[[float], TaskTarget]:
        hold = TaskTarget(
            position=dyn0.tcp_position_world.copy(), rotation=dyn0.tcp_rotation_world.copy(), q_posture=dyn0.q.copy()
        )
        return lambda t: hold

    def velocity_limits(self, robot: RobotDescription) -> np.ndarray:
        """Per-joint velocity limits for this case (joint 4 lowered in case (b))."""
        dq_max = robot.dq_max.copy()
        if self.limit == "velocity":
            dq_max[FALLING_JOINT] = LOWERED_VELOCITY_LIMIT
        return dq_max

    def prepare_executor(self, executor: Executor, robot: RobotDescription) -> None:
        """Posture only (no task) and this case's velocity limits on the dampers (the [C] QP executor;
        other executors are left as they are)."""
        if isinstance(executor, ComplianceQPExecutor):
            executor.set_tasks([])
            executor.damper.configure(executor.damper.gains, dq_max=self.velocity_limits(robot))

    def executor_changes(self, groups: Mapping[str, ParamGroup], robot: RobotDescription) -> dict[str, ParamGroup]:
        """Γ₀ = e₄ on the posture task, the fusion estimate, feedback on (the [C] QP executor's
        groups; none for another executor)."""
        if "compliance_qp" not in groups:
            return {}
        gamma0 = np.zeros(robot.nq)
        gamma0[FALLING_JOINT] = 1.0
        return {
            "posture_task": PostureTaskGains(
                stiffness=POSTURE_STIFFNESS, damping=POSTURE_DAMPING, compliance=tuple(gamma0)
            ),
            "estimator": EstimatorGains(source="fusion", observer_gain=OBSERVER_GAIN),
            "compliance_qp": replaced(groups["compliance_qp"], "feedback", True),
        }


SCENARIO = LimitDropScenario()
