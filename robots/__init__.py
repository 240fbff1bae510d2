"""Robot descriptions shipped with torquelab and the loader that reads them.

`load(name_or_path)` returns a `RobotDescription`: the URDF path, a Pinocchio model of the arm
with the TCP and sensor frames added and the rotor armature set, joint limits and named postures.
A sidecar TOML next to the URDF (same stem) adds what URDF cannot hold; for a foreign URDF without
one, defaults are used and listed in `guessed` (flange = the chain's tip, TCP = flange, no armature).

The arm is the 7-joint chain between a base and a tip link (`robots.chain`): every other joint of
the URDF (fingers, a second arm) is locked, in Pinocchio with `buildReducedModel` and in MuJoCo by
`app.sim.world`. Mesh names (`package://`...) resolve with `robots.packages`. The Franka Panda
loads by name from the optional `example-robot-data` package (`robots.external`).

A robot is named by one string everywhere (sessions, worker processes): a shipped name, a URDF
path, or a URDF path with options `PATH#base=LINK&tip=LINK&package_path=DIR` (`robot_spec`).
"""

from __future__ import annotations

import contextlib
import os
import sys
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from urllib.parse import parse_qs, urlencode

import numpy as np
import pinocchio as pin

from robots import external
from robots.chain import Chain, ChainError, read_chain

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

ROBOTS_DIR = Path(__file__).resolve().parent
BUILTIN = ("rizon4s", "gen3")
EXTERNAL = ("panda",)  # loaded from an optional package (robots.external)
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
    base_link: str = ""
    tip_link: str = ""
    locked: dict[str, float] = field(default_factory=dict)  # joint -> position it is locked at (rad or m)
    package_paths: tuple[Path, ...] = ()
    guessed: dict[str, str] = field(default_factory=dict)  # value -> why it is a guess (no sidecar entry)
    spec: str = ""  # the string `load` takes to build this description again (robot_spec)

    @property
    def nq(self) -> int:
        return N_JOINTS

    @property
    def home(self) -> np.ndarray:
        return self.postures["home"].copy()

    def set_armature(self, armature: np.ndarray) -> None:
        """Set the rotor armature (kg m², one per joint) of this description and of its controller
        model: a `RobotModel` built on `model` includes it in M from its next snapshot."""
        armature = np.asarray(armature, dtype=float)
        if armature.shape != self.armature.shape or not np.all(np.isfinite(armature)) or np.any(armature < 0):
            raise ValueError(f"armature must be {self.armature.size} finite non-negative numbers, got {armature!r}")
        self.armature[:] = armature
        self.model.armature = self.armature.copy()


def available() -> tuple[str, ...]:
    """Names of the robots that load by name here: the shipped ones, and the Panda when its optional
    package is installed."""
    return BUILTIN + tuple(n for n in EXTERNAL if external.installed(n))


def robot_spec(
    urdf: str | Path, base: str | None = None, tip: str | None = None, package_paths: tuple[str, ...] | list[str] = ()
) -> str:
    """The one string that names a URDF with its chain and package options (what `load` takes)."""
    query = [(k, v) for k, v in (("base", base), ("tip", tip)) if v]
    query += [("package_path", str(Path(p).expanduser().resolve())) for p in package_paths]
    path = str(Path(urdf).expanduser())
    return f"{path}#{urlencode(query)}" if query else path


ROBOT_ENV = "TORQUELAB_ROBOT"  # the robot of headless commands (experiment, sweep), workers included


def chosen(default: str) -> str:
    """The robot a headless command was given (`--robot` / `--urdf` set ROBOT_ENV), else `default`
    (the scenario's own arm)."""
    return os.environ.get(ROBOT_ENV) or default


def short_name(spec: str) -> str:
    """A robot's name for a list: a shipped name as it is; for a URDF (a path or a `robot_spec`) the
    name its `<robot name="…">` gives, else the file's stem."""
    if spec in BUILTIN + EXTERNAL:
        return spec
    import xml.etree.ElementTree as ET

    path = Path(spec.partition("#")[0]).expanduser()
    try:
        name = (ET.parse(path).getroot().get("name") or "").strip()
    except (OSError, ET.ParseError):
        name = ""
    return name or path.stem


def guessed_text(robot: RobotDescription) -> str:
    """One paragraph naming the values `robot` had to guess and why each matters ("" when none)."""
    if not robot.guessed:
        return ""
    parts = [f"{key}: {why}" for key, why in robot.guessed.items()]
    return f"{robot.name} has no sidecar values for these, guessed: " + "; ".join(parts) + "."


def spec_from_args(args: object) -> str | None:
    """The robot string of parsed --robot / --urdf [--base --tip --package-path] options (None when
    neither is given); ValueError for chain options without --urdf."""
    urdf = getattr(args, "urdf", None)
    base, tip = getattr(args, "base", None), getattr(args, "tip", None)
    packages = list(getattr(args, "package_path", None) or [])
    if urdf:
        return robot_spec(urdf, base, tip, packages)
    if base or tip or packages:
        raise ValueError("--base, --tip and --package-path go with --urdf PATH")
    return getattr(args, "robot", None)


