"""The compiled kernels equal their plain-numpy references (control/kernels/).

Relative tolerance 1e-10 on each output (max abs difference over max abs entry), at random states
of both robots and at near-singular states where Λx reaches 1e5-1e6 (wrist singularity approached
from a random direction, on both sides of the damping threshold).

Near a singularity, Λx = (J M⁻¹ Jᵀ)⁻¹ is ill-conditioned: inputs that agree to machine precision
(M⁻¹ from two Cholesky/LU implementations, two LAPACK builds of eigh) give a Λx that agrees only
to about eps·κ, κ = cond(J M⁻¹ Jᵀ). The outputs derived from Λx are therefore held to
max(1e-10, 100·eps·κ) — the first-order bound for inverting an input known to eps — and everything
else to 1e-10 flat. The same bound covers the coupling and gradient kernels, whose algebra
(A⁻¹, D − BᵀA⁻¹B, Λx G Λx) loses digits to cancellation at those states.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from control.coupling import (
    Subspaces,
    coupling_gradient,
    coupling_gradient_direct,
    coupling_weights,
    task_scale,
    terms_of,
)
from control.gains import MotionForceGains, NullspaceGains
from control.kernel_registry import qp_problem
from control.kernels import chain as Kchain
from control.kernels import compliance as Kcompliance
from control.kernels import coupling as Kcoupling
from control.kernels import dense_qp as KQ
from control.kernels import estimation as Kestimation
from control.kernels import geometry as Kgeometry
from control.kernels import gradients as Kgradients
from control.kernels import law as Klaw
from control.kernels import line_qp as Kline_qp
from control.kernels import snapshot as Ksnapshot
from control.kernels.records import target_record
from control.model import SINGULAR_EIGENVALUE, RobotModel
from tests.conftest import random_configurations

RTOL = 1e-10
SUBSPACES = [Subspaces.from_force_axes(a) for a in (("pz",), ("px", "rz"), ("py", "pz", "rx"))]


def _rel(a, b, scale: float = 0.0) -> float:
    """max |a − b| over max |b| (or over `scale` when larger: the size of the terms b was computed from)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    return float(np.max(np.abs(a - b)) / max(float(np.max(np.abs(b))), scale, 1e-300))


def _tolerance(Lambda_inv: np.ndarray) -> float:
    """max(1e-10, 100·eps·cond(Λx⁻¹)): see the module docstring."""
    w = np.linalg.eigvalsh(Lambda_inv)
    return max(RTOL, 100 * np.finfo(float).eps * w[-1] / max(w[0], 1e-300))


def near_singular_configurations(robot, count: int, seed: int = 0) -> list[np.ndarray]:
    """Postures close to a singular one: min eig of J M⁻¹ Jᵀ from ~1e-4 down to ~1e-8."""
    model = RobotModel(robot.model)
    rng = np.random.default_rng(seed)
    q_sing = np.zeros(robot.model.nq)  # straight up: shoulder and wrist axes aligned (both robots)
    assert model.compute(q_sing, np.zeros(7)).min_eig_Lambda_inv < 1e-9
    out = []
    for scale in np.geomspace(3e-1, 3e-5, count):
        d = rng.standard_normal(robot.model.nq)
        out.append(q_sing + scale * d / np.linalg.norm(d))
    return out


def _states(robot, seed: int):
    return random_configurations(robot, 4, seed=seed) + near_singular_configurations(robot, 6, seed=seed)


def test_near_singular_states_cover_both_sides_of_the_damping_threshold(robot):
    model = RobotModel(robot.model)
    eigs = [model.compute(q, np.zeros(7)).min_eig_Lambda_inv for q in near_singular_configurations(robot, 6)]
    assert min(eigs) < SINGULAR_EIGENVALUE < max(eigs)
    assert max(np.abs(model.compute(q, np.zeros(7)).Lambda).max() for q in near_singular_configurations(robot, 6)) > 1e5


