"""Self-motion preview: where the nullspace objective would take the elbow (DESIGN §8).

At a fixed TCP pose the self-motion of a 7-DOF arm is a one-dimensional loop (the elbow swivel).
W_f, W_a and W_d have several local minima along it, and the gradient flow of [T15] only finds the
nearest one downhill. When switched on, the preview traces that loop through the current posture
about once a second (`control.coupling.swivel_scan`, in a separate process: a scan is ~0.1 s of
Python, which in a thread would hold the interpreter the simulation loop needs; the process gets
the robot's Pinocchio model, so the simulation's model is never shared), plots the chosen W along
it with the current posture, the flow's end and the best posture inside the joint limits marked,
and draws a translucent ghost arm at one of them. Nothing here touches the session: it reads the
joint positions of the last frame.
"""

from __future__ import annotations

import math
import threading
import time
import traceback
from typing import Any

import numpy as np
import pinocchio as pin
import viser

from app.live.ui import latency_map
from app.live.ui.chart_draws import W_SERIES
from app.live.ui.scene import add_ghost_arm, hide_ghost_arm, link_meshes, pose_ghost_arm
from app.live.ui.selfmotion_worker import SCAN_NICENESS, Preview, scan_in_worker, scan_preview
from app.live.workers import Worker, WorkerLost
from control.coupling import Subspaces, task_scale
from control.gains import NullspaceGains
from control.model import RobotModel
from robots import RobotDescription

__all__ = ["Preview", "SelfMotionPreview", "link_poses", "preview_objective", "scan_preview"]

MAX_SCAN_FAILURES = 3  # scan-process failures in a row before scans run in this thread
SCAN_TIMEOUT_S = 60.0  # a scan process that has not come up, or not answered, by then counts as failed
PREVIEW_PERIOD_S = 1.0  # s between two scans while the preview is on (a scan takes ~0.1 s)
PLANNED_SIGNAL = "swivel_plan_deg"  # the polish scenario's planned swivel, when it runs a planned path
GHOST_COLOR = (110, 130, 255)
GHOST_OPACITY = 0.35
GHOST_HIDE_RAD = np.radians(2.0)  # a ghost this close to the arm on every joint is hidden (no flicker through it)
GHOST_SHOW_RAD = np.radians(3.0)  # … and shows again once it is this far (no flicker at the edge)
AS_CONTROLLER = "as the controller"
OBJECTIVE_CHOICES = (AS_CONTROLLER, "W_f", "W_a", "W_d")
GHOST_CHOICES = ("where the flow settles (on the plan when one runs)", "best inside the limits", "hidden")
INTRO = (
    "The elbow's self-motion at the current TCP pose is a loop (swivel angle, 0° = elbow up). "
    "The scan shows W along it: the flow of [T15] only reaches the nearest minimum downhill; "
    "the ghost arm shows where it settles (or, in a planned case, the planned posture now, as it moves) or "
    "the best posture inside the joint limits."
)


def scan_worker() -> Worker:
    """The scan process: spawned (it does not inherit the server's threads), SCAN_NICENESS steps
    nicer than the server."""
    return Worker("torquelab-selfmotion-scan", niceness_above_app=SCAN_NICENESS)


def wrap_deg(value: Any) -> Any:
    """Angles in degrees wrapped into [−180, 180)."""
    return (np.asarray(value, dtype=float) + 180.0) % 360.0 - 180.0


def _units_of(frame: Any) -> np.ndarray | None:
    """The task scale of the frame's nullspace group (the units the controller takes W in), or None."""
    settings = getattr(frame, "settings", None)
    ns = getattr(settings, "groups", {}).get("nullspace") if settings is not None else None
    if not isinstance(ns, NullspaceGains):
        return None
    return task_scale(ns.unit_length_m, ns.unit_mass_kg)


def _mu_of(frame: Any) -> float | None:
    """The friction μ of the frame's contact group (a scenario with a table), or None."""
    settings = getattr(frame, "settings", None)
    contact = getattr(settings, "groups", {}).get("contact") if settings is not None else None
    mu = getattr(contact, "mu", None)
    return float(mu) if isinstance(mu, int | float) and np.isfinite(mu) else None


