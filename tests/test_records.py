"""Named records at the compiled boundary (`control.kernels.records`): each record carries every
numeric field of its parameter groups by name, and a group goes in and comes back unchanged."""

from __future__ import annotations

import dataclasses
import itertools

import numpy as np
import pytest

from control.gains import MotionForceGains, NullspaceGains
from control.kernels.law import LAW_GROUPS, law_record, law_record_dtype
from control.kernels.records import group_fields, group_of, record_dtype, record_values


def _law_derived(n: int = 7) -> dict:
    rng = np.random.default_rng(3)
    return {
        "objective": 2, "k0": 12.5, "n_m": 3, "perm": np.array([0, 1, 5, 2, 3, 4]),
        "kp_m": rng.uniform(1, 9, 3), "kd_scale_m": rng.uniform(1, 9, 3), "q_lower": -rng.uniform(1, 3, n),
        "q_upper": rng.uniform(1, 3, n), "dq_limit": rng.uniform(1, 3, n), "endless": (np.arange(n) == 6).astype(float),
        "kn": rng.uniform(1, 9, n), "closed_form": True, "task_scale": rng.uniform(0.5, 2, 6),
    }  # fmt: skip


def test_the_law_record_holds_every_numeric_field_of_its_groups_by_name():
    names = set(law_record_dtype(7).names)
    for group in LAW_GROUPS:
        numeric = [f.name for f in dataclasses.fields(group) if f.type in ("float", "int", "bool")]
        assert numeric and set(numeric) <= names, group.__name__
        assert [name for name, _ in group_fields(group)] == numeric
    assert {"force_kp", "force_ki", "shaping", "k0_a", "damper_influence", "damper_speed"} <= names


def test_the_law_record_round_trips_its_groups_and_its_derived_fields():
    gains = dataclasses.replace(MotionForceGains(), force_kp=1.25, force_ki=3.5, shaping=False)
    nullspace = dataclasses.replace(NullspaceGains(), k0_a=0.7, damper_safety=0.03, damper_speed=0.6)
    derived = _law_derived()
    rec = law_record(gains, nullspace, **derived)
    values = record_values(rec)
    assert group_of(MotionForceGains, values, MotionForceGains()) == gains
    assert group_of(NullspaceGains, values, NullspaceGains()) == nullspace
    for name, value in derived.items():
        got = values[name]
        if np.ndim(value):
            np.testing.assert_array_equal(got[: len(value)], value)
            assert not np.any(got[len(value) :]), name  # a shorter value leaves the rest zero
        else:
            assert got == value, name


def test_a_record_refuses_a_missing_or_unknown_derived_field_and_a_name_used_twice():
    derived = _law_derived()
    del derived["kn"]
    with pytest.raises(ValueError, match=r"missing \['kn'\]"):
        law_record(MotionForceGains(), NullspaceGains(), **derived)
    with pytest.raises(ValueError, match=r"unknown \['gain'\]"):
        law_record(MotionForceGains(), NullspaceGains(), **_law_derived(), gain=1.0)
    with pytest.raises(ValueError, match="named twice: force_kp"):
        record_dtype((MotionForceGains,), (("force_kp", np.float64),))


