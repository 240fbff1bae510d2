"""The polish experiment's latency table: each stage of the loop's latency alone (the F/T reading's age,
the actuation delay) and both together per row at μ = 1, the smallest delay at which a run is not
stable by the one verdict, the hold's early verdict (`HoldWatch`) and the table as text."""

from __future__ import annotations

import numpy as np

from app.headless.experiments.polish_report import _deg
from app.headless.experiments.polish_rows import ROWS
from app.scenarios import verdict as V
from app.scenarios.polish_stroke import SETTLE_SPEED_RAD_S, SETTLE_WINDOW_S

# The latency table: each stage of the loop's latency alone (the other at 0), at μ = 1, seed 0.
LATENCY_ROWS = ("j", "f", "a", "d", "mirror", "planned_a", "planned")
LATENCY_QUICK_ROWS = ("j", "a")
LATENCY_SENSING_STEPS = (0, 1, 2, 3, 4)  # F/T reading age, control periods
LATENCY_TORQUE_MS = (0.0, 1.0, 2.0, 3.0, 4.0)  # actuation delay
LATENCY_QUICK_MAX = 2  # --quick: delays up to this many periods (ms)
# both stages at once: the F/T reading one period old and 1 ms at the drive (1 + 1 periods, the 1 + 0 and
# 0 + 1 cases being the single stages above), as a rig with an F/T path and a command path both has
LATENCY_COMBINED = ((1, 1.0),)
LATENCY_MU = 1.0
# A latency run whose force loop already oscillates or loses contact while the TCP is held (the settle
# phase, before the strokes) has its verdict there (`app.scenarios.verdict` over the held second) and
# stops (`HoldWatch`): at 3-4 periods of delay the hold oscillates, W never settles and the run would
# otherwise sit out the settle cap.
HOLD_CHECK_EVERY = 100  # steps between two looks at the hold's last second
# ... once the posture has stopped flowing, by the settle phase's own test: the swivel moved at most what
# the converged nullspace speed (polish.SETTLE_SPEED_RAD_S) moves it over the settle window
HOLD_STILL_DEG = float(np.rad2deg(SETTLE_SPEED_RAD_S * SETTLE_WINDOW_S))