def test_snapshot_kernel_equals_numpy_reference(robot):
    model = RobotModel(robot.model)
    rng = np.random.default_rng(5)
    for q in _states(robot, seed=11):
        dq = rng.uniform(-1, 1, 7)
        fused, ref = model.compute(q, dq), model.compute_reference(q, dq)
        assert fused.near_singular == ref.near_singular
        for name in ("M", "M_inv", "h", "J", "dJ_dq", "Lambda_inv"):
            assert _rel(getattr(fused, name), getattr(ref, name)) < RTOL, name
        tol = _tolerance(ref.Lambda_inv)
        for name in ("Lambda", "J_bar", "N", "Lambda_n"):
            assert _rel(getattr(fused, name), getattr(ref, name)) < tol, (name, fused.min_eig_Lambda_inv)
        assert abs(fused.min_eig_Lambda_inv - ref.min_eig_Lambda_inv) < RTOL * np.abs(ref.Lambda_inv).max()


def test_snapshot_kernel_for_more_than_one_redundant_joint_uses_the_pseudo_inverse():
    """n = 8 (a random SPD M and a random 6×8 J): Λn from the eigh path equals the reference."""
    rng = np.random.default_rng(3)
    A = rng.standard_normal((8, 8))
    M = A @ A.T + 8 * np.eye(8)
    J = rng.standard_normal((6, 8))
    for a, b in zip(
        Ksnapshot.snapshot_fused(np.triu(M), J, 1e-6), Ksnapshot.snapshot_reference(np.triu(M), J, 1e-6), strict=True
    ):
        assert _rel(a, b) < RTOL


TASK_SCALES = {"SI": task_scale(), "L_c=0.2m,m_c=3kg": task_scale(0.2, 3.0)}


@pytest.mark.parametrize("units", TASK_SCALES.values(), ids=TASK_SCALES.keys())
@pytest.mark.parametrize("sub", SUBSPACES, ids=lambda s: "+".join(s.names()[1]))
def test_coupling_kernel_equals_numpy_reference(robot, sub, units):
    model = RobotModel(robot.model)
    for q in _states(robot, seed=12):
        dyn = model.compute(q, np.zeros(7))
        for exact in (True, False):
            fused = Kcoupling.coupling_fused(dyn.Lambda, dyn.Lambda_inv, sub.perm, sub.n_m, exact, units)
            ref = Kcoupling.coupling_reference(dyn.Lambda, dyn.Lambda_inv, sub.perm, sub.n_m, exact, units)
            tol = _tolerance(dyn.Lambda_inv)
            for i, (a, b) in enumerate(zip(fused, ref, strict=True)):
                # D̂ = D − BᵀA⁻¹B (inexact path) is a difference of terms of the size of D
                scale = float(np.abs(ref[2]).max()) if i == 4 and not exact else 0.0
                assert _rel(a, b, scale) < tol, (i, exact, dyn.min_eig_Lambda_inv)


def test_kinematic_hessian_from_J_equals_pinocchio(robot):
    model = RobotModel(robot.model)
    assert model.revolute_chain
    for q in _states(robot, seed=13):
        H = Kchain.kinematic_hessian_reference(model.tcp_jacobian(q))
        H_pin = model.tcp_jacobian_derivative(q)
        assert np.max(np.abs(H - H_pin)) < 1e-12 * max(1.0, np.abs(H_pin).max())


def test_tcp_bias_acceleration_from_J_equals_pinocchio(robot):
    """J̇q̇ from J and q̇ (serial revolute chain) against Pinocchio's classical TCP acceleration at
    q̈ = 0; the compiled O(n) form against the Hessian-sum reference."""
    model = RobotModel(robot.model)
    rng = np.random.default_rng(21)
    for q in _states(robot, seed=15):
        dq = rng.uniform(-2, 2, 7)
        pin.computeAllTerms(model.model, model.data, q, dq)
        J = pin.getFrameJacobian(model.model, model.data, model.tcp_frame_id, pin.LOCAL_WORLD_ALIGNED)
        expected = pin.getFrameClassicalAcceleration(
            model.model, model.data, model.tcp_frame_id, pin.LOCAL_WORLD_ALIGNED
        ).vector.copy()
        ref = Kchain.tcp_bias_acceleration_reference(J, dq)
        fused = np.empty(6)
        Kchain.tcp_bias_acceleration_into(J, dq, fused)
        assert _rel(ref, expected) < 1e-12
        assert _rel(fused, ref) < 1e-13
        assert _rel(model.compute(q, dq).dJ_dq, expected) < 1e-12


