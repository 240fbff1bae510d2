"""Robot descriptions shipped with torquelab and the loader that reads them.

`load(name_or_path)` returns a `RobotDescription`: the URDF path, a Pinocchio model with the TCP
and sensor frames added and the rotor armature set, joint limits and named postures. A sidecar
TOML next to the URDF (same stem) adds what URDF cannot hold; for a foreign URDF without one,
sensible defaults are used (flange = last link, TCP = flange, no armature).
"""

from __future__ import annotations

import contextlib
import os
import sys
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pinocchio as pin

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

ROBOTS_DIR = Path(__file__).resolve().parent
BUILTIN = ("rizon4s", "gen3")
DEFAULT_ROBOT = "rizon4s"
N_JOINTS = 7
TCP_FRAME = "tcp"
SENSOR_FRAME = "ft_sensor"


class RobotLoadError(ValueError):
    """A robot could not be loaded; the message says why in one line."""


@dataclass(frozen=True)
class RobotDescription:
    """Everything the controller, the simulation and the renderer need to know about an arm."""

    name: str
    urdf_path: Path
    model: pin.Model  # controller model: armature set, frames `tcp` and `ft_sensor` added
    joint_names: tuple[str, ...]
    q_lower: np.ndarray  # rad
    q_upper: np.ndarray  # rad
    dq_max: np.ndarray  # rad/s
    tau_max: np.ndarray  # N m
    armature: np.ndarray  # kg m^2, reflected rotor inertia
    endless: np.ndarray  # bool per joint: no position limit
    flange_frame: str
    tcp_in_flange: pin.SE3
    sensor_frame: str  # the link frame the sensor is attached to (its pose = the `ft_sensor` frame)
    postures: dict[str, np.ndarray] = field(default_factory=dict)
    link_names: tuple[str, ...] = ()

    @property
    def nq(self) -> int:
        return N_JOINTS

    @property
    def home(self) -> np.ndarray:
        return self.postures["home"].copy()

    def last_joint_id(self) -> int:
        """Pinocchio id of the 7th (last) joint, the body the flange is welded to."""
        return self.model.njoints - 1


def available() -> tuple[str, ...]:
    """Names of the robots shipped in this package."""
    return BUILTIN


def load(name_or_path: str | Path = DEFAULT_ROBOT) -> RobotDescription:
    """Load a shipped robot by name (`rizon4s`, `gen3`) or any 7-DOF serial URDF by path."""
    text = str(name_or_path)
    if text in BUILTIN:
        urdf = ROBOTS_DIR / f"{text}.urdf"
    elif text.endswith(".urdf") or "/" in text or Path(text).suffix:
        urdf = Path(text).expanduser()
        if not urdf.is_file():
            raise RobotLoadError(f"URDF file not found: {urdf}")
    else:
        raise RobotLoadError(f"unknown robot {text!r}; choose one of {', '.join(BUILTIN)} or give a URDF path")
    sidecar_path = urdf.with_suffix(".toml")
    sidecar: dict = {}
    if sidecar_path.is_file():
        try:
            sidecar = tomllib.loads(sidecar_path.read_text())
        except tomllib.TOMLDecodeError as exc:
            raise RobotLoadError(f"cannot read sidecar {sidecar_path}: {exc}") from None
    return _build(urdf.stem if text not in BUILTIN else text, urdf.resolve(), sidecar)


