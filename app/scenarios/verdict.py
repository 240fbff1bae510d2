"""One verdict for a force-controlled contact run: is a stroke (and the run) stable, oscillating or
did it lose contact — decided from the step log alone, the same way by the page, the lessons, the
sweeps, the latency table and every report.

- **Lost contact**: the true contact force reached 0 (the table pushed no more: the tool left it) at
  one 1 ms step or more of the stroke. No threshold to choose: a force that cannot be negative.
- **Oscillating**: the F/T reading's RMS in the contact mode's band over the stroke is at least the
  sensor's floor: the RMS its noise and sinusoid leave on a steady reading after its low-pass
  (`reading_floor_n`, 1.55 N with [T] §IV-A's sensor). An oscillation below it is lost in what the
  sensor adds to a steady force, on the page's force plot and in the controller's input alike;
  at or above it, the contact mode is the loudest thing the reading carries. The threshold is that
  physical quantity of the run's own sensor (its stated noise variance, sinusoid and cutoff), not a
  number taken from this project's runs.
- **Stable**: neither. A run's verdict is its worst stroke's ("lost contact" > "oscillating" >
  "stable"); a run whose simulation diverged is "diverged".

The band is one octave around the force loop's contact mode (`MODE_HZ`), where the linearised loop
puts its slowest mode (12–14 Hz at the polish postures: the table's 30 kN/m spring against the shaped
task inertia along z): wide enough that the shift of the mode with posture and latency stays inside,
narrow enough to leave out the stroke's own 0.4 Hz motion and the sensor's 1 Hz sinusoid. The same
band gives the margin its floor (`band_floor_n`: the sensor's noise in the band, the disturbance that
seeds the mode; the sinusoid cannot). Not chosen: twice that band floor (a peak sensitivity M_s ≤ 2):
the paper's gains leave the contact mode lightly damped in every posture (ζ ≈ 0.07 where the loop is
calmest) and each corner's friction reversal rings it, so every calm stroke sits at 1.6–2.6 band
floors — that rule measured the loop's resonance, not an oscillation a person sees. `scale`
(default 1) multiplies the oscillation threshold, for the calibration's sensitivity (× 0.5, × 2).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

STABLE = "stable"
OSCILLATING = "oscillating"
LOST = "lost contact"
DIVERGED = "diverged"
SEVERITY = (STABLE, OSCILLATING, LOST, DIVERGED)  # a run's verdict is its worst stroke's

MODE_HZ = 13.0  # the force loop's contact mode: control.margin's slowest mode at the polish postures
BAND_HZ = (MODE_HZ / math.sqrt(2.0), MODE_HZ * math.sqrt(2.0))  # one octave around it: 9.2-18.4 Hz
BAND_ORDER = 4  # Butterworth band-pass, run forwards and backwards (zero phase: |H|⁴ in power)
DEFAULT_SENSOR = {"force_noise_var": 5.0, "sine_amplitude_n": 2.0, "cutoff_hz": 25.0}  # [T] §IV-A
PAD_S = 0.5  # the series either side of the strokes that the band-pass runs over (its transient: < 0.3 s)


@lru_cache(maxsize=8)
def _band_sos(dt: float) -> np.ndarray:
    from scipy.signal import butter

    hi = min(BAND_HZ[1], 0.45 / dt)
    return butter(BAND_ORDER, [BAND_HZ[0], hi], btype="band", fs=1.0 / dt, output="sos")


def band_force_n(series_n: np.ndarray, dt: float) -> np.ndarray:
    """The series (N, one sample per step dt) in the contact mode's band: its mean removed, NaNs
    replaced by the mean, band-passed forwards and backwards (zero phase)."""
    from scipy.signal import sosfiltfilt

    x = np.asarray(series_n, dtype=float)
    if x.size == 0:
        return x.copy()
    finite = np.isfinite(x)
    mean = float(np.mean(x[finite])) if np.any(finite) else 0.0
    x = np.where(finite, x, mean) - mean
    sos = _band_sos(dt)
    if x.size <= 3 * (2 * sos.shape[0] + 1):  # too short for the filter's edge padding
        return np.zeros_like(x)
    return sosfiltfilt(sos, x)


@lru_cache(maxsize=64)
def band_floor_n(force_noise_var_n2: float, cutoff_hz: float, dt: float) -> float:
    """RMS (N) of the sensor's white force noise (variance per reading, one reading per step dt) in
    the contact mode's band: one-sided density 2σ²Δt through the first-order low-pass
    y ← y + α(x − y), α = 1 − exp(−2π f_c Δt) ([T] §IV-A), and `band_force_n`'s zero-phase band-pass."""
    from scipy.signal import sosfreqz

    alpha = 1.0 - math.exp(-2.0 * math.pi * cutoff_hz * dt) if cutoff_hz > 0 else 1.0
    f, h = sosfreqz(_band_sos(dt), worN=16384, fs=1.0 / dt)
    z = np.exp(-2j * np.pi * f * dt)
    lpf2 = np.abs(alpha / (1.0 - (1.0 - alpha) * z)) ** 2
    density = 2.0 * float(force_noise_var_n2) * dt * lpf2 * np.abs(h) ** 4
    return math.sqrt(float(np.trapezoid(density, f)))


