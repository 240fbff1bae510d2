"""Velocity dampers [C17–24]: bounds, and the closed-loop response of the proposed form."""

from __future__ import annotations

import numpy as np
import pytest

from app.sim.world import World
from control.compliance_qp import ComplianceQPExecutor, TaskRows
from control.dampers import JointLimitDamper, second_order_response
from control.executor import ControlInputs, TaskTarget
from control.gains import ComplianceQPSettings, DamperGains, EstimatorGains, PostureTaskGains
from control.model import RobotModel

JOINT = 3  # Gen3 joint 4, position-limited


def _damper(gen3, **kw):
    return JointLimitDamper(gen3.q_lower, gen3.q_upper, gen3.dq_max, gen3.endless, DamperGains(**kw))


def test_bad_damper_parameters_are_rejected():
    with pytest.raises(ValueError, match="lambda_"):
        DamperGains(lambda_=-1.0)
    with pytest.raises(ValueError, match="form"):
        DamperGains(form="magic")
    with pytest.raises(ValueError, match="influence_fraction"):
        DamperGains(safety_fraction=0.2, influence_fraction=0.1)


def test_proposed_bound_is_the_formula_of_c24_on_both_sides(gen3):
    d = _damper(gen3, lambda_=100.0, M=2.0)
    q = np.zeros(7)
    q[JOINT] = gen3.q_upper[JOINT] - 0.2
    dq = np.zeros(7)
    dq[JOINT] = 0.3
    b = d.bounds(q, dq)
    e, de = 0.2, -0.3
    d_s = 0.01 * (gen3.q_upper[JOINT] - gen3.q_lower[JOINT])
    e_p = -100.0 * de - 100.0**2 / (4 * 2.0**2) * (e - d_s)
    e_v = -100.0 * (de + gen3.dq_max[JOINT])
    assert b.upper[JOINT] == pytest.approx(-max(e_p, e_v), rel=1e-12)
    # mirrored state near the lower limit gives the mirrored bound
    b2 = d.bounds(-q, -dq)
    assert b2.lower[JOINT] == pytest.approx(-b.upper[JOINT], rel=1e-12)


def test_endless_joints_get_only_velocity_bounds(gen3):
    d = _damper(gen3)
    q = gen3.q_upper - 1e-3  # every joint at its "limit"
    b = d.bounds(q, np.zeros(7))
    for j in np.flatnonzero(gen3.endless):  # velocity bound only: λ q̇⁺ at rest
        assert b.upper[j] == pytest.approx(100.0 * gen3.dq_max[j])
    for j in np.flatnonzero(~gen3.endless):  # position bound pushes back
        assert b.upper[j] < 0


def test_classic_form_is_inactive_beyond_the_influence_distance(gen3):
    d = _damper(gen3, form="classic")
    q = np.zeros(7)  # mid-range: far beyond d_i
    b = d.bounds(q, np.zeros(7))
    assert b.upper[JOINT] == pytest.approx(gen3.dq_max[JOINT] / 1e-3)  # only the velocity row [C18]


class ConstantPush:
    """A one-row task asking joint `j` for a constant acceleration (rad/s²)."""

    strict = False
    dim = 1

    def __init__(self, j: int, acc: float, n: int = 7):
        self.J = np.zeros((1, n))
        self.J[0, j] = 1.0
        self.b = np.array([acc])

    def reset(self, dyn, target):
        pass

    def rows(self, dyn, target, ddq_e):
        return TaskRows(self.J, self.b, 1e4, None)


_DRIVES: dict = {}


def _drive_into_limit(gen3, dt: float, form: str, lam: float = 100.0, M: float = 2.0):
    """Cached: each (dt, form, λ, M) closed loop is simulated once per test session."""
    key = (dt, form, lam, M)
    if key not in _DRIVES:
        _DRIVES[key] = _simulate_drive(gen3, dt, form, lam, M)
    return _DRIVES[key]


