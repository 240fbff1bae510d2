"""A page that falls behind the simulation says so, and how far.

Under load a browser can process the server's messages later than they come: one page showed
t = 117 s "running" for over a minute while another read 248 s, and nothing said so. The server now
stamps a hidden element of the page (`PageClock.tick`, a few times a second) with its wall clock and
the simulation time, and a small script in each page (`LAG_JS`, run the way `app.live.ui.typed` runs
its own) compares the stamp the page shows with the page's clock, the moment a new stamp lands in the
page (a MutationObserver: a page that is busy catching up runs few timers, and a check on a timer alone
went unheard for tens of seconds) and on a timer (a page that stopped: its stamp ages). The smallest
difference seen is the clocks' offset plus the quickest delivery; what exceeds it is how late the page's
picture is (`lagS`, NaN until the first stamp was measured; `measured` counts the measurements). Over
BEHIND_S a banner at the top of the page says how far behind it is and which simulated instant it
shows, while it catches up (it goes once the page is back within BEHIND_S); over GIVE_UP_S it says the
page gave up catching up and asks for a reload (a reload starts from the simulation's present).
"""

from __future__ import annotations

import base64
import json
import time
from collections.abc import Callable

import viser

BEHIND_S = 1.0  # a page this far behind says so
GIVE_UP_S = 30.0  # a page this far behind says it gave up catching up
TICK_S = 0.25  # the stamp is sent at most this often
CLOCK_ORDER = 1e9 + 1  # at the bottom of the control panel, out of sight

LAG_JS = r"""
(() => {
  if (window.__torquelabLag) return;
  const state = window.__torquelabLag = {
    behindS: %BEHIND%, giveUpS: %GIVE_UP%, minOffset: Infinity, lagS: NaN, maxShownS: 0, measured: 0, texts: [],
  };
  const banner = document.createElement("div");
  banner.id = "torquelab-lag";
  banner.setAttribute("role", "status");
  Object.assign(banner.style, {
    position: "fixed", top: "8px", left: "50%", transform: "translateX(-50%)", zIndex: 100000,
    padding: "6px 14px", borderRadius: "6px", background: "#ffe8a3", color: "#3d2f00",
    font: "14px sans-serif", boxShadow: "0 1px 4px rgba(0,0,0,0.3)", display: "none",
  });
  document.body.appendChild(banner);
  const say = (text) => {
    banner.textContent = text;
    banner.style.display = text ? "block" : "none";
    if (state.texts[state.texts.length - 1] !== text) {
      state.texts.push(text);
      if (state.texts.length > 50) state.texts.shift();
    }
  };
  let watched = null;
  const measure = () => {
    const el = document.querySelector("[data-torquelab-clock]");
    if (!el) return;
    if (el.parentElement !== watched) {  // the stamp's box: measured again the moment a new stamp lands in it
      observer.disconnect();
      watched = el.parentElement;
      if (watched) observer.observe(watched, {childList: true, subtree: true, attributes: true});
    }
    const [wallMs, simT] = el.getAttribute("data-torquelab-clock").split(" ").map(Number);
    if (!Number.isFinite(wallMs)) return;
    const offset = Date.now() - wallMs;  // the clocks' offset, plus how late this stamp is shown
    state.minOffset = Math.min(state.minOffset, offset);
    const lag = (offset - state.minOffset) / 1000;
    state.lagS = lag;
    state.measured += 1;
    if (lag <= state.behindS) { say(""); return; }
    state.maxShownS = Math.max(state.maxShownS, lag);
    const shows = Number.isFinite(simT) ? ` (it shows t = ${simT.toFixed(1)} s)` : "";
    if (lag > state.giveUpS) {
      const reload = "reload it to see the simulation now";
      say(`This page is ${lag.toFixed(0)} s behind the simulation${shows} and gave up catching up: ${reload}.`);
    } else {
      say(`This page is ${lag.toFixed(1)} s behind the simulation${shows}; catching up.`);
    }
  };
  const observer = new MutationObserver(measure);
  setInterval(measure, 200);  // also while no stamp lands (a page that stopped: its stamp ages)
})();
"""


def lag_script_html() -> str:
    """The HTML element that runs `LAG_JS` once in each page (from a never-loading image)."""
    code = LAG_JS.replace("%BEHIND%", json.dumps(BEHIND_S)).replace("%GIVE_UP%", json.dumps(GIVE_UP_S))
    encoded = base64.b64encode(code.encode("utf-8")).decode("ascii")
    script = f"new Function(decodeURIComponent(escape(atob('{encoded}'))))()"
    return f'<img alt="" src="data:," style="display:none" onerror="{script}">'


def clock_html(wall_ms: float, sim_t: float) -> str:
    """The hidden element that carries the stamp: the server's wall clock (ms) and the simulation time (s)."""
    return f'<span data-torquelab-clock="{wall_ms:.0f} {sim_t:.3f}" style="display:none"></span>'


class PageClock:
    """The stamp element and the page script of one server (see the module docstring)."""

    def __init__(self, server: viser.ViserServer, wall_ms: Callable[[], float] = lambda: 1e3 * time.time()):
        self._wall_ms = wall_ms
        self._next = 0.0
        gui = server.gui
        self.clock = gui.add_html(clock_html(wall_ms(), 0.0), order=CLOCK_ORDER)
        self.script = gui.add_html(lag_script_html(), order=CLOCK_ORDER)
        self.ticks = 0

    def tick(self, sim_t: float) -> None:
        """Stamp the pages with now and the simulation time shown (at most once per TICK_S)."""
        now = time.monotonic()
        if now < self._next:
            return
        self._next = now + TICK_S
        self.clock.content = clock_html(self._wall_ms(), sim_t)
        self.ticks += 1
