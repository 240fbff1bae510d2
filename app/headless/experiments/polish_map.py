"""The stability map's cell: one held posture × friction μ × latency (F/T reading + drive), its run's
one verdict (`app.scenarios.verdict`) beside the force-loop margin's prediction (`polish_margin`).

A cell is the polish run of a held swivel (`polish.simulate` with `hold_swivel_deg`: W_j on the start
posture at that swivel, no self-motion flow): contact, the held second, then the six strokes. What
repeats across cells is done once per process and swivel (`settled`):

- **The settled posture.** The session is built and stepped through contact and the held second
  with the session's defaults (μ 0.25, the F/T reading one period old, no drive delay). Each cell
  then runs in a forked copy of that process (`sweep.forked`), which sets the cell's μ and latency
  through the parameter path (`Session.set_param`, as the page does) and runs the strokes. The copy
  continues the full simulator and controller state (filters, integrators, delay lines, the noise
  generator), so a cell at the defaults is bit for bit the fresh run; a cell with another μ or
  latency differs from the fresh run only in the held second before the strokes (its latency and μ
  take effect at the first stroke). `tests/test_polish_map.py` checks the verdicts against fresh runs.
- **The zig-zag.** Once the clock has started the strokes, a held posture's target is a function of
  time alone: it is built once for every step time of the strokes and the hold (`TargetTable`) and
  each cell reads it instead of building it again at every step.
- **The margin's postures.** The margin is evaluated every `MARGIN_SAMPLE_S` on the strokes, as in
  every polish run, but at the postures of one calm pass of the strokes at this swivel (μ 0.25, no
  latency), not at the cell's own: the held posture fixes them up to the tracking error, and a cell
  that stops early (below) still gets a prediction for all six strokes. Their Λx is computed once;
  a cell computes σ at them with its own μ, latency, contact, sensor and gains (σ alone: the
  headroom needs no K_f^d search). The loop's parts at each posture do not depend on the latency
  (it enters after them): they are built once per μ (`share_parts`), and a cell adds its latency
  and solves the eigenvalue problems of all postures in one call (`rates`), σ bit for bit as
  `polish_margin.sample` computes it.

A cell stops at the first step of a stroke whose true contact force is 0: its verdict is then "lost
contact" whatever follows (only a later divergence would have ranked higher, and the map counts both
as not stable). Stable and oscillating cells run all six strokes and the final hold.
"""

from __future__ import annotations

import math
import re
from collections import OrderedDict, deque
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from app.scenarios import polish_margin as PM
from app.scenarios import polish_stroke as S
from app.scenarios import verdict as V

LATENCY = re.compile(r"^\s*(\d+)\s*\+\s*(\d+)\s*$")
SETTLED_KEPT = 2  # settled swivels a process keeps (the sweep sends a swivel's cells together)
REFERENCE_MU = 0.25  # the calm pass whose postures the margin is evaluated at
REFERENCE_LATENCY = (0, 0)


def parse_latency(text: str) -> tuple[int, int]:
    """ "R+D" → (F/T reading age, drive delay) in control periods; ValueError otherwise."""
    m = LATENCY.match(str(text))
    if m is None:
        raise ValueError(f"latency {text!r}: write it as READING+DRIVE in control periods, e.g. 1+0 or 2+1")
    return int(m.group(1)), int(m.group(2))


@dataclass
class Settled:
    """A held posture after contact and the held second, ready to be forked per cell."""

    session: Any
    pre_rows: list[tuple[float, float, float]]  # (segment, F/T reading z, contact force) of the last rows
    settle_steps: int
    taus: np.ndarray  # trajectory times of the margin's postures (s)
    lambdas: list[np.ndarray]  # Λx at each of them
    reference_verdict: str  # the calm pass's verdict (its postures are the margin's)
    targets: TargetTable | None = None  # the zig-zag at the strokes' step times (None: not a function of time)
    # the force loop's parts at each posture per latency-free loop (`loop_parts`), built once per μ
    parts: dict[Any, tuple[Any, Any]] = field(default_factory=dict)


