"""Mass drop [C] §IV-D (Fig. 5): the Gen3 holds a 1.25 kg mass at the tool and lets it go; the
TCP must stay put. Three modes: Position (an acceleration-based joint PID standing in for the
arm's internal position loop), Torque + Residual and Torque + Fusion (pose task non-compliant,
Γ = 0; nullspace compliant, Γ₀ = I).

Constants, chosen once from the paper and physical sense, not tuned afterwards:
- posture `mass_drop_nominal` (robots/gen3.toml): the nominal posture with the TCP 5 cm forward;
- payload 1.25 kg at the TCP, distal to the F/T sensor (as in the paper, the sensor sees it);
- release at t = 1.5 s: the PID integral and the observer have settled (both < 0.3 s);
- analysis window 4 s from the release ([C] §IV-D);
- Position mode: joint PID with a triple real pole at ω = 20 rad/s (K_p = 3ω², K_d = 3ω,
  K_i = ω³): a stiff position loop without overshoot; no external-torque estimate;
- Torque modes: TCP pose task K_p = ω² = 400 s⁻², K_d = 2ω = 40 s⁻¹ (the same 20 rad/s bandwidth,
  critically damped), weight 1e4; posture task K_p = 1, K_d = 2, weight 1, Γ₀ = I; K_I = 50 s⁻¹;
- F/T sensor: Gaussian noise σ = 0.1 N / 0.005 N m per channel, no filter (a digital 6-axis
  sensor read within 1 ms, [C] §IV-A); the 1 Hz sinusoid of the [T] sensor model is not used;
- actuator torque ripple: Gaussian σ = 0.05 N m per joint per step (the low-level torque loop is
  never exact), so that repetitions with different seeds differ as on hardware;
- stabilisation band 1 mm around the target.
"""

from __future__ import annotations

import mujoco
import numpy as np

from app.scenarios import Environment, Scenario, Sensor
from app.scenarios.payload import PayloadEnvironment, add_payload_body
from app.sim.sensor import FTSensor
from app.sim.world import World
from control.compliance_qp import ComplianceQPExecutor, PoseTask
from control.gains import EstimatorGains, PoseTaskGains, PostureTaskGains
from robots import RobotDescription

MODES = ("position", "torque-residual", "torque-fusion")
PAYLOAD_KG = 1.25
RELEASE_TIME_S = 1.5
WINDOW_S = 4.0
PID_OMEGA = 20.0  # rad/s
TASK_OMEGA = 20.0  # rad/s
OBSERVER_GAIN = 50.0  # 1/s
FORCE_NOISE_STD = 0.1  # N
TORQUE_NOISE_STD = 0.005  # N m (sensor moment channels)


def wrist_ft_sensor(rng: np.random.Generator) -> Sensor:
    """The [C] scenarios' wrist F/T sensor: white noise of the stds above, no sine, no filter."""
    return SensorAdapter(
        FTSensor(
            rng,
            force_noise_var=FORCE_NOISE_STD**2,
            torque_noise_var=TORQUE_NOISE_STD**2,
            sine_amplitude_n=0.0,
            cutoff_hz=0.0,
        )
    )


ACTUATOR_RIPPLE_STD = 0.05  # N m
STABLE_BAND_M = 1e-3


class RippleAndPayload(PayloadEnvironment):
    """The payload (released at RELEASE_TIME_S) plus seeded actuator torque ripple."""

    def __init__(self, world: World, rng: np.random.Generator):
        super().__init__(world, PAYLOAD_KG, release_time_s=RELEASE_TIME_S)
        self.rng = rng

    def apply(self, world: World, t: float) -> dict[str, float]:
        signals = super().apply(world, t)
        ripple = ACTUATOR_RIPPLE_STD * self.rng.standard_normal(len(world.dof_adr))
        world.data.qfrc_applied[world.dof_adr] += ripple
        return signals


class SensorAdapter(Sensor):
    """The F/T sensor model behind the scenario's `Sensor` interface."""

    def __init__(self, sensor: FTSensor):
        self.sensor = sensor

    def measure(self, true_wrench: np.ndarray, t: float) -> np.ndarray:
        return self.sensor.measure(true_wrench, t)

    def configure(self, **changes: object) -> None:
        self.sensor.configure(**changes)

    def reset(self) -> None:
        self.sensor.reset()


class MassDropScenario(Scenario):
    name = "mass-drop"
    title = "Mass drop [C]"
    description = (
        "The Gen3 holds 1.25 kg at its tool and lets go at t = 1.5 s. Compare a stiff joint position "
        "loop with torque control fed by the momentum observer alone or fused with the F/T sensor: "
        "peak deflection, stabilisation time and residual error of the TCP."
    )
    default_robot = "gen3"
    default_executor = "compliance-qp"

    def __init__(self, mode: str = "torque-fusion"):
        if mode not in MODES:
            raise ValueError(f"mode must be one of {', '.join(MODES)}, got {mode!r}")
        self.mode = mode

    def initial_q(self, robot: RobotDescription) -> np.ndarray:
        return self.named_posture(robot, "mass_drop_nominal")

    def customize_world(self, spec: mujoco.MjSpec, robot: RobotDescription) -> None:
        add_payload_body(spec, robot, PAYLOAD_KG)

    def make_environment(self, world: World, rng: np.random.Generator) -> Environment:
        return RippleAndPayload(world, rng)

    def make_sensor(self, rng: np.random.Generator) -> Sensor:
        return wrist_ft_sensor(rng)

    def configure_executor(self, executor: object, robot: RobotDescription) -> None:
        """Position: joint PID, no estimate. Torque modes: stiff pose task, compliant nullspace.

        Other executors are left as they are (the Session may call this for any executor).
        """
        if not isinstance(executor, ComplianceQPExecutor):
            return
        if self.mode == "position":
            w = PID_OMEGA
            executor.set_tasks([])
            executor.posture.configure(
                PostureTaskGains(stiffness=3 * w * w, damping=3 * w, integral=w**3, weight=1.0, compliance=0.0)
            )
            executor.estimator.configure(EstimatorGains(source="none", observer_gain=OBSERVER_GAIN))
            executor.configure(feedback=False)
            return
        w = TASK_OMEGA
        executor.set_tasks([PoseTask(PoseTaskGains(stiffness=w * w, damping=2 * w, weight=1e4, compliance=0.0))])
        executor.posture.configure(PostureTaskGains(stiffness=1.0, damping=2.0, weight=1.0, compliance=1.0))
        source = "residual" if self.mode == "torque-residual" else "fusion"
        executor.estimator.configure(EstimatorGains(source=source, observer_gain=OBSERVER_GAIN))
        executor.configure(feedback=True)


SCENARIO = MassDropScenario()
