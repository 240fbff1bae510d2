"""The plots' decimated window of the step log: a column kept by peak (the deflections) reaches the
largest magnitude of the rows each sample stands for, wherever the sampling grid falls; the others are
the sampled rows themselves."""

import numpy as np
import pytest

from app.core.session import StepRecord
from app.core.steplog import StepLog
from control.executor import TaskTarget

N = 7
DT = 1e-3


def _target() -> TaskTarget:
    return TaskTarget(position=np.zeros(3), rotation=np.eye(3))


def _log(values: np.ndarray, capacity: int = 60_000) -> StepLog:
    log = StepLog(N, capacity=capacity)
    target = _target()
    z = np.zeros(N)
    for k, v in enumerate(values):
        log.append(
            StepRecord(k * DT, z, z, z, np.zeros(6), target, False, {"elbow_dev_mm": float(v), "other": float(v)})
        )
    return log


@pytest.mark.parametrize("rows", [1000, 1007, 1013, 1019])  # the newest row moves against the peak
def test_a_peak_column_reaches_the_peak_of_every_row_and_the_others_are_sampled(rows):
    t = np.arange(rows) * DT
    push = 29.44 * np.exp(-(((t - 0.5) / 0.03) ** 2))  # a 30 ms wide deflection peak at 0.5 s
    w = _log(push).window(2.0, DT, every=20, peaks=("elbow_dev_mm",))
    assert np.max(w["elbow_dev_mm"]) == pytest.approx(push.max(), abs=1e-12)
    i = np.rint(w["t"] / DT).astype(int)
    np.testing.assert_array_equal(w["other"], push[i])  # not a peak column: the sampled rows
    assert i[-1] == rows - 1  # the newest row last
    assert np.all((i[:-1] + 1) % 20 == 0)  # the others on the log's fixed grid: rows 19, 39, 59, …
    # each kept value is the largest in magnitude of the rows its sample stands for (after the previous)
    for k, end in enumerate(i):
        span = push[max(0, end - 19 if k == 0 else i[k - 1] + 1) : end + 1]
        assert w["elbow_dev_mm"][k] == pytest.approx(span[np.argmax(np.abs(span))], abs=1e-12)


def test_the_samples_stay_on_their_rows_from_one_window_to_the_next():
    """Two windows taken 7 rows apart sample the same rows (a trace does not shimmer as frames go by),
    so a peak inside a push window of whole grid cells is in the window's samples however it is cut."""
    values = np.sin(np.arange(2000) * 0.01)
    log = _log(values)
    a = log.window(1.0, DT, every=20)
    for _ in range(7):
        log.append(StepRecord(log.count * DT, *(np.zeros(N),) * 3, np.zeros(6), _target(), False, {}))
    b = log.window(1.0, DT, every=20)
    shared = np.intersect1d(np.rint(a["t"][:-1] / DT), np.rint(b["t"][:-1] / DT))
    assert len(shared) >= 45  # all but the ends of the 50 grid samples a second holds


def test_a_peak_column_keeps_a_negative_extreme_and_ignores_rows_no_longer_held():
    values = np.zeros(300)
    values[95] = -5.0  # overwritten once the ring holds only the last 200 rows
    values[250] = -3.0
    w = _log(values, capacity=200).window(1.0, DT, every=20, peaks=("elbow_dev_mm",))
    assert w["elbow_dev_mm"].min() == pytest.approx(-3.0) and np.rint(w["t"][0] / DT) >= 100