def test_each_compliance_qp_record_round_trips_its_group_and_its_owners_views_share_its_memory():
    """The [C] step's records (pose task, posture task, damper, estimator, settings): the group comes
    back unchanged from its record, and the owner's arrays (K_p, the damper's rows) are the record's."""
    import robots
    from control.compliance_qp import ComplianceQPExecutor, PoseTask, PostureTask
    from control.dampers import JointLimitDamper
    from control.estimation import ExternalTorqueEstimator
    from control.gains import ComplianceQPSettings, DamperGains, EstimatorGains, PoseTaskGains, PostureTaskGains

    robot = robots.load("rizon4s")
    pose_gains = PoseTaskGains(stiffness=(100.0, 200.0, 300.0, 10.0, 20.0, 30.0), weight=50.0, compliance=0.5)
    pose = PoseTask(pose_gains)
    posture_gains = PostureTaskGains(stiffness=4.0, integral=2.0, weight=3.0, metric="inertia")
    posture = PostureTask(7, posture_gains)
    damper_gains = DamperGains(lambda_=120.0, safety_fraction=0.02)
    damper = JointLimitDamper(robot.q_lower, robot.q_upper, robot.dq_max, robot.endless, damper_gains, dt=1e-3)
    est_gains = EstimatorGains(source="residual", observer_gain=80.0)
    est = ExternalTorqueEstimator(7, est_gains)
    settings = ComplianceQPSettings(feedback=False, eps=1e-7)
    ex = ComplianceQPExecutor.for_robot(robot, settings=settings)
    for group, base, rec in (
        (pose_gains, PoseTaskGains(), pose.kernel_record),
        (posture_gains, PostureTaskGains(), posture.kernel_record),
        (damper_gains, DamperGains(), damper.kernel_record),
        (est_gains, EstimatorGains(), est.kernel_record),
        (settings, ComplianceQPSettings(), ex._settings_record),
    ):
        values = record_values(rec)
        back = group_of(type(group), values, base)
        # fields the record cannot hold (strings, per-axis tuples) come from `base`: compare the rest
        for name, _ in group_fields(type(group)):
            assert getattr(back, name) == getattr(group, name), (type(group).__name__, name)
    np.testing.assert_array_equal(record_values(pose.kernel_record)["kp"], [100.0, 200.0, 300.0, 10.0, 20.0, 30.0])
    assert np.shares_memory(pose.kp, pose.kernel_record) and np.shares_memory(posture.ki, posture.kernel_record)
    assert np.shares_memory(damper.d_s, damper.kernel_record) and np.shares_memory(damper.q_lower, damper.kernel_record)
    values = record_values(damper.kernel_record)
    np.testing.assert_allclose(values["d_s"], 0.02 * (robot.q_upper - robot.q_lower))
    np.testing.assert_array_equal(values["endless"], np.asarray(robot.endless, dtype=float))
    assert record_values(est.kernel_record)["source_code"] == 1.0
    s = record_values(ex._settings_record)
    assert s["pose_on"] and not s["feedback"] and s["eps"] == 1e-7
    np.testing.assert_array_equal(s["tau_max"], robot.tau_max)


def test_the_snapshot_is_a_view_of_its_record_and_round_trips_through_it():
    """`Dynamics`' arrays are the record's fields (what a kernel reads by name is what Python reads and
    writes); a snapshot built from arrays gives them back; records from one block never share memory;
    a pickled snapshot comes back whole; rebinding an array is refused."""
    import pickle

    import robots
    from control.kernels.snapshot import SNAPSHOT_FIELDS
    from control.model import Dynamics, RobotModel

    robot = robots.load("rizon4s")
    model = RobotModel(robot.model)
    rng = np.random.default_rng(8)
    snaps = [model.compute(rng.uniform(-1, 1, 7), rng.uniform(-1, 1, 7)) for _ in range(70)]  # two blocks
    dyn = snaps[3]
    for name, _ in SNAPSHOT_FIELDS:
        assert np.shares_memory(getattr(dyn, name), dyn.record), name
        np.testing.assert_array_equal(getattr(dyn, name), dyn.record[name][0])
    assert bool(dyn.record["near_singular"][0]) == dyn.near_singular
    dyn.M[0, 0] += 1.0  # written through the view: in the record
    assert dyn.record["M"][0][0, 0] == dyn.M[0, 0]
    assert not any(np.shares_memory(a.record, b.record) for a, b in itertools.pairwise(snaps))
    arrays = {name: rng.standard_normal(np.shape(getattr(dyn, name))) for name, _ in SNAPSHOT_FIELDS}
    built = Dynamics.of(True, 0.5, **arrays)
    for name, value in arrays.items():
        np.testing.assert_array_equal(getattr(built, name), value)
        np.testing.assert_array_equal(built.record[name][0], value)
    assert built.near_singular and bool(built.record["near_singular"][0]) and built.min_eig_Lambda_inv == 0.5
    back = pickle.loads(pickle.dumps(snaps[5]))
    for name, _ in SNAPSHOT_FIELDS:
        np.testing.assert_array_equal(getattr(back, name), getattr(snaps[5], name))
    with pytest.raises(AttributeError, match="view of the snapshot's record"):
        dyn.J = np.zeros((6, 7))
