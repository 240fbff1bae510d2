"""Cell results that survive a kill: one JSON line per finished cell in `DIR/cells.jsonl`.

A line is appended (and flushed to disk) as soon as a cell finishes, so a killed sweep keeps
everything it finished; a re-run reads the file and skips those cells. A half-written last line
(the process died while writing: no newline at its end) is cut off the file when it is opened, so
the next record starts on a line of its own, and that cell runs again. `write_csv` flattens the
records for pandas.
"""

from __future__ import annotations

import csv
import hashlib
import json
import os
from pathlib import Path


def cell_key(experiment: str, params: dict, seed: int) -> str:
    """Hash of the experiment, the cell's parameters and its seed: the identity used for resume."""
    text = json.dumps({"experiment": experiment, "params": params, "seed": int(seed)}, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


class CellStore:
    """The append-only cell log of one sweep directory."""

    def __init__(self, path: Path):
        self.path = Path(path)
        self.records: dict[str, dict] = {}
        self.torn = 0  # bytes of a half-written last line cut off when the file was opened
        if self.path.exists():
            self._cut_torn_tail()
            for line in self.path.read_text().splitlines():
                try:
                    rec = json.loads(line)
                except json.JSONDecodeError:
                    continue  # a line cut short by a kill
                if isinstance(rec, dict) and "key" in rec:
                    self.records[rec["key"]] = rec  # the latest record of a key wins

    def _cut_torn_tail(self) -> None:
        """Truncate the file after its last newline (a kill during a write leaves a line without one)."""
        data = self.path.read_bytes()
        if not data or data.endswith(b"\n"):
            return
        keep = data.rfind(b"\n") + 1
        with self.path.open("r+b") as f:
            f.truncate(keep)
            f.flush()
            os.fsync(f.fileno())
        self.torn = len(data) - keep

    def finished(self, key: str, retry_failed: bool) -> bool:
        """True when the cell need not run again (done, or failed and failures are not retried)."""
        rec = self.records.get(key)
        if rec is None:
            return False
        return rec.get("status") == "ok" or not retry_failed

    def append(self, record: dict) -> None:
        """Write one finished cell at once (flushed and synced) and remember it."""
        self.path.parent.mkdir(parents=True, exist_ok=True)
        line = json.dumps(record, sort_keys=True, allow_nan=False)
        with self.path.open("a") as f:
            f.write(line + "\n")
            f.flush()
            os.fsync(f.fileno())
        self.records[record["key"]] = record


def write_csv(path: Path, records: list[dict]) -> None:
    """One row per cell: params as `p_NAME`, metrics as `m_NAME`, plus seed, status, timing, worker."""
    base = ["key", "experiment", "seed", "status", "stable", "wall_s", "cpu_s", "worker", "code", "commit", "error"]
    params = sorted({k for r in records for k in r.get("params", {})})
    metrics = sorted({k for r in records for k in (r.get("metrics") or {})})
    header = base + [f"p_{k}" for k in params] + [f"m_{k}" for k in metrics]
    with Path(path).open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(header)
        for r in records:
            m = r.get("metrics") or {}
            row = [r.get(k) for k in base]
            row += [r.get("params", {}).get(k) for k in params]
            row += [m.get(k) for k in metrics]
            writer.writerow(["" if v is None else v for v in row])
