"""Typed numbers reach the server as text: "1e9", "abc" or "NaN" in a number box get a notice, not silence.

viser's number boxes (a number input, and the box beside each slider) are Mantine inputs that drop
every character a plain decimal lacks before anything is sent: "1e9" becomes 19, "abc" and "NaN" an
empty box, and the server never learns what was typed. `TypedNumbers` puts a small script in the page
(`TYPED_JS`, run once from an image's error handler, the one way viser's HTML element runs code): when
a key a decimal lacks is typed into such a box, or text pasted, the script keeps the box's raw text
itself and sends it, with the box's input id, through a hidden text input (`CHANNEL_LABEL`) once typing
pauses, on Enter or on leaving the box. The server parses it (`parse_typed`): an input registered with
`register` (the knob panels) gets the number or the reason; any other number box is clamped and set
here. Either way the box then shows the value in force, and the sender gets one notice naming it.
Plain digits still go the usual way (viser sends each parsed value at once).
"""

from __future__ import annotations

import base64
import json
import math
import weakref
from collections.abc import Callable
from typing import Any

import viser

from app.live.ui.viser_seam import input_by_uuid, input_state, input_uuid

CHANNEL_LABEL = "typed number"  # the hidden text input the page's script writes to
CHANNEL_ORDER = 1e9  # below everything (and hidden)
MAX_TYPED = 200  # characters of typed text the server looks at

# The page's script. A box in "raw" mode (a key a decimal lacks was typed) shows what was typed and
# sends it through the channel; the server's answer re-renders the box, and a box the answer did not
# change (the value in force is the one it showed) gets its old text back.
TYPED_JS = r"""
(() => {
  if (window.__torquelabTyped) return;
  window.__torquelabTyped = true;
  const CHANNEL = %CHANNEL%;
  const setValue = Object.getOwnPropertyDescriptor(HTMLInputElement.prototype, "value").set;
  const IDLE_MS = 2000;  // a pause this long in typing sends the text
  const DECIMAL = /^[0-9.\-]*$/;
  let raw = null;  // the box in raw mode: {input, id, timer, text, caret}; its text before: input.__typedBefore
  const row = (label) => {
    let el = label;
    for (let i = 0; i < 6 && el.parentElement; i++) {
      el = el.parentElement;
      if (el.querySelector("input")) return el;
    }
    return null;
  };
  const channel = () => {
    for (const label of document.querySelectorAll("label[for]")) {
      if (label.textContent.trim() !== CHANNEL) continue;
      const r = row(label);
      if (r) { r.parentElement.style.display = "none"; return r.querySelector("input"); }
    }
    return null;
  };
  const numberBox = (input) => {
    if (!(input instanceof HTMLInputElement) || !input.classList.contains("mantine-NumberInput-input")) return null;
    let el = input;
    while (el && el.parentElement) {
      el = el.parentElement;
      const labels = el.querySelectorAll("label[for]");
      if (labels.length === 1) return labels[0].htmlFor;
      if (labels.length > 1) return null;
    }
    return null;
  };
  const send = () => {
    if (raw === null) return;
    const r = raw;
    raw = null;
    clearTimeout(r.timer);
    const ch = channel();
    if (ch === null) return;
    const text = r.text;
    r.input.value = text;
    setValue.call(ch, JSON.stringify({id: r.id, text: text, n: Date.now()}));
    ch.dispatchEvent(new Event("input", {bubbles: true}));
    const sent = {text: text};  // this send's token: only the box's latest send restores it
    r.input.__typedSent = sent;
    setTimeout(() => {  // the server left the box as it was: its old text back
      if (r.input.__typedSent !== sent || (raw !== null && raw.input === r.input)) return;
      if (r.input.value === text && r.input.__typedBefore !== undefined) r.input.value = r.input.__typedBefore;
      delete r.input.__typedBefore;
    }, 1500);
  };
  const show = (r) => {  // the raw text back in the box (a re-render of the page may have replaced it)
    if (r.input.value !== r.text) r.input.value = r.text;
    if (document.activeElement === r.input) r.input.setSelectionRange(r.caret, r.caret);
  };
  const edit = (input, id, insert, forward) => {  // insert null: delete (backward unless forward)
    if (raw === null || raw.input !== input) {
      send();
      // the text before raw mode: kept while the box still shows a sent text not yet answered ("1e")
      const pending = input.__typedSent !== undefined && input.value === input.__typedSent.text;
      if (input.__typedBefore === undefined || !pending) input.__typedBefore = input.value;
      raw = {input: input, id: id, timer: 0, text: input.value, caret: input.value.length};
    }
    const v = raw.text;
    let a = raw.caret, b = raw.caret;
    if (input.value === v && input.selectionStart !== null) {
      a = input.selectionStart;
      b = input.selectionEnd ?? a;
    }
    if (insert === null && a === b) {
      if (forward) b = Math.min(v.length, b + 1);
      else a = Math.max(0, a - 1);
    }
    const put = insert ?? "";
    raw.text = v.slice(0, a) + put + v.slice(b);
    raw.caret = a + put.length;
    show(raw);
    const r = raw;
    requestAnimationFrame(() => { if (raw === r) show(r); });
    clearTimeout(raw.timer);
    raw.timer = setTimeout(send, IDLE_MS);
  };
  document.addEventListener("beforeinput", (e) => {
    const id = numberBox(e.target);
    if (id === null) return;
    const inRaw = raw !== null && raw.input === e.target;
    let text = e.data;
    if (text === null && e.dataTransfer) text = e.dataTransfer.getData("text");
    if (e.inputType.startsWith("insert") && text !== null && text !== undefined) {
      // a decimal typed into a box showing a decimal: viser's own way (a box still showing raw text that
      // was sent, e.g. "1e" when typing paused, goes on in raw mode: "1e9" is sent next)
      if (!inRaw && DECIMAL.test(text) && DECIMAL.test(e.target.value)) return;
      e.preventDefault();
      edit(e.target, id, text);
    } else if (inRaw && e.inputType.startsWith("delete")) {
      e.preventDefault();
      edit(e.target, id, null, e.inputType === "deleteContentForward");
    }
  }, true);
  document.addEventListener("keydown", (e) => {
    if (raw === null || raw.input !== e.target) return;
    if (e.key === "Enter" || e.key === "Tab") send();
    else if (e.key === "Escape") {
      e.target.value = e.target.__typedBefore;
      clearTimeout(raw.timer);
      raw = null;
    }
  }, true);
  document.addEventListener("focusout", (e) => { if (raw !== null && raw.input === e.target) send(); }, true);
  channel();
})();
"""


