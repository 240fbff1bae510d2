"""The polish experiment's latency table: each stage of the loop's latency alone (the F/T reading's age,
the actuation delay) per row at μ = 1, the smallest delay at which a run oscillates or leaves the
table, the hold's early verdict (`HoldWatch`) and the table as text."""

from __future__ import annotations

import numpy as np

from app.headless.experiments.polish_calibration import OSCILLATION_FACTOR
from app.headless.experiments.polish_report import _deg
from app.headless.experiments.polish_rows import ROWS

# The latency table: each stage of the loop's latency alone (the other at 0), at μ = 1, seed 0.
LATENCY_ROWS = ("j", "f", "a", "d", "mirror", "planned_a", "planned")
LATENCY_QUICK_ROWS = ("j", "a")
LATENCY_SENSING_STEPS = (0, 1, 2, 3, 4)  # F/T reading age, control periods
LATENCY_TORQUE_MS = (0.0, 1.0, 2.0, 3.0, 4.0)  # actuation delay
LATENCY_QUICK_MAX = 2  # --quick: delays up to this many periods (ms)
LATENCY_MU = 1.0
# "Oscillates or leaves the table": contact lost, a divergence, or a segment whose force-error STD is
# at least this many times the median segment STD of the same row with no latency at all.
OSCILLATION_STD_FACTOR = 3.0
# A latency run whose force loop already oscillates or loses contact while the TCP is held (the settle
# phase, before the strokes) has its verdict there and stops (`HoldWatch`): at 3-4 periods of delay the
# hold oscillates, W never settles and the run would otherwise sit out the settle cap.
HOLD_CHECK_EVERY = 100  # steps between two looks at the hold's last second
# ... once the posture has stopped flowing: the swivel moved at most this much over that second (half
# the slowest flow a settle passes through, W_a's ≈ 0.2°/s on its plateau; a posture held in place by an
# oscillating loop jitters by ≤ 0.04°)
HOLD_STILL_DEG = 0.1


def latency_specs(quick: bool = False, only: list[str] | None = None, mu: float = LATENCY_MU) -> list[dict]:
    """The latency table's runs: per row, the F/T reading age over `LATENCY_SENSING_STEPS` with no
    torque delay, and the torque delay over `LATENCY_TORQUE_MS` with a same-step reading (each stage
    alone; both 0 is the zero-latency reference); seed 0, μ = 1. `quick`: W_j and W_a, delays up to
    `LATENCY_QUICK_MAX`; `only` keeps the rows among these keys."""
    keys = [k for k in (LATENCY_QUICK_ROWS if quick else LATENCY_ROWS) if not only or k in only]
    cap = LATENCY_QUICK_MAX if quick else None
    pairs = [(d, 0.0) for d in LATENCY_SENSING_STEPS if cap is None or d <= cap]
    pairs += [(0, ms) for ms in LATENCY_TORQUE_MS if ms > 0 and (cap is None or ms <= cap)]
    base = {
        "sander": False,
        "start_swivel_deg": 0.0,
        "shaping": True,
        "armature_scale": 1.0,
        "group": "latency",
        "stop_on_verdict": True,
    }
    return [
        {**base, **ROWS[k], "mu": mu, "seed": 0, "reading_delay_steps": d, "torque_delay_ms": ms}
        for k in keys
        for d, ms in pairs
    ]


