"""Fused compiled kernels for the per-step algebra, each beside its plain-numpy reference, by subject.

The snapshot, the coupling blocks and the gradient contraction are small dense algebra on 6×7
matrices: in plain numpy every product and every `np.linalg` call costs more in Python overhead
than in arithmetic. Each `*_fused` function does the same algebra as the `*_reference` function
of the same name in one compiled call (numba, `cache=True`: compiled once per machine, then loaded
from `__pycache__`). The references are the readable statement of the formulas; the tests
(`tests/test_kernels.py`) hold the fused versions to them (relative 1e-10 over random and
near-singular states of both robots).

Modules:
- `records`: the named records the kernels read (parameter groups, the task target's named positions).
- `snapshot`: from M and the TCP Jacobian J: M⁻¹, Λx⁻¹, Λx [T3], J̄ [T2], N [T4], Λn [T5], into the
  snapshot's record (`control.model.Dynamics` is a view of it).
- `chain`: ∂J/∂q, J̇q̇ and the ∂M/∂q contraction [T24] of a serial revolute chain.
- `coupling`: blocks A, B, D [T6, T20], A⁻¹, D̂ [T9], P_f, P_a, P_d (Table I) and W [T22].
- `gradients`: the ∂J part of ∂W/∂q [T24-27] and the vectors of its ∂M part.
- `geometry`: log3 [T11], a wrench moved between points, the elbow swivel.
- `line_qp`: the 7-joint nullspace QP [T15-17] in closed form.
- `law`: the [T] law [T7, T11-14, T17] and its whole step in one call.
- `compliance`: the [C] task rows, objective, torque rows and dampers [C3-24].
- `estimation`: the momentum observer and the sensor's high pass [C25-26].
- `dense_qp`: the dense QP backend's load and exact fast path.
- `cqp`: the [C] executor's problem in one call.

Every compiled kernel is paired with its reference in `registry.KERNELS` (a test enforces it). The
names below are re-exported so that `control.kernels.X` reads as before the split.
"""

from control.kernels.chain import (
    chain_constants,
    inertia_contraction_fused,
    inertia_contraction_reference,
    kinematic_hessian_reference,
    pack_chain,
    tcp_bias_acceleration_into,
    tcp_bias_acceleration_reference,
)
from control.kernels.compliance import (
    acceleration_bounds_fused,
    add_task_rows_fused,
    inverse_dynamics_fused,
    pose_task_target_fused,
    posture_target_fused,
    torque_rows_fused,
)
from control.kernels.coupling import coupling_fused, coupling_reference
from control.kernels.cqp import cqp_problem_fused
from control.kernels.dense_qp import (
    CROSSED_BOUNDS,
    FAST_SOLVED,
    NEEDS_SOLVER,
    NON_FINITE_DATA,
    PIVOT_FLOOR,
    dense_qp_buffer,
    dense_qp_load_fused,
    dense_qp_load_reference,
    dense_qp_views,
    unconstrained_optimum_fused,
)
from control.kernels.estimation import momentum_observer_fused, sensor_high_pass_fused
from control.kernels.geometry import log3_fused, move_wrench_fused, move_wrench_reference, swivel_of_anchors_fused
from control.kernels.gradients import OBJECTIVE_CODES, gradient_contraction_fused, gradient_contraction_reference
from control.kernels.law import (
    OBJECTIVE_J,
    damper_bounds_fused,
    joint_torque_fused,
    joint_torque_reference,
    law_record,
    law_record_dtype,
    projection_law_fused,
    projection_step_fused,
    task_wrench_fused,
    task_wrench_reference,
)
from control.kernels.line_qp import LINE_QP_RANK, LINE_QP_TINY, nullspace_line_qp_fused, nullspace_line_qp_reference
from control.kernels.snapshot import (
    nullspace_inertia_reference,
    snapshot_fused,
    snapshot_into,
    snapshot_record,
    snapshot_record_dtype,
    snapshot_reference,
    snapshot_work,
)

__all__ = [
    "CROSSED_BOUNDS",
    "FAST_SOLVED",
    "LINE_QP_RANK",
    "LINE_QP_TINY",
    "NEEDS_SOLVER",
    "NON_FINITE_DATA",
    "OBJECTIVE_CODES",
    "OBJECTIVE_J",
    "PIVOT_FLOOR",
    "acceleration_bounds_fused",
    "add_task_rows_fused",
    "chain_constants",
    "coupling_fused",
    "coupling_reference",
    "cqp_problem_fused",
    "damper_bounds_fused",
    "dense_qp_buffer",
    "dense_qp_load_fused",
    "dense_qp_load_reference",
    "dense_qp_views",
    "gradient_contraction_fused",
    "gradient_contraction_reference",
    "inertia_contraction_fused",
    "inertia_contraction_reference",
    "inverse_dynamics_fused",
    "joint_torque_fused",
    "joint_torque_reference",
    "kinematic_hessian_reference",
    "law_record",
    "law_record_dtype",
    "log3_fused",
    "momentum_observer_fused",
    "move_wrench_fused",
    "move_wrench_reference",
    "nullspace_inertia_reference",
    "nullspace_line_qp_fused",
    "nullspace_line_qp_reference",
    "pack_chain",
    "pose_task_target_fused",
    "posture_target_fused",
    "projection_law_fused",
    "projection_step_fused",
    "sensor_high_pass_fused",
    "snapshot_fused",
    "snapshot_into",
    "snapshot_record",
    "snapshot_record_dtype",
    "snapshot_reference",
    "snapshot_work",
    "swivel_of_anchors_fused",
    "task_wrench_fused",
    "task_wrench_reference",
    "tcp_bias_acceleration_into",
    "tcp_bias_acceleration_reference",
    "torque_rows_fused",
    "unconstrained_optimum_fused",
]
