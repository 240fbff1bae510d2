"""The arm inside a real URDF: chain selection, locked joints in Pinocchio and MuJoCo, package://
mesh resolution, and a one-line error for every bad case (URDFs of our own, tests/urdf_fixtures)."""

from __future__ import annotations

import mujoco
import numpy as np
import pinocchio as pin
import pytest

import robots
from app.sim.world import World
from app.tools.check import cross_check
from control.model import RobotModel
from robots import meshes
from robots.packages import PackageResolver
from tests import urdf_fixtures as fx

CHECK_TOLERANCE = 1e-9


def _one_line(exc: pytest.ExceptionInfo) -> str:
    text = str(exc.value)
    assert text and "\n" not in text
    return text


def _body_poses_agree(robot: robots.RobotDescription, q: np.ndarray) -> float:
    """Worst position error between MuJoCo's body poses and Pinocchio's link frames at q (m)."""
    world = World(robot)
    world.set_state(q, np.zeros(7))
    data = robot.model.createData()
    pin.framesForwardKinematics(robot.model, data, q)
    worst = 0.0
    for name in robot.link_names:
        oMf = data.oMf[robot.model.getFrameId(name)]
        bid = mujoco.mj_name2id(world.model, mujoco.mjtObj.mjOBJ_BODY, name)
        assert bid >= 0, name
        worst = max(worst, float(np.max(np.abs(world.data.xpos[bid] - oMf.translation))))
        worst = max(worst, float(np.max(np.abs(world.data.xmat[bid].reshape(3, 3) - oMf.rotation))))
    return worst


def test_gripper_arm_is_the_seven_joint_chain_with_the_fingers_locked(tmp_path):
    path = fx.write(tmp_path / "gripper_arm.urdf", fx.gripper_arm())
    r = robots.load(str(path))
    assert r.joint_names == tuple(f"a_joint{i}" for i in range(1, 8))
    assert r.tip_link == "a_flange" and r.base_link == "world_base"
    assert r.locked == {"a_left_finger_joint": 0.0, "a_right_finger_joint": 0.0}
    assert "a_left_finger" in r.link_names  # drawn, at its locked position
    rep = cross_check(r, samples=20)
    assert max(rep["worst_relative_error"].values()) <= CHECK_TOLERANCE


def test_locked_positions_from_the_sidecar_are_where_both_models_put_the_links(tmp_path):
    path = fx.write(tmp_path / "two_arms.urdf", fx.two_arms())
    (tmp_path / "two_arms.toml").write_text(
        'base_link = "torso"\ntip_link = "left_flange"\n'
        "[locked]\nwaist = 0.4\nright_joint2 = 0.7\nright_joint4 = -1.1\nleft_left_finger_joint = 0.03\n"
    )
    r = robots.load(str(path))
    assert r.joint_names == tuple(f"left_joint{i}" for i in range(1, 8))
    assert r.locked["waist"] == 0.4 and r.locked["right_joint4"] == -1.1
    assert r.locked["left_left_finger_joint"] == 0.03 and r.locked["right_joint1"] == 0.0
    q = np.linspace(-0.8, 0.9, 7)
    assert _body_poses_agree(r, q) <= 1e-12
    rep = cross_check(r, samples=20)
    assert max(rep["worst_relative_error"].values()) <= CHECK_TOLERANCE
    # the locked waist turns the whole torso: the left arm's base is rotated by 0.4 rad about z
    data = r.model.createData()
    pin.framesForwardKinematics(r.model, data, np.zeros(7))
    torso = data.oMf[r.model.getFrameId("torso")]
    np.testing.assert_allclose(pin.rpy.matrixToRpy(torso.rotation), [0, 0, 0.4], atol=1e-12)