@pytest.mark.parametrize("scale", TASK_SCALES.values(), ids=TASK_SCALES.keys())
@pytest.mark.parametrize("sub", SUBSPACES, ids=lambda s: "+".join(s.names()[1]))
@pytest.mark.parametrize("objective", ["f", "a", "d"])
def test_gradient_contraction_kernel_equals_numpy_reference(robot, sub, objective, scale):
    model = RobotModel(robot.model)
    weight = coupling_weights(sub, scale)[objective]
    for q in _states(robot, seed=14):
        dyn = model.compute(q, np.zeros(7))
        t = terms_of(dyn, sub)
        P = {"f": t.P_f, "a": t.P_a, "d": t.P_d}[objective]
        args = (dyn.M_inv, dyn.Lambda, dyn.Lambda_inv, P, t.A_inv, sub.perm, sub.n_m, weight)
        fused = Kgradients.gradient_contraction_fused(Kgradients.OBJECTIVE_CODES[objective], dyn.J, *args)
        ref = Kgradients.gradient_contraction_reference(objective, dyn.J, model.tcp_jacobian_derivative(q), *args)
        for a, b in zip(fused, ref, strict=True):
            assert _rel(a, b) < _tolerance(dyn.Lambda_inv), dyn.min_eig_Lambda_inv


@pytest.mark.parametrize("scale", TASK_SCALES.values(), ids=TASK_SCALES.keys())
@pytest.mark.parametrize("objective", ["f", "a", "d"])
def test_direct_gradient_equals_gradient_through_dLambda(robot, objective, scale):
    """The fused ∂W/∂q path against the one through the full (n, 6, 6) ∂Λx/∂q (random states)."""
    model = RobotModel(robot.model)
    sub = SUBSPACES[0]
    for q in random_configurations(robot, 3, seed=15):
        dyn = model.compute(q, np.zeros(7))
        t = terms_of(dyn, sub)
        W1, g1 = coupling_gradient(t, dyn.Lambda_inv, model.dLambda_dq(dyn), sub, objective, scale)
        W2, g2 = coupling_gradient_direct(model, dyn, t, sub, objective, scale)
        assert abs(W1 - W2) <= RTOL * abs(W1)
        assert _rel(g2, g1) < 1e-9


def test_classical_acceleration_after_compute_all_terms_is_the_bias_acceleration(rizon):
    """compute() reads J̇q̇ after computeAllTerms: the same as forwardKinematics with q̈ = 0."""
    model = RobotModel(rizon.model)
    q, dq = random_configurations(rizon, 1, seed=16)[0], np.linspace(-1, 1, 7)
    data = rizon.model.createData()
    pin.forwardKinematics(rizon.model, data, q, dq, np.zeros(7))
    pin.updateFramePlacements(rizon.model, data)
    fid = rizon.model.getFrameId("tcp")
    expected = pin.getFrameClassicalAcceleration(rizon.model, data, fid, pin.LOCAL_WORLD_ALIGNED).vector
    np.testing.assert_allclose(model.compute(q, dq).dJ_dq, expected, rtol=0, atol=1e-12)


