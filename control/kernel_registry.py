"""Every compiled kernel with its plain-numpy reference and sample inputs: `KERNELS`.

`KERNELS[name] = KernelPair(compiled, reference, samples, tolerance, scratch)`: `reference` takes
the compiled kernel's arguments and returns the same outputs (and writes the same output buffers);
`samples(rng)` gives argument tuples at states of the shipped Rizon 4s (random postures inside the
limits, away from singularities: the near-singular states, where tolerances scale with the
condition number, are `tests/test_kernels.py`'s); `tolerance(args)` is the relative tolerance of
every output for those arguments; `scratch` names the argument positions that are work space.

`tests/test_kernels.py` enumerates every numba dispatcher of the `control.kernels` modules: a
compiled kernel that is not in this table fails, and every pair is held equal on its samples. A new
kernel goes in its subject's module beside its reference, and here.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any, NamedTuple

import numpy as np

from control.kernels import _linalg as L
from control.kernels import (
    chain,
    compliance,
    coupling,
    cqp,
    dense_qp,
    estimation,
    geometry,
    gradients,
    law,
    line_qp,
    snapshot,
)
from control.kernels.records import target_record

RTOL = 1e-10  # relative, on each output (max |a − b| over max |b|)
EPS = float(np.finfo(float).eps)


def _flat(args: tuple) -> float:
    return RTOL


class KernelPair(NamedTuple):
    """A compiled kernel, its reference (same arguments, same outputs) and how to test the two."""

    compiled: Any  # a numba dispatcher
    reference: Callable[..., Any]
    samples: Callable[[np.random.Generator], list[tuple]]
    tolerance: Callable[[tuple], float] = _flat
    scratch: tuple[int, ...] = ()  # argument positions the kernel uses as work space


# ---- states of the shipped arm -------------------------------------------------------------------
@functools.cache
def sample_arm() -> tuple:
    """(the arm the samples' states are drawn on, the Rizon 4s; its `RobotModel`), built once per process."""
    import robots
    from control.model import RobotModel

    robot = robots.load("rizon4s")
    return robot, RobotModel(robot.model)


_PLAIN_STATES = False  # `states` from the plain-numpy snapshot (`use_plain_states`)


def use_plain_states() -> None:
    """From now on `states` builds its snapshots with the plain-numpy algebra (`RobotModel.compute_reference`),
    which compiles nothing: the same record type as the compiled snapshot's, the same values to rounding.
    A first start's worker process (`app.live.warm_workers`) then compiles a kernel on its samples
    without waiting for another process to compile the snapshot."""
    global _PLAIN_STATES
    _PLAIN_STATES = True


def state_at(model: Any, q: np.ndarray, dq: np.ndarray) -> Any:
    """`model.compute(q, dq)`, or its plain-numpy form after `use_plain_states`."""
    return model.compute_reference(q, dq) if _PLAIN_STATES else model.compute(q, dq)


def states(rng: np.random.Generator, count: int = 4) -> list:
    """`Dynamics` snapshots of the Rizon 4s at random postures (margin 0.9 of the limits, min eig of
    Λx⁻¹ above 1e-3) and velocities in ±1 rad/s."""
    robot, model = sample_arm()
    lo = np.where(robot.endless, -np.pi, robot.q_lower)
    hi = np.where(robot.endless, np.pi, robot.q_upper)
    mid, half = (lo + hi) / 2, (hi - lo) / 2 * 0.9
    out: list = []
    while len(out) < count:
        dyn = state_at(model, rng.uniform(mid - half, mid + half), rng.uniform(-1, 1, 7))
        if dyn.min_eig_Lambda_inv > 1e-3:
            out.append(dyn)
    return out


def lambda_tolerance(Lambda_inv: np.ndarray) -> float:
    """max(1e-10, 100·eps·cond(Λx⁻¹)): outputs derived from Λx = (J M⁻¹ Jᵀ)⁻¹ agree to about eps·κ
    when their inputs agree to eps (see `tests/test_kernels.py`)."""
    w = np.linalg.eigvalsh(Lambda_inv)
    return max(RTOL, 100 * EPS * w[-1] / max(w[0], 1e-300))


def _rotation(rng: np.random.Generator, max_angle: float = 3.0) -> np.ndarray:
    axis = rng.standard_normal(3)
    axis /= np.linalg.norm(axis)
    K = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    t = rng.uniform(0.0, max_angle)
    return np.eye(3) + np.sin(t) * K + (1.0 - np.cos(t)) * (K @ K)


def _spd(rng: np.random.Generator, n: int) -> np.ndarray:
    G = rng.standard_normal((n, n))
    return G @ G.T + n * np.eye(n)


# ---- small helpers (control.kernels._linalg) -------------------------------------------------------
def _matmul_into_ref(A, B, out):
    out[:] = A @ B


def _matmul_bt_into_ref(A, B, out):
    out[:] = A @ B.T


def _symmetrise_ref(A):
    A[:] = 0.5 * (A + A.T)


def _cholesky_into_ref(A, shift, Lout):
    n = A.shape[0]
    try:
        factor = np.linalg.cholesky(A - shift * np.eye(n))
    except np.linalg.LinAlgError:
        return False
    rows, cols = np.tril_indices(n)
    Lout[rows, cols] = factor[rows, cols]
    return True


def _spd_inverse_into_ref(A, L_, Li, out):
    out[:] = np.linalg.inv(A)
    return True


def _cross_ref(a, b, out):
    out[:] = np.cross(a, b)


def _mat3_vec_ref(A, x, out):
    out[:] = A @ x


def _mat3_mat_ref(A, B, out):
    out[:] = A @ B


def _pairs(rng, make, count=5):
    return [make(rng) for _ in range(count)]


def _linalg_entries() -> dict[str, KernelPair]:
    def two(rng, m, k, n, bt=False, out=True):
        A = rng.standard_normal((m, k))
        B = rng.standard_normal((n, k) if bt else (k, n))
        return (A, B, np.zeros((m, n))) if out else (A, B)

    return {
        "_matmul_into": KernelPair(L._matmul_into, _matmul_into_ref, lambda r: _pairs(r, lambda g: two(g, 6, 7, 6))),
        "_matmul_bt_into": KernelPair(
            L._matmul_bt_into, _matmul_bt_into_ref, lambda r: _pairs(r, lambda g: two(g, 7, 7, 6, bt=True))
        ),
        "_matmul": KernelPair(L._matmul, np.matmul, lambda r: _pairs(r, lambda g: two(g, 6, 7, 5, out=False))),
        "_matmul_bt": KernelPair(
            L._matmul_bt, lambda A, B: A @ B.T, lambda r: _pairs(r, lambda g: two(g, 7, 6, 6, bt=True, out=False))
        ),
        "_symmetrise": KernelPair(L._symmetrise, _symmetrise_ref, lambda r: _pairs(r, lambda g: (g.random((7, 7)),))),
        "_sym_from_eig": KernelPair(
            L._sym_from_eig,
            lambda V, f: (V * f) @ V.T,
            lambda r: _pairs(r, lambda g: (np.linalg.qr(g.standard_normal((6, 6)))[0], g.uniform(-2, 2, 6))),
        ),
        "_cholesky_into": KernelPair(
            L._cholesky_into,
            _cholesky_into_ref,
            lambda r: _pairs(r, lambda g: (_spd(g, 7), float(g.uniform(0, 1)), np.zeros((7, 7)))),
        ),
        "_spd_inverse_into": KernelPair(
            L._spd_inverse_into,
            _spd_inverse_into_ref,
            lambda r: _pairs(r, lambda g: (_spd(g, 7), np.zeros((7, 7)), np.zeros((7, 7)), np.zeros((7, 7)))),
            scratch=(1, 2),
        ),
        "_inverse": KernelPair(L._inverse, np.linalg.inv, lambda r: _pairs(r, lambda g: (g.standard_normal((5, 5)),))),
        "_sqnorm": KernelPair(
            L._sqnorm, lambda P: float(np.sum(P * P)), lambda r: _pairs(r, lambda g: (g.standard_normal((2, 4)),))
        ),
        "_cross": KernelPair(
            L._cross,
            _cross_ref,
            lambda r: _pairs(r, lambda g: (g.standard_normal(3), g.standard_normal(3), np.zeros(3))),
        ),
        "_mat3_vec": KernelPair(
            L._mat3_vec,
            _mat3_vec_ref,
            lambda r: _pairs(r, lambda g: (g.standard_normal((3, 3)), g.standard_normal(3), np.zeros(3))),
        ),
        "_mat3_mat": KernelPair(
            L._mat3_mat,
            _mat3_mat_ref,
            lambda r: _pairs(r, lambda g: (g.standard_normal((3, 3)), g.standard_normal((3, 3)), np.zeros((3, 3)))),
        ),
        "_np_max": KernelPair(
            L._np_max,
            lambda a, b: float(np.maximum(a, b)),
            lambda r: [(1.0, 2.0), (-3.0, -4.0), (np.nan, 1.0), (1.0, np.nan), (np.inf, 0.0)],
        ),
    }


# ---- the snapshot, the chain, coupling and gradients [T2-6, T9, T22, T24-27] ----------------------
def _snapshot_samples(rng):  # (M upper, J, ρ)
    out = []
    for dyn in states(rng, 3):
        # column-major, as Pinocchio's `data.M` is when `RobotModel.compute` passes it: the type the loop meets
        out.append((np.asfortranarray(np.triu(dyn.M)), dyn.J, 1e-6))
    return out


def _snapshot_into_samples(rng):
    out = []
    for k, (M_upper, J, rho) in enumerate(_snapshot_samples(rng)):
        n = J.shape[1]
        snap = snapshot.snapshot_record(J, dq=rng.uniform(-1, 1, n))
        out.append((M_upper, rho, snap, snapshot.snapshot_work(n), k % 2 == 0))
    return out


def _snapshot_into_tolerance(args) -> float:
    M_upper, J = args[0], args[2][0]["J"]
    M = np.triu(M_upper) + np.triu(M_upper, 1).T
    return lambda_tolerance(J @ np.linalg.solve(M, J.T))


def _chain_samples(rng):
    _, model = sample_arm()
    return [(dyn.q, *model.chain, rng.standard_normal(7), rng.standard_normal(7)) for dyn in states(rng, 3)]


SUBSPACES = ((2,), (0, 5), (1, 2, 3))  # force axes (pz; px+rz; py+pz+rx)
# task scales of the W's (`control.coupling.task_scale`): SI units, and L_c = 0.3 m with m_c = 4 kg
SCALES = (np.ones(6), np.r_[np.full(3, 0.5), np.full(3, 0.5 / 0.3)])


def _perm(force: tuple[int, ...]) -> tuple[np.ndarray, int]:
    motion = [a for a in range(6) if a not in force]
    return np.array(motion + list(force), dtype=np.int64), len(motion)


def _coupling_samples(rng):
    out = []
    for dyn in states(rng, 2):
        for force in SUBSPACES:
            perm, n_m = _perm(force)
            for scale in SCALES:
                out += [(dyn.Lambda, dyn.Lambda_inv, perm, n_m, exact, scale) for exact in (True, False)]
    return out


def _gradient_reference(objective, J, M_inv, Lambda, Lambda_inv, P, A_inv, perm, n_m, weight):
    name = "fad"[objective]
    return gradients.gradient_contraction_reference(
        name, J, chain.kinematic_hessian_reference(J), M_inv, Lambda, Lambda_inv, P, A_inv, perm, n_m, weight
    )


def _gradient_samples(rng):
    out = []
    for dyn in states(rng, 2):
        for force in SUBSPACES:
            perm, n_m = _perm(force)
            blocks = coupling.coupling_reference(dyn.Lambda, dyn.Lambda_inv, perm, n_m, True, SCALES[0])
            for objective in range(3):
                P = blocks[5 + objective]
                for scale in SCALES:
                    w = coupling.coupling_weights_reference(scale, perm, n_m)[objective]
                    out.append((objective, dyn.J, dyn.M_inv, dyn.Lambda, dyn.Lambda_inv, P, blocks[3], perm, n_m, w))
    return out


def _pack_samples(rng):
    return [(chain.pack_chain(sample_arm()[1].chain),)]


# ---- the [T] law [T7, T11-18] ----------------------------------------------------------------------
def _task_wrench_samples(rng):
    out = []
    for dyn in states(rng, 2):
        for force in SUBSPACES:
            perm, n_m = _perm(force)
            n_f = 6 - n_m
            blocks = coupling.coupling_reference(dyn.Lambda, dyn.Lambda_inv, perm, n_m, True, SCALES[0])
            record = _law_args(rng, dyn, 3, force, 0.0)[2]
            for shaping in (True, False):
                record[0]["shaping"] = shaping
                target = target_record(
                    np.zeros(3), np.eye(3), rng.standard_normal(6), rng.standard_normal(6), np.zeros(6)
                )
                out.append((
                    dyn.record, target, rng.standard_normal(6), blocks[0], blocks[7], blocks[5],
                    rng.standard_normal(6), rng.standard_normal(n_f), rng.standard_normal(n_f), record.copy(),
                ))  # fmt: skip
    return out


def _joint_torque_samples(rng):
    return [
        (
            dyn.J,
            rng.standard_normal(6),
            dyn.N,
            dyn.Lambda_n,
            rng.uniform(1, 100, 7),
            rng.standard_normal(7),
            dyn.dq,
            dyn.h,
        )
        for dyn in states(rng, 3)
    ]


def _damper_bounds_samples(rng):
    robot, _ = sample_arm()
    out = []
    for _ in range(20):
        edge = np.where(rng.random(7) < 0.5, robot.q_lower, robot.q_upper)
        q = edge + rng.uniform(-0.35, 0.35, 7)  # outside, inside d_s, inside d_i, free
        endless = np.asarray(robot.endless, dtype=bool)
        out.append((q, robot.q_lower, robot.q_upper, 0.5 * robot.dq_max, endless, 0.2, 0.05, 0.5))
    return out


def _law_args(rng, dyn, objective: int, force: tuple[int, ...], ki: float, closed_form: bool = False) -> tuple:
    from control.gains import MotionForceGains, NullspaceGains

    robot, model = sample_arm()
    perm, n_m = _perm(force)
    gains = MotionForceGains(force_kp=0.5, force_kd=0.01, force_ki=ki, force_integral_limit_n=20.0,
                             shaping=bool(rng.random() < 0.5))  # fmt: skip
    nullspace = NullspaceGains(damper_influence=0.2, damper_safety=0.05, damper_speed=0.5)
    record = law.law_record(
        gains, nullspace, objective=objective, k0=30.0, n_m=n_m, perm=perm, kp_m=rng.uniform(100, 3000, n_m),
        kd_scale_m=rng.uniform(0.5, 2.0, n_m), q_lower=robot.q_lower, q_upper=robot.q_upper,
        dq_limit=0.5 * robot.dq_max, endless=robot.endless, kn=rng.uniform(1, 100, 7), closed_form=closed_form,
        task_scale=SCALES[int(rng.random() < 0.5)],
    )  # fmt: skip
    R = _rotation(rng, 0.3) @ dyn.tcp_rotation_world
    target = target_record(
        dyn.tcp_position_world + 0.02 * rng.standard_normal(3), R, rng.standard_normal(6), rng.standard_normal(6),
        np.r_[rng.standard_normal(3) * 5, 0, 0, 0],
    )  # fmt: skip
    step = np.zeros(1, law.projection_step_dtype(7))
    row = step[0]
    row["F_e"], row["q_d"] = rng.standard_normal(6) * 10, dyn.q + 0.1 * rng.standard_normal(7)
    row["force_integral"][: 6 - n_m] = rng.standard_normal(6 - n_m)
    return dyn.record, target, record, chain.pack_chain(model.chain), step


def _law_samples(rng):
    out = []
    for k, dyn in enumerate(states(rng, 4)):
        for objective in range(4):
            out.append(_law_args(rng, dyn, objective, SUBSPACES[(k + objective) % 3], 5.0 if k % 2 else 0.0))
    return out


def _step_samples(rng):
    out = []
    for k, dyn in enumerate(states(rng, 4)):
        for objective in range(4):
            args = _law_args(
                rng, dyn, objective, SUBSPACES[(k + objective) % 3], 5.0 if k % 2 else 0.0, bool(rng.random() < 0.8)
            )
            out.append(args)
    return out


def _law_tolerance(args) -> float:
    return lambda_tolerance(args[0][0]["Lambda_inv"])


def _line_qp_samples(rng):
    out = []
    for dyn in states(rng, 6):
        g = rng.standard_normal(7) * rng.choice([0.01, 1.0, 30.0])
        lower, upper = -rng.uniform(0.1, 2.0, 7), rng.uniform(0.1, 2.0, 7)
        if rng.random() < 0.3:  # a damper pushing one joint out: 0 not in its box
            k = rng.integers(7)
            lower[k], upper[k] = 0.05, 1.0
        out.append((dyn.J, g, lower, upper, np.zeros(7)))
    return out


def _line_qp_tolerance(args) -> float:
    """The kernel line of J is known to about eps·cond(J) (QR against SVD)."""
    sv = np.linalg.svd(args[0], compute_uv=False)
    return max(RTOL, 100 * EPS * sv[0] / sv[-1])


# ---- geometry ----------------------------------------------------------------------------------------
def _log3_samples(rng):
    return [(_rotation(rng),) for _ in range(20)] + [(_rotation(rng, 1e-6),) for _ in range(3)]


def _swivel_samples(rng):
    return [(rng.standard_normal((8, 3)), 2, 4, 6) for _ in range(10)]


def _wrench_samples(rng):
    return [(rng.normal(size=6) * 30, rng.normal(size=3), rng.normal(size=3)) for _ in range(10)]


# ---- the [C] rows, estimate and problem [C3-26] -------------------------------------------------------
def _pose_target_samples(rng):
    from control.compliance_qp import PoseTask
    from control.gains import PoseTaskGains

    out = []
    for k, dyn in enumerate(states(rng, 3)):
        task = PoseTask(PoseTaskGains(stiffness=400.0, damping=40.0, compliance=0.5 if k % 2 else 0.0))
        target = target_record(
            dyn.tcp_position_world + 0.05 * rng.standard_normal(3), _rotation(rng, 0.3) @ dyn.tcp_rotation_world,
            rng.standard_normal(6), rng.standard_normal(6), np.zeros(6),
        )  # fmt: skip
        out.append((dyn.record, target, task.kernel_record, rng.standard_normal(7)))
    return out


def _add_rows_samples(rng):
    return [
        (rng.standard_normal((7, 7)), rng.standard_normal(7), rng.standard_normal((6, 7)), rng.standard_normal(6), 3.0)
    ]


def _posture_samples(rng):
    from control.compliance_qp import PostureTask
    from control.gains import PostureTaskGains

    out = []
    for k, dyn in enumerate(states(rng, 3)):
        gains = PostureTaskGains(stiffness=30.0, damping=8.0, integral=2.0 * (k % 2), compliance=0.3 if k % 3 else 0.0)
        task = PostureTask(7, gains)
        out.append((
            dyn.record, dyn.q + 0.1 * rng.standard_normal(7), rng.standard_normal(7), rng.standard_normal(7) * 0.01,
            task.kernel_record, rng.standard_normal(7),
        ))  # fmt: skip
    return out


def _torque_rows_samples(rng):
    robot, _ = sample_arm()
    return [
        (dyn.M, dyn.h, rng.standard_normal(7) * 5, np.asarray(robot.tau_max, dtype=float), np.zeros((7, 7)),
         np.zeros(7), np.zeros(7), on, 1e30)
        for dyn, on in zip(states(rng, 2), (True, False), strict=True)
    ]  # fmt: skip


def _inverse_dynamics_samples(rng):
    robot, _ = sample_arm()
    tau_max = np.asarray(robot.tau_max, dtype=float)
    return [
        (dyn.M, rng.standard_normal(7) * 50, dyn.h, rng.standard_normal(7) * 5, tau_max, clip)
        for dyn, clip in zip(states(rng, 2), (True, False), strict=True)
    ]


def _acceleration_bounds_samples(rng):
    from control.dampers import JointLimitDamper
    from control.gains import DamperGains

    robot, _ = sample_arm()
    out = []
    for k in range(40):
        edge = np.where(rng.random(7) < 0.5, robot.q_lower, robot.q_upper)
        q = edge + rng.uniform(-0.3, 0.3, 7)
        dq = rng.uniform(-3, 3, 7) * robot.dq_max
        gains = DamperGains(form="proposed" if k % 2 else "classic")
        damper = JointLimitDamper(robot.q_lower, robot.q_upper, robot.dq_max, robot.endless, gains, dt=1e-3)
        out.append((q, dq, damper.kernel_record))
    return out


def _observer_samples(rng):
    out = []
    for dyn in states(rng, 3):
        out.append(
            (
                dyn.M,
                dyn.dq,
                rng.uniform(-1, 1, 7),
                rng.standard_normal(7) * 10,
                dyn.h,
                1e-3,
                0.95,
                rng.standard_normal(7),
            )
        )
    return out


def _high_pass_samples(rng):
    return [(dyn.J, rng.standard_normal(6) * 10, rng.standard_normal(7), 0.95) for dyn in states(rng, 3)]


def qp_problem(rng: np.random.Generator, n: int, m: int, active: bool) -> tuple:
    """(P, q, A, l, u, lb, ub): a strictly convex problem whose unconstrained optimum meets every bound
    and row (active False) or violates some (active True)."""
    P = _spd(rng, n) * 0.1 + 0.1 * np.eye(n)
    x_unc = rng.normal(size=n)
    q = -P @ x_unc
    A = rng.normal(size=(m, n))
    lb, ub = x_unc - rng.uniform(0.1, 1.0, n), x_unc + rng.uniform(0.1, 1.0, n)
    l, u = A @ x_unc - rng.uniform(0.1, 1.0, m), A @ x_unc + rng.uniform(0.1, 1.0, m)
    if active:
        k = rng.integers(n + m)
        if k < n:
            ub[k] = x_unc[k] - 0.05
            lb[k] = min(lb[k], ub[k] - 1.0)
        else:
            l[k - n] = (A @ x_unc)[k - n] + 0.05
            u[k - n] = max(u[k - n], l[k - n] + 1.0)
    return P, q, A, l, u, lb, ub


def _dense_load_samples(rng):
    out = []
    for k in range(12):
        n, m = (7, 7) if k % 3 else (5, 9)
        P, q, A, l, u, lb, ub = qp_problem(rng, n, m, active=k % 4 == 0)
        if k == 5:
            q[0] = np.nan
        if k == 7:
            lb[2] = 1e200  # its square overflows: the bounds are clipped to ±1e30, then cross
        if k == 9:
            lb[3], ub[3] = 1.0, -1.0
        n_eq = 2 if k == 10 else 0
        setup = dense_qp.dense_qp_setup(n, m, n_eq, 1e30, 1e-6)
        out.append((dense_qp.dense_qp_buffer(n, m), setup, P, q, A, l, u, lb, ub, np.zeros(n)))
    # P None: the P loaded before is kept (the compliance QP's call when only its vectors changed)
    data, setup, P, *rest = out[1]
    data = data.copy()
    dense_qp.dense_qp_load_reference(data, setup, P, *[a.copy() if isinstance(a, np.ndarray) else a for a in rest])
    out.append((data, setup, None, *rest))
    return out


def _unconstrained_samples(rng):
    out = []
    for k in range(10):
        P, q, A, l, u, lb, ub = qp_problem(rng, 7, 7, active=k % 3 == 0)
        if k == 4:
            q[3] = np.nan
        out.append((P, q, A, lb, l, ub, u, 1e-6, np.zeros(7)))
    return out


def _cqp_samples(rng):
    from control.compliance_qp import AccelerationQP, PoseTask, PostureTask
    from control.dampers import JointLimitDamper
    from control.estimation import ExternalTorqueEstimator
    from control.gains import ComplianceQPSettings, DamperGains, EstimatorGains, PostureTaskGains
    from control.kernels.records import fill_record

    robot, model = sample_arm()
    out = []
    tau_max = np.asarray(robot.tau_max, dtype=float)
    for k, dyn in enumerate(states(rng, 4)):
        pose = PoseTask()
        posture = PostureTask(
            7, PostureTaskGains(integral=2.0 if k % 2 else 0.0, metric="inertia" if k % 3 else "identity")
        )
        posture.integral[:] = rng.standard_normal(7) * 0.01
        damper = JointLimitDamper(robot.q_lower, robot.q_upper, robot.dq_max, robot.endless, DamperGains(), dt=1e-3)
        settings_group = ComplianceQPSettings(feedback=bool(k % 3 != 1), torque_limits=True)
        settings = fill_record(
            cqp.settings_record_dtype(7), (settings_group,), tau_max=tau_max, no_bound=1e30, pose_on=k != 3,
            fast_on=k != 2,
        )  # fmt: skip
        est = ExternalTorqueEstimator(7, EstimatorGains(source=("fusion", "residual", "none")[k % 3]), dt=1e-3)
        prev = state_at(model, dyn.q - 1e-3 * dyn.dq, dyn.dq + 0.01 * rng.standard_normal(7))
        est.observer.reset(prev)
        est.observer.r[:] = rng.standard_normal(7)
        est.high_pass.update(rng.standard_normal(7))
        est.estimate_on[0] = k % 2 == 0
        est.estimate[:], est.tau_prev[:], est.wrench[:] = (
            rng.standard_normal(7),
            rng.standard_normal(7) * 5,
            rng.standard_normal(6) * 5,
        )
        target = target_record(
            dyn.tcp_position_world + 0.02 * rng.standard_normal(3), _rotation(rng, 0.2) @ dyn.tcp_rotation_world,
            rng.standard_normal(6), rng.standard_normal(6), np.zeros(6),
        )  # fmt: skip
        aqp = AccelerationQP(7, 0, settings_group, "dense")
        aqp.q_ref[:], aqp.dq_ref[:] = dyn.q + 0.1 * rng.standard_normal(7), np.zeros(7)
        out.append((
            dyn.record, est.kernel_record, target, pose.kernel_record, posture.kernel_record, damper.kernel_record,
            settings, aqp.work,
        ))  # fmt: skip
    return out


KERNELS: dict[str, KernelPair] = {
    **_linalg_entries(),
    "snapshot_into": KernelPair(
        snapshot.snapshot_into,
        snapshot.snapshot_into_reference,
        _snapshot_into_samples,
        _snapshot_into_tolerance,
        (3,),
    ),
    "tcp_bias_acceleration_into": KernelPair(
        chain.tcp_bias_acceleration_into,
        chain.tcp_bias_acceleration_into_reference,
        lambda r: [(d.J, d.dq, np.zeros(6)) for d in states(r, 3)],
    ),
    "inertia_contraction_fused": KernelPair(
        chain.inertia_contraction_fused, chain.inertia_contraction_reference, _chain_samples
    ),
    "unpack_chain_fused": KernelPair(chain.unpack_chain_fused, chain.unpack_chain_reference, _pack_samples),
    "coupling_weights_fused": KernelPair(
        coupling.coupling_weights_fused,
        coupling.coupling_weights_reference,
        lambda r: [(scale, *_perm(force)) for scale in SCALES for force in SUBSPACES],
    ),
    "coupling_fused": KernelPair(
        coupling.coupling_fused, coupling.coupling_reference, _coupling_samples, lambda a: lambda_tolerance(a[1])
    ),
    "gradient_contraction_fused": KernelPair(
        gradients.gradient_contraction_fused, _gradient_reference, _gradient_samples, lambda a: lambda_tolerance(a[4])
    ),
    "log3_fused": KernelPair(geometry.log3_fused, geometry.log3_reference, _log3_samples),
    "move_wrench_fused": KernelPair(geometry.move_wrench_fused, geometry.move_wrench_reference, _wrench_samples),
    "swivel_of_anchors_fused": KernelPair(
        geometry.swivel_of_anchors_fused, geometry.swivel_of_anchors_reference, _swivel_samples
    ),
    "nullspace_line_qp_fused": KernelPair(
        line_qp.nullspace_line_qp_fused,
        line_qp.nullspace_line_qp_into_reference,
        _line_qp_samples,
        _line_qp_tolerance,
    ),
    "task_wrench_fused": KernelPair(
        law.task_wrench_fused,
        law.task_wrench_reference,
        _task_wrench_samples,
        lambda a: lambda_tolerance(a[0][0]["Lambda_inv"]),
    ),
    "joint_torque_fused": KernelPair(law.joint_torque_fused, law.joint_torque_reference, _joint_torque_samples),
    "damper_bounds_fused": KernelPair(law.damper_bounds_fused, law.damper_bounds_reference, _damper_bounds_samples),
    "projection_law_fused": KernelPair(
        law.projection_law_fused, law.projection_law_reference, _law_samples, _law_tolerance
    ),
    "projection_step_fused": KernelPair(
        law.projection_step_fused, law.projection_step_reference, _step_samples, _law_tolerance
    ),
    "pose_task_target_fused": KernelPair(
        compliance.pose_task_target_fused, compliance.pose_task_target_reference, _pose_target_samples
    ),
    "add_task_rows_fused": KernelPair(
        compliance.add_task_rows_fused, compliance.add_task_rows_reference, _add_rows_samples
    ),
    "posture_target_fused": KernelPair(
        compliance.posture_target_fused, compliance.posture_target_reference, _posture_samples
    ),
    "torque_rows_fused": KernelPair(
        compliance.torque_rows_fused, compliance.torque_rows_reference, _torque_rows_samples
    ),
    "inverse_dynamics_fused": KernelPair(
        compliance.inverse_dynamics_fused, compliance.inverse_dynamics_reference, _inverse_dynamics_samples
    ),
    "acceleration_bounds_fused": KernelPair(
        compliance.acceleration_bounds_fused, compliance.acceleration_bounds_reference, _acceleration_bounds_samples
    ),
    "momentum_observer_fused": KernelPair(
        estimation.momentum_observer_fused, estimation.momentum_observer_reference, _observer_samples
    ),
    "sensor_high_pass_fused": KernelPair(
        estimation.sensor_high_pass_fused, estimation.sensor_high_pass_reference, _high_pass_samples
    ),
    "dense_qp_load_fused": KernelPair(
        dense_qp.dense_qp_load_fused, dense_qp.dense_qp_load_reference, _dense_load_samples
    ),
    "unconstrained_optimum_fused": KernelPair(
        dense_qp.unconstrained_optimum_fused, dense_qp.unconstrained_optimum_reference, _unconstrained_samples
    ),
    "cqp_problem_fused": KernelPair(cqp.cqp_problem_fused, cqp.cqp_problem_reference, _cqp_samples),
}