def test_two_arms_without_a_tip_are_refused_with_the_candidate_tips(tmp_path):
    path = fx.write(tmp_path / "two_arms.urdf", fx.two_arms())
    with pytest.raises(robots.RobotLoadError) as exc:
        robots.load(str(path))  # from the root: waist + 7 arm joints, no 7-joint chain
    assert "no 7-DOF arm (a chain of 7 revolute joints) starts at link 'world_base'" in _one_line(exc)
    with pytest.raises(robots.RobotLoadError) as exc:
        robots.load(str(path), base="torso")
    text = _one_line(exc)
    assert "choose one with --tip" in text and "left_flange" in text and "right_flange" in text
    r = robots.load(robots.robot_spec(path, base="torso", tip="right_flange"))
    assert r.joint_names[0] == "right_joint1" and "left_joint1" in r.locked
    assert r.spec == robots.robot_spec(path, base="torso", tip="right_flange")


@pytest.mark.parametrize(
    ("base", "tip", "words"),
    [
        ("torso", "nowhere", "no link 'nowhere' (--tip)"),
        ("nowhere", None, "no link 'nowhere' (--base)"),
        ("left_link3", "right_flange", "is not below link 'left_link3'"),
        ("left_link2", "left_flange", "has 5 movable joints"),
    ],
)
def test_bad_base_or_tip_is_one_line(tmp_path, base, tip, words):
    path = fx.write(tmp_path / "two_arms.urdf", fx.two_arms())
    with pytest.raises(robots.RobotLoadError) as exc:
        robots.load(str(path), base=base, tip=tip)
    assert words in _one_line(exc)


def test_a_sidecar_locking_an_arm_joint_or_an_unknown_joint_is_refused(tmp_path):
    path = fx.write(tmp_path / "gripper_arm.urdf", fx.gripper_arm())
    for body, words in (("a_joint3 = 0.2", "one of the arm's joints"), ("nope = 0.1", "which the URDF lacks")):
        (tmp_path / "gripper_arm.toml").write_text(f"[locked]\n{body}\n")
        with pytest.raises(robots.RobotLoadError) as exc:
            robots.load(str(path))
        assert words in _one_line(exc)


# ---- package:// ------------------------------------------------------------------------------
def test_package_uri_resolves_from_an_ancestor_folder_named_like_the_package(tmp_path):
    fx.box_mesh(tmp_path / "my_arm" / "meshes" / "link.stl")
    path = fx.write(tmp_path / "my_arm" / "urdf" / "arm.urdf", fx.gripper_arm("package://my_arm/meshes/link.stl"))
    r = robots.load(str(path))
    assert PackageResolver(r.urdf_path).resolve("package://my_arm/meshes/link.stl") == (
        tmp_path / "my_arm" / "meshes" / "link.stl"
    )


def test_package_uri_resolves_from_package_path_then_ros_package_path(tmp_path, monkeypatch):
    fx.box_mesh(tmp_path / "elsewhere" / "my_arm" / "meshes" / "link.stl")
    fx.box_mesh(tmp_path / "ros" / "my_arm" / "meshes" / "link.stl")
    path = fx.write(tmp_path / "desc" / "arm.urdf", fx.gripper_arm("package://my_arm/meshes/link.stl"))
    monkeypatch.delenv("ROS_PACKAGE_PATH", raising=False)
    monkeypatch.setenv("TORQUELAB_CACHE", str(tmp_path / "cache"))
    r = robots.load(str(path))  # not found: the arm loads, its links drawn as nothing
    (text,) = set(meshes.mesh_problems(r.urdf_path).values())
    assert "\n" not in text and "package://my_arm/meshes/link.stl" in text and "--package-path" in text
    # --package-path DIR (DIR/NAME inside, or DIR named NAME itself)
    for given in (tmp_path / "elsewhere", tmp_path / "elsewhere" / "my_arm"):
        r = robots.load(robots.robot_spec(path, package_paths=[str(given)]))
        found = PackageResolver(r.urdf_path, r.package_paths).resolve("package://my_arm/meshes/link.stl")
        assert found == tmp_path / "elsewhere" / "my_arm" / "meshes" / "link.stl"
    # ROS_PACKAGE_PATH comes after --package-path
    monkeypatch.setenv("ROS_PACKAGE_PATH", f"{tmp_path / 'nothing'}:{tmp_path / 'ros'}")
    resolver = PackageResolver(path)
    assert resolver.resolve("package://my_arm/meshes/link.stl") == tmp_path / "ros" / "my_arm" / "meshes" / "link.stl"
    resolver = PackageResolver(path, [tmp_path / "elsewhere"])
    assert resolver.resolve("package://my_arm/meshes/link.stl").parts[-4] == "elsewhere"