def latency_table(runs: list[dict]) -> dict:
    """Per row of the latency runs: the smallest F/T reading age and the smallest torque delay at which
    the run oscillates or leaves the table (`oscillates`), with each run's worst segment STD ratio to
    the row's zero-latency reference and its lost contact. None: no delay tried did it."""
    rows: list[dict] = []
    for name in dict.fromkeys(r["row"] for r in runs):
        rs = [r for r in runs if r["row"] == name]
        ref = next((r for r in rs if r["reading_delay_steps"] == 0 and r["torque_delay_ms"] == 0.0), None)
        ref_std = _median_segment_std(ref) if ref is not None else None
        cells = []
        for r in sorted(rs, key=lambda x: (x["torque_delay_ms"], x["reading_delay_steps"])):
            ratio = None if ref_std is None else _worst_segment_std(r) / ref_std
            cells.append(
                {
                    "reading_delay_steps": r["reading_delay_steps"],
                    "torque_delay_ms": r["torque_delay_ms"],
                    "std_ratio": ratio,
                    "contact_lost_ms": r["contact_lost_ms"],
                    "diverged": r["diverged"],
                    "ptp": r["force_error"]["ptp"],
                    "oscillates": oscillates(r, ref_std),
                    "held": (r.get("held") or {}).get("verdict"),
                    "held_std_n": (r.get("held") or {}).get("window_std_n"),
                    "held_swivel_deg": (r.get("held") or {}).get("at_swivel_deg"),
                    "converged": r.get("converged"),
                    "converged_swivel_deg": r["converged_swivel_deg"],
                }
            )
        sensing = [c for c in cells if c["torque_delay_ms"] == 0.0]
        torque = [c for c in cells if c["reading_delay_steps"] == 0]
        rows.append(
            {
                "row": name,
                "objective": rs[0]["objective"],
                "reference_median_segment_std": ref_std,
                "swivel_deg": ref["converged_swivel_deg"] if ref is not None else None,
                "smallest_sensing_delay_steps": next(
                    (c["reading_delay_steps"] for c in sensing if c["oscillates"]), None
                ),
                "smallest_torque_delay_ms": next((c["torque_delay_ms"] for c in torque if c["oscillates"]), None),
                "sensing_tried": [c["reading_delay_steps"] for c in sensing],
                "torque_tried": [c["torque_delay_ms"] for c in torque],
                "cells": cells,
            }
        )
    held = next((r["held"] for r in runs if r.get("held")), None)
    criterion = {
        "std_factor": OSCILLATION_STD_FACTOR,
        "held_std_n": None if held is None else held["threshold_n"],
        "held_floor_factor": OSCILLATION_FACTOR,  # held_std_n is this many noise floors
        "held_window_s": None if held is None else held["window_s"],
        "held_still_deg": None if held is None else held.get("still_deg"),
        "settle_cap_s": next((r["settle_cap_s"] for r in runs if r.get("settle_cap_s") is not None), None),
    }
    return {"criterion": criterion, "mu": runs[0]["mu"] if runs else None, "rows": rows}


def oscillates(r: dict, reference_median_std: float | None) -> bool:
    """The latency table's criterion: the run diverged, lost contact, oscillated or lost contact while
    held (`HoldWatch`), or has a segment whose force-error STD is ≥ OSCILLATION_STD_FACTOR × the
    reference's median segment STD."""
    if r["diverged"] or r["contact_lost_ms"] > 0 or (r.get("held") or {}).get("verdict"):
        return True
    if reference_median_std is None or reference_median_std <= 0.0:
        return False
    return _worst_segment_std(r) >= OSCILLATION_STD_FACTOR * reference_median_std


class HoldWatch:
    """What the force loop does while the TCP is held (the settle phase), judged only once the posture
    has stopped flowing: the swivel moved at most `still_deg` over the last `window` steps (so the
    verdict is on the posture the row settles in, not one it passes through). Then the verdict is
    "contact lost" when the true contact force was ≤ 0 at some step of that window, or "oscillation"
    when the force-error STD over it is at least `threshold_n` (looked at every `every` steps; the
    polish threshold is `OSCILLATION_FACTOR` × the sensor's noise floor, `oscillation_threshold_n`)."""

    def __init__(
        self,
        threshold_n: float,
        window: int,
        dt: float,
        every: int = HOLD_CHECK_EVERY,
        still_deg: float = HOLD_STILL_DEG,
    ):
        from collections import deque

        self.threshold_n, self.window, self.every = float(threshold_n), max(1, int(window)), max(1, int(every))
        self.window_s = self.window * float(dt)
        self.still_deg = float(still_deg)
        self._errors: deque[float] = deque(maxlen=self.window)
        self._swivels: deque[float] = deque(maxlen=self.window)
        self._lost: deque[bool] = deque(maxlen=self.window)
        self._n = 0
        self.verdict: str | None = None
        self.at_s: float | None = None
        self.at_swivel_deg: float | None = None
        self.window_std_n: float | None = None  # the STD that gave the verdict, else the largest seen
        self.contact_lost_ms = 0

    def add(
        self, t: float, force_error_n: float, true_error_n: float, desired_n: float, swivel_deg: float
    ) -> str | None:
        """One held step: the filtered and the true force error (N) and the swivel (°). Returns the
        verdict (None: none yet)."""
        lost = true_error_n >= desired_n
        self.contact_lost_ms += int(lost)
        self._errors.append(force_error_n)
        self._swivels.append(swivel_deg)
        self._lost.append(lost)
        self._n += 1
        if self.verdict is not None or len(self._errors) < self.window or self._n % self.every:
            return self.verdict
        std = float(np.std(self._errors))
        self.window_std_n = std if self.window_std_n is None else max(self.window_std_n, std)
        if not max(self._swivels) - min(self._swivels) <= self.still_deg:  # still flowing (or NaN)
            return None
        verdict = "contact lost" if any(self._lost) else "oscillation" if std >= self.threshold_n else None
        if verdict is not None:
            self.verdict, self.at_s, self.at_swivel_deg, self.window_std_n = verdict, float(t), float(swivel_deg), std
        return self.verdict

    def result(self, stopped: bool) -> dict:
        """The hold's record in a run's result."""
        return {
            "verdict": self.verdict,
            "at_s": self.at_s,
            "at_swivel_deg": self.at_swivel_deg,
            "window_std_n": self.window_std_n,
            "threshold_n": self.threshold_n,
            "window_s": self.window_s,
            "still_deg": self.still_deg,
            "contact_lost_ms": self.contact_lost_ms,
            "stopped": bool(stopped),
        }