def load(
    name_or_path: str | Path = DEFAULT_ROBOT,
    base: str | None = None,
    tip: str | None = None,
    package_paths: tuple[str | Path, ...] | list[str | Path] = (),
) -> RobotDescription:
    """Load a robot by name (`rizon4s`, `gen3`, `panda`), or any 7-DOF arm inside a URDF by path
    (optionally `PATH#base=..&tip=..&package_path=..`, see `robot_spec`; the keyword arguments
    override those)."""
    text = str(name_or_path)
    path_text, _, query = text.partition("#")
    options = parse_qs(query)
    base = base or next(iter(options.get("base", [])), None)
    tip = tip or next(iter(options.get("tip", [])), None)
    packages = tuple(Path(p) for p in (*package_paths, *options.get("package_path", [])))
    if text in BUILTIN:
        urdf, sidecar_path, name = ROBOTS_DIR / f"{text}.urdf", ROBOTS_DIR / f"{text}.toml", text
    elif text in EXTERNAL:
        try:
            urdf = external.urdf_path(text)
        except external.NotInstalled as exc:
            raise RobotLoadError(str(exc)) from None
        sidecar_path, name = ROBOTS_DIR / f"{text}.toml", text
    elif path_text.endswith(".urdf") or "/" in path_text or Path(path_text).suffix:
        urdf = Path(path_text).expanduser()
        if not urdf.is_file():
            raise RobotLoadError(f"URDF file not found: {urdf}")
        sidecar_path, name = urdf.with_suffix(".toml"), urdf.stem
    else:
        names = ", ".join((*BUILTIN, *EXTERNAL))
        raise RobotLoadError(f"unknown robot {text!r}; choose one of {names} or give a URDF path")
    sidecar: dict = {}
    if sidecar_path.is_file():
        try:
            sidecar = tomllib.loads(sidecar_path.read_text())
        except tomllib.TOMLDecodeError as exc:
            raise RobotLoadError(f"cannot read sidecar {sidecar_path}: {exc}") from None
    spec = text if text in BUILTIN + EXTERNAL else robot_spec(urdf, base, tip, [str(p) for p in packages])
    return _build(name, urdf.resolve(), sidecar, base, tip, packages, spec, has_sidecar=bool(sidecar))


def _parse_full_model(urdf: Path) -> pin.Model:
    """Pinocchio's model of the whole URDF (every joint); RobotLoadError with the parser's own words."""
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
    return model


def _reduced(model: pin.Model, chain: Chain, urdf: Path) -> pin.Model:
    """The arm alone: every joint not in the chain locked at its stated position [buildReducedModel]."""
    if not chain.locked:
        return model
    q_ref = pin.neutral(model)
    lock_ids = []
    for name, value in chain.locked.items():
        if not model.existJointName(name):
            raise RobotLoadError(f"{urdf.name}: Pinocchio did not build joint {name!r}")
        jid = model.getJointId(name)
        joint = model.joints[jid]
        if joint.nq == 1:
            q_ref[joint.idx_q] = value
        lock_ids.append(jid)
    return pin.buildReducedModel(model, sorted(lock_ids), q_ref)


def _build(
    name: str,
    urdf: Path,
    sidecar: dict,
    base: str | None = None,
    tip: str | None = None,
    package_paths: tuple[Path, ...] = (),
    spec: str = "",
    has_sidecar: bool = True,
) -> RobotDescription:
    locked_given = sidecar.get("locked", {})
    if not isinstance(locked_given, dict) or not all(isinstance(v, (int, float)) for v in locked_given.values()):
        raise RobotLoadError(f"{name}: sidecar `locked` must be a table of joint = position")
    full = _parse_full_model(urdf)  # first: urdfdom's own words on a URDF that does not parse
    try:
        _, chain = read_chain(urdf, base or sidecar.get("base_link"), tip or sidecar.get("tip_link"), locked_given)
    except ChainError as exc:
        raise RobotLoadError(f"{urdf.name}: {exc}") from None
    model = _reduced(full, chain, urdf)
    joint_names = tuple(model.names[1:])
    if model.nv == N_JOINTS and joint_names != chain.arm_joints:
        raise RobotLoadError(f"{urdf.name}: Pinocchio ordered the arm's joints as {', '.join(joint_names)}")
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
    flange = sidecar.get("flange_frame") or chain.tip
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
    guessed = {}
    if "armature" not in sidecar:
        guessed["armature"] = (
            "zero (no sidecar value): the rotor inertia adds to M's diagonal, so Λx, the nullspace inertia"
            " and every coupling metric (W_a, W_f, P_d·f̂) differ from the real arm's"
        )
    if "tcp_offset_xyz" not in sidecar and "flange_frame" not in sidecar:
        guessed["tcp"] = (
            f"at the chain's tip {chain.tip!r} (no sidecar TCP): the contact point, the task inertia Λx"
            " and the coupling seen there move with the tool"
        )
    if not has_sidecar:
        guessed["postures"] = (
            "home is the zero posture clipped into the limits; the polish start is searched over the arm's"
            " self-motion (app/scenarios/reach.py) and the limit-drop and mass-drop starts from the arm's load and"
            " reach (app/scenarios/drop_postures.py), not chosen"
        )
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
        base_link=chain.base,
        tip_link=chain.tip,
        locked=dict(chain.locked),
        package_paths=package_paths,
        guessed=guessed,
        spec=spec or str(urdf),
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


def _se3(xyz, rpy) -> pin.SE3:
    return pin.SE3(pin.rpy.rpyToMatrix(*map(float, rpy)), np.asarray(xyz, dtype=float))


def _add_frame(model: pin.Model, name: str, parent_frame: str, offset: pin.SE3) -> None:
    """Add an operational frame `name` at `offset` from `parent_frame` (expressed in it)."""
    parent_id = model.getFrameId(parent_frame)
    parent = model.frames[parent_id]
    placement = parent.placement * offset
    model.addFrame(pin.Frame(name, parent.parentJoint, parent_id, placement, pin.FrameType.OP_FRAME))