W_UNITS = {name: unit for name, unit, _ in W_SERIES}


def decades_of(W: np.ndarray) -> tuple[float, float]:
    """The whole decades (10^a, 10^b), b > a, that hold the positive finite values of W (1…10 for none)."""
    w = np.asarray(W, dtype=float)
    w = w[np.isfinite(w) & (w > 0)]
    if not w.size:
        return (1.0, 10.0)
    lo = math.floor(math.log10(float(w.min())) + 1e-9)
    hi = max(lo + 1, math.ceil(math.log10(float(w.max())) - 1e-9))
    return (10.0**lo, 10.0**hi)


def loop_scales(decades: tuple[float, float]) -> dict[str, Any]:
    """The loop plot's scales: the swivel in degrees, W on a log axis over `decades`."""
    return {
        "x": {"time": False, "auto": False, "range": (-180.0, 180.0)},
        "y": {"distr": 3, "auto": False, "range": decades},
    }


def loop_axes(decades: tuple[float, float], name: str) -> tuple[Any, Any]:
    """The loop plot's axes: W `name` with its unit, a tick at every decade of its range, the top one
    included, written out."""
    lo, hi = (round(math.log10(v)) for v in decades)
    splits = tuple(10.0**k for k in range(lo, hi + 1))
    texts = tuple(f"{v:g}" for v in splits)
    width = 16 + 7 * max(len(t) for t in texts)
    label = f"{name} ({W_UNITS[name]})" if name in W_UNITS else name
    y = {"label": label, "labelSize": 18, "splits": splits, "values": texts, "size": width}
    return ({"label": "swivel (°, 0 = elbow up)", "labelSize": 16}, y)


def preview_objective(choice: str, controller_objective: str | None) -> str:
    """The objective letter a dropdown choice stands for (W_a when the controller's is W_j or none)."""
    if choice == AS_CONTROLLER:
        return controller_objective if controller_objective in ("f", "a", "d") else "a"
    if choice not in OBJECTIVE_CHOICES:
        raise ValueError(f"unknown objective {choice!r}")
    return choice[2:]