def _simulate_drive(gen3, dt: float, form: str, lam: float, M: float):
    """Joint 4 is pushed toward its upper limit at +2 rad/s², the other joints are held; returns
    (t, x = e − d_s, ẋ, damper-active mask) of the closed loop in MuJoCo at control period dt."""

    def set_dt(spec):
        spec.option.timestep = dt

    world = World(gen3, customize=set_dt)
    model = RobotModel(gen3.model)
    q0 = gen3.home.copy()
    q0[JOINT] = gen3.q_upper[JOINT] - 0.6
    world.reset(q0)
    ex = ComplianceQPExecutor.for_robot(
        gen3,
        tasks=[ConstantPush(JOINT, 2.0)],
        posture=PostureTaskGains(stiffness=400.0, damping=40.0, weight=1.0),
        dampers=DamperGains(form=form, lambda_=lam, M=M),
        estimator=EstimatorGains(source="none"),
        settings=ComplianceQPSettings(eps=1e-9),
        dt=dt,
    )
    dyn = model.compute(world.q, world.dq)
    target = TaskTarget(position=dyn.tcp_position_world, rotation=dyn.tcp_rotation_world, q_posture=q0)
    ex.reset(dyn, target)
    ex.posture.kp[JOINT] = 0.0  # joint 4 is left to the push
    ex.posture.kd[JOINT] = 0.0
    d_s = 0.01 * (gen3.q_upper[JOINT] - gen3.q_lower[JOINT])
    ts, xs, vs, active = [], [], [], []
    for _ in range(round(1.2 / dt)):
        dyn = model.compute(world.q, world.dq)
        out = ex.step(dyn, ControlInputs(t=world.time, target=target, wrench_tcp=np.zeros(6)))
        ub = ex.damper.bounds(dyn.q, dyn.dq).upper[JOINT]
        x = gen3.q_upper[JOINT] - dyn.q[JOINT] - d_s
        ts.append(world.time)
        xs.append(x)
        vs.append(-dyn.dq[JOINT])
        position_row = -lam * dyn.dq[JOINT] + lam * lam / (4 * M * M) * x  # [C24] as a bound on q̈
        active.append(abs(ex.ddq[JOINT] - ub) < 1e-4 * max(1.0, abs(ub)) and abs(ub - position_row) < 1e-9)
        world.step(out.tau)
    return np.array(ts), np.array(xs), np.array(vs), np.array(active)


@pytest.mark.parametrize("dt", [1e-3, 5e-4])
def test_proposed_damper_follows_the_second_order_response_at_any_control_period(gen3, dt):
    lam, M = 100.0, 2.0
    t, x, v, active = _drive_into_limit(gen3, dt, "proposed", lam, M)
    assert active.any(), "the damper never became active"
    k0 = int(np.argmax(active))
    assert active[k0:].mean() > 0.99  # stays saturated until rest
    pred = second_order_response(lam / (2 * M), M, x[k0], v[k0], t[k0:] - t[k0])
    err = np.max(np.abs(x[k0:] - pred))
    assert err < 0.01 * x[k0], f"max deviation {err:.2e} rad from [C21–22] (start {x[k0]:.3f} rad)"
    # time constant and damping: the slow pole of [C22] is −ω_n(M − √(M²−1)), ω_n = λ/(2M)
    slow = lam / (2 * M) * (M - np.sqrt(M * M - 1))
    late = (t - t[k0] > 0.2) & (x > 1e-5)
    rate = -np.polyfit(t[late], np.log(x[late]), 1)[0]
    assert rate == pytest.approx(slow, rel=0.03)
    assert np.min(x) > -1e-5  # overdamped (ζ = M = 2): never enters the safety distance d_s


def test_proposed_damper_trajectory_is_the_same_at_1ms_and_0p5ms(gen3):
    t1, x1, _, _ = _drive_into_limit(gen3, 1e-3, "proposed")
    t2, x2, _, _ = _drive_into_limit(gen3, 5e-4, "proposed")
    tt = np.linspace(0.0, 1.1, 200)
    diff = np.max(np.abs(np.interp(tt, t1, x1) - np.interp(tt, t2, x2)))
    assert diff < 1e-3 * np.max(x1)  # 0.1 % of the travel


def test_classic_damper_gain_is_one_over_the_control_period(gen3):
    """[C17–18]: the classic bound's slope in q̇ is 1/δt, so halving δt doubles it."""
    q = np.zeros(7)
    q[JOINT] = gen3.q_upper[JOINT] - 0.02  # inside d_i
    slopes = []
    for dt in (1e-3, 5e-4):
        d = JointLimitDamper(gen3.q_lower, gen3.q_upper, gen3.dq_max, gen3.endless, DamperGains(form="classic"), dt)
        dq1, dq2 = np.zeros(7), np.zeros(7)
        dq2[JOINT] = 0.01
        slopes.append((d.bounds(q, dq2).upper[JOINT] - d.bounds(q, dq1).upper[JOINT]) / 0.01)
    assert slopes[0] == pytest.approx(-1e3, rel=1e-9)
    assert slopes[1] == pytest.approx(-2e3, rel=1e-9)
