"""Panels generated from parameter metadata (`control.params`).

A panel names the parameters it shows, in order, as `"group.field"` strings (see
`Session.params()` for the groups), optionally with an element or a slice of a vector field:
`"posture_task.compliance[3]"` (Γ₀ of joint 4), `"motion_force.motion_kp[0:3]"` (the translation
stiffnesses, one slider). Everything else — the input kind (checkbox, dropdown, slider, number),
label with unit, range, step and hint with the paper tag — comes from the field's metadata, so
adding a knob is one field in its dataclass plus one name in a panel's list.

A change is sent as `SetParam` commands (one per element for a slice) that the loop validates and
applies between two steps — no read-modify-write of vectors on the GUI thread, so two element
changes in one frame both land. Each frame the panel shows the values in force and greys out (or
hides) inputs whose group the running session lacks, so one panel serves every executor.
"""

from __future__ import annotations

import math
import re
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
import viser

from app.core.commands import SetParam
from app.core.params import field_spec
from app.live.loop import Settings, SimLoop
from app.live.ui.typed import parse_typed, shown_text, typed_numbers
from control.params import ParamSpec

TOUCH_HOLD_S = 0.6  # after a person moves a knob, the panel does not overwrite it for this long
_PATH = re.compile(r"^(\w+)\.(\w+)(?:\[(\d+)(?::(\d+))?\])?$")


FLOAT_DIGITS = 4  # decimals a number box of a real-valued knob takes as typed


@dataclass(frozen=True)
class Knob:
    """One input bound to `group.field` (elements `lo_index` … `hi_index` − 1 of a vector field,
    or the whole field when `lo_index` is None)."""

    group: str
    field: str
    spec: ParamSpec
    lo_index: int | None = None
    hi_index: int | None = None

    @property
    def path(self) -> str:
        """The name it was declared with."""
        if self.lo_index is None:
            return f"{self.group}.{self.field}"
        if self.hi_index == self.lo_index + 1:
            return f"{self.group}.{self.field}[{self.lo_index}]"
        return f"{self.group}.{self.field}[{self.lo_index}:{self.hi_index}]"

    @property
    def kind(self) -> str:
        """ "checkbox", "dropdown", "slider" or "number"."""
        k = self.spec.kind
        if k == "bool":
            return "checkbox"
        if k == "choice":
            return "dropdown"
        lo, hi = self.bounds
        return "slider" if lo is not None and hi is not None and self.spec.step is not None else "number"

    @property
    def first(self) -> int:
        return self.lo_index or 0

    @property
    def bounds(self) -> tuple[float | None, float | None]:
        """(lo, hi) of the element shown."""
        return self.spec.element(self.spec.lo, self.first), self.spec.element(self.spec.hi, self.first)

    @property
    def step(self) -> float:
        lo, hi = self.bounds
        step = self.spec.element(self.spec.step, self.first)
        if step is not None:
            return step
        return (hi - lo) / 100.0 if lo is not None and hi is not None else 0.001

    @property
    def label(self) -> str:
        """Label with the element names and the unit: "K_m^p px–pz (N/m)", "Γ₀ joint 4"."""
        spec, text = self.spec, self.spec.label
        if self.lo_index is not None and self.hi_index is not None:
            first, last = spec.axis_name(self.lo_index), spec.axis_name(self.hi_index - 1)
            text += f" {first}" if first == last else f" {first}–{last}"
        unit = spec.element_unit(self.first)
        return f"{text} ({unit})" if unit else text

    @property
    def hint(self) -> str | None:
        """One-line help with the paper tag."""
        text = " ".join(part for part in (self.spec.help, self.spec.tag) if part)
        return (text[0].upper() + text[1:]) if text else None

    @property
    def options(self) -> tuple[str, ...]:
        """Dropdown entries (the choice labels when the metadata has them)."""
        return self.spec.choice_labels or self.spec.choices

    def shown(self, value: Any) -> Any:
        """The input value for a stored field value."""
        spec = self.spec
        if spec.kind == "choice":
            return self.options[spec.choices.index(value)] if value in spec.choices else self.options[0]
        if spec.kind in ("bool",):
            return bool(value)
        arr = np.asarray(value, dtype=float)
        if arr.ndim == 2:  # Γ matrix: its diagonal
            arr = np.diag(arr)
        if arr.ndim == 0:
            return float(arr)
        return float(arr[self.first]) if self.lo_index is not None else float(np.mean(arr))

    def commands(self, value: Any, client_id: int | None) -> list[SetParam]:
        """The SetParam commands for an input value (one per element of a slice)."""
        spec = self.spec
        if spec.kind == "choice":
            labels = self.options
            value = spec.choices[labels.index(value)] if value in labels else value
        if self.lo_index is None or self.hi_index is None:
            return [SetParam(self.group, self.field, value, None, client_id)]
        return [SetParam(self.group, self.field, value, i, client_id) for i in range(self.lo_index, self.hi_index)]


