"""Loader: shipped numbers, frames, sidecar validation, foreign URDFs."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

import robots
from control.model import RobotModel


def test_rizon_limits_and_tool(rizon):
    np.testing.assert_allclose(rizon.q_lower[[3, 5]], [-1.9548, -1.4835])
    np.testing.assert_allclose(rizon.q_upper[[3, 5]], [2.7751, 4.6251])
    np.testing.assert_allclose(rizon.tau_max, [123, 123, 64, 64, 39, 39, 39])
    model = RobotModel(rizon.model)
    flange = model.frame_pose(rizon.home, "flange")
    tcp = model.frame_pose(rizon.home, "tcp")
    # the TCP is 0.10 m along the flange z axis
    np.testing.assert_allclose(flange.actInv(tcp.translation), [0, 0, 0.10], atol=1e-12)
    assert np.all(rizon.armature > 0)
    np.testing.assert_allclose(rizon.model.armature, rizon.armature)


def test_gen3_endless_joints_and_home(gen3):
    assert list(gen3.endless) == [True, False, True, False, True, False, True]
    np.testing.assert_allclose(gen3.home, [0, 0.2618, 3.1416, -2.2689, 0, 0.9599, 1.5708])
    assert gen3.model.nq == 7


def test_total_mass_matches_published_link_masses(rizon, gen3):
    def arm_mass(r):
        return sum(i.mass for i in r.model.inertias[1:])

    assert arm_mass(rizon) == pytest.approx(3.6 + 2.7 + 2.4 + 2.4 + 2.3 + 2.2 + 1.4)
    assert arm_mass(gen3) == pytest.approx(1.3773 + 2 * 1.1636 + 0.9302 + 2 * 0.6781 + 0.5)


def test_foreign_urdf_without_sidecar_loads_with_defaults(tmp_path):
    path = tmp_path / "arm.urdf"
    path.write_text((robots.ROBOTS_DIR / "rizon4s.urdf").read_text())
    r = robots.load(str(path))
    assert r.flange_frame == "flange"
    assert np.all(r.armature == 0)
    assert r.model.existFrame("tcp")
    assert isinstance(r.tcp_in_flange, pin.SE3)


def test_sidecar_naming_a_missing_frame_is_refused(tmp_path):
    path = tmp_path / "arm.urdf"
    path.write_text((robots.ROBOTS_DIR / "rizon4s.urdf").read_text())
    (tmp_path / "arm.toml").write_text('flange_frame = "tool0"\n')
    with pytest.raises(robots.RobotLoadError, match="no frame 'tool0'"):
        robots.load(str(path))
