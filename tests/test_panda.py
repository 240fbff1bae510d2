"""The Franka Panda by name, from the optional example-robot-data package: published limits, the
sidecar's frames, the locked fingers, the model cross-check, and the one-line error without it."""

from __future__ import annotations

import importlib.metadata

import numpy as np
import pytest

import robots
from app.tools.check import cross_check
from control.model import RobotModel
from robots import external

pytestmark = pytest.mark.skipif(not external.installed("panda"), reason="needs the robots extra (example-robot-data)")

# Franka's published limits (FCI "Robot and interface specifications")
Q_LOWER = [-2.8973, -1.7628, -2.8973, -3.0718, -2.8973, -0.0175, -2.8973]
Q_UPPER = [2.8973, 1.7628, 2.8973, -0.0698, 2.8973, 3.7525, 2.8973]
DQ_MAX = [2.175, 2.175, 2.175, 2.175, 2.61, 2.61, 2.61]
TAU_MAX = [87, 87, 87, 87, 12, 12, 12]


@pytest.fixture(scope="module")
def panda():
    return robots.load("panda")


def test_panda_loads_by_name_with_its_published_limits(panda):
    assert "panda" in robots.available()
    assert panda.joint_names == tuple(f"panda_joint{i}" for i in range(1, 8))
    np.testing.assert_allclose(panda.q_lower, Q_LOWER)
    np.testing.assert_allclose(panda.q_upper, Q_UPPER)
    np.testing.assert_allclose(panda.dq_max, DQ_MAX)
    np.testing.assert_allclose(panda.tau_max, TAU_MAX)
    assert panda.locked == {"panda_finger_joint1": 0.0, "panda_finger_joint2": 0.0}
    assert {"panda_hand", "panda_leftfinger", "panda_rightfinger"} <= set(panda.link_names)
    assert panda.guessed == {}  # the sidecar gives armature, TCP and postures
    np.testing.assert_allclose(panda.armature, 0.1)


def test_panda_tcp_is_at_the_hand_tcp_frame_and_the_postures_are_inside_the_limits(panda):
    model = RobotModel(panda.model)
    q = panda.postures["ready"]
    tcp = model.frame_pose(q, "tcp")
    hand_tcp = model.frame_pose(q, "panda_hand_tcp")
    np.testing.assert_allclose(tcp.translation, hand_tcp.translation, atol=1e-12)
    np.testing.assert_allclose(tcp.rotation[:, 2], hand_tcp.rotation[:, 2], atol=1e-12)  # same tool axis
    for name, posture in panda.postures.items():
        assert np.all(posture >= panda.q_lower) and np.all(posture <= panda.q_upper), name


def test_panda_pinocchio_and_mujoco_agree(panda):
    rep = cross_check(panda, samples=50)
    assert max(rep["worst_relative_error"].values()) <= 1e-9, rep


def test_panda_without_the_extra_is_one_line_with_the_install_command(monkeypatch):
    def missing(name):
        raise importlib.metadata.PackageNotFoundError(name)

    monkeypatch.setattr(external.importlib.metadata, "distribution", missing)
    assert "panda" not in robots.available()
    with pytest.raises(robots.RobotLoadError) as exc:
        robots.load("panda")
    text = str(exc.value)
    assert "\n" not in text and "pip install 'torquelab[robots]'" in text