def _field(sensor: object, name: str) -> float:
    value = sensor.get(name) if isinstance(sensor, Mapping) else getattr(sensor, name, None)
    return float(DEFAULT_SENSOR[name] if value is None else value)  # type: ignore[arg-type]


def _noise_on(sensor: object) -> bool:
    value = sensor.get("noise", True) if isinstance(sensor, Mapping) else getattr(sensor, "noise", True)
    return bool(value)


def sensor_band_floor_n(sensor: object, dt: float, noise_switch: bool = False) -> float:
    """`band_floor_n` of a sensor group (`SensorParams`) or its fields as a mapping; with
    `noise_switch` a sensor whose noise is off has floor 0 (the margin's use: nothing to grow)."""
    if noise_switch and not _noise_on(sensor):
        return 0.0
    return band_floor_n(_field(sensor, "force_noise_var"), _field(sensor, "cutoff_hz"), dt)


def reading_floor_n(force_noise_var_n2: float, sine_amplitude_n: float, cutoff_hz: float, dt: float) -> float:
    """STD (N) of a steady F/T reading ([T] §IV-A): white noise of variance σ² through the first-order
    low-pass leaves σ² α/(2 − α), α = 1 − exp(−2π f_c Δt); a slow sinusoid of amplitude A passes with A²/2."""
    alpha = 1.0 - math.exp(-2.0 * math.pi * cutoff_hz * dt) if cutoff_hz > 0 else 1.0
    return math.sqrt(force_noise_var_n2 * alpha / (2.0 - alpha) + 0.5 * sine_amplitude_n**2)


def oscillation_threshold_n(sensor: object, dt: float, scale: float = 1.0) -> float:
    """The band RMS (N) of the F/T reading from which a stroke oscillates: the sensor's `reading_floor_n`
    (of its stated noise and sinusoid whether or not the run draws them; [T] §IV-A's where both are 0),
    × `scale` (the calibration's sensitivity: 0.5, 1, 2)."""
    var, sine = _field(sensor, "force_noise_var"), _field(sensor, "sine_amplitude_n")
    if var <= 0.0 and sine <= 0.0:
        var, sine = DEFAULT_SENSOR["force_noise_var"], DEFAULT_SENSOR["sine_amplitude_n"]
    return float(scale) * reading_floor_n(var, sine, _field(sensor, "cutoff_hz"), dt)


def contact_lost(contact_force_n: np.ndarray) -> np.ndarray:
    """Per step of a stroke or a held window: the contact force (N, pressing the tool: > 0) is at or below
    0, the tool left the table (`metrics.contact_lost`, every step watched)."""
    from app.scenarios.metrics import contact_lost as lost_where_watched

    force = np.asarray(contact_force_n, dtype=float)
    return lost_where_watched(force, np.ones_like(force))


def judge(band_rms_n: float | None, contact_lost_steps: int, threshold_n: float, scale: float = 1.0) -> str:
    """The verdict of one stroke (or window): LOST when the contact force reached 0 at a step,
    OSCILLATING when its band RMS is at least `scale` × threshold_n, else STABLE."""
    if contact_lost_steps > 0:
        return LOST
    if band_rms_n is not None and math.isfinite(band_rms_n) and band_rms_n >= scale * threshold_n:
        return OSCILLATING
    return STABLE


def worst(verdicts: list[str]) -> str:
    """The most severe of some verdicts (STABLE for none)."""
    return max(verdicts, key=SEVERITY.index, default=STABLE)


@dataclass(frozen=True)
class StrokeVerdict:
    """One stroke's verdict with the numbers it rests on."""

    segment: int
    verdict: str
    band_rms_n: float  # the F/T reading's RMS in the contact mode's band over the stroke
    threshold_n: float  # the oscillation threshold it was held against (scale 1)
    contact_lost_ms: int  # steps (1 ms) with the true contact force ≤ 0
    min_contact_force_n: float

    def as_dict(self) -> dict:
        """The stroke's verdict as JSON-ready fields."""
        return {
            "segment": self.segment,
            "verdict": self.verdict,
            "band_rms_n": self.band_rms_n,
            "threshold_n": self.threshold_n,
            "contact_lost_ms": self.contact_lost_ms,
            "min_contact_force_n": self.min_contact_force_n,
        }