class TargetTable:
    """The session's target (`PolishTarget`) at the step times of the strokes and the final hold, built
    once in the settled process and read by every forked cell: once its clock has started, a held
    posture's zig-zag is a function of time alone (no plan; the cells change μ and latency, not the
    target; `current` says whether the target's inputs are still those). A time not in the table (none
    is expected: the world's clock advances by the same additions) is computed as before; the target's
    other attributes are the original's."""

    def __init__(self, target_fn: Any, times: list[float]):
        self._fn = target_fn
        self._at = {t: target_fn(t) for t in times}
        self._inputs = self._inputs_now()
        self.missed = 0

    def _inputs_now(self) -> tuple:
        fn = self._fn
        arrays = (fn.wrench, fn.start, fn.rotation, fn.q_posture)
        return (fn.clock.trajectory_start, fn.plan, *(a.tobytes() for a in arrays))

    def current(self) -> bool:
        """The target's inputs (its clock's start, plan, wrench, start pose and posture) are still those the
        table was built from."""
        return self._inputs_now() == self._inputs

    @property
    def target_fn(self) -> Any:
        """The target the table was built from."""
        return self._fn

    def __call__(self, t: float):
        target = self._at.get(t)
        if target is None:
            self.missed += 1
            return self._fn(t)
        return target

    def __getattr__(self, name: str) -> Any:  # the target group's `wrench` (`Session._owners`) and the rest
        if name.startswith("_"):
            raise AttributeError(name)
        return getattr(self._fn, name)

    def __setattr__(self, name: str, value: Any) -> None:  # the target group's new `wrench` goes to the target
        if name.startswith("_") or name == "missed":
            object.__setattr__(self, name, value)
        else:
            setattr(self._fn, name, value)

    def __len__(self) -> int:
        return len(self._at)


def target_table(session) -> TargetTable | None:
    """The `TargetTable` of a session settled at the strokes' start: the times its world's clock will
    read (its own additions of the step) until the trajectory and its hold are over; None when the
    target follows a plan."""
    target_fn = session.target_fn
    clock = session.environment.clock
    if getattr(target_fn, "plan", None) is not None or clock.trajectory_start is None:
        return None
    dt = float(session.world.model.opt.timestep)
    t = float(session.world.time)
    times: list[float] = []
    while len(times) < round(S.trajectory_duration() / dt) * 2:  # the strokes and the hold, with room to spare
        times.append(t)
        if clock.finished(t):
            break
        t += dt
    return TargetTable(target_fn, times)


_SETTLED: OrderedDict[tuple, Settled] = OrderedDict()
_STATS = {"settled": 0, "reused": 0}


def _session(swivel_deg: float, seed: int):
    from app.core.session import Session
    from app.scenarios.polish import PolishScenario

    session = Session(PolishScenario(hold_swivel_deg=float(swivel_deg)), seed=int(seed))
    session.environment.live_margin_every_s = math.inf  # type: ignore[attr-defined]  # a page signal only
    return session


def _row(rec) -> tuple[float, float, float]:
    sig = rec.signals
    return (float(sig["segment"]), float(rec.wrench_tcp[2]), float(sig["contact_force_n"]))


def _set_cell(session, mu: float, reading: int, drive: int) -> None:
    """The cell's μ and latency through the parameter path (drive periods as ms of the world's step)."""
    dt_ms = float(session.world.model.opt.timestep) * 1e3
    session.set_param("contact", "mu", float(mu))
    session.set_param("sensor", "reading_delay_steps", int(reading))
    session.set_param("world", "torque_delay_ms", float(drive) * dt_ms)


def _strokes(session, stop_on_loss: bool, margin_postures: bool = False):
    """Run the strokes and the final hold from a settled session: (rows, RunResult, [(τ, Λx)], whether
    it stopped at a lost contact)."""
    from app.headless.experiments.polish import SAFETY_CAP_S

    clock = session.environment.clock
    start = float(clock.trajectory_start)
    dt = float(session.world.model.opt.timestep)
    every = max(1, round(PM.MARGIN_SAMPLE_S / dt))
    rows: list[tuple[float, float, float]] = []
    postures: list[tuple[float, np.ndarray]] = []
    n = len(session.world.q)
    lost = [False]
    add, finished, strokes = rows.append, clock.finished, S.N_SEGMENTS

    def step_over(rec) -> bool:
        """Keep the step's row (`_row`), then: the stroke lost contact (when stopping there), or the
        trajectory and its hold are over (`polish._run_over` of all strokes)."""
        sig = rec.signals
        seg, force = sig["segment"], sig["contact_force_n"]
        add((float(seg), float(rec.wrench_tcp[2]), float(force)))
        if margin_postures and 1 <= seg <= strokes and round((rec.t - start) / dt) % every == 0:
            postures.append((rec.t - start, session.model.compute(rec.q, np.zeros(n)).Lambda.copy()))
        if stop_on_loss and force <= 0.0 and 1 <= seg <= strokes:
            lost[0] = True
            return True
        return finished(rec.t)

    result = session.run(SAFETY_CAP_S, until=step_over)  # one callback a step: the row is kept in it
    if result.stop == "diverged" and session.last is not None:  # the run ended before `until` saw it
        rows.append(_row(session.last))
    return rows, result, postures, lost[0]


