"""Replay: pause and scrub the logged window; the 3D arm, its overlays' anchor and every plot move to
the chosen instant; events are marked and can be jumped to; a run can pause itself at an event.

Turning *Replay* on pauses the simulation and takes the last minute of the step log (every
`REPLAY_EVERY` steps) on the loop thread. The slider picks an instant: the plots draw their window
up to it (`Plots.replay_t`), and the arm is posed from the logged joint positions with MuJoCo's
forward kinematics on a private `MjData` of the same model (the simulation's own data is never
touched). Every scene object follows: a payload fixed to the arm is posed with it, the task target is
the logged one, the contact point, normal and friction forces are the logged ones at the tool, the
contact ring is red where contact was lost and the lift marks are those before the instant, and a
twin arm stands at its own logged posture of the instant. The coupling ellipse follows the tool, and
its shape and W value are computed again at the instant's posture from the arm's model
(`ArmPoser.coupling`: the controller's terms are not logged). The commanded path ahead and a drag are
hidden while replaying. The status line says it is a replay and shows the instant (`status_hook`).

Events: the phase markers of the plots (S1…S6, the drop, a payload release), each QP fallback
(onsets closer than `FALLBACK_BURST_S` to the one before count as one burst), contact lost
(`metrics.contact_loss_onsets`: the true contact force reaching zero while the strokes run) and a
halt; all of them, listed in *Jump to event*, which follows the slider to the latest event at or before
the instant. *Pause at events* pauses a running simulation `EVENT_HOLD_S` after an event (the end of a
drop, a stroke), so a person can look at it and replay it. A preset switch or a Reset ends a replay
and resets its controls.
"""

from __future__ import annotations

import dataclasses
import threading
import time
import traceback
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np
import viser

from app.core.commands import Pause
from app.live.loop import SimLoop
from app.live.ui.plot_history import phase_markers
from app.live.ui.plots import Plots
from app.scenarios import PhaseMark
from app.scenarios.metrics import contact_loss_onsets, contact_lost
from control.coupling import Subspaces, coupling_terms, coupling_values
from control.model import RobotModel

REPLAY_EVERY = 5  # logged steps per replay sample (5 ms)
REPLAY_SECONDS = 60.0
FALLBACK_BURST_S = 0.05  # QP fallback onsets within this of the previous one are one burst
EVENT_HOLD_S = 1.0  # Pause at events: this long after an event
PLAY_GRACE_S = 1.5  # a running frame this soon after turning replay on is one built before the pause


@dataclass(frozen=True)
class Event:
    """Something worth jumping to: simulated time and a short name."""

    t: float
    label: str


def fallback_bursts(t: np.ndarray, fallback: np.ndarray, gap_s: float = FALLBACK_BURST_S) -> list[Event]:
    """One event per burst of QP fallback onsets (an onset within `gap_s` of the previous one joins its
    burst), labelled with the burst's count when above one."""
    on = np.flatnonzero((fallback[1:] > 0.5) & (fallback[:-1] < 0.5)) + 1
    if len(fallback) and fallback[0] > 0.5:
        on = np.concatenate([[0], on])
    out: list[Event] = []
    start, count, last = None, 0, -np.inf
    for i in on:
        ti = float(t[i])
        if start is not None and ti - last <= gap_s:
            count += 1
        else:
            if start is not None:
                out.append(Event(start, "QP fallback" if count == 1 else f"QP fallback ×{count}"))
            start, count = ti, 1
        last = ti
    if start is not None:
        out.append(Event(start, "QP fallback" if count == 1 else f"QP fallback ×{count}"))
    return out