def strokes(
    segment: np.ndarray,
    reading_n: np.ndarray,
    contact_force_n: np.ndarray,
    sensor: object,
    dt: float,
    segments: range | tuple[int, ...] = range(1, 7),
) -> list[StrokeVerdict]:
    """Per stroke present in the log (rows with `segment` == k): its verdict from the F/T reading
    along the force axis (N) and the true contact force (N), one row per step dt."""
    seg = np.asarray(segment, dtype=float)
    reading = np.asarray(reading_n, dtype=float)
    contact = np.asarray(contact_force_n, dtype=float)
    on = np.flatnonzero(np.isin(seg, list(segments)))
    if on.size == 0:
        return []
    pad = round(PAD_S / dt)
    a, b = max(0, int(on[0]) - pad), min(seg.size, int(on[-1]) + 1 + pad)
    band = band_force_n(reading[a:b], dt)
    threshold = oscillation_threshold_n(sensor, dt)
    out = []
    for k in segments:
        rows = np.flatnonzero(seg[a:b] == k)
        if rows.size == 0:
            continue
        force = contact[a:b][rows]
        lost = int(np.count_nonzero(contact_lost(force)))
        rms = float(np.sqrt(np.mean(band[rows] ** 2)))
        least = float(np.nanmin(force)) if np.any(np.isfinite(force)) else math.nan
        out.append(StrokeVerdict(int(k), judge(rms, lost, threshold), rms, threshold, lost, least))
    return out


def run_verdict(stroke_verdicts: list[StrokeVerdict], diverged: bool = False) -> str:
    """A run's verdict: DIVERGED when its simulation diverged, else its worst stroke's."""
    return DIVERGED if diverged else worst([s.verdict for s in stroke_verdicts])


def verdict_of_metrics(metrics: Mapping, scale: float = 1.0) -> str | None:
    """A run's verdict again from its recorded scalars ("diverged", "contact_lost_ms",
    "band_rms_max_n", "oscillation_threshold_n"), with the threshold × `scale`; None for a record
    made before the verdict recorded its band RMS."""
    if metrics.get("diverged"):
        return DIVERGED
    rms, threshold = metrics.get("band_rms_max_n"), metrics.get("oscillation_threshold_n")
    if threshold is None:
        return None
    return judge(rms, int(metrics.get("contact_lost_ms") or 0), float(threshold), scale)


def unstable(verdict: str) -> bool:
    """Not STABLE: oscillating, lost contact or diverged."""
    return verdict != STABLE


def window(reading_n: np.ndarray, contact_force_n: np.ndarray, threshold_n: float, dt: float) -> tuple[str, float]:
    """(verdict, band RMS in N) of a window of steps judged as one stroke (the held second before the
    strokes): the band-pass runs over the window alone."""
    band = band_force_n(np.asarray(reading_n, dtype=float), dt)
    rms = float(np.sqrt(np.mean(band**2))) if band.size else math.nan
    lost = int(np.count_nonzero(contact_lost(contact_force_n)))
    return judge(rms, lost, threshold_n), rms


def band_facts() -> dict[str, float]:
    """The band a run's verdict was judged in, for the run's record (a report reads it from there)."""
    return {"verdict_mode_hz": MODE_HZ, "verdict_band_lo_hz": BAND_HZ[0], "verdict_band_hi_hz": BAND_HZ[1]}


def definition_text(threshold_n: float, run: Mapping | None = None) -> str:
    """The verdict's definition in words, with a run's threshold and the band its record names
    (`band_facts`; a record without them, made before they were kept, gets the band without numbers)."""
    keys = ("verdict_band_lo_hz", "verdict_band_hi_hz", "verdict_mode_hz")
    band = ""
    if run is not None and all(run.get(k) is not None for k in keys):
        lo, hi, mode = (float(run[k]) for k in keys)
        band = f" ({lo:.1f}–{hi:.1f} Hz, one octave around {mode:g} Hz)"
    return (
        "Lost contact: the true contact force reached 0 at a 1 ms step of the stroke. Oscillating: the F/T "
        f"reading's RMS in the contact mode's band{band} over the stroke is at least {threshold_n:.2f} N, the "
        "sensor's floor (the RMS its noise "
        "and sinusoid leave on a steady reading after its low-pass): the contact mode is louder than "
        "everything the sensor adds. Stable: neither. A run takes its worst stroke's verdict."
    )