def latency_specs(quick: bool = False, only: list[str] | None = None, mu: float = LATENCY_MU) -> list[dict]:
    """The latency table's runs: per row, the F/T reading age over `LATENCY_SENSING_STEPS` with no
    torque delay, and the torque delay over `LATENCY_TORQUE_MS` with a same-step reading (each stage
    alone; both 0 is the zero-latency reference), then both stages at once (`LATENCY_COMBINED`);
    seed 0, μ = 1. `quick`: W_j and W_a, delays up to
    `LATENCY_QUICK_MAX`; `only` keeps the rows among these keys."""
    keys = [k for k in (LATENCY_QUICK_ROWS if quick else LATENCY_ROWS) if not only or k in only]
    cap = LATENCY_QUICK_MAX if quick else None
    pairs = [(d, 0.0) for d in LATENCY_SENSING_STEPS if cap is None or d <= cap]
    pairs += [(0, ms) for ms in LATENCY_TORQUE_MS if ms > 0 and (cap is None or ms <= cap)]
    pairs += [(d, ms) for d, ms in LATENCY_COMBINED if cap is None or d + ms <= cap]
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
    the run is not stable by the one verdict (`app.scenarios.verdict`: oscillating, lost contact or
    diverged, on a stroke or while held), with each run's worst stroke band RMS over its oscillation
    threshold and its lost contact. None: no delay tried did it."""
    rows: list[dict] = []
    for name in dict.fromkeys(r["row"] for r in runs):
        rs = [r for r in runs if r["row"] == name]
        ref = next((r for r in rs if r["reading_delay_steps"] == 0 and r["torque_delay_ms"] == 0.0), None)
        cells = []
        for r in sorted(rs, key=lambda x: (x["torque_delay_ms"], x["reading_delay_steps"])):
            cells.append(
                {
                    "reading_delay_steps": r["reading_delay_steps"],
                    "torque_delay_ms": r["torque_delay_ms"],
                    "band_ratio": band_ratio(r),
                    "contact_lost_ms": r["contact_lost_ms"],
                    "diverged": r["diverged"],
                    "ptp": r["force_error"]["ptp"],
                    "verdict": run_verdict(r),
                    "oscillates": oscillates(r),
                    "held": (r.get("held") or {}).get("verdict"),
                    "held_band_rms_n": (r.get("held") or {}).get("window_band_rms_n"),
                    "held_swivel_deg": (r.get("held") or {}).get("at_swivel_deg"),
                    "converged": r.get("converged"),
                    "converged_swivel_deg": r["converged_swivel_deg"],
                }
            )
        sensing = [c for c in cells if c["torque_delay_ms"] == 0.0]
        torque = [c for c in cells if c["reading_delay_steps"] == 0]
        both = [c for c in cells if c["reading_delay_steps"] > 0 and c["torque_delay_ms"] > 0.0]
        rows.append(
            {
                "row": name,
                "objective": rs[0]["objective"],
                "swivel_deg": ref["converged_swivel_deg"] if ref is not None else None,
                "smallest_sensing_delay_steps": next(
                    (c["reading_delay_steps"] for c in sensing if c["oscillates"]), None
                ),
                "smallest_torque_delay_ms": next((c["torque_delay_ms"] for c in torque if c["oscillates"]), None),
                "sensing_tried": [c["reading_delay_steps"] for c in sensing],
                "torque_tried": [c["torque_delay_ms"] for c in torque],
                "combined": [
                    {
                        "reading_delay_steps": c["reading_delay_steps"],
                        "torque_delay_ms": c["torque_delay_ms"],
                        "oscillates": c["oscillates"],
                        "verdict": c["verdict"],
                    }
                    for c in both
                ],
                "cells": cells,
            }
        )
    held = next((r["held"] for r in runs if r.get("held")), None)
    criterion = {
        "threshold_n": next((r["oscillation_threshold_n"] for r in runs if r.get("oscillation_threshold_n")), None),
        "floor_n": next((r["band_floor_n"] for r in runs if r.get("band_floor_n")), None),
        "held_window_s": None if held is None else held["window_s"],
        "held_still_deg": None if held is None else held.get("still_deg"),
        "settle_cap_s": next((r["settle_cap_s"] for r in runs if r.get("settle_cap_s") is not None), None),
        **{k: next((r[k] for r in runs if r.get(k) is not None), None) for k in V.band_facts()},
    }
    return {"criterion": criterion, "mu": runs[0]["mu"] if runs else None, "rows": rows}


def run_verdict(r: dict) -> str:
    """The run's verdict: as stopped while held (`HoldWatch`), else as the run recorded it; a run made
    before the verdict was recorded: from its divergence and lost contact alone."""
    held = (r.get("held") or {}).get("verdict")
    if held:
        return str(held)
    if r.get("verdict"):
        return str(r["verdict"])
    return V.DIVERGED if r["diverged"] else V.LOST if r["contact_lost_ms"] > 0 else V.STABLE


def oscillates(r: dict) -> bool:
    """The latency table's criterion: the run is not stable by the one verdict (`run_verdict`)."""
    return V.unstable(run_verdict(r))


def band_ratio(r: dict) -> float | None:
    """The run's worst stroke band RMS over its oscillation threshold (None without them)."""
    rms, threshold = r.get("band_rms_max_n"), r.get("oscillation_threshold_n")
    return None if rms is None or not threshold else float(rms) / float(threshold)