def find_events(
    columns: dict[str, np.ndarray], halted: str = "", segments: int = 0, marks: Iterable[PhaseMark] = ()
) -> list[Event]:
    """Every event in logged columns: phase markers (the preset's `segments` strokes and its `marks`), QP
    fallback bursts, contact losses, a halt at the end."""
    t = columns.get("t", np.zeros(0))
    out = [Event(m.t, m.label) for m in phase_markers(columns, segments, marks)]
    fb = columns.get("fallback")
    if fb is not None and len(fb) == len(t) and len(t) > 1:
        out += fallback_bursts(t, fb)
    force, segment = columns.get("contact_force_n"), columns.get("segment")
    if force is not None and segment is not None and len(force) == len(t):
        out += [Event(float(t[i]), "contact lost") for i in contact_loss_onsets(force, segment)]
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

    def body_com(self, body: int) -> np.ndarray:
        """A body's centre of mass as of the last `pose` (a payload fixed to the arm moves with it)."""
        return self.data.xipos[body].copy()

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


def logged_index(times: np.ndarray, t: float) -> int:
    """The logged row shown for instant t: the first at or after it (the last one beyond the window)."""
    return int(np.clip(np.searchsorted(times, t), 0, len(times) - 1))


def instant_snapshot(live: Any, columns: dict[str, np.ndarray], poser: ArmPoser, t: float) -> Any:
    """The live snapshot with every scene object moved to the logged instant t (see the module docstring);
    the live one when the row's posture is not finite."""
    times = columns["t"]
    i = logged_index(times, t)
    q = np.array([columns[f"q_{j + 1}"][i] for j in range(len(live.joint_margins))])
    if not np.all(np.isfinite(q)):
        return live
    positions, wxyz, tcp, rot = poser.pose(q)
    body = live.payload_body
    payload = None  # a free mass (mass-drop's) as logged, a payload fixed to the arm posed with it
    if live.payload_position is not None:
        payload = _logged_vector(columns, ("payload_x_m", "payload_y_m", "payload_z_m"), i)
        if payload is None and body is not None:
            payload = poser.body_com(body)
    coupling = poser.coupling(q, live.subspaces)
    P, W = coupling if coupling is not None else (live.P, live.W)
    target = _logged_vector(columns, ("target_x_m", "target_y_m", "target_z_m"), i)
    contact: dict[str, Any] = {"contact_point": None, "contact_force": None, "contact_lost": False}
    force = _logged_vector(columns, ("friction_x_n", "friction_y_n", "contact_force_n"), i)
    segment = columns.get("segment")
    lifts, lift_times = np.zeros((0, 3)), np.zeros(0)
    if force is not None and segment is not None and live.contact_point is not None:
        lost = contact_lost(columns["contact_force_n"][: i + 1], segment[: i + 1])
        contact = {"contact_point": tcp, "contact_force": force, "contact_lost": bool(lost[-1])}
        onsets = contact_loss_onsets(columns["contact_force_n"][: i + 1], segment[: i + 1])
        lifts = np.array([lift_point(poser, columns, k, len(q)) for k in onsets]).reshape(-1, 3)
        lift_times = np.array(times[onsets], dtype=float)
    twin_positions = twin_wxyz = None  # the twin arm at its logged posture of the instant (same model)
    if live.twin_link_positions is not None and "twin_q_1" in columns:
        twin_q = np.array([columns[f"twin_q_{j + 1}"][i] for j in range(len(q))])
        if np.all(np.isfinite(twin_q)):
            twin_positions, twin_wxyz, _, _ = poser.pose(twin_q)
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
        q=q,
        drag_point=None,
        drag_target=None,
        drag_force=None,
        **contact,
        contact_lifts=lifts,
        contact_lift_times=lift_times,
        target_position=target,
        payload_position=payload,
        path=np.zeros((0, 3)),
        twin_link_positions=twin_positions,
        twin_link_wxyz=twin_wxyz,
    )


def lift_point(poser: ArmPoser, columns: dict[str, np.ndarray], i: int, n: int) -> np.ndarray:
    """Where the tool was at logged row i (a contact loss's onset)."""
    q = np.array([columns[f"q_{j + 1}"][i] for j in range(n)])
    return poser.pose(q)[2]