def test_missing_package_mesh_names_the_folders_searched(tmp_path, monkeypatch):
    monkeypatch.setenv("ROS_PACKAGE_PATH", str(tmp_path / "ros"))
    monkeypatch.setenv("TORQUELAB_CACHE", str(tmp_path / "cache"))
    path = fx.write(tmp_path / "my_arm" / "urdf" / "arm.urdf", fx.gripper_arm("package://my_arm/meshes/gone.stl"))
    r = robots.load(robots.robot_spec(path, package_paths=[str(tmp_path / "pp")]))
    problems = meshes.mesh_problems(r.urdf_path, r.package_paths)
    assert list(problems) == ["package://my_arm/meshes/gone.stl"]  # eight links, one file: named once
    text = problems["package://my_arm/meshes/gone.stl"]
    assert "\n" not in text
    for folder in (tmp_path / "my_arm", tmp_path / "pp" / "my_arm", tmp_path / "ros" / "my_arm"):
        assert str(folder) in text


def test_relative_mesh_name_is_relative_to_the_urdf(tmp_path, monkeypatch):
    fx.box_mesh(tmp_path / "meshes" / "link.obj")
    path = fx.write(tmp_path / "arm.urdf", fx.gripper_arm("meshes/link.obj"))
    r = robots.load(str(path))
    assert PackageResolver(r.urdf_path).resolve("meshes/link.obj") == tmp_path / "meshes" / "link.obj"
    monkeypatch.setenv("TORQUELAB_CACHE", str(tmp_path / "cache"))
    path = fx.write(tmp_path / "arm2.urdf", fx.gripper_arm("meshes/none.obj"))
    r = robots.load(str(path))
    assert "mesh meshes/none.obj not found" in meshes.mesh_problems(r.urdf_path)["meshes/none.obj"]
    assert meshes.link_meshes(r.urdf_path) == {}  # every link drawn as nothing


def test_the_arm_model_is_the_reduced_model_of_the_whole_urdf(tmp_path):
    """Pinocchio's M of the 7 arm joints equals the arm block of the full model's M with the
    locked joints at their positions (the fingers' mass rides on link 7)."""
    path = fx.write(tmp_path / "gripper_arm.urdf", fx.gripper_arm())
    (tmp_path / "gripper_arm.toml").write_text("[locked]\na_left_finger_joint = 0.02\n")
    r = robots.load(str(path))
    full = pin.buildModelFromUrdf(str(path))
    q_full = pin.neutral(full)
    q = np.linspace(0.3, -0.5, 7)
    q_full[:7] = q
    q_full[full.joints[full.getJointId("a_left_finger_joint")].idx_q] = 0.02
    M_full = pin.crba(full, full.createData(), q_full)
    M_full = np.triu(M_full) + np.triu(M_full, 1).T
    M = RobotModel(r.model).mass_matrix(q)
    np.testing.assert_allclose(M, M_full[:7, :7], atol=1e-12)