@pytest.mark.parametrize("sub", SUBSPACES, ids=lambda s: "+".join(s.names()[1]))
@pytest.mark.parametrize("shaping", [True, False])
def test_projection_law_kernels_equal_numpy_reference(robot, sub, shaping):
    """[T7, T11-14] around the QP: the task wrench and the joint torque, random inputs."""
    model = RobotModel(robot.model)
    rng = np.random.default_rng(17)
    for q in _states(robot, seed=18):
        dyn = model.compute(q, rng.uniform(-1, 1, 7))
        t = terms_of(dyn, sub)
        e, velocity, acceleration = (rng.standard_normal(6) for _ in range(3))
        law = Klaw.law_record(
            MotionForceGains(force_kp=0.5, force_kd=200.0, shaping=shaping), NullspaceGains(), objective=0, k0=1.0,
            n_m=sub.n_m, perm=sub.perm, kp_m=rng.uniform(10, 4000, sub.n_m), kd_scale_m=rng.uniform(0.5, 200, sub.n_m),
            q_lower=robot.q_lower, q_upper=robot.q_upper, dq_limit=robot.dq_max, endless=robot.endless, kn=np.ones(7),
            closed_form=False, task_scale=task_scale(),
        )  # fmt: skip
        target = target_record(np.zeros(3), np.eye(3), velocity, acceleration, np.zeros(6))
        args = (
            dyn.record, target, e, t.A, t.P_d, t.P_f, rng.standard_normal(6), rng.standard_normal(sub.n_f),
            rng.standard_normal(sub.n_f), law,
        )  # fmt: skip
        fused, ref = Klaw.task_wrench_fused(*args), Klaw.task_wrench_reference(*args)
        tol = _tolerance(dyn.Lambda_inv)
        for a, b in zip(fused, ref, strict=True):
            assert _rel(a, b) < tol
        targs = (dyn.J, ref[1], dyn.N, dyn.Lambda_n, rng.uniform(1, 100, 7), rng.standard_normal(7), dyn.dq, dyn.h)
        assert _rel(Klaw.joint_torque_fused(*targs), Klaw.joint_torque_reference(*targs)) < tol


def test_damper_bounds_kernel_equals_numpy_reference(robot):
    """Random postures, some inside d_s, d_i or beyond a limit, endless joints included."""
    from control.gains import NullspaceGains
    from control.nullspace import damper_bounds

    rng = np.random.default_rng(19)
    gains = NullspaceGains()
    endless = np.asarray(robot.endless, dtype=bool)
    dq_limit = 0.5 * np.asarray(robot.dq_max, dtype=float)
    for _ in range(200):
        edge = np.where(rng.random(7) < 0.5, robot.q_lower, robot.q_upper)
        q = edge + rng.uniform(-0.35, 0.35, 7)  # around a limit: outside, inside d_s, inside d_i, free
        ref = damper_bounds(q, robot.q_lower, robot.q_upper, dq_limit, endless, gains)
        fused = Klaw.damper_bounds_fused(
            q, robot.q_lower, robot.q_upper, dq_limit, endless,
            gains.damper_influence, gains.damper_safety, gains.damper_speed,
        )  # fmt: skip
        for a, b in zip(fused, ref, strict=True):
            np.testing.assert_array_equal(a, b)


def test_swivel_of_points_equals_swivel_angle(robot):
    """The per-step float version of the swivel formula agrees with `coupling.swivel_angle`."""
    from control.coupling import swivel_angle
    from control.planner import swivel_of_points

    model = RobotModel(robot.model)
    data = robot.model.createData()
    for q in random_configurations(robot, 20, seed=20):
        pin.forwardKinematics(robot.model, data, q)
        points = [data.oMi[j].translation for j in (2, 4, 6)]
        assert abs(swivel_of_points(*points) - swivel_angle(model, q)) < 1e-12
        anchors = np.array([data.oMi[j].translation for j in range(robot.model.njoints)])
        assert abs(Kgeometry.swivel_of_anchors_fused(anchors, 2, 4, 6) - swivel_of_points(*points)) < 1e-14


def test_inertia_contraction_kernel_equals_rnea_derivatives(robot):
    """aᵀ ∂M/∂q_k b from the chain's kinematics and inertias equals Pinocchio's RNEA derivatives."""
    model = RobotModel(robot.model)
    rng = np.random.default_rng(21)
    for q in _states(robot, seed=22):
        a, b = rng.standard_normal(7), rng.standard_normal(7)
        ref = model.mass_matrix_derivative_times(q, b).T @ a
        assert _rel(Kchain.inertia_contraction_fused(q, *model.chain, a, b), ref) < RTOL