def link_poses(model: RobotModel, robot: RobotDescription, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World positions (L, 3) and quaternions (L, 4, wxyz) of `robot.link_names` at q."""
    data = model.model.createData()
    pin.framesForwardKinematics(model.model, data, np.asarray(q, dtype=float))
    positions, wxyz = [], []
    for name in robot.link_names:
        pose = data.oMf[model.model.getFrameId(name)]
        x, y, z, w = pin.Quaternion(pose.rotation).coeffs()
        positions.append(pose.translation.copy())
        wxyz.append((w, x, y, z))
    return np.array(positions), np.array(wxyz)


class SelfMotionPreview:
    """The preview's inputs (inside the Nullspace folder), its plot and its ghost arm."""

    def __init__(self, server: viser.ViserServer):
        self.server = server
        gui = server.gui
        self.enabled: Any = gui.add_checkbox(
            "Self-motion preview", False, hint="Scan the elbow's self-motion loop once a second and show W along it"
        )
        self.folder = gui.add_folder("Self-motion loop", expand_by_default=True, visible=False)
        with self.folder:
            with gui.add_folder("?", expand_by_default=False):
                gui.add_markdown(INTRO)
            self.objective = gui.add_dropdown("Scan W", OBJECTIVE_CHOICES, initial_value=AS_CONTROLLER)
            self.ghost_at: Any = gui.add_dropdown("Ghost arm", GHOST_CHOICES, initial_value=GHOST_CHOICES[0])
            self.text = gui.add_markdown("")
            self.plot = gui.add_uplot(
                tuple(np.zeros(2) for _ in range(7 + len(latency_map.LEVELS))),
                (
                    {"label": "swivel (°, 0 = elbow up)"},
                    _line("W inside the limits", "#1f77b4", 2.0),
                    _line("beyond a limit", "#aaaaaa", 1.0, dash=(4.0, 4.0)),
                    _marker("now", "#222222"),
                    _marker("flow settles", "#6e82ff"),
                    _marker("best", "#2ca02c"),
                    _marker("plan", "#ff7f0e"),
                    *(
                        _line(latency_map.level_label(level), colour, 5.0)
                        for level, colour in zip(latency_map.LEVELS, latency_map.LEVEL_COLOURS, strict=True)
                    ),
                ),
                title="W along the self-motion loop",
                scales=loop_scales((1.0, 10.0)),
                axes=loop_axes((1.0, 10.0), "W"),
                legend={"live": False},  # type: ignore[typeddict-item]
                aspect=1.6,
                padding=(24, 12, 0, 0),
            )
        self._decades: tuple[tuple[float, float], str] = ((1.0, 10.0), "W")  # the y range (whole decades) and W
        self.latest: Preview | None = None
        # the stability map's tolerated latency (`latency_map`), read once; the loop is coloured with it at
        # the session's μ while the arm is the map's
        self.latency_map = latency_map.load()
        self.tolerated: np.ndarray | None = None  # per plotted swivel, the latency the last plot coloured
        self._mu: float | None = None
        self._robot_name: str | None = None
        self.scans = 0
        self._input: tuple[Any, np.ndarray, Subspaces, str | None] | None = None
        self._scale: np.ndarray | None = None  # the controller's units of W (`control.coupling.task_scale`)
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._models: dict[str, RobotModel] = {}
        self._worker = scan_worker()  # started on the first scan
        self._in_process = True  # off after MAX_SCAN_FAILURES failures in a row: scans then run in this thread
        self._scan_failures = 0  # scan-process failures in a row (a dead process is replaced)
        self.scan_restarts = 0  # scan processes started again after one died
        self._ghost: dict[str, viser.MeshHandle] = {}
        self._ghost_robot: str | None = None
        self.ghost_q: np.ndarray | None = None  # the posture the ghost was last drawn at (tests read it)
        self._planned_deg: float | None = None  # swivel the planned path heads for, if the scenario plans one
        self._planned_q: np.ndarray | None = None  # the planned posture now, if the scenario tracks a plan
        self._ghost_hidden_near = False  # the ghost is hidden because it stands in the arm's posture
        self._ghost_lock = threading.Lock()  # the ghost is posed from the publisher and the scan thread
        for handle in (self.objective, self.ghost_at):
            handle.on_update(lambda _: self._wake.set())
        self.enabled.on_update(lambda _: self._on_enabled())
        self._thread = threading.Thread(target=self._run, name="torquelab-selfmotion", daemon=True)
        self._thread.start()

    # ---- input from the publisher ---------------------------------------------------------------
    def feed(self, frame: Any) -> None:
        """Remember the newest posture (called a few times a second with the loop's frame)."""
        scene: Any = getattr(frame, "scene", None)
        q = getattr(scene, "q", None)
        if scene is None or q is None or not np.all(np.isfinite(q)) or getattr(scene, "near_singular", False):
            return
        planned = getattr(frame, "status", None)
        planned = planned.signals.get(PLANNED_SIGNAL) if planned is not None else None
        self._planned_deg = float(planned) if planned is not None and np.isfinite(planned) else None
        planned_q = getattr(scene, "planned_q", None)
        self._planned_q = None if planned_q is None else np.array(planned_q, dtype=float)
        with self._lock:
            self._input = (frame.robot, np.array(q, dtype=float), scene.subspaces, scene.objective)
            self._scale = _units_of(frame)
            self._mu = _mu_of(frame)
            self._robot_name = getattr(frame.robot, "name", None)
        if self._planned_q is not None and self._on_plan():
            self._show_ghost(frame.robot, self._planned_q)  # follows the plan at the panels' rate

    def _on_plan(self) -> bool:
        """True when the ghost stands on the planned posture: preview on, first ghost choice, a plan runs."""
        return bool(self.enabled.value) and str(self.ghost_at.value) == GHOST_CHOICES[0] and self._planned_q is not None

    def set_enabled(self, on: bool, ghost_at: str | None = None) -> None:
        """Switch the preview on or off from the server side (benchmarks, tests); `ghost_at` is one
        of GHOST_CHOICES."""
        if ghost_at is not None:
            if ghost_at not in GHOST_CHOICES:
                raise ValueError(f"ghost_at must be one of {', '.join(GHOST_CHOICES)}")
            self.ghost_at.value = ghost_at
        self.enabled.value = bool(on)
        self._on_enabled()

    def _on_enabled(self) -> None:
        """Show the loop's fold and scan at once when switched on; hide both when off."""
        on = bool(self.enabled.value)
        if self.folder.visible != on:
            self.folder.visible = on
        self._wake.set()

    def stop(self) -> None:
        """End the worker thread."""
        self._stop.set()
        self._wake.set()
        self._thread.join(timeout=2.0)
        self._worker.stop()

    # ---- worker ---------------------------------------------------------------------------------
    def _run(self) -> None:
        while not self._stop.is_set():
            self._wake.wait(PREVIEW_PERIOD_S)
            self._wake.clear()
            if self._stop.is_set():
                return
            try:
                self._tick()
            except Exception:  # a failed scan must not end the preview
                if not self._stop.is_set():  # (a scan cut short by `stop` is no failure)
                    traceback.print_exc()

    def _tick(self) -> None:
        if not self.enabled.value:
            self._show_ghost(None, None)
            return
        with self._lock:
            job = self._input
        if job is None:
            return
        robot, q, sub, controller_objective = job
        result = self._scan(robot, q, sub, preview_objective(str(self.objective.value), controller_objective))
        self.latest = result
        self.scans += 1
        self._show_plot(result)
        if self._on_plan():
            self._show_ghost(robot, self._planned_q)
            return
        index = {GHOST_CHOICES[0]: result.flow, GHOST_CHOICES[1]: result.best}.get(str(self.ghost_at.value))
        self._show_ghost(robot, None if index is None else result.q[index])

    def _scan(self, robot: RobotDescription, q: np.ndarray, sub: Subspaces, objective: str) -> Preview:
        """One scan in the scan process (started on first use; this thread waits without the GIL). A
        process that died is replaced by a new one, which scans again; after MAX_SCAN_FAILURES
        failures in a row (no process can run here) scans run in this thread."""
        while self._in_process:
            try:
                return self._in_worker(robot, q, sub, objective)
            except (WorkerLost, TimeoutError) as exc:  # a dead, stuck or missing process: a new one
                if self._worker.stopped:  # the preview is being stopped: no scan here either
                    raise
                self._scan_failures += 1
                if self._scan_failures >= MAX_SCAN_FAILURES or self._worker.gave_up is not None:
                    print(f"torquelab: self-motion scan process failed ({exc!r}); scanning in the server process")
                    self._in_process = False
                else:
                    self.scan_restarts += 1
        return scan_preview(self._model_for(robot), robot, q, sub, objective, self._scale)

    def _in_worker(self, robot: RobotDescription, q: np.ndarray, sub: Subspaces, objective: str) -> Preview:
        args = (
            str(robot.urdf_path), robot.model, robot.q_lower, robot.q_upper, q, sub.force_axes, objective, self._scale
        )  # fmt: skip
        preview = self._worker.call(scan_in_worker, *args, timeout=SCAN_TIMEOUT_S)
        self._scan_failures = 0
        return preview

    def _model_for(self, robot: RobotDescription) -> RobotModel:
        key = str(robot.urdf_path)
        if key not in self._models:
            self._models.clear()
            self._models[key] = RobotModel(robot.model)
        return self._models[key]

    def _show_plot(self, p: Preview) -> None:
        wrapped = wrap_deg(p.swivel_deg)  # −180…180°, as the text says the angles
        order = np.argsort(wrapped, kind="stable")
        x = wrapped[order]
        W, feasible = p.W[order], p.feasible[order]
        inside = np.where(feasible, W, np.nan)
        outside = np.where(feasible, np.nan, W)
        rank = np.empty(len(order), dtype=int)
        rank[order] = np.arange(len(order))
        plan = None
        if self._planned_deg is not None and len(x):
            gap = np.abs(wrap_deg(x - self._planned_deg))
            plan = int(order[int(np.argmin(gap))])
        marks = []
        for index in (0, p.flow, p.best, plan):
            m = np.full(len(x), np.nan)
            if index is not None:
                m[rank[index]] = p.W[index]
            marks.append(m)
        tolerated = self._tolerated(x)
        self.tolerated = tolerated
        decades = decades_of(W)
        if (decades, p.name) != self._decades:  # a new range rebuilds the chart in the browser: only on change
            self._decades = (decades, p.name)
            self.plot.scales = loop_scales(decades)
            self.plot.axes = loop_axes(decades, p.name)
        self.plot.data = (x, inside, outside, *marks, *latency_map.level_series(inside, tolerated))
        self.plot.title = f"{p.name} along the self-motion loop"
        text = p.summary()
        if np.any(np.isfinite(tolerated)):
            text += (
                f"\n\nColoured by the latency each swivel tolerates at μ = {self._mu:g} in the stability map "
                "(held postures at the polish start, reading + drive periods: docs/map.md)."
            )
        if self.text.content != text:
            self.text.content = text

    def _tolerated(self, swivel_deg: np.ndarray) -> np.ndarray:
        """The map's tolerated latency at each swivel at the session's μ (NaN: no map, no μ, another arm)."""
        with self._lock:
            mu, name = self._mu, self._robot_name
        m = self.latency_map
        if m is None or mu is None or (m.robot is not None and name != m.robot):
            return np.full(np.shape(swivel_deg), np.nan)
        return m.at(mu, swivel_deg)

    def _near_the_arm(self, q: np.ndarray) -> bool:
        """True while the ghost's posture is within GHOST_HIDE_RAD of the arm's on every joint (it would
        flicker through the arm); once hidden it shows again only beyond GHOST_SHOW_RAD."""
        with self._lock:
            current = None if self._input is None else self._input[1]
        if current is None or np.shape(current) != np.shape(q):
            return False
        gap = float(np.max(np.abs(np.asarray(q, dtype=float) - current)))
        self._ghost_hidden_near = gap < (GHOST_SHOW_RAD if self._ghost_hidden_near else GHOST_HIDE_RAD)
        return self._ghost_hidden_near

    def _show_ghost(self, robot: RobotDescription | None, q: np.ndarray | None) -> None:
        with self._ghost_lock:
            if robot is None or q is None or self._near_the_arm(q):
                hide_ghost_arm(self._ghost)
                return
            if self._ghost_robot != str(robot.urdf_path):
                self._build_ghost(robot)
            positions, wxyz = link_poses(self._model_for(robot), robot, q)
            with self.server.atomic():
                pose_ghost_arm(self._ghost, robot.link_names, positions, wxyz)
            self.ghost_q = np.array(q, dtype=float)

    def _build_ghost(self, robot: RobotDescription) -> None:
        for handle in self._ghost.values():
            handle.remove()
        shapes = link_meshes(str(robot.urdf_path), robot.package_paths)
        self._ghost = add_ghost_arm(self.server, "/ghost", shapes, GHOST_COLOR, GHOST_OPACITY, visible=False)
        self._ghost_robot = str(robot.urdf_path)

    @property
    def ghost_visible(self) -> bool:
        """True while the ghost arm is drawn."""
        return any(h.visible for h in self._ghost.values())

    def wait_scans(self, count: int, timeout: float = 10.0) -> bool:
        """Wait until `count` scans have been made (for tests)."""
        deadline = time.monotonic() + timeout
        while self.scans < count and time.monotonic() < deadline:
            time.sleep(0.02)
        return self.scans >= count


def _line(label: str, color: str, width: float, **extra: Any) -> Any:
    return {"label": label, "stroke": color, "width": width, **extra}


def _marker(label: str, color: str) -> Any:
    return {"label": label, "stroke": color, "width": 0, "points": {"show": True, "size": 9, "fill": color}}