# ---- visual meshes ------------------------------------------------------------------------------
def test_visual_meshes_of_package_uris_are_read_once_and_cached(tmp_path, monkeypatch):
    monkeypatch.setenv("TORQUELAB_CACHE", str(tmp_path / "cache"))
    fx.box_mesh(tmp_path / "my_arm" / "meshes" / "link.stl")
    path = fx.write(tmp_path / "my_arm" / "urdf" / "arm.urdf", fx.gripper_arm("package://my_arm/meshes/link.stl"))
    r = robots.load(str(path))
    first = meshes.link_meshes(r.urdf_path, r.package_paths)
    assert set(first) == {f"a_link{i}" for i in range(8)}
    np.testing.assert_allclose(first["a_link3"].extents, [0.05, 0.05, 0.1], atol=1e-6)
    assert len(list((tmp_path / "cache" / "meshes").glob("arm-*.npz"))) == 1
    meshes._MEMORY.clear()  # a new process: the disk cache, not the mesh files
    monkeypatch.setattr(meshes, "read_mesh_file", lambda *a: pytest.fail("mesh file read again"))
    again = meshes.link_meshes(r.urdf_path, r.package_paths)
    np.testing.assert_allclose(again["a_link3"].vertices, first["a_link3"].vertices, atol=1e-6)


@pytest.mark.parametrize(
    ("name", "content", "words"),
    [
        ("link.stl", b"solid nothing here\nendsolid\n", "mesh meshes/link.stl"),  # an empty or broken STL
        ("link.xyz", b"1 2 3\n4 5 6\n", "holds no triangles"),  # a point cloud, not a mesh
        ("link.foo", b"1 2 3", "trimesh cannot read .foo files"),
        ("link.obj", bytes(range(256)) * 4, "mesh meshes/link.obj"),  # binary noise
    ],
)
def test_a_mesh_file_that_is_not_a_mesh_is_drawn_as_nothing_and_named_in_one_line(
    tmp_path, monkeypatch, name, content, words
):
    monkeypatch.setenv("TORQUELAB_CACHE", str(tmp_path / "cache"))
    (tmp_path / "meshes").mkdir()
    (tmp_path / "meshes" / name).write_bytes(content)
    path = fx.write(tmp_path / "arm.urdf", fx.gripper_arm(f"meshes/{name}"))
    r = robots.load(str(path))  # the file exists: the model loads
    assert meshes.link_meshes(r.urdf_path) == {}
    problems = meshes.mesh_problems(r.urdf_path)
    assert list(problems) == [f"meshes/{name}"]
    text = problems[f"meshes/{name}"]
    assert words in text and "\n" not in text
    said = meshes.missing_meshes_text(problems)
    assert said.startswith("1 mesh file drawn as nothing: ") and text in said


# ---- the command line -----------------------------------------------------------------------------
@pytest.fixture
def cli(capfd, monkeypatch):
    """`torquelab ARGS` in this process: (exit code, stderr lines); the robot choice is not kept."""
    from app.cli import main

    monkeypatch.delenv(robots.ROBOT_ENV, raising=False)

    def run(*args: str) -> tuple[int, list[str]]:
        capfd.readouterr()
        try:
            code = main(list(args))
        except SystemExit as exc:
            code = exc.code if isinstance(exc.code, int) else 2
        err = capfd.readouterr().err
        return code, [ln for ln in err.splitlines() if ln.strip()]

    return run


def test_chain_and_robot_errors_at_the_command_line_are_one_line(cli, tmp_path):
    path = fx.write(tmp_path / "two_arms.urdf", fx.two_arms())
    code, lines = cli("check", "--urdf", str(path), "--base", "torso")
    assert code == 2 and len(lines) == 1 and "choose one with --tip" in lines[0]
    code, lines = cli("check", "--base", "torso")
    assert code == 2 and lines == ["torquelab: error: --base, --tip and --package-path go with --urdf PATH"]
    code, lines = cli("experiment", "polish", "--robot", "nope", "--out", str(tmp_path / "out"))
    assert code == 2 and len(lines) == 1 and "unknown robot 'nope'" in lines[0]
    assert not (tmp_path / "out").exists()