def _verdict(session, rows: list[tuple[float, float, float]], diverged: bool) -> tuple[str, list]:
    """The one verdict over the rows (as `polish.simulate` judges a run)."""
    arr = np.asarray(rows, dtype=float).reshape(-1, 3)
    dt = float(session.world.model.opt.timestep)
    judged = V.strokes(arr[:, 0], arr[:, 1], arr[:, 2], session.params()["sensor"], dt)
    verdict = V.run_verdict(judged, diverged=diverged)
    traj = (arr[:, 0] >= 1) & (arr[:, 0] <= S.N_SEGMENTS)
    return (verdict if np.any(traj) or verdict != V.STABLE else "no strokes"), judged


def _reference_pass(session) -> tuple[np.ndarray, list[np.ndarray], str]:
    """In a forked copy: the calm pass (μ 0.25, no latency) and the Λx of its stroke postures."""
    _set_cell(session, REFERENCE_MU, *REFERENCE_LATENCY)
    rows, result, postures, _ = _strokes(session, stop_on_loss=False, margin_postures=True)
    verdict, _ = _verdict(session, rows, result.stop == "diverged")
    return np.array([t for t, _ in postures]), [lam for _, lam in postures], verdict


def settled(swivel_deg: float, seed: int) -> tuple[Settled, bool]:
    """The settled posture of this swivel and seed (built on first use, then kept: `SETTLED_KEPT`);
    True when it was kept from an earlier cell."""
    from app.headless.sweep.forked import call_forked

    key = (float(swivel_deg), int(seed))
    if key in _SETTLED:
        _SETTLED.move_to_end(key)
        _STATS["reused"] += 1
        return _SETTLED[key], True
    session = _session(swivel_deg, seed)
    clock = session.environment.clock
    pre: deque[tuple[float, float, float]] = deque(maxlen=round(V.PAD_S / session.world.model.opt.timestep) + 1)
    cap = S.CONTACT_TIME_S + clock.timeout_s + 2 * session.world.model.opt.timestep
    result = session.run(cap, until=lambda r: clock.trajectory_start is not None, record=lambda r: pre.append(_row(r)))
    if clock.trajectory_start is None:
        raise RuntimeError(f"the held posture at {swivel_deg:g}° did not reach the strokes ({result.stop})")
    targets = target_table(session)
    if targets is not None:
        session.target_fn = targets
    taus, lambdas, ref_verdict = call_forked(_reference_pass, session)
    # what the copies would otherwise load each time (the band-pass's imports and filter design, the
    # margin's): loaded here once, the copies inherit them
    _verdict(session, list(pre), diverged=False)
    margin_prediction(session, taus[:2], lambdas[:2])
    entry = Settled(session, list(pre), result.steps, taus, lambdas, ref_verdict, targets)
    _SETTLED[key] = entry
    _STATS["settled"] += 1
    while len(_SETTLED) > SETTLED_KEPT:
        _SETTLED.popitem(last=False)
    return entry, False


def _margin_inputs(session) -> tuple[Any, Any]:
    """(gains, `ContactLoop`) of the session's own loop, as the margin reads them."""
    shaping = bool(session.params()["motion_force"].shaping)
    gains = replace(session.executor.gains, shaping=shaping)
    return gains, PM.contact_loop(session.environment.contact, session.sensor, session.world)


def _without_latency(loop):
    """The loop with what `control.margin.force_loop_parts` does not read set to 0: the latency (it
    enters after the parts, `delayed_loop`) and the speed (each posture's own)."""
    return replace(loop, sensing_delay_steps=0, actuation_delay_steps=0, speed_m_s=0.0)


def loop_parts(taus: np.ndarray, lambdas: list[np.ndarray], gains, loop):
    """`control.margin.force_loop_parts` at each posture (its Λx, the stroke's speed and friction
    direction at τ), stacked (`control.margin.stacked`): everything of σ but the latency, shared by
    the cells of one μ."""
    from control.margin import force_loop_parts, stacked

    out = []
    for tau, lam in zip(taus, lambdas, strict=True):
        speed, f_hat = PM.operating_point(float(tau))
        out.append(force_loop_parts(lam, PM.POLISH_SUBSPACES, gains, replace(loop, speed_m_s=speed), f_hat))
    return stacked(out) if out else None


def rates(parts, loop) -> list[float]:
    """σ (1/s) at each posture from its stacked parts with the loop's latency: `control.margin.loop_rate`'s
    arithmetic, the maps and the eigenvalue problems of all postures in one call each."""
    from control.margin import delayed_loop

    if parts is None:
        return []
    phis = delayed_loop(parts, loop.sensing_delay_steps, loop.actuation_delay_steps)
    rho = np.max(np.abs(np.linalg.eigvals(phis)), axis=-1)
    return [-math.log(r) / loop.dt if r > 0 else math.inf for r in rho.tolist()]


