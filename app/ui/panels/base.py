"""Knobs: one GUI input bound to one setting of the running session.

A `Knob` names the `configure()` key it writes, the target it belongs to ("executor",
"environment", "sensor", "drag", "target", "world"), how to read its current value from the session
(`read`: dotted attribute paths tried in order, e.g. "damper.gains.lambda_"), and the input kind.
`KnobPanel` builds a folder of knobs, writes each change as a `Configure` command (never touching
the session), checks the value first (kind, finite, range) and refuses nonsense with a
notification, and on every frame shows the values in force — greying out knobs the current
controller does not have, so one panel serves every executor.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Literal

import viser

from app.commands import Configure
from app.loop import Settings, SimLoop
from app.session import Session
from app.settings import plain, settings_of

TOUCH_HOLD_S = 0.6  # after a person moves a knob, the panel does not overwrite it for this long


@dataclass(frozen=True)
class Knob:
    """One input; see the module docstring. `show` maps the stored value to the input's value and
    `changes` maps the input's value (and the stored one) to the `configure()` changes."""

    key: str
    label: str
    target: str = "executor"
    kind: str = "slider"  # "slider", "number", "checkbox" or "dropdown"
    lo: float = 0.0
    hi: float = 1.0
    step: float = 0.01
    options: tuple[str, ...] = ()
    read: tuple[str, ...] = ()
    hint: str | None = None
    show: Callable[[Any], Any] | None = None
    changes: Callable[[Any, Any], dict[str, Any]] | None = None

    def display(self, stored: Any) -> Any:
        """The input value for a stored setting."""
        return self.show(stored) if self.show is not None else stored

    def to_changes(self, value: Any, stored: Any) -> dict[str, Any]:
        """The configure() changes for an input value."""
        return self.changes(value, stored) if self.changes is not None else {self.key: value}


def resolve(obj: Any, path: str) -> Any:
    """Follow a dotted path of attributes / list indices; AttributeError if any part is missing."""
    for part in path.split("."):
        if part.isdigit() and not isinstance(obj, (str, bytes)) and hasattr(obj, "__getitem__"):
            obj = obj[int(part)]
        else:
            obj = getattr(obj, part)
    return obj


def target_object(session: Session, target: str) -> Any:
    """The object behind a settings target."""
    return {
        "executor": session.executor,
        "environment": session.environment,
        "sensor": session.sensor,
        "drag": session.drag,
        "target": session.target_fn,
        "world": session.world,
    }.get(target)


_PROBED: dict[int, tuple[Any, tuple[str, ...]]] = {}


def configurable_scalars(executor: Any, values: dict[str, Any]) -> tuple[str, ...]:
    """Scalar settings (numbers, switches) the executor's `configure()` accepts, found once per
    executor by re-applying each current value (which changes nothing)."""
    cached = _PROBED.get(id(executor))
    if cached is not None and cached[0] is executor:
        return cached[1]
    keys = []
    for key, value in values.items():
        if isinstance(value, bool) or (isinstance(value, float) and math.isfinite(value)):
            try:
                executor.configure(**{key: value})
            except Exception:
                continue
            keys.append(key)
    _PROBED.clear()  # one executor at a time: keep the cache small
    _PROBED[id(executor)] = (executor, tuple(keys))
    return tuple(keys)


def make_settings_reader(knobs: Sequence[Knob]) -> Callable[[Session], dict[str, dict[str, Any]]]:
    """A reader for `SimLoop(settings_reader=...)`: generic settings plus every knob's `read` path,
    and under "meta" the executor's configurable scalar settings (for the "More gains" fold)."""

    def read(session: Session) -> dict[str, dict[str, Any]]:
        out: dict[str, dict[str, Any]] = {}
        for target in ("executor", "environment", "sensor", "target", "world"):
            obj = target_object(session, target)
            out[target] = settings_of(obj) if obj is not None else {}
        out["meta"] = {"executor_scalars": configurable_scalars(session.executor, out["executor"])}
        for knob in knobs:
            obj = target_object(session, knob.target)
            for path in knob.read:
                try:
                    out.setdefault(knob.target, {})[knob.key] = plain(resolve(obj, path))
                    break
                except (AttributeError, IndexError, TypeError, KeyError):
                    continue
        return out

    return read


