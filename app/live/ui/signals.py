"""Which series each plot draws: a person's choice, kept across preset switches and resets.

Every chart of the Plots panel names the series one may choose (`app.live.ui.charts.signal_specs`): the
joints of the torque plot and its limit lines, the force error, the twin's and the previous run's traces,
W_f / W_a / W_d, the phase plot's velocity limits and its limit / d_s / d_i lines, TCP and elbow
deflection, a preset's own signals. `SignalChoice`
holds what is drawn; it is view state (like the time window), so a preset switch, Reset or Restore
defaults keeps it. A choice arrives from a checkbox (viser's update guard, `app.live.ui.inputs`, refuses
a junk value with one notice to its sender) or from `choose`, which checks the chart, the series and
the value and says in one line what it refused.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

import numpy as np

SignalSpecs = dict[str, tuple[tuple[str, str], ...]]  # chart → (series key, label) in drawing order


class SignalChoice:
    """What each chart draws (every series at first); see the module docstring."""

    def __init__(self, specs: SignalSpecs):
        self.specs = specs
        self._shown: dict[str, dict[str, bool]] = {c: {k: True for k, _ in series} for c, series in specs.items()}
        self.version = 0  # grows with every change (a chart redraws when it differs from what it drew)

    def add(self, chart: str, series: tuple[tuple[str, str], ...]) -> None:
        """Offer a chart's series (a preset's chart, built when it is first shown), every one drawn at first;
        a chart offered before keeps its choice."""
        if chart not in self.specs:
            self.specs[chart] = series
            self._shown[chart] = {k: True for k, _ in series}

    def shown(self, chart: str, key: str) -> bool:
        """Whether `chart` draws its series `key` (True for a chart or series with no choice)."""
        return self._shown.get(chart, {}).get(key, True)

    def shown_keys(self, chart: str) -> tuple[str, ...]:
        """The series of `chart` it draws, in drawing order."""
        return tuple(k for k, _ in self.specs.get(chart, ()) if self.shown(chart, k))

    def check(self, chart: str, key: str, value: object) -> str:
        """ "" if `value` may be set for series `key` of `chart`, else why not (one line)."""
        if chart not in self.specs:
            return f"no plot {chart!r} (plots: {', '.join(self.specs)})"
        keys = [k for k, _ in self.specs[chart]]
        if key not in keys:
            return f"the {chart} plot has no series {key!r} (series: {', '.join(keys)})"
        if not isinstance(value, (bool, np.bool_)):
            return f"expected true or false for {chart} {key}, got {value!r:.40}"
        return ""

    def set(self, chart: str, key: str, value: object) -> bool:
        """Draw series `key` of `chart` or not; ValueError (one line) for an unknown chart or series or a
        value that is not a bool. True if it changed."""
        why = self.check(chart, key, value)
        if why:
            raise ValueError(why)
        shown = bool(value)
        if self._shown[chart][key] == shown:
            return False
        self._shown[chart][key] = shown
        self.version += 1
        return True

    def choose(self, chart: str, keys: Iterable[str]) -> bool:
        """Draw exactly the series `keys` of `chart` (checked first: nothing changes on a refusal)."""
        wanted = set(keys)
        for key in wanted:
            why = self.check(chart, key, True)
            if why:
                raise ValueError(why)
        changed = False
        for key, _ in self.specs[chart]:
            changed |= self.set(chart, key, key in wanted)
        return changed

    def as_dict(self) -> dict[str, dict[str, bool]]:
        """A copy of the whole choice (chart → series → drawn)."""
        return {c: dict(v) for c, v in self._shown.items()}


def masked(values: np.ndarray, shown: bool) -> np.ndarray:
    """`values`, or NaN of its length when the series is not drawn (its samples leave the y range too)."""
    return values if shown else np.full(len(values), np.nan)


def series_shown(series: tuple[Mapping[str, object], ...], flags: Mapping[int, bool]) -> tuple | None:
    """`series` with `show` set per index of `flags`, or None if every flag already holds (then nothing is
    sent: new series options rebuild the chart in the browser)."""
    if all(series[i].get("show", True) is shown for i, shown in flags.items()):
        return None
    return tuple({**s, "show": flags[i]} if i in flags else s for i, s in enumerate(series))
