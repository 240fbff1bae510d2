"""Replay: pause and scrub the logged window; the 3D arm, its overlays' anchor and every plot move to
the chosen instant; events are marked and can be jumped to; a run can pause itself at an event.

Turning *Replay* on pauses the simulation and takes the last minute of the step log (every
`REPLAY_EVERY` steps) on the loop thread. The slider picks an instant: the plots draw their window
up to it (`Plots.replay_t`), and the arm is posed from the logged joint positions with MuJoCo's
forward kinematics on a private `MjData` of the same model (the simulation's own data is never
touched). The coupling ellipse follows the tool, and its shape and W value are computed again at the
instant's posture from the arm's model (`ArmPoser.coupling`: the controller's terms are not logged);
arrows and the commanded path are hidden while replaying.

Events: the phase markers of the plots (S1…S6, the drop, a payload release), the first step of each
QP fallback, contact lost (polish: the F/T reading falls below `CONTACT_LOST_N` while the setpoint
asks for force) and a halt. *Pause at events* pauses a running simulation `EVENT_HOLD_S` after an event
(the end of a drop, a stroke), so a person can look at it and replay it.
"""

from __future__ import annotations

import dataclasses
import threading
import time
import traceback
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np
import viser

from app.core.commands import Pause
from app.live.loop import SimLoop
from app.live.ui.plots import Plots, phase_markers
from control.coupling import Subspaces, coupling_terms, coupling_values
from control.model import RobotModel

REPLAY_EVERY = 5  # logged steps per replay sample (5 ms)
REPLAY_SECONDS = 60.0
CONTACT_LOST_N = 1.0  # |F_z| below this while the setpoint asks for more than SETPOINT_N: contact lost
SETPOINT_N = 5.0
EVENT_HOLD_S = 1.0  # Pause at events: this long after an event
PLAY_GRACE_S = 1.5  # a running frame this soon after turning replay on is one built before the pause


@dataclass(frozen=True)
class Event:
    """Something worth jumping to: simulated time and a short name."""

    t: float
    label: str


def find_events(columns: dict[str, np.ndarray], halted: str = "", segments: int = 0) -> list[Event]:
    """The events in logged columns: phase markers (the preset's `segments` strokes among them), QP
    fallback onsets, contact lost, a halt at the end."""
    t = columns.get("t", np.zeros(0))
    out = [Event(m.t, m.label) for m in phase_markers(columns, segments)]
    fb = columns.get("fallback")
    if fb is not None and len(fb) == len(t) and len(t) > 1:
        on = np.flatnonzero((fb[1:] > 0.5) & (fb[:-1] < 0.5)) + 1
        out += [Event(float(t[i]), "QP fallback") for i in on[:20]]
    fz, fd = columns.get("F_z"), columns.get("Fd_z")
    if fz is not None and fd is not None and len(t) > 1:
        lost = (np.abs(fz) < CONTACT_LOST_N) & (np.abs(fd) > SETPOINT_N)
        starts = np.flatnonzero(lost[1:] & ~lost[:-1]) + 1
        out += [Event(float(t[i]), "contact lost") for i in starts[:20]]
    if halted and len(t):
        out.append(Event(float(t[-1]), "halt"))
    return sorted(out, key=lambda e: e.t)


