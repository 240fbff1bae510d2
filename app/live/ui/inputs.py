"""Client input checked on arrival: a GUI update a page could not have sent is refused before viser applies it.

A browser sends `GuiUpdateMessage`s (an input's uuid and new property values); viser casts the value to
the input's current type and stores it as the value every client sees, then runs the callbacks. A raw
websocket can send anything there: a dropdown value that is none of its options, text for a number,
NaN, a list of the wrong length, a property the input lacks. `guard_gui_updates(server)` puts
`check_update` in front of viser's handler (reached through `app.live.ui.viser_seam`): a refused
update changes nothing (the value every client sees stays) and its sender alone gets one notice per
input per minute (`ErrorBudget`); the panels' own checks (`control.params`) still judge the values
that pass.
"""

from __future__ import annotations

import inspect
import math
from collections import Counter
from collections.abc import Callable
from typing import Any

import viser

from app.live.supervise import ErrorBudget
from app.live.ui.viser_seam import GuiUpdateMessage, gui_update_handlers, input_by_uuid, input_state

MAX_TEXT = 10_000  # characters a text input takes


def _label(state: Any) -> str:
    return str(getattr(state.props, "label", "") or "an input")


def _number(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    try:
        x = float(value)
    except OverflowError:
        return None
    return x if math.isfinite(x) else None


def check_value(current: Any, props: Any, value: Any) -> str:
    """ "" if `value` can be an input's value (one with this current value and these props), else why not."""
    if isinstance(current, viser.UploadedFile):  # a file comes in through the upload's own messages
        return f"a file is uploaded with the button, not sent as a value (got {_short(value)})"
    if isinstance(current, bool):
        return "" if isinstance(value, bool) else f"expected true or false, got {_short(value)}"
    if isinstance(current, (int, float)):
        return "" if _number(value) is not None else f"expected a finite number, got {_short(value)}"
    if isinstance(current, str):
        if not isinstance(value, str):
            return f"expected text, got {_short(value)}"
        options = getattr(props, "options", None)
        if options is not None and value not in options:
            return f"expected one of {', '.join(map(str, options))}, got {_short(value)}"
        return "" if len(value) <= MAX_TEXT else f"text longer than {MAX_TEXT} characters"
    if isinstance(current, tuple):
        if not isinstance(value, (list, tuple)) or len(value) != len(current):
            return f"expected {len(current)} values, got {_short(value)}"
        for old, new in zip(current, value, strict=True):
            why = check_value(old, None, new)
            if why:
                return why
        return ""
    return ""  # an input of another kind (None: e.g. an upload): viser's own handling


def check_update(state: Any, updates: Any) -> str:
    """ "" if a GUI update message's `updates` may be applied to the input with `state`, else why not."""
    if not isinstance(updates, dict):
        return "not a property update"
    for name, value in updates.items():
        if name != "value":
            return f"a page does not set {_short(name)}"
        if state.is_button and not isinstance(state.value, viser.UploadedFile):
            continue  # a click: viser ignores the value (an upload button casts it, and raised)
        why = check_value(state.value, state.props, value)
        if why:
            return why
    return ""


def _short(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


class GuiUpdateGuard:
    """`check_update` in front of viser's GUI update handler (see the module docstring)."""

    def __init__(self, server: viser.ViserServer, budget: ErrorBudget | None = None):
        self.server = server
        self.budget = budget if budget is not None else ErrorBudget()
        self.refused = 0  # updates refused
        self.notified: Counter[int] = Counter()  # notices sent, per open page's client id
        server.on_client_disconnect(self._forget)
        handlers = gui_update_handlers(server)
        self._inner: list[Callable[..., Any]] = list(handlers)
        handlers[:] = [self.handle]

    def _forget(self, client: viser.ClientHandle) -> None:
        """A page that left: its notice count goes with it."""
        self.notified.pop(client.client_id, None)

    async def handle(self, client_id: int, message: GuiUpdateMessage) -> None:
        """Check one update; pass it to viser's handlers, or refuse it with a notice to its sender."""
        handle = input_by_uuid(self.server, message.uuid)
        if handle is not None:
            state = input_state(handle)
            why = check_update(state, message.updates)
            if why:
                self._refuse(client_id, _label(state), why)
                return
        for inner in self._inner:
            result = inner(client_id, message)
            if inspect.isawaitable(result):
                await result

    def _refuse(self, client_id: int, label: str, why: str) -> None:
        self.refused += 1
        if not self.budget.should_report(f"{client_id}: {label}"):
            return
        client = self.server.get_clients().get(client_id)
        if client is None:
            return
        try:
            client.add_notification("Input refused", f"{label}: {why}", auto_close_seconds=6.0, color="red")
            self.notified[client_id] += 1
        except Exception:  # the tab may have closed meanwhile
            pass


def guard_gui_updates(server: viser.ViserServer) -> GuiUpdateGuard:
    """Install the guard on a server (once: its GUI inputs' updates are checked from now on)."""
    return GuiUpdateGuard(server)