def knob(path: str) -> Knob:
    """The knob for `"group.field"`, `"group.field[i]"` or `"group.field[a:b]"` (ValueError for a
    malformed path or an unknown group/field)."""
    m = _PATH.match(path)
    if m is None:
        raise ValueError(f"a knob is named 'group.field', 'group.field[i]' or 'group.field[a:b]', got {path!r}")
    group, field, a, b = m.groups()
    spec = field_spec(group, field)
    if a is None:
        return Knob(group, field, spec)
    lo = int(a)
    hi = int(b) if b is not None else lo + 1
    size = spec.size or 0
    if spec.kind not in ("vector", "scalar_or_vector", "gamma") or not 0 <= lo < hi <= size:
        raise ValueError(f"{path}: elements {lo}…{hi - 1} are not elements of {group}.{field}")
    return Knob(group, field, spec, lo, hi)


def number_in_range(label: str, value: Any, lo: float, hi: float) -> float:
    """A finite number within [lo, hi] from an input; ValueError with a short reason otherwise."""
    if isinstance(value, bool) or isinstance(value, str):
        raise ValueError(f"{label} must be a number, got {value!r}")
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{label} must be a number, got {value!r}") from None
    if not math.isfinite(number) or not lo <= number <= hi:
        raise ValueError(f"{label} must be between {lo:g} and {hi:g}, got {value!r}")
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


ECHO_TIMEOUT_S = 2.0  # the longest a panel callback waits for the loop to apply a change