def test_check_takes_the_chain_options(cli, tmp_path):
    path = fx.write(tmp_path / "two_arms.urdf", fx.two_arms())
    code, lines = cli("check", "--urdf", str(path), "--base", "torso", "--tip", "left_flange", "--samples", "10")
    assert code == 0 and lines == []


def _drops(monkeypatch, spec: str) -> dict:
    """The limit drop (λ = 100, M = 2, position limit) with and without feedback on the arm `spec`."""
    from app.headless.experiments.limit_drop import run_drop

    monkeypatch.setenv(robots.ROBOT_ENV, spec)
    return {fb: run_drop("proposed", 100.0, 2.0, fb, "position", 3.0) for fb in (True, False)}


def assert_drop_reaches_and_holds(on: dict, off: dict) -> None:
    """Joint 4 comes to rest within 2 d_s of the limit it falls toward, never inside d_s (0.1 mrad
    slack) with feedback; without feedback it goes at least 2 mrad deeper, into d_s."""
    assert on["stop"] == "until" and abs(on["trace_dq"][-1]) < 0.01
    assert 0.0 < on["final_margin"] < 2 * on["d_s"]
    assert on["max_violation"] < 0.0 and on["overshoot_beyond_ds"] < 1e-4
    assert off["overshoot_beyond_ds"] > max(on["overshoot_beyond_ds"], 0.0) + 2e-3


def test_a_urdf_without_sidecar_drops_joint_4_into_a_limit_from_a_searched_start(tmp_path, monkeypatch):
    """No sidecar: the limit drop's start is searched (the load pushes joint 4 into a limit all the
    way), the guessed values say so, and the dampers catch the fall at that limit."""
    from app.core.session import Session

    path = fx.write(tmp_path / "gripper_arm.urdf", fx.gripper_arm())
    session = Session("limit-drop", robot=str(path))
    robot = session.robot
    assert "limit_drop" in robot.guessed and "joint 4" in robot.guessed["limit_drop"]
    assert "the limit drop starts" in robots.guessed_text(robot)
    fall = session.scenario.fall(robot)
    assert fall.reaches_limit and abs(fall.limit - robot.postures["l_shape"][3]) == pytest.approx(1.0)
    drops = _drops(monkeypatch, str(path))
    assert drops[True]["q_limit"] == pytest.approx(fall.limit) and drops[True]["direction"] == fall.direction
    assert_drop_reaches_and_holds(drops[True], drops[False])


def test_a_urdf_without_sidecar_runs_the_mass_drop_from_a_searched_start(tmp_path):
    """No sidecar: the mass drop starts tool down half the arm's size in front of the shoulder, inside
    the limits; the mass is released at 1.5 s, the rope's catch moves the TCP (more than 0.1 mm) and it is back
    within 5 mm by 3 s."""
    from app.core.session import Session
    from app.scenarios.drop_postures import TOOL_DOWN, mass_drop_target
    from app.scenarios.mass_drop import RELEASE_TIME_S

    path = fx.write(tmp_path / "gripper_arm.urdf", fx.gripper_arm())
    session = Session("mass-drop", robot=str(path))
    robot = session.robot
    assert "mass_drop" in robot.guessed
    q0 = session.world.q
    assert np.all(q0 > robot.q_lower) and np.all(q0 < robot.q_upper)
    p0 = session.dyn.tcp_position_world.copy()
    np.testing.assert_allclose(p0, mass_drop_target(robot), atol=1e-6)
    np.testing.assert_allclose(session.dyn.tcp_rotation_world, TOOL_DOWN, atol=1e-6)
    peak = [0.0]

    def record(rec) -> None:
        if rec.t > RELEASE_TIME_S:
            peak[0] = max(peak[0], float(np.linalg.norm(session.dyn.tcp_position_world - p0)))

    result = session.run(3.0, record=record)
    assert not result.halted, result.reason
    assert getattr(session.environment, "released", False) and peak[0] > 1e-4  # the catch moved the TCP
    assert np.linalg.norm(session.dyn.tcp_position_world - p0) < 5e-3