class ArmPoser:
    """Link poses for logged joint positions: forward kinematics on a private MjData of the world's model."""

    def __init__(self, world: Any, link_names: tuple[str, ...]):
        self.model = world.model
        self.data = mujoco.MjData(world.model)
        self.qpos_adr = np.array(world.qpos_adr)
        self.ids = np.array(world.body_ids(link_names))
        self.tcp_site = int(world.tcp_site)
        self.data.qpos[:] = world.data.qpos  # the other joints (a free mass, …) where they are now
        robot = world.robot
        self.q_lower, self.q_upper = np.array(robot.q_lower), np.array(robot.q_upper)
        self.endless = np.array(robot.endless, dtype=bool)
        self.dynamics = RobotModel(robot.model.copy())  # private: the session's model is the loop's

    def coupling(self, q: np.ndarray, sub: Subspaces) -> tuple[dict[str, np.ndarray], dict[str, float]] | None:
        """(P_f, P_a, P_d and W_f, W_a, W_d) of [T] Table I at joint positions q (q̇ = 0), for the
        coupling ellipse of a replayed instant; None where the motion block is singular."""
        dyn = self.dynamics.compute(q, np.zeros_like(q))
        try:
            terms = coupling_terms(dyn.Lambda, dyn.Lambda_inv, sub)
        except np.linalg.LinAlgError:
            return None
        P = {"P_f": terms.P_f.copy(), "P_a": terms.P_a.copy(), "P_d": terms.P_d.copy()}
        return P, dict(coupling_values(terms))

    def margins(self, q: np.ndarray) -> np.ndarray:
        """Distance of each joint to its nearer position limit (inf for endless joints), as the scene's."""
        m = np.minimum(q - self.q_lower, self.q_upper - q)
        return np.where(self.endless, np.inf, m)

    def pose(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(link positions (L, 3), link wxyz (L, 4), TCP position, TCP rotation) at joint positions q."""
        self.data.qpos[self.qpos_adr] = q
        mujoco.mj_kinematics(self.model, self.data)
        return (
            self.data.xpos[self.ids].copy(),
            self.data.xquat[self.ids].copy(),
            self.data.site_xpos[self.tcp_site].copy(),
            self.data.site_xmat[self.tcp_site].reshape(3, 3).copy(),
        )


class ReplayPanel:
    """The Replay fold of the Plots panel (see the module docstring); the publisher asks it for the scene
    to show (`scene_for`) and calls it like a panel."""

    def __init__(self, server: viser.ViserServer, loop: SimLoop, plots: Plots, order: float | None = None):
        self.server = server
        self.loop = loop
        self.plots = plots
        self.publisher: Any = None  # set by the app: its scene view and last frame
        self.columns: dict[str, np.ndarray] = {}
        self.events: list[Event] = []
        self.t: float | None = None  # the instant shown, while replaying
        self._poser: ArmPoser | None = None
        self._poser_session = -1
        self._lock = threading.Lock()
        self._seen_events: set[tuple[float, str]] = set()
        self._hold_until: float | None = None
        self._run: tuple[int, int] | None = None
        self._since = 0.0  # wall time replay was turned on (frames built before the pause still say running)
        gui = server.gui
        with plots.panel_tab:
            self.folder = gui.add_folder("Replay", order=order, expand_by_default=True)
        with self.folder:
            self.active: Any = gui.add_checkbox(
                "Replay", False, hint="Pause and scrub the last minute: the arm and every plot move to the instant"
            )
            self.slider: Any = gui.add_slider("At t (s)", 0.0, 1.0, 0.005, 1.0, disabled=True)
            self.jump: Any = gui.add_dropdown("Jump to event", ("–",), disabled=True)
            self.pause_at_events: Any = gui.add_checkbox(
                "Pause at events", False, hint=f"Pause {EVENT_HOLD_S:g} s after a drop, a stroke's end, a fallback"
            )
            self.clear_previous = gui.add_button("Clear previous run", hint="Drop the faint trace of the run before")
            self.info = gui.add_markdown("")
        self.active.on_update(lambda e: self._on_active(e))
        self.slider.on_update(lambda e: self._on_slider(e))
        self.jump.on_update(lambda e: self._on_jump(e))
        self.clear_previous.on_click(lambda e: self.plots.clear_previous())

    # ---- callbacks --------------------------------------------------------------------------------
    def _on_active(self, event: viser.GuiEvent) -> None:
        if event.client_id is None:
            return
        self.set_active(bool(self.active.value))

    def set_active(self, on: bool) -> None:
        """Start replaying (pauses the run, takes the logged window) or go back to the live view."""
        if not on:
            with self._lock:
                self.t = None
            self.plots.replay_t = None
            self.slider.disabled = True
            self.jump.disabled = True
            self.info.content = ""
            self._redraw()
            return
        self._since = time.monotonic()
        self.loop.submit(Pause())
        lab = self.loop.lab
        columns, halted, session_id, poser = self.loop.call(lambda s: self._take(lab), timeout=30.0)
        t = columns.get("t", np.zeros(0))
        if len(t) < 2:
            self.info.content = "*Nothing logged since the last reset.*"
            return
        with self._lock:
            self.columns = columns
            self.events = find_events(columns, halted, lab.session.scenario.segments)
            self._poser, self._poser_session = poser, session_id
        self.slider.min, self.slider.max = float(t[0]), float(t[-1])
        self.slider.value = float(t[-1])
        self.slider.disabled = False
        labels = tuple(f"{e.label} at {e.t:.2f} s" for e in self.events) or ("–",)
        self.jump.options = labels
        self.jump.disabled = not self.events
        self.info.content = (
            f"Replaying {t[0]:.2f}…{t[-1]:.2f} s; {len(self.events)} event(s) marked. "
            "The arm and the plots show the chosen instant; the coupling ellipse follows the tool with the "
            "values of the live instant; arrows and the commanded path are hidden."
        )
        self.show(float(t[-1]))

    def _take(self, lab: Any) -> tuple[dict[str, np.ndarray], str, int, ArmPoser]:
        """On the loop thread: the logged window, the halt reason and a poser for the current model."""
        columns = lab.log.window(REPLAY_SECONDS, lab.dt, REPLAY_EVERY)
        poser = ArmPoser(lab.session.world, tuple(lab.session.robot.link_names))
        return columns, lab.halted, lab.session_id, poser

    def _on_slider(self, event: viser.GuiEvent) -> None:
        if event.client_id is None or self.t is None:
            return
        self.show(float(self.slider.value))

    def _on_jump(self, event: viser.GuiEvent) -> None:
        if event.client_id is None or self.t is None:
            return
        labels = list(self.jump.options)
        if event.target.value in labels and self.events:
            e = self.events[labels.index(event.target.value)]
            self.slider.value = e.t
            self.show(e.t)

    # ---- showing an instant -------------------------------------------------------------------------
    def show(self, t: float) -> None:
        """Move the arm and every plot to simulated time t (within the logged window)."""
        with self._lock:
            self.t = t
        self.plots.replay_t = t
        self._redraw()

    def _redraw(self) -> None:
        pub = self.publisher
        try:
            with self.server.atomic():
                self.plots.redraw()
                if pub is not None and pub.scene is not None and pub.last_frame is not None:
                    snap = self.scene_for(pub.last_frame.scene, pub.last_frame.session_id)
                    if snap is not None:
                        pub.scene.update(snap)
        except Exception:  # a scene being rebuilt meanwhile
            traceback.print_exc()

    def scene_for(self, live: Any, session_id: int) -> Any:
        """The snapshot to draw: the live one, or while replaying the arm at the chosen instant."""
        with self._lock:
            t, columns, poser = self.t, self.columns, self._poser
            same = session_id == self._poser_session
        if t is None or live is None or poser is None or not same:
            return live
        times = columns["t"]
        i = int(np.clip(np.searchsorted(times, t), 0, len(times) - 1))
        q = np.array([columns[f"q_{j + 1}"][i] for j in range(len(live.joint_margins))])
        if not np.all(np.isfinite(q)):
            return live
        positions, wxyz, tcp, rot = poser.pose(q)
        coupling = poser.coupling(q, live.subspaces)
        P, W = coupling if coupling is not None else (live.P, live.W)
        return dataclasses.replace(
            live,
            P=P,
            W=W,
            t=float(times[i]),
            link_positions=positions,
            link_wxyz=wxyz,
            tcp_position=tcp,
            tcp_rotation=rot,
            joint_margins=poser.margins(q),
            drag_point=None,
            drag_target=None,
            drag_force=None,
            contact_point=None,
            contact_force=None,
            path=np.zeros((0, 3)),
            twin_link_positions=None,
            twin_link_wxyz=None,
        )

    # ---- panel hooks --------------------------------------------------------------------------------
    def refresh(self, settings: Any) -> None:
        """Nothing: the replay follows the log."""

    def live(self, frame: Any) -> None:
        """Pause at events: a running simulation pauses EVENT_HOLD_S after a new event. Play ends a replay."""
        if frame.status.running and self.t is not None and time.monotonic() - self._since > PLAY_GRACE_S:
            self.active.value = False
            self.set_active(False)
        if not self.pause_at_events.value or not frame.status.running or self.t is not None:
            return
        run = (frame.session_id, frame.restarts)
        if run != self._run:
            self._run, self._seen_events, self._hold_until = run, set(), None
        markers = self.plots.markers
        now = frame.status.t
        for m in markers:
            key = (round(m.t, 3), m.label)
            if key not in self._seen_events and m.t <= now:
                self._seen_events.add(key)
                self._hold_until = m.t + EVENT_HOLD_S
        if self._hold_until is not None and now >= self._hold_until:
            self._hold_until = None
            self.loop.submit(Pause())
