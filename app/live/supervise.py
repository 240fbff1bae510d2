"""Error boundaries for the display path: a failing stage is skipped, reported rarely, and retried.

A frame goes through stages (on the loop thread: capture, twin poses, build; on the publisher thread:
notify, scene, panels, plots). Each runs inside `Stages.run(name, fn)`: an exception skips that stage
for that frame only (the others still run, and the stage is tried again with the next frame, so it
comes back by itself once the error stops) and is reported through `report` once per distinct error
per `ErrorBudget.period_s` (60 s), never more. The budget remembers at most `capacity` distinct errors
(oldest forgotten first), so errors whose text varies every frame cost bounded memory and at most
`capacity` reports per period. `rearm()` (a preset switch) forgets them all: the next failure is
reported at once.
"""

from __future__ import annotations

import time
import traceback
from collections import Counter, OrderedDict
from collections.abc import Callable
from typing import Any, TypeVar

T = TypeVar("T")

REPORT_PERIOD_S = 60.0  # one report per distinct error per minute
BUDGET_CAPACITY = 32  # distinct errors remembered (and so reported) per period at most


def error_text(exc: BaseException) -> str:
    """`Type: message` on one line (at most 200 characters)."""
    text = " ".join(f"{type(exc).__name__}: {exc}".split())
    return text if len(text) <= 200 else text[:197] + "..."


class ErrorBudget:
    """Says whether an error should be reported: each distinct key once per `period_s`, and no more
    than `capacity` keys per period (memory and reports stay bounded whatever the errors are)."""

    def __init__(
        self,
        period_s: float = REPORT_PERIOD_S,
        capacity: int = BUDGET_CAPACITY,
        clock: Callable[[], float] = time.monotonic,
    ):
        self.period_s = period_s
        self.capacity = capacity
        self._clock = clock
        self._seen: OrderedDict[str, float] = OrderedDict()  # key → when it was last reported
        self.suppressed = 0  # errors not reported since the budget was built

    def __len__(self) -> int:
        return len(self._seen)

    def should_report(self, key: str) -> bool:
        """True if `key` has not been reported within the period (and it is now counted as reported)."""
        now = self._clock()
        while self._seen:  # forget what is older than the period (oldest first)
            oldest, at = next(iter(self._seen.items()))
            if now - at < self.period_s:
                break
            del self._seen[oldest]
        if key in self._seen or len(self._seen) >= self.capacity:
            self.suppressed += 1
            return False
        self._seen[key] = now
        return True

    def rearm(self) -> None:
        """Forget every reported error: the next one of each is reported at once."""
        self._seen.clear()


class Stages:
    """One error boundary per named stage; see the module docstring. `report(stage, text)` is called
    for the errors the budget lets through (the traceback goes to stderr then too)."""

    def __init__(self, report: Callable[[str, str], None], budget: ErrorBudget | None = None):
        self.report = report
        self.budget = budget if budget is not None else ErrorBudget()
        self.failures: Counter[str] = Counter()  # failed runs per stage
        self.runs: Counter[str] = Counter()  # successful runs per stage
        self.failing: set[str] = set()  # the stages whose last run failed
        self.last_error: dict[str, str] = {}  # stage → its last failure's one-line text

    def run(self, stage: str, fn: Callable[..., T], *args: Any, default: Any = None) -> T | Any:
        """`fn(*args)`, or `default` when it raises (reported per the budget)."""
        try:
            result = fn(*args)
        except Exception as exc:
            self.failures[stage] += 1
            self.failing.add(stage)
            text = error_text(exc)
            self.last_error[stage] = text
            if self.budget.should_report(f"{stage}: {text}"):
                traceback.print_exc()
                try:
                    self.report(stage, text)
                except Exception:  # the report itself must not escape the boundary
                    traceback.print_exc()
            return default
        self.runs[stage] += 1
        self.failing.discard(stage)
        return result

    def rearm(self) -> None:
        """A preset switch: report the next failure of every stage at once."""
        self.budget.rearm()