def coerce(knob: Knob, value: Any) -> Any:
    """The input value checked for its kind and range; ValueError with a short reason otherwise."""
    if knob.kind == "checkbox":
        if not isinstance(value, bool):
            raise ValueError(f"{knob.label} must be on or off")
        return value
    if knob.kind == "dropdown":
        if value not in knob.options:
            raise ValueError(f"{knob.label} must be one of {', '.join(knob.options)}")
        return value
    if isinstance(value, bool):
        raise ValueError(f"{knob.label} must be a number")
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{knob.label} must be a number, got {value!r}") from None
    if not math.isfinite(number) or not knob.lo <= number <= knob.hi:
        raise ValueError(f"{knob.label} must be between {knob.lo:g} and {knob.hi:g}, got {value!r}")
    return number


def notify(server: viser.ViserServer, client_id: int | None, title: str, body: str, error: bool = True) -> None:
    """A notification for one client (or all when `client_id` is None); ignores closed clients."""
    color: Literal["red"] | None = "red" if error else None
    targets = server.get_clients()
    clients = [targets[client_id]] if client_id in targets else list(targets.values()) if client_id is None else []
    for client in clients:
        try:
            client.add_notification(title, body, auto_close_seconds=6.0, color=color)
        except Exception:  # the tab may have closed meanwhile
            pass


class KnobPanel:
    """A folder of knobs bound to the loop's settings (see the module docstring). Knobs the running
    session lacks are greyed out (or hidden when `hide_missing`), so every knob of both papers
    stays in view."""

    hide_missing = False

    def __init__(
        self,
        server: viser.ViserServer,
        loop: SimLoop,
        title: str,
        intro: str,
        knobs: Sequence[Knob],
        order: float | None = None,
        expand: bool = True,
    ):
        self.server = server
        self.loop = loop
        self.knobs = list(knobs)
        self.handles: dict[int, Any] = {}
        self.folder = server.gui.add_folder(title, order=order, expand_by_default=expand)
        with self.folder:
            self.intro = server.gui.add_markdown(intro)
            self.build_extra_top()
            for i, knob in enumerate(self.knobs):
                self.handles[i] = self._add(knob)
            self.build_extra_bottom()

    def build_extra_top(self) -> None:
        """Hook for subclasses: inputs above the knobs."""

    def build_extra_bottom(self) -> None:
        """Hook for subclasses: inputs below the knobs."""

    def _add(self, knob: Knob) -> Any:
        gui = self.server.gui
        if knob.kind == "checkbox":
            handle: Any = gui.add_checkbox(knob.label, False, hint=knob.hint)
        elif knob.kind == "dropdown":
            handle = gui.add_dropdown(knob.label, knob.options, initial_value=knob.options[0], hint=knob.hint)
        elif knob.kind == "number":
            handle = gui.add_number(knob.label, knob.lo, min=knob.lo, max=knob.hi, step=knob.step, hint=knob.hint)
        else:
            handle = gui.add_slider(knob.label, knob.lo, knob.hi, knob.step, knob.lo, hint=knob.hint)
        handle.disabled = True  # until the loop says the running controller has this setting
        handle.visible = not self.hide_missing

        def on_update(event: viser.GuiEvent, knob: Knob = knob) -> None:
            if event.client_id is None:  # our own refresh, not a person
                return
            self.submit(knob, event.target.value, event.client_id)

        handle.on_update(on_update)
        return handle

    def submit(self, knob: Knob, value: Any, client_id: int | None) -> None:
        """Check a value from the browser and queue it for the loop (or refuse it)."""
        try:
            checked = coerce(knob, value)
            stored = self.loop.settings.values.get(knob.target, {}).get(knob.key)
            changes = knob.to_changes(checked, stored)
        except (ValueError, TypeError) as exc:
            notify(self.server, client_id, "Value refused", str(exc))
            return
        self.loop.submit(Configure(knob.target, changes, client_id))

    def refresh(self, settings: Settings) -> None:
        """Show the values in force; grey out (or hide) knobs the session lacks. Called every frame."""
        now = time.time()
        for i, knob in enumerate(self.knobs):
            handle = self.handles[i]
            values = settings.values.get(knob.target, {})
            present = knob.key in values
            if self.hide_missing and handle.visible != present:
                handle.visible = present
            if handle.disabled == present:
                handle.disabled = not present
            if not present or now - handle.update_timestamp < TOUCH_HOLD_S:
                continue
            try:
                shown = knob.display(values[knob.key])
                if knob.kind in ("slider", "number"):
                    shown = min(max(float(shown), knob.lo), knob.hi)
                if handle.value != shown:
                    handle.value = shown
            except (TypeError, ValueError, IndexError):
                continue

    def live(self, frame: Any) -> None:
        """Hook for subclasses: live numbers from a frame (called a few times a second)."""