class KnobPanel:
    """A folder of generated knobs (see the module docstring). Knobs whose group the running
    session lacks are hidden (greyed out instead when `hide_missing` is False).

    With a `summary`, the panel shows that one line and folds the longer `intro` (and whatever
    `build_help` adds) behind a "?"; each knob keeps its one-line hint with the paper tag. The prose
    belongs to `OWNER_GROUPS` (e.g. the [T] gains' group): without any of them in the running session
    it is hidden, and the whole folder is hidden when no knob applies and `has_content` says so."""

    hide_missing = True  # a knob the running session lacks is hidden, not shown greyed with a stale value
    OWNER_GROUPS: tuple[str, ...] = ()  # the prose applies when one of these groups runs (() = always)

    def __init__(
        self,
        server: viser.ViserServer,
        loop: SimLoop,
        title: str,
        intro: str,
        fields: Sequence[str],
        order: float | None = None,
        expand: bool = True,
        summary: str = "",
    ):
        self.server = server
        self.loop = loop
        self.title = title
        self.knobs: list[Knob] = []
        self.handles: list[Any] = []
        self.folder = server.gui.add_folder(title, order=order, expand_by_default=expand)
        self.help: Any = None  # the "?" fold, when there is a summary
        with self.folder:
            if summary:
                self.intro = server.gui.add_markdown(summary)
                self.help = server.gui.add_folder("?", expand_by_default=False)
                with self.help:
                    server.gui.add_markdown(intro)
                    self.build_help()
            else:
                self.intro = server.gui.add_markdown(intro)
            self.build_extra_top()
            for path in fields:
                self.add(knob(path))
            self.build_extra_bottom()

    def build_help(self) -> None:
        """Hook for subclasses: more text inside the "?" fold."""

    def prose_applies(self, settings: Settings) -> bool:
        """Whether the panel's summary and help speak of the running session (an owner group runs)."""
        return not self.OWNER_GROUPS or any(g in settings.groups for g in self.OWNER_GROUPS)

    def has_content(self, settings: Settings) -> bool:
        """Whether the folder shows something besides its knobs for the running session (live lines)."""
        return False

    def build_extra_top(self) -> None:
        """Hook for subclasses: inputs above the knobs."""

    def build_extra_bottom(self) -> None:
        """Hook for subclasses: inputs below the knobs."""

    def add(self, k: Knob) -> Any:
        """Build the input of a knob in the current GUI container; returns its handle."""
        gui = self.server.gui
        hint = k.hint
        if k.kind == "checkbox":
            handle: Any = gui.add_checkbox(k.label, False, hint=hint)
        elif k.kind == "dropdown":
            handle = gui.add_dropdown(k.label, k.options, initial_value=k.options[0], hint=hint)
        else:
            lo, hi = k.bounds
            lo_f = lo if lo is not None else -1e9
            hi_f = hi if hi is not None else 1e9
            if k.kind == "number":
                handle = gui.add_number(k.label, lo_f, min=lo_f, max=hi_f, step=k.step, hint=hint)
            else:
                handle = gui.add_slider(k.label, lo_f, hi_f, k.step, lo_f, hint=hint)
            if k.spec.kind != "int" and handle.precision < FLOAT_DIGITS:
                # the box keeps the decimals a person types (viser's precision follows the step: with a step
                # of 1 the page dropped the "." and 250.5 arrived as 250); the slider still moves by its step
                handle.precision = FLOAT_DIGITS
        handle.disabled = True  # until the loop says the running session has this group
        handle.visible = not self.hide_missing

        def on_update(event: viser.GuiEvent, k: Knob = k) -> None:
            if event.client_id is None:  # our own refresh, not a person
                return
            log = self.loop.lab.notice_log
            before = log[-1] if log else None
            for cmd in k.commands(event.target.value, event.client_id):
                self.loop.submit(cmd)
            if k.kind in ("slider", "number"):
                self.echo(k, event.target, event.target.value, event.client_id, before)

        handle.on_update(on_update)
        if k.kind in ("slider", "number"):

            def on_typed(text: str, client_id: int | None, k: Knob = k, h: Any = handle) -> None:
                self.typed(k, h, text, client_id)

            typed_numbers(self.server).register(handle, on_typed)
        self.knobs.append(k)
        self.handles.append(handle)
        return handle

    def echo(self, k: Knob, handle: Any, typed: Any, client_id: int | None, before: Any = None) -> Any:
        """After a person's change is applied, put the value in force back into the input at once when
        it differs from what arrived (refused, clamped or coerced; a number box sends only what the
        browser parsed) and say so (a refusal already has its notice). Returns the value in force, or
        None when the loop is busy (a preset's work under way, or no answer within ECHO_TIMEOUT_S): this
        runs in viser's thread pool, which must not wait on the loop; the panels' refresh shows the
        value in force later anyway."""
        if self.loop.planner.busy:
            return None
        try:
            self.loop.sync(timeout=ECHO_TIMEOUT_S)
        except (TimeoutError, RuntimeError):
            return None
        try:
            in_force = self.shown_value(k, self.loop.settings)
        except (KeyError, TypeError, ValueError, IndexError, AttributeError):
            return None
        number = typed if isinstance(typed, (int, float)) and not isinstance(typed, bool) else None
        if number is not None and math.isfinite(number) and math.isclose(number, in_force, rel_tol=1e-9, abs_tol=1e-12):
            return in_force
        try:
            handle.value = in_force
        except (TypeError, ValueError):  # an input holding something that is not a number
            return in_force
        if not _refused_since(self.loop.lab.notice_log, before, client_id):
            notify(self.server, client_id, "Value adjusted", f"{k.label}: {typed!r} arrived, {in_force:g} is in force")
        return in_force

    def typed(self, k: Knob, handle: Any, text: str, client_id: int | None) -> None:
        """Text typed into a knob's number box (`app.live.ui.typed`): the number, clamped to the knob's
        range, is applied; text that is no finite number changes nothing. Either way the box shows the
        value in force, and a clamp or a refusal gets one notice naming that value."""
        lab = self.loop.lab
        lo, hi = k.bounds
        value, why = parse_typed(text, lo, hi)
        if value is None:
            try:
                current = self.shown_value(k, self.loop.settings)
            except (KeyError, TypeError, ValueError, IndexError, AttributeError):
                return
            lab.notify("error", "Input refused", f"{k.label}: {shown_text(text)} {why}; {current:g} stays", client_id)
            handle.value = current
            return
        before = lab.notice_log[-1] if lab.notice_log else None
        for cmd in k.commands(value, client_id):
            self.loop.submit(cmd)
        in_force = self.echo(k, handle, value, client_id, before)
        shown = value if in_force is None else in_force
        if why:
            body = f"{k.label}: {shown_text(text)} {why}; {shown:g} is in force"
            lab.notify("warning", "Value adjusted", body, client_id)
        try:
            handle.value = shown
        except (TypeError, ValueError):
            pass

    def shown_value(self, k: Knob, settings: Settings) -> Any:
        """The input value of a knob for the values in force (numbers clamped to the input's range)."""
        shown = k.shown(getattr(settings.groups[k.group], k.field))
        if k.kind in ("slider", "number"):
            lo, hi = k.bounds
            shown = min(max(float(shown), lo if lo is not None else -1e9), hi if hi is not None else 1e9)
        return shown

    def wanted(self, k: Knob, settings: Settings) -> bool:
        """Whether a knob applies now (its group exists); subclasses may narrow it."""
        return k.group in settings.groups

    def refresh(self, settings: Settings) -> None:
        """Show the values in force; grey out (or hide) knobs the session lacks, and the prose or the
        whole folder when they do not apply. Called every frame."""
        now = time.time()
        prose = self.prose_applies(settings)
        for handle in (self.intro, self.help):
            if handle is not None and handle.visible != prose:
                handle.visible = prose
        if self.hide_missing:
            shown = self.has_content(settings) or any(self.wanted(k, settings) for k in self.knobs)
            if self.folder.visible != shown:
                self.folder.visible = shown
        for k, handle in zip(self.knobs, self.handles, strict=True):
            present = self.wanted(k, settings)
            if self.hide_missing and handle.visible != present:
                handle.visible = present
            if handle.disabled == present:
                handle.disabled = not present
            if not present or now - handle.update_timestamp < TOUCH_HOLD_S:
                continue
            try:
                shown = self.shown_value(k, settings)
                if handle.value != shown:
                    handle.value = shown
            except (TypeError, ValueError, IndexError, AttributeError):
                continue

    def live(self, frame: Any) -> None:
        """Hook for subclasses: live numbers from a frame (called a few times a second)."""


def _refused_since(log: Any, before: Any, client_id: int | None) -> bool:
    """Whether the lab's notice log has a "Value refused" for `client_id` after the notice `before`."""
    try:
        notices = list(log)
    except RuntimeError:  # appended to meanwhile
        return False
    start = 0
    for i in range(len(notices) - 1, -1, -1):
        if notices[i] is before:
            start = i + 1
            break
    return any(n.title == "Value refused" and n.client_id == client_id for n in notices[start:])