def _segment_stds(r: dict) -> list[float]:
    return [s["force_error"]["std"] for s in r["per_segment"] if s["force_error"]["std"] is not None]


def _median_segment_std(r: dict) -> float | None:
    stds = _segment_stds(r)
    return float(np.median(stds)) if stds else None


def _worst_segment_std(r: dict) -> float:
    stds = _segment_stds(r)
    return float(max(stds)) if stds else float("nan")


def _latency_of(r: dict) -> tuple:
    """(F/T reading age, torque delay) of a run; (None, None) for runs made before they were recorded."""
    return (r.get("reading_delay_steps"), r.get("torque_delay_ms"))


def _held_rule(criterion: dict) -> str:
    """The hold's stop rule of a latency table, as text ("" for tables made without it)."""
    if criterion.get("held_std_n") is None:
        return ""
    return (
        f"; held: a run whose posture has stopped flowing (swivel within {criterion.get('held_still_deg')}° over "
        f"{criterion['held_window_s']:g} s) while the TCP is held, and that lost contact or whose force-error STD "
        f"reached {criterion['held_std_n']:.2f} N over that time, stops there with that verdict"
    )


def format_latency(latency: dict) -> str:
    """The latency table as text: per row, the smallest F/T reading age and torque delay at which the
    run oscillates or leaves the table, and each delay's worst segment STD ratio (! = oscillates)."""

    def smallest(x, unit: str, tried: list) -> str:
        return f"{x:g} {unit}" if x is not None else f"none ≤ {max(tried):g} {unit}" if tried else "-"

    lines = [
        f"latency at μ = {latency['mu']:g}: oscillates = contact lost, diverged, or a segment force-error STD ≥ "
        f"{latency['criterion']['std_factor']:g}× the row's zero-latency median segment STD"
        + _held_rule(latency["criterion"]),
        f"{'row':22s} {'swivel':>7s} {'sensing':>14s} {'torque':>14s}  STD ratio per delay (sensing | torque)",
    ]
    for e in latency["rows"]:

        def ratios(cells: list) -> str:
            return " ".join(
                f"held:{c['held']}!"
                if c.get("held")
                else "-"
                if c["std_ratio"] is None
                else f"{c['std_ratio']:.1f}{'!' if c['oscillates'] else ''}"
                for c in cells
            )

        sensing = [c for c in e["cells"] if c["torque_delay_ms"] == 0.0]
        torque = [c for c in e["cells"] if c["reading_delay_steps"] == 0]
        sw = "-" if e["swivel_deg"] is None else f"{_deg(e['swivel_deg'])}°"
        first_s = smallest(e["smallest_sensing_delay_steps"], "periods", e["sensing_tried"])
        first_t = smallest(e["smallest_torque_delay_ms"], "ms", e["torque_tried"])
        lines.append(f"{e['row']:22s} {sw:>7s} {first_s:>14s} {first_t:>14s}  {ratios(sensing)} | {ratios(torque)}")
    return "\n".join(lines)