def _logged_vector(columns: dict[str, np.ndarray], names: tuple[str, str, str], i: int) -> np.ndarray | None:
    """The three logged columns at row i as a vector; None when one is missing or not finite."""
    if not all(name in columns for name in names):
        return None
    v = np.array([float(columns[name][i]) for name in names])
    return v if np.all(np.isfinite(v)) else None


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
        self._shown_run: tuple[int, int] | None = None  # the run (session, restarts) the controls belong to
        self.status_hook: Any = None  # called with the instant shown (None: live) to rewrite the status line
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
            self._status(None)
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
            self.events = find_events(columns, halted, lab.session.scenario.segments, lab.session.scenario.phase_marks)
            self._poser, self._poser_session = poser, session_id
        self.slider.min, self.slider.max = float(t[0]), float(t[-1])
        self.slider.value = float(t[-1])
        self.slider.disabled = False
        labels = tuple(f"{e.label} at {e.t:.2f} s" for e in self.events) or ("–",)
        self.jump.options = labels
        self.jump.disabled = not self.events
        self.info.content = (
            f"Replaying {t[0]:.2f}…{t[-1]:.2f} s; {len(self.events)} event(s), all in *Jump to event*. "
            "The arm, the payload, the target, the contact forces and marks and the plots show the chosen "
            "instant (a twin arm too); the coupling ellipse is computed at its posture; the path ahead is hidden."
        )
        self.show(float(t[-1]))

    def _take(self, lab: Any) -> tuple[dict[str, np.ndarray], str, int, ArmPoser]:
        """On the loop thread: the logged window, the halt reason and a poser for the current model."""
        columns = lab.log.window(REPLAY_SECONDS, lab.dt, REPLAY_EVERY)
        if lab.twin is not None and "t" in columns:  # the twin's postures at the same instants
            twin = lab.twin.columns_at(columns["t"])
            columns |= {f"twin_{k}": v for k, v in twin.items() if k.startswith("q_")}
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
        """Move the arm and every plot to simulated time t (within the logged window); *Jump to event*
        and the status line follow."""
        with self._lock:
            self.t = t
        self.plots.replay_t = t
        label = self.event_at(t)
        if label is not None and self.jump.value != label:
            self.jump.value = label
        self._status(t)
        self._redraw()

    def event_at(self, t: float) -> str | None:
        """The *Jump to event* entry of the latest event at or before t (the first one before any)."""
        if not self.events:
            return None
        labels = list(self.jump.options)
        times = np.array([e.t for e in self.events])
        k = max(int(np.searchsorted(times, t + 1e-9, side="right")) - 1, 0)
        return labels[k] if k < len(labels) else None

    def _status(self, t: float | None) -> None:
        if self.status_hook is not None:
            try:
                self.status_hook(t)
            except Exception:  # the status line is decoration here; the replay goes on
                traceback.print_exc()

    def reset_controls(self) -> None:
        """Back to live with the controls as on a fresh run: no range, no events."""
        if self.t is not None or self.active.value:
            self.active.value = False
            self.set_active(False)
        with self._lock:
            self.columns, self.events = {}, []
        self.slider.min, self.slider.max = 0.0, 1.0
        self.slider.value = 1.0
        self.jump.options = ("–",)
        self.jump.disabled = True
        self.info.content = ""

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
        """The snapshot to draw: the live one, or while replaying every object at the chosen instant."""
        with self._lock:
            t, columns, poser = self.t, self.columns, self._poser
            same = session_id == self._poser_session
        if t is None or live is None or poser is None or not same:
            return live
        return instant_snapshot(live, columns, poser, t)

    # ---- panel hooks --------------------------------------------------------------------------------
    def refresh(self, settings: Any) -> None:
        """Nothing: the replay follows the log."""

    def live(self, frame: Any) -> None:
        """Pause at events: a running simulation pauses EVENT_HOLD_S after a new event. Play ends a replay;
        a preset switch or a Reset resets the controls."""
        run = (frame.session_id, frame.restarts)
        if self._shown_run is not None and run != self._shown_run:
            self.reset_controls()
        self._shown_run = run
        if frame.status.running and self.t is not None and time.monotonic() - self._since > PLAY_GRACE_S:
            self.active.value = False
            self.set_active(False)
        if not self.pause_at_events.value or not frame.status.running or self.t is not None:
            return
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