def _build(name: str, urdf: Path, sidecar: dict) -> RobotDescription:
    error = ""
    with _captured_stderr() as parser_says:
        try:
            model = pin.buildModelFromUrdf(str(urdf))
        except (RuntimeError, ValueError) as exc:
            error = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
    if error:  # the parser's own first complaint says more than Pinocchio's "not a valid URDF model"
        detail = next((ln.split("Error:", 1)[1].strip() for ln in parser_says if "Error:" in ln), error)
        raise RobotLoadError(f"cannot parse URDF {urdf}: {detail}")
    if parser_says:  # warnings of a model that loaded: pass them on
        print("\n".join(parser_says), file=sys.stderr)
    joint_names = tuple(model.names[1:])
    if model.nv != N_JOINTS:
        raise RobotLoadError(f"{urdf.name} has {model.nv} degrees of freedom; torquelab needs a 7-DOF serial arm")
    if model.nq != model.nv:
        raise RobotLoadError(
            f"{urdf.name} has continuous joints; declare them revolute with wide limits and list them as"
            " `endless` in the sidecar"
        )
    for j in range(2, model.njoints):
        if model.parents[j] != j - 1:
            raise RobotLoadError(f"{urdf.name} is not a serial chain (joint {model.names[j]!r} branches)")
    for j in range(1, model.njoints):
        if not model.joints[j].shortname().startswith(("JointModelR", "JointModelP")):
            raise RobotLoadError(f"{urdf.name}: joint {model.names[j]!r} is not revolute or prismatic")

    frames = [f.name for f in model.frames]
    flange = sidecar.get("flange_frame") or _last_body_frame(model)
    sensor = sidecar.get("sensor_frame", flange)
    for key, frame in (("flange_frame", flange), ("sensor_frame", sensor)):
        if frame not in frames:
            raise RobotLoadError(f"{urdf.name}: no frame {frame!r} ({key}); frames are {', '.join(frames)}")

    tcp_in_flange = _se3(sidecar.get("tcp_offset_xyz", [0, 0, 0]), sidecar.get("tcp_offset_rpy", [0, 0, 0]))
    _add_frame(model, TCP_FRAME, flange, tcp_in_flange)
    _add_frame(model, SENSOR_FRAME, sensor, pin.SE3.Identity())

    armature = np.asarray(sidecar.get("armature", np.zeros(N_JOINTS)), dtype=float)
    if armature.shape != (N_JOINTS,) or np.any(~np.isfinite(armature)) or np.any(armature < 0):
        raise RobotLoadError(f"{name}: sidecar `armature` must be 7 non-negative numbers")
    model.armature = armature.copy()

    endless_names = list(sidecar.get("endless", []))
    for jn in endless_names:
        if jn not in joint_names:
            raise RobotLoadError(f"{name}: sidecar lists endless joint {jn!r} that the URDF lacks")
    endless = np.array([jn in endless_names for jn in joint_names])

    lower = np.array(model.lowerPositionLimit, dtype=float)
    upper = np.array(model.upperPositionLimit, dtype=float)
    dq_max = np.array(model.velocityLimit, dtype=float)
    tau_max = np.array(model.effortLimit, dtype=float)
    if np.any(~(upper > lower)):
        raise RobotLoadError(f"{urdf.name}: every joint needs a position limit (lower < upper)")
    if np.any(dq_max <= 0) or np.any(tau_max <= 0):
        raise RobotLoadError(f"{urdf.name}: every joint needs positive velocity and effort limits")

    postures: dict[str, np.ndarray] = {}
    for key, value in sidecar.get("postures", {}).items():
        arr = np.asarray(value, dtype=float)
        if arr.shape != (N_JOINTS,):
            raise RobotLoadError(f"{name}: posture {key!r} must have 7 joint values")
        postures[key] = arr
    if "home" not in postures:
        postures["home"] = np.clip(np.zeros(N_JOINTS), lower, upper)

    link_names = tuple(f.name for f in model.frames if f.type == pin.FrameType.BODY)
    return RobotDescription(
        name=name,
        urdf_path=urdf,
        model=model,
        joint_names=joint_names,
        q_lower=lower,
        q_upper=upper,
        dq_max=dq_max,
        tau_max=tau_max,
        armature=armature,
        endless=endless,
        flange_frame=flange,
        tcp_in_flange=tcp_in_flange,
        sensor_frame=sensor,
        postures=postures,
        link_names=link_names,
    )


@contextlib.contextmanager
def _captured_stderr() -> Iterator[list[str]]:
    """Collect what native code writes to file descriptor 2 meanwhile (urdfdom prints its parse
    errors there, before Pinocchio raises): the lines are in the yielded list afterwards."""
    lines: list[str] = []
    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile() as tmp:
        os.dup2(tmp.fileno(), 2)
        try:
            yield lines
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            tmp.seek(0)
            lines.extend(ln for ln in tmp.read().decode(errors="replace").splitlines() if ln.strip())


def _last_body_frame(model: pin.Model) -> str:
    bodies = [f for f in model.frames if f.type == pin.FrameType.BODY]
    return bodies[-1].name


def _se3(xyz, rpy) -> pin.SE3:
    return pin.SE3(pin.rpy.rpyToMatrix(*map(float, rpy)), np.asarray(xyz, dtype=float))


def _add_frame(model: pin.Model, name: str, parent_frame: str, offset: pin.SE3) -> None:
    """Add an operational frame `name` at `offset` from `parent_frame` (expressed in it)."""
    parent_id = model.getFrameId(parent_frame)
    parent = model.frames[parent_id]
    placement = parent.placement * offset
    model.addFrame(pin.Frame(name, parent.parentJoint, parent_id, placement, pin.FrameType.OP_FRAME))
