"""A preset that lives only in the tests: registered at test time (`register`), it must reach the page with
its phases, its chart and its readouts through the `Scenario` contract alone, with no edit of the app.

Its environment logs a wave ("toy_wave", amplitude WAVE_N at WAVE_HZ) and a beat that turns on at BEAT_S
("toy_beat"): the phase text says before or after the beat, the charts mark it, its own chart draws the
wave, and its readout is the wave's largest magnitude over every logged step since the reset.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np
import pytest

from app.scenarios import SCENARIOS, Chart, Environment, PhaseMark, Scenario

NAME = "toy"
WAVE_N = 3.0
WAVE_HZ = 0.7
BEAT_S = 0.4
CHART = Chart("toy_wave", "Toy wave", (("toy_wave", "wave (N)"),), "wave (N)", (-1.0, 1.0))


def wave(t: np.ndarray | float) -> np.ndarray:
    """The wave the environment logs at simulated time t."""
    return WAVE_N * np.sin(2.0 * math.pi * WAVE_HZ * np.asarray(t, dtype=float))


class ToyEnvironment(Environment):
    """Logs the wave and the beat; applies no force."""

    def apply(self, world, t: float) -> dict[str, float]:
        return {"toy_wave": float(wave(t)), "toy_beat": float(t >= BEAT_S - 1e-12)}


class PeakWave:
    """The wave's largest magnitude over the rows fed since the reset (a `metrics.Fold`)."""

    names = ("toy_wave",)

    def __init__(self) -> None:
        self.peak = 0.0

    def add(self, columns: Mapping[str, np.ndarray]) -> None:
        values = np.abs(np.asarray(columns["toy_wave"], dtype=float))
        if np.any(np.isfinite(values)):
            self.peak = max(self.peak, float(np.nanmax(values)))

    def value(self) -> dict[str, float]:
        return {"toy_peak_wave_n": self.peak}


class ToyScenario(Scenario):
    name = NAME
    title = "Toy (tests only)"
    description = "A wave and a beat, to prove a preset needs no edit of the app."
    default_robot = "rizon4s"
    default_executor = "projection"  # the Nullspace panel and its self-motion preview come with it
    logs_deflection = True  # the live lab logs the TCP's and the elbow's distance from the start
    plot_layout = (CHART, "torque")
    phase_marks = (PhaseMark("toy_beat", "beat"),)

    def make_environment(self, world, rng) -> Environment:
        return ToyEnvironment()

    def phase_text(self, status, scene, memory) -> str:
        beat = status.signals.get("toy_beat")
        return "" if beat is None else ("toy: after the beat" if beat > 0.5 else "toy: before the beat")

    def readout_fold(self) -> PeakWave:
        return PeakWave()

    def readout_text(self, values: Mapping[str, float]) -> list[str]:
        return [f"Toy wave: peak {values['toy_peak_wave_n']:.3f} N"] if "toy_peak_wave_n" in values else []


SCENARIO = ToyScenario()


def register(monkeypatch: pytest.MonkeyPatch) -> None:
    """Add the toy to the registered presets for one test (or a module, with a module-scoped monkeypatch)."""
    monkeypatch.setitem(SCENARIOS, NAME, __name__)
