"""Hints close when the pointer is no longer over their control, also when the control moved away.

viser shows a control's hint (a Mantine tooltip, `role="tooltip"`, linked to its control by the control's
`aria-describedby`) on the pointer entering the control and hides it on the pointer leaving. A panel that
changes under a still pointer (the status line at the top of the Plots panel grows by a line, a fold
opens, a control is disabled) moves the control away without a leave event, and its hint stayed over
whatever came under the pointer (often a button) until the pointer crossed that control again.

`TOOLTIP_JS` (run once per page, as `app.live.ui.typed` runs its script) checks every open hint on each
pointer move and every `CHECK_MS`: when the pointer is not over the hint's control (or the control is
gone) it sends the control the leave events the browser did not, and hides the hint if it is still
shown `HIDE_AFTER_MS` later.
"""

from __future__ import annotations

import base64

import viser

CHECK_MS = 250
HIDE_AFTER_MS = 400
GUARD_ORDER = 1e9 + 1  # at the bottom of the root panel, hidden (after the typed-number channel)

TOOLTIP_JS = r"""
(() => {
  if (window.__torquelabTooltips) return;
  window.__torquelabTooltips = true;
  let x = -1, y = -1;  // the pointer in the page; -1: outside it
  const SLACK = 2;  // px around a control that still counts as over it
  const over = (el) => {
    const r = el.getBoundingClientRect();
    return r.width > 0 && x >= r.left - SLACK && x <= r.right + SLACK && y >= r.top - SLACK && y <= r.bottom + SLACK;
  };
  const leave = (el) => {
    const at = {clientX: x, clientY: y};
    el.dispatchEvent(new PointerEvent("pointerleave", {bubbles: false, ...at}));
    el.dispatchEvent(new MouseEvent("mouseleave", {bubbles: false, ...at}));
    el.dispatchEvent(new MouseEvent("mouseout", {bubbles: true, relatedTarget: document.body, ...at}));
  };
  const check = () => {
    for (const tip of document.querySelectorAll('[role="tooltip"]')) {
      const style = getComputedStyle(tip);
      if (style.display === "none" || Number(style.opacity) === 0) { tip.__staleSince = 0; continue; }
      const control = tip.id ? document.querySelector('[aria-describedby~="' + CSS.escape(tip.id) + '"]') : null;
      if (control && over(control)) { tip.__staleSince = 0; continue; }
      if (!tip.__staleSince) {
        tip.__staleSince = performance.now();
        if (control) leave(control);
      } else if (performance.now() - tip.__staleSince > %HIDE_AFTER_MS%) {
        tip.style.display = "none";
      }
    }
  };
  document.addEventListener("pointermove", (e) => { x = e.clientX; y = e.clientY; check(); },
                            {capture: true, passive: true});
  document.documentElement.addEventListener("pointerleave", () => { x = -1; y = -1; check(); });
  window.addEventListener("blur", () => { x = -1; y = -1; check(); });
  setInterval(check, %CHECK_MS%);
})();
"""


def tooltip_html() -> str:
    """The HTML element that runs `TOOLTIP_JS` once in each page (from a never-loading image)."""
    code = TOOLTIP_JS.replace("%CHECK_MS%", str(CHECK_MS)).replace("%HIDE_AFTER_MS%", str(HIDE_AFTER_MS))
    encoded = base64.b64encode(code.encode("utf-8")).decode("ascii")
    script = f"new Function(decodeURIComponent(escape(atob('{encoded}'))))()"
    return f'<img alt="" src="data:," style="display:none" onerror="{script}">'


def guard_tooltips(server: viser.ViserServer) -> viser.GuiHtmlHandle:
    """Put the hint guard in every page of `server` (call once, at the GUI's root)."""
    return server.gui.add_html(tooltip_html(), order=GUARD_ORDER)
