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

Every compiled kernel is paired with its reference in `control.kernel_registry.KERNELS` (a test
enforces it). This package imports nothing: a caller imports the subject module it needs, so that
loading one kernel does not compile or load the others.
"""