def share_parts(entry: Settled, mu: float) -> None:
    """Build (once per μ, in the settled process) the parts a cell of this μ needs, so its forked
    copy reads them: the loop is the settled session's with the cell's μ (`_set_cell` sets no other
    field the parts read); the copy checks that against its own before using them."""
    gains, loop = _margin_inputs(entry.session)
    key = _without_latency(replace(loop, mu=float(mu)))
    if key not in entry.parts:
        entry.parts[key] = (gains, loop_parts(entry.taus, entry.lambdas, gains, key))


def margin_prediction(session, taus: np.ndarray, lambdas: list[np.ndarray], shared: dict | None = None) -> dict:
    """The stroke headroom (`polish_margin`) at the given postures with the session's own loop: per
    stroke and its least value h_min, and the prediction h_min < 0 (the tool leaves the table).
    `shared`: parts already built for this loop (`share_parts`), used when gains and loop match."""
    from app.headless.experiments.polish import _finite_or_none

    gains, loop = _margin_inputs(session)
    kept = (shared or {}).get(_without_latency(loop))
    parts = kept[1] if kept is not None and kept[0] == gains else loop_parts(taus, lambdas, gains, loop)
    samples = [PM.MarginSample(rate, math.nan, math.nan) for rate in rates(parts, loop)]  # σ alone: find_kd=False
    floor = PM.sensor_floor_n(session.params()["sensor"], loop.dt)
    budget = PM.headroom_budget_np(S.DESIRED_FORCE_N, floor)
    strokes = PM.per_stroke(taus, samples, budget)
    summary = PM.summary(strokes)
    h = summary["headroom_min_np"]
    statement = PM.headroom_statement(h if h is not None else math.nan)
    return {
        "headroom_min_np": _finite_or_none(h) if h is not None else None,
        "rate_min_per_s": summary["rate_min_per_s"],
        "growth_max_np": summary["growth_max_np"],
        "margin_predicts_loss": bool(h is not None and h < 0.0),
        "margin_sign": statement.sign,
        "headroom_budget_np": budget,
        "headroom_per_stroke_np": [s["headroom_min_np"] for s in strokes],
    }


def _cell_in_copy(entry: Settled, mu: float, reading: int, drive: int, stop_on_loss: bool) -> dict:
    """In a forked copy of the settled process: set the cell, run the strokes, judge them."""
    session = entry.session
    _set_cell(session, mu, reading, drive)
    if entry.targets is not None and not entry.targets.current():  # not expected: the cell sets no target
        session.target_fn = entry.targets.target_fn
    rows, result, _, stopped = _strokes(session, stop_on_loss)
    all_rows = entry.pre_rows + rows
    verdict, judged = _verdict(session, all_rows, result.stop == "diverged")
    arr = np.asarray(rows, dtype=float).reshape(-1, 3)
    on = (arr[:, 0] >= 1) & (arr[:, 0] <= S.N_SEGMENTS)
    dt = float(session.world.model.opt.timestep)
    return {
        "verdict": verdict,
        "stable": verdict == V.STABLE,
        "stopped_at_loss": bool(stopped),
        "run_stop": result.stop,
        "stroke_steps": int(result.steps),
        "contact_lost_ms": int(np.count_nonzero(V.contact_lost(arr[on, 2]))),
        "band_rms_max_n": max((s.band_rms_n for s in judged), default=None),
        "oscillation_threshold_n": V.oscillation_threshold_n(session.params()["sensor"], dt),
        "stroke_verdicts": [s.verdict for s in judged],
        **V.band_facts(),
        **margin_prediction(session, entry.taus, entry.lambdas, entry.parts),
    }


def run_cell(swivel_deg: float, mu: float, latency: str, seed: int = 0, stop_on_loss: bool = True) -> dict:
    """One map cell (module docstring): its verdict, the margin's prediction and what they rest on."""
    from app.headless.sweep.forked import call_forked, can_fork

    reading, drive = parse_latency(latency)
    if not can_fork():
        raise RuntimeError("the stability map's cells fork the settled posture: this platform has no os.fork")
    entry, reused = settled(swivel_deg, seed)
    share_parts(entry, mu)
    out = call_forked(_cell_in_copy, entry, float(mu), reading, drive, bool(stop_on_loss))
    return {
        "hold_swivel_deg": float(swivel_deg),
        "mu": float(mu),
        "reading_delay_steps": reading,
        "drive_delay_steps": drive,
        "latency_periods": reading + drive,
        "settled_reused": bool(reused),
        "settle_steps": entry.settle_steps,
        "reference_verdict": entry.reference_verdict,
        **out,
    }