def page_html(channel_label: str = CHANNEL_LABEL) -> str:
    """The HTML element that runs `TYPED_JS` once in each page (from a never-loading image)."""
    code = TYPED_JS.replace("%CHANNEL%", json.dumps(channel_label))
    encoded = base64.b64encode(code.encode("utf-8")).decode("ascii")
    script = f"new Function(decodeURIComponent(escape(atob('{encoded}'))))()"
    return f'<img alt="" src="data:," style="display:none" onerror="{script}">'


def parse_typed(text: str, lo: float | None, hi: float | None) -> tuple[float | None, str]:
    """The number typed as `text` within [lo, hi] and "" when it is that number, the bound and why
    when it was clamped (e.g. "above the largest value 1000"), or None and why it is not a number."""
    cleaned = text.strip().replace(" ", "").replace("\u2212", "-")
    if "," in cleaned and "." not in cleaned:
        cleaned = cleaned.replace(",", ".")  # a decimal comma
    try:
        number = float(cleaned)
    except ValueError:
        return None, "is not a number" if cleaned else "is empty"
    if not math.isfinite(number):
        return None, "is not a finite number"
    if hi is not None and number > hi:
        return float(hi), f"is above the largest value {hi:g}"
    if lo is not None and number < lo:
        return float(lo), f"is below the smallest value {lo:g}"
    return number, ""


def shown_text(text: str) -> str:
    """Typed text for a notice: quoted, cut to 40 characters."""
    return repr(text if len(text) <= 40 else text[:37] + "...")


TypedHandler = Callable[[str, int | None], None]


class TypedNumbers:
    """The channel (hidden text input) and the page script of one server; see the module docstring."""

    def __init__(self, server: viser.ViserServer):
        self.server = server
        self.handlers: dict[str, TypedHandler] = {}
        self.received = 0  # typed texts that arrived
        gui = server.gui
        self.channel = gui.add_text(CHANNEL_LABEL, "", order=CHANNEL_ORDER)
        self.script = gui.add_html(page_html(), order=CHANNEL_ORDER)
        self.channel.on_update(self._on_channel)

    def register(self, handle: Any, handler: TypedHandler) -> None:
        """Send the text typed into `handle`'s box to `handler(text, client_id)`."""
        self.handlers[input_uuid(handle)] = handler

    def _on_channel(self, event: viser.GuiEvent) -> None:
        if event.client_id is None:
            return
        try:
            message = json.loads(str(event.target.value))
            uuid, text = str(message["id"]), str(message["text"])[:MAX_TYPED]
        except (ValueError, KeyError, TypeError):
            return  # not what the page's script sends
        self.received += 1
        handler = self.handlers.get(uuid)
        if handler is not None:
            handler(text, event.client_id)
            return
        handle = input_by_uuid(self.server, uuid)
        if handle is not None:
            self._set_plain(handle, text, event.client_id)

    def _set_plain(self, handle: Any, text: str, client_id: int | None) -> None:
        """A number box no panel registered: the typed number clamped to its range, or its value kept."""
        current = handle.value
        if isinstance(current, bool) or not isinstance(current, (int, float)):
            return
        props = input_state(handle).props
        lo, hi = getattr(props, "min", None), getattr(props, "max", None)
        value, why = parse_typed(text, lo, hi)
        label = str(getattr(props, "label", "") or "a number box")
        if value is None:
            body = f"{label}: {shown_text(text)} {why}; {current:g} stays"
            notify_client(self.server, client_id, "Input refused", body)
            return
        if why:
            body = f"{label}: {shown_text(text)} {why}; {value:g} is set"
            notify_client(self.server, client_id, "Value adjusted", body)
        handle.value = type(current)(value)


def notify_client(server: viser.ViserServer, client_id: int | None, title: str, body: str) -> None:
    """One red notification for a client (ignored when it has closed)."""
    client = server.get_clients().get(client_id) if client_id is not None else None
    if client is None:
        return
    try:
        client.add_notification(title, body, auto_close_seconds=6.0, color="red")
    except Exception:  # the tab may have closed meanwhile
        pass


_BY_SERVER: weakref.WeakKeyDictionary[Any, TypedNumbers] = weakref.WeakKeyDictionary()


def typed_numbers(server: viser.ViserServer) -> TypedNumbers:
    """The server's `TypedNumbers` (made on first use: call it once at the GUI's root before the panels)."""
    typed = _BY_SERVER.get(server)
    if typed is None:
        typed = _BY_SERVER[server] = TypedNumbers(server)
    return typed
