"""The self-motion preview colours the loop by the stability map's tolerated latency at the session's μ
(`app.live.ui.latency_map`): the colour of each swivel is the map's, and it changes where the map does."""

from __future__ import annotations

import itertools
import json
from types import SimpleNamespace

import numpy as np
import pytest

from app.live.ui import latency_map as L


def _write_map(path, robot="Rizon 4s") -> None:
    swivels = [-170.0 + 10.0 * k for k in range(35)]
    doc = {
        "format": L.FORMAT,
        "robot": robot,
        "tolerated": [
            # μ 0.25: 3 periods everywhere but −60…−40 (1); μ 1.5: −1 left of 0°, 2 from 0° on
            {"mu": 0.25, "swivel_deg": swivels, "tolerated_periods": [1 if -60 <= s <= -40 else 3 for s in swivels]},
            {"mu": 1.5, "swivel_deg": swivels, "tolerated_periods": [-1 if s < 0 else 2 for s in swivels]},
        ],
    }
    path.write_text(json.dumps(doc))


def test_the_map_is_read_at_the_nearest_mu_and_swivel_around_the_loop(tmp_path):
    _write_map(tmp_path / "m.json")
    m = L.load(tmp_path / "m.json")
    assert m is not None and m.mu == (0.25, 1.5)
    at = m.at(0.3, np.array([-50.0, -44.0, -34.0, 172.0, -174.0, 178.0]))
    np.testing.assert_array_equal(at, [1.0, 1.0, 3.0, 3.0, 3.0, np.nan])  # 178°: 8° from ±170°, beyond half a step
    np.testing.assert_array_equal(m.at(1.4, np.array([-5.1, -4.9, 4.9])), [-1.0, 2.0, 2.0])
    assert L.load(tmp_path / "missing.json") is None
    (tmp_path / "other.json").write_text(json.dumps({"format": "something else"}))
    assert L.load(tmp_path / "other.json") is None


def test_each_level_series_holds_w_only_where_the_posture_tolerates_that_latency():
    W = np.array([1.0, 2.0, 3.0, 4.0, 5.0])
    series = L.level_series(W, np.array([-1.0, 0.0, 7.0, np.nan, 2.0]))
    assert len(series) == len(L.LEVELS)
    drawn = np.array([[np.isfinite(s[i]) for s in series] for i in range(len(W))])
    assert drawn.sum(axis=1).tolist() == [1, 1, 1, 0, 1]  # one colour per posture, none where unknown
    assert series[L.LEVELS.index(-1)][0] == 1.0 and series[L.LEVELS.index(0)][1] == 2.0
    assert series[L.LEVELS.index(4)][2] == 3.0  # 7 periods: "4 or more"
    assert series[L.LEVELS.index(2)][4] == 5.0


@pytest.mark.parametrize(("mu", "changes_at"), [(0.25, (-65.0, -35.0)), (1.5, (-5.0,))])
def test_the_preview_colours_the_loop_by_the_map_at_the_sessions_mu(server, tmp_path, mu, changes_at):
    """A scan of the polish start posture's loop: the colour (level series) drawn at each swivel is the
    map's tolerated latency there, and it changes exactly at the swivels where the map's changes."""
    import robots
    from app.live.ui.selfmotion import SelfMotionPreview, scan_preview
    from app.scenarios import get_scenario
    from control import coupling as c
    from control.gains import NullspaceGains
    from control.model import RobotModel

    robot = robots.load("rizon4s")
    _write_map(tmp_path / "m.json", robot=robot.name)
    preview = SelfMotionPreview(server)
    preview.stop()  # no scan thread: the scan below is drawn by hand
    preview.latency_map = L.load(tmp_path / "m.json")
    q0 = get_scenario("polish").initial_q(robot)
    groups = {"contact": SimpleNamespace(mu=mu), "nullspace": NullspaceGains()}
    scene = SimpleNamespace(q=q0, near_singular=False, subspaces=c.POLISH_SUBSPACES, objective="a", planned_q=None)
    frame = SimpleNamespace(
        scene=scene, status=SimpleNamespace(signals={}), robot=robot, settings=SimpleNamespace(groups=groups)
    )
    preview.feed(frame)
    p = scan_preview(RobotModel(robot.model), robot, q0, c.POLISH_SUBSPACES, "a", None)
    preview._show_plot(p)
    x, inside = preview.plot.data[0], preview.plot.data[1]
    levels = preview.plot.data[7:]
    expected = preview.latency_map.at(mu, x)
    for i in range(len(x)):
        drawn = [L.LEVELS[k] for k, s in enumerate(levels) if np.isfinite(s[i])]
        if np.isfinite(inside[i]) and np.isfinite(expected[i]):
            assert drawn == [min(int(expected[i]), L.LEVELS[-1])]
        else:
            assert drawn == []
    colour = np.array([next((k for k, s in enumerate(levels) if np.isfinite(s[i])), -1) for i in range(len(x))])
    coloured = np.flatnonzero(colour >= 0)
    switches = [0.5 * (x[a] + x[b]) for a, b in itertools.pairwise(coloured) if colour[a] != colour[b]]
    assert len(switches) == len(changes_at)
    for s, want in zip(switches, changes_at, strict=True):
        assert s == pytest.approx(want, abs=3.0)  # the scan's own spacing around the map's midpoint
    assert f"μ = {mu:g}" in preview.text.content
    preview.latency_map = None  # no map: no colour
    preview._show_plot(p)
    assert all(not np.any(np.isfinite(s)) for s in preview.plot.data[7:])