@pytest.mark.parametrize("form", ["proposed", "classic"])
def test_acceleration_bounds_kernel_equals_numpy_reference(robot, form):
    """[C13-24] damper bounds, bit for bit, at states inside, near and beyond the limits."""
    from control.dampers import JointLimitDamper
    from control.gains import DamperGains

    damper = JointLimitDamper(
        robot.q_lower, robot.q_upper, robot.dq_max, robot.endless, DamperGains(form=form), dt=1e-3
    )
    rng = np.random.default_rng(23)
    crossed = 0
    for _ in range(300):
        edge = np.where(rng.random(7) < 0.5, robot.q_lower, robot.q_upper)
        q = edge + rng.uniform(-0.3, 0.3, 7)
        dq = rng.uniform(-3, 3, 7) * robot.dq_max
        fused, ref = damper.bounds(q, dq), damper.bounds_reference(q, dq)
        np.testing.assert_array_equal(fused.lower, ref.lower)
        np.testing.assert_array_equal(fused.upper, ref.upper)
        assert fused.crossed == ref.crossed
        crossed += ref.crossed
    assert 0 < crossed < 300  # both branches exercised


def test_nullspace_line_qp_kernel_equals_numpy_reference(robot):
    """[T15-17] closed form on the kernel line: random and near-singular states, gradients small and
    large (bounds active), boxes that exclude zero (no solution: both say so), a rank-deficient J.
    The kernel direction of J is known to about eps·cond(J) (QR against SVD): held to
    max(1e-10, 100·eps·cond(J))."""
    model = RobotModel(robot.model)
    rng = np.random.default_rng(31)
    solved = active = 0
    for q in _states(robot, seed=32) * 8:
        J = model.compute(q, np.zeros(7)).J
        g = rng.standard_normal(7) * rng.choice([0.01, 1.0, 30.0])
        lower, upper = -rng.uniform(0.1, 2.0, 7), rng.uniform(0.1, 2.0, 7)
        if rng.random() < 0.2:  # a damper pushing one joint out: 0 not in its box
            k = rng.integers(7)
            lower[k], upper[k] = 0.05, 1.0
        x = np.full(7, np.nan)
        code = Kline_qp.nullspace_line_qp_fused(J, g, lower, upper, x)
        ref = Kline_qp.nullspace_line_qp_reference(J, g, lower, upper)
        if ref is None:
            assert code == -1
            continue
        solved += 1
        active += ref[1]
        assert code == ref[1]
        sv = np.linalg.svd(J, compute_uv=False)
        tol = max(RTOL, 100 * np.finfo(float).eps * sv[0] / sv[-1])
        assert float(np.max(np.abs(x - ref[0]))) <= tol * max(1.0, float(np.max(np.abs(ref[0]))))
    assert solved >= 40 and active >= 10
    J = model.compute(robot.home, np.zeros(7)).J.copy()
    J[5] = J[4]  # rank 5: a two-dimensional kernel, not a line
    assert Kline_qp.nullspace_line_qp_reference(J, np.ones(7), -np.ones(7), np.ones(7)) is None
    assert Kline_qp.nullspace_line_qp_fused(J, np.ones(7), -np.ones(7), np.ones(7), np.empty(7)) == -1


