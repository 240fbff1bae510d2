"""The force-loop margin's prediction for each polish stroke, in words, and once the stroke is over
whether it came true.

The prediction is the sign of the stroke's least headroom h with its band (`polish_margin.
headroom_statement`: a sign only outside h ± the margin's growth error; no magnitude is shown, only
the sign has been shown to mean something). The outcome is the stroke's one verdict
(`app.scenarios.verdict`): stable, oscillating, or lost contact (the true contact force reached 0).
The page's Nullspace panel, the margin plot and the lessons' claims all take their words from here (the
live app reaches the margin's statement only through this module, which names no preset).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from app.scenarios import polish_margin as PM
from app.scenarios import verdict as V

HEADROOM_BAND_NP = PM.HEADROOM_BAND_NP  # only the sign of the headroom outside ± this is a prediction
HeadroomStatement = PM.HeadroomStatement
headroom_statement = PM.headroom_statement


@dataclass(frozen=True)
class StrokeOutcome:
    """One stroke: its margin's statement and, once it is over, its verdict (None while it runs)."""

    segment: int
    statement: PM.HeadroomStatement
    verdict: str | None = None
    rate_min_per_s: float = float("nan")  # the stroke's worst live σ (1/s), NaN without one

    @property
    def checked(self) -> str:
        """After the stroke, the prediction against its verdict and whether contact was kept
        (`polish_margin.headroom_came_true`): "came true: the stroke was stable, contact kept"; "" while
        the stroke runs."""
        if self.verdict is None:
            return ""
        lost = self.verdict in (V.LOST, V.DIVERGED)
        return PM.headroom_came_true(self.statement, self.verdict) + ("" if lost else ", contact kept")

    @property
    def came_true(self) -> bool | None:
        """The prediction against the verdict: None while the stroke runs or without a prediction."""
        return None if self.verdict is None else PM.prediction_held(self.statement, self.verdict)

    def rate_text(self) -> str:
        """What the stroke's worst σ predicted (< 0: a disturbance grows there) and, after the stroke,
        whether that came true (it grew: the stroke oscillated or lost contact); "" without a σ."""
        r = self.rate_min_per_s
        if not np.isfinite(r):
            return ""
        text = f"σ's worst {r:+.1f} 1/s predicted a disturbance to {'grow' if r < 0 else 'decay'}"
        if self.verdict is None:
            return text
        came = (r < 0) == V.unstable(self.verdict)
        return f"{text} — {'came true' if came else 'did not come true'}: the stroke was {self.verdict}"

    def text(self) -> str:
        """ "S4: predicted to keep contact through this stroke — came true: the stroke was stable, contact kept"."""
        head = f"S{self.segment}: {self.statement.words}"
        return f"{head} — {self.checked}" if self.verdict is not None else head


def band_words(band_np: float = PM.HEADROOM_BAND_NP) -> str:
    """How a statement's band is meant, for a reader."""
    return (
        f"it states only the sign of its least headroom on a stroke, and only beyond ±{band_np:g} Np, the error "
        "of its growth against the runs'"
    )


# the logged signals a stroke's margin figures are read from (`stroke_figures`)
MARGIN_COLUMNS = (
    "segment",
    "margin_headroom_stroke_min_np",
    "margin_headroom_segment",
    "margin_rate_stroke_min",
)


def stroke_figures(columns: Mapping[str, np.ndarray], segments: int) -> dict[int, tuple[float, float]]:
    """Each stroke 1…`segments` that has a figure: its least headroom (Np) and its worst σ (1/s), NaN where
    it has none. Read from the rows the environment tagged with the stroke ("margin_headroom_segment":
    a stroke's figures come from the offload a little after its steps, the last ones while the next
    stroke runs) and their running least values on the stroke (`MARGIN_COLUMNS`)."""
    tag, h = columns.get("margin_headroom_segment"), columns.get("margin_headroom_stroke_min_np")
    rate = columns.get("margin_rate_stroke_min")
    if tag is None or h is None or rate is None:
        return {}
    out = {}
    for k in range(1, segments + 1):
        on = tag == k
        values, rates = h[on & np.isfinite(h)], rate[on & np.isfinite(rate)]
        if values.size or rates.size:
            least = float(np.min(values)) if values.size else float("nan")
            out[k] = (least, float(np.min(rates)) if rates.size else float("nan"))
    return out


def stroke_outcomes(
    columns: Mapping[str, np.ndarray], sensor: object, dt: float, segments: int, finished: bool = False
) -> list[StrokeOutcome]:
    """Every stroke in the logged `columns` (`MARGIN_COLUMNS`, "F_z" and "contact_force_n"): its statement
    from its least headroom, its worst σ (`stroke_figures`) and, for a stroke the zig-zag has left (or
    every stroke with `finished`), its verdict."""
    seg = columns.get("segment")
    if seg is None or columns.get("margin_headroom_segment") is None or not len(seg):
        return []
    verdicts: dict[int, str] = {}
    fz, contact = columns.get("F_z"), columns.get("contact_force_n")
    if fz is not None and contact is not None and sensor is not None:
        found = V.strokes(seg, fz, contact, sensor, dt, range(1, segments + 1))
        verdicts = {s.segment: s.verdict for s in found}
    now = float(seg[np.isfinite(seg)][-1]) if np.any(np.isfinite(seg)) else -1.0
    figures = stroke_figures(columns, segments)
    out = []
    for k in range(1, segments + 1):
        if not np.any(seg == k):
            continue
        least, worst = figures.get(k, (float("nan"), float("nan")))
        over = finished or now > k
        out.append(StrokeOutcome(k, PM.headroom_statement(least), verdicts.get(k) if over else None, worst))
    return out