class HoldWatch:
    """What the force loop does while the TCP is held (the settle phase), judged only once the posture
    has stopped flowing: the swivel moved at most `still_deg` over the last `window` steps (so the
    verdict is on the posture the row settles in, not one it passes through). Then the one verdict
    (`app.scenarios.verdict.window`) of that window, judged as a stroke against `threshold_n` (the
    sensor's oscillation threshold, `verdict.oscillation_threshold_n`), looked at every `every` steps."""

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
        self.dt = float(dt)
        self._readings: deque[float] = deque(maxlen=self.window)
        self._contact: deque[float] = deque(maxlen=self.window)
        self._swivels: deque[float] = deque(maxlen=self.window)
        self._n = 0
        self.verdict: str | None = None
        self.at_s: float | None = None
        self.at_swivel_deg: float | None = None
        self.window_band_rms_n: float | None = None  # the band RMS that gave the verdict, else the largest seen
        self.contact_lost_ms = 0

    def add(self, t: float, reading_n: float, contact_force_n: float, swivel_deg: float) -> str | None:
        """One held step: the F/T reading along the force axis and the true contact force (N), and the
        swivel (°). Returns the verdict (None: none yet)."""
        self.contact_lost_ms += int(V.contact_lost(np.array([contact_force_n]))[0])
        self._readings.append(reading_n)
        self._contact.append(contact_force_n)
        self._swivels.append(swivel_deg)
        self._n += 1
        if self.verdict is not None or len(self._readings) < self.window or self._n % self.every:
            return self.verdict
        verdict, rms = V.window(np.asarray(self._readings), np.asarray(self._contact), self.threshold_n, self.dt)
        self.window_band_rms_n = rms if self.window_band_rms_n is None else max(self.window_band_rms_n, rms)
        if not max(self._swivels) - min(self._swivels) <= self.still_deg:  # still flowing (or NaN)
            return None
        if V.unstable(verdict):
            self.verdict, self.at_s, self.at_swivel_deg = verdict, float(t), float(swivel_deg)
            self.window_band_rms_n = rms
        return self.verdict

    def result(self, stopped: bool) -> dict:
        """The hold's record in a run's result."""
        return {
            "verdict": self.verdict,
            "at_s": self.at_s,
            "at_swivel_deg": self.at_swivel_deg,
            "window_band_rms_n": self.window_band_rms_n,
            "threshold_n": self.threshold_n,
            "window_s": self.window_s,
            "still_deg": self.still_deg,
            "contact_lost_ms": self.contact_lost_ms,
            "stopped": bool(stopped),
        }


def _latency_of(r: dict) -> tuple:
    """(F/T reading age, torque delay) of a run; (None, None) for runs made before they were recorded."""
    return (r.get("reading_delay_steps"), r.get("torque_delay_ms"))


def _held_rule(criterion: dict) -> str:
    """The hold's stop rule of a latency table, as text ("" for tables made without it)."""
    if criterion.get("held_window_s") is None:
        return ""
    return (
        f"; held: a run whose posture has stopped flowing (swivel within {criterion.get('held_still_deg'):.3f}° "
        f"over {criterion['held_window_s']:g} s) while the TCP is held, and whose verdict over that time is not "
        "stable, stops there with that verdict"
    )


def format_latency(latency: dict) -> str:
    """The latency table as text: per row, the smallest F/T reading age and torque delay at which the
    run is not stable, and each delay's worst stroke band RMS over the threshold (! = not stable)."""

    def smallest(x, unit: str, tried: list) -> str:
        return f"{x:g} {unit}" if x is not None else f"none ≤ {max(tried):g} {unit}" if tried else "-"

    threshold = latency["criterion"].get("threshold_n")
    lines = [
        f"latency at μ = {latency['mu']:g}: not stable = diverged, lost contact, or a stroke's F/T band RMS ≥ "
        + ("-" if threshold is None else f"{threshold:.2f} N")
        + " (the one verdict, app.scenarios.verdict)"
        + _held_rule(latency["criterion"]),
        f"{'row':22s} {'swivel':>7s} {'sensing':>14s} {'torque':>14s}  "
        "band RMS / threshold per delay (sensing | torque)",
    ]
    for e in latency["rows"]:

        def ratios(cells: list) -> str:
            return " ".join(
                f"held:{c['held']}!"
                if c.get("held")
                else "-"
                if c["band_ratio"] is None
                else f"{c['band_ratio']:.1f}{'!' if c['oscillates'] else ''}"
                for c in cells
            )

        sensing = [c for c in e["cells"] if c["torque_delay_ms"] == 0.0]
        torque = [c for c in e["cells"] if c["reading_delay_steps"] == 0]
        both = [c for c in e["cells"] if c["reading_delay_steps"] > 0 and c["torque_delay_ms"] > 0.0]
        sw = "-" if e["swivel_deg"] is None else f"{_deg(e['swivel_deg'])}°"
        first_s = smallest(e["smallest_sensing_delay_steps"], "periods", e["sensing_tried"])
        first_t = smallest(e["smallest_torque_delay_ms"], "ms", e["torque_tried"])
        combined = "".join(f" | {c['reading_delay_steps']}+{c['torque_delay_ms']:g}: {ratios([c])}" for c in both)
        lines.append(
            f"{e['row']:22s} {sw:>7s} {first_s:>14s} {first_t:>14s}  {ratios(sensing)} | {ratios(torque)}{combined}"
        )
    return "\n".join(lines)