@pytest.mark.parametrize("objective", ["j", "f", "a", "d"])
@pytest.mark.parametrize("axes", ["pz", "pz rz", "px py pz"])
def test_fused_projection_step_equals_the_step_kernel_by_kernel(robot, objective, axes):
    """[T7-17] `projection_law_fused`: the executor's fused step gives the torque, W values, QP
    result and task wrench of its reference step (the kernels called one by one), at random and
    near-singular states, with and without shaping, force integral on, some joints near limits."""
    from dataclasses import replace

    from control.executor import ControlInputs, TaskTarget
    from control.gains import MotionForceGains, NullspaceGains
    from control.motion_force import make_projection_executor

    model = RobotModel(robot.model)
    rng = np.random.default_rng(33)
    gains = replace(MotionForceGains(), force_axes=axes, force_ki=5.0)
    solved_in_the_law = 0  # steps whose QP the compiled step solved in closed form (solve_us NaN)
    for shaping in (True, False):
        kw = {"gains": replace(gains, shaping=shaping), "nullspace": NullspaceGains(objective=objective)}
        fused = make_projection_executor(robot, model, **kw)
        ref = make_projection_executor(robot, model, fused=False, **kw)
        assert fused.fused and not ref.fused
        for k, q in enumerate(_states(robot, seed=34)):
            dyn = model.compute(q, rng.uniform(-1, 1, 7))
            target = TaskTarget(
                dyn.tcp_position_world + 0.02 * rng.standard_normal(3), dyn.tcp_rotation_world,
                velocity=rng.standard_normal(6), acceleration=rng.standard_normal(6),
                wrench=np.r_[rng.standard_normal(3) * 5, 0, 0, 0], q_posture=q + 0.1 * rng.standard_normal(7),
            )  # fmt: skip
            if k == 0:
                fused.reset(dyn, target)
                ref.reset(dyn, target)
            inputs = ControlInputs(0.0, target, rng.standard_normal(6) * 10)
            a, b = fused.step(dyn, inputs), ref.step(dyn, inputs)
            tol = _tolerance(dyn.Lambda_inv)
            assert a.fallback == b.fallback
            assert _rel(a.tau, b.tau) < tol
            assert _rel(fused.last_wrench, ref.last_wrench) < tol
            assert _rel(fused.last_qp.x, ref.last_qp.x, scale=1.0) < tol
            assert _rel(fused.force_integral, ref.force_integral) < RTOL
            for key in ("W", "W_f", "W_a", "W_d", "coupled_accel", "nullspace_speed"):
                assert _rel(a.info[key], b.info[key], scale=1e-12) < tol, key
            for name in ("P_f", "P_a", "P_d"):
                assert _rel(getattr(fused.last_terms, name), getattr(ref.last_terms, name)) < tol
            solved_in_the_law += int(np.isnan(fused.last_qp.solve_us))
    assert solved_in_the_law >= 10  # of 20 steps


def test_log3_kernel_equals_pinocchio_log3():
    """The orientation error's SO(3) log: random rotations, small angles (1e-9…1e-3 rad, the held
    tool) and angles up to 1e-6 short of π. Equal to the rotation vector θ·axis the rotation was
    made from to 1e-14 rad, and to `pinocchio.log3` to 1e-12 rad below 3 rad (nearer π Pinocchio's
    own error reaches ~1e-11 there: held to 1e-10)."""
    rng = np.random.default_rng(35)
    angles = np.r_[rng.uniform(0, np.pi, 200), np.geomspace(1e-9, 1e-3, 50), np.pi - np.geomspace(1e-6, 1e-2, 50)]
    for angle in angles:
        axis = rng.standard_normal(3)
        axis /= np.linalg.norm(axis)
        R = pin.exp3(angle * axis)
        ours = Kgeometry.log3_fused(R)
        assert float(np.max(np.abs(ours - angle * axis))) < 1e-14
        assert float(np.max(np.abs(ours - pin.log3(R)))) < (1e-12 if angle < 3.0 else 1e-10)


def test_pose_task_rows_and_objective_kernels_equal_numpy_reference(robot):
    """[C3-9] the pose task's right-hand side (with and without Γ) and a soft task's share of the
    QP objective, at random states and targets."""
    from control.compliance_qp import PoseTask
    from control.executor import TaskTarget
    from control.gains import PoseTaskGains

    model = RobotModel(robot.model)
    rng = np.random.default_rng(36)
    for k, q in enumerate(_states(robot, seed=37)):
        dyn = model.compute(q, rng.uniform(-1, 1, 7))
        task = PoseTask(PoseTaskGains(stiffness=400.0, damping=40.0, compliance=0.5 if k % 2 else 0.0))
        R = pin.exp3(0.3 * rng.standard_normal(3)) @ dyn.tcp_rotation_world
        target = TaskTarget(
            dyn.tcp_position_world + 0.05 * rng.standard_normal(3), R,
            velocity=rng.standard_normal(6), acceleration=rng.standard_normal(6),
        )  # fmt: skip
        ddq_e = rng.standard_normal(7)
        fused, ref = task.rows(dyn, target, ddq_e), task.rows_reference(dyn, target, ddq_e)
        assert _rel(fused.b, ref.b) < RTOL
        P, qv = rng.standard_normal((7, 7)), rng.standard_normal(7)
        P_ref, q_ref = P + (ref.J.T * 3.0) @ ref.J, qv - (ref.J.T * 3.0) @ ref.b
        Kcompliance.add_task_rows_fused(P, qv, ref.J, ref.b, 3.0)
        assert _rel(P, P_ref) < RTOL and _rel(qv, q_ref) < RTOL


def test_posture_torque_rows_and_inverse_dynamics_kernels_equal_numpy_reference(robot):
    """[C7-10] the posture task's right-hand side (integral, Γ₀, a velocity reference), the torque
    rows of the QP and τ_d = M q̈ + h − τ_fb with its clipping, at random states."""
    from control.compliance_qp import PostureTask
    from control.executor import TaskTarget
    from control.gains import PostureTaskGains

    model = RobotModel(robot.model)
    rng = np.random.default_rng(38)
    tau_max = np.asarray(robot.tau_max, dtype=float)
    for k, q in enumerate(_states(robot, seed=39)):
        dyn = model.compute(q, rng.uniform(-1, 1, 7))
        gains = PostureTaskGains(stiffness=30.0, damping=8.0, integral=2.0 if k % 2 else 0.0)
        fused, ref = PostureTask(7, gains), PostureTask(7, gains)
        target = TaskTarget(dyn.tcp_position_world, dyn.tcp_rotation_world, q_posture=q + 0.1 * rng.standard_normal(7))
        for task in (fused, ref):
            task.reset(dyn, target)
            task.dq_ref = rng.standard_normal(7) if k % 3 else None
        fused.dq_ref = ref.dq_ref
        ddq_e = rng.standard_normal(7)
        for _ in range(3):  # the integral advances alike
            assert _rel(fused.rows(dyn, target, ddq_e).b, ref.rows_reference(dyn, target, ddq_e).b) < RTOL
        tau_fb = rng.standard_normal(7) * 5
        A, lo, up = np.zeros((7, 7)), np.zeros(7), np.zeros(7)
        Kcompliance.torque_rows_fused(dyn.M, dyn.h, tau_fb, tau_max, A, lo, up, True, 1e30)
        assert np.array_equal(A, dyn.M)
        assert np.array_equal(lo, -tau_max - dyn.h + tau_fb) and np.array_equal(up, tau_max - dyn.h + tau_fb)
        ddq = rng.standard_normal(7) * 50
        for clip in (False, True):
            tau, cmd, saturated = Kcompliance.inverse_dynamics_fused(dyn.M, ddq, dyn.h, tau_fb, tau_max, clip)
            tau_ref = dyn.M @ ddq + dyn.h - tau_fb
            tau_ref = np.clip(tau_ref, -tau_max, tau_max) if clip else tau_ref
            assert _rel(tau, tau_ref) < RTOL
            assert np.array_equal(cmd, np.clip(tau, -tau_max, tau_max))
            assert saturated == bool((np.abs(tau) > tau_max + 1e-9).any())


def test_estimation_kernels_equal_numpy_reference(robot):
    """[C25-26] the momentum observer's step and the sensor torque's high-pass, over a random
    sequence of states, torques and readings, against `update_reference` and `HighPass.update`."""
    from control.estimation import HighPass, MomentumObserver

    model = RobotModel(robot.model)
    rng = np.random.default_rng(40)
    fused, ref = MomentumObserver(7, 50.0, 1e-3), MomentumObserver(7, 50.0, 1e-3)
    hp_fused, hp_ref = HighPass(7, 50.0, 1e-3), HighPass(7, 50.0, 1e-3)
    for q in _states(robot, seed=41):
        dyn = model.compute(q, rng.uniform(-1, 1, 7))
        tau, wrench = rng.standard_normal(7) * 10, rng.standard_normal(6) * 10
        assert _rel(fused.update(dyn, tau), ref.update_reference(dyn, tau), scale=1.0) < RTOL
        if hp_fused.lp is None:
            hp_fused.update(dyn.J.T @ wrench)
            hp_ref.update(dyn.J.T @ wrench)
            continue
        tau_s, hp = Kestimation.sensor_high_pass_fused(dyn.J, wrench, hp_fused.lp, hp_fused.a)
        assert _rel(tau_s, dyn.J.T @ wrench) < RTOL
        assert _rel(hp, hp_ref.update(dyn.J.T @ wrench), scale=float(np.abs(tau_s).max())) < RTOL


def test_moved_wrench_equals_numpy_reference():
    """The F/T reading moved from the sensor to the TCP: the compiled transport against np.cross."""
    rng = np.random.default_rng(8)
    for _ in range(50):
        w, a, b = rng.normal(size=6) * 30, rng.normal(size=3), rng.normal(size=3)
        assert _rel(Kgeometry.move_wrench_fused(w, a, b), Kgeometry.move_wrench_reference(w, a, b)) < 1e-14


# ---- [C] QP kernels (control/kernels/dense_qp.py) ---------------------------------------------------
def test_dense_qp_load_kernel_equals_numpy_reference():
    """Same outcome code, same buffer and the same fast-path x (1e-10 relative) on feasible and
    active unconstrained optima, ±inf bounds, NaN, crossed bounds, a semidefinite P and
    equality rows."""
    rng = np.random.default_rng(21)
    seen = set()
    for k in range(120):
        n, m = (7, 7) if k % 3 else (5, 9)
        P, q, A, l, u, lb, ub = qp_problem(rng, n, m, active=k % 4 == 0)
        n_eq = 2 if k % 17 == 5 else 0
        if k % 10 == 3:
            ub[1], l[0] = np.inf, -np.inf
        if k % 10 == 7:
            lb[2] = 1e200  # its square overflows: the bounds are clipped to ±1e30, then cross
        if k % 23 == 11:
            q = q.copy()
            q[0] = np.nan
        if k % 29 == 13:
            lb[3], ub[3] = 1.0, -1.0
        if k % 31 == 2:
            P = np.outer(P[0], P[0])  # rank one: left to the solver
        out = {}
        for name, fn in (("ref", KQ.dense_qp_load_reference), ("fused", KQ.dense_qp_load_fused)):
            data, x = KQ.dense_qp_buffer(n, m), np.zeros(n)
            code = fn(data, KQ.dense_qp_setup(n, m, n_eq, 1e30, 1e-6), P, q, A, l, u, lb, ub, x)
            out[name] = code, data, x
        (c_ref, d_ref, x_ref), (c_fused, d_fused, x_fused) = out["ref"], out["fused"]
        assert c_ref == c_fused, k
        np.testing.assert_array_equal(d_fused, d_ref)
        seen.add(c_ref)
        if c_ref == KQ.FAST_SOLVED:
            assert _rel(x_fused, x_ref) < RTOL
            np.testing.assert_allclose(x_ref, -np.linalg.solve(P, q), rtol=1e-9)
    assert seen == {KQ.FAST_SOLVED, KQ.NEEDS_SOLVER, KQ.NON_FINITE_DATA, KQ.CROSSED_BOUNDS}


def test_unconstrained_optimum_kernel_agrees_with_the_backend_load_and_refuses_bad_data():
    """The fused [C] step's fast path (`unconstrained_optimum_fused`, on separate arrays) takes
    exactly the problems the backend's load takes, with the same x; NaN or crossed bounds: refused."""
    rng = np.random.default_rng(22)
    n_fast = 0
    for k in range(80):
        P, q, A, l, u, lb, ub = qp_problem(rng, 7, 7, active=k % 3 == 0)
        data, x_ref, x = KQ.dense_qp_buffer(7, 7), np.zeros(7), np.zeros(7)
        code = KQ.dense_qp_load_reference(data, KQ.dense_qp_setup(7, 7, 0, 1e30, 1e-6), P, q, A, l, u, lb, ub, x_ref)
        took = KQ.unconstrained_optimum_fused(P, q, A, lb, l, ub, u, 1e-6, x)
        assert took == (code == KQ.FAST_SOLVED)
        if took:
            n_fast += 1
            assert _rel(x, x_ref) < RTOL
        for spoil in ("nan", "crossed"):
            q2, lb2 = q.copy(), lb.copy()
            if spoil == "nan":
                q2[3] = np.nan
            else:
                lb2[2] = ub[2] + 1.0
            assert not KQ.unconstrained_optimum_fused(P, q2, A, lb2, l, ub, u, 1e-6, x)
    assert 30 <= n_fast <= 70
