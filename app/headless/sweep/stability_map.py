"""The stability map's report: held swivel × latency × μ, the run's verdict beside the margin's.

From the finished cells of `torquelab sweep polish-map` (`app.headless.experiments.polish_map`):

- `tolerance`: per μ and held swivel, the total latency (F/T reading + drive, control periods) the
  posture tolerates: the largest L such that every cell of total latency ≤ L is stable by the one
  verdict (−1: not even without latency); None where a total below it has no finished cell.
- `DIR/stability_map.json` (`write_json`): that table and every cell's verdict and margin, the file the
  page's self-motion preview reads (docs/map.md).
- `DIR/stability_map.png` (`figure`): one panel per μ, swivel across, latency up, each cell coloured by
  its verdict, a dot where the margin predicts contact loss (h_min < 0), the postures W_j, W_a, W_d
  and the planned paths reach marked on the swivel axis.
- `section`: the report's HTML: the figure, the margin's agreement over all cells, the cell count.
"""

from __future__ import annotations

import html
import json
import math
from pathlib import Path

import numpy as np

from app.scenarios import verdict as V

SWIVEL, MU, LATENCY = "hold_swivel", "mu", "latency"
COLOURS = {V.STABLE: "#4caf50", V.OSCILLATING: "#ff9800", V.LOST: "#d32f2f", V.DIVERGED: "#212121"}
FORMAT = "torquelab stability map 1"


def latency_parts(text: str) -> tuple[int, int]:
    """ "R+D" → (reading, drive) periods."""
    r, _, d = str(text).partition("+")
    return int(r), int(d)


def latency_sorted(values) -> list[str]:
    """Latency texts by total, then by the reading's share."""
    return sorted(values, key=lambda v: (sum(latency_parts(v)), latency_parts(v)[0]))


def _ok(records: list[dict]) -> list[dict]:
    return [r for r in records if r.get("status") == "ok" and r.get("metrics")]


def tolerance(records: list[dict]) -> dict[float, dict[float, int | None]]:
    """μ → swivel → the tolerated total latency (module docstring)."""
    cells: dict[tuple[float, float], dict[int, list[bool]]] = {}
    for r in _ok(records):
        p = r["params"]
        total = sum(latency_parts(p[LATENCY]))
        cells.setdefault((float(p[MU]), float(p[SWIVEL])), {}).setdefault(total, []).append(bool(r["stable"]))
    out: dict[float, dict[float, int | None]] = {}
    for (mu, swivel), by_total in sorted(cells.items()):
        tolerated: int | None = -1
        for total in range(0, max(by_total) + 1):
            if total not in by_total:
                tolerated = None if tolerated == -1 else tolerated
                break
            if not all(by_total[total]):
                break
            tolerated = total
        out.setdefault(mu, {})[swivel] = tolerated
    return out


def agreement(records: list[dict]) -> dict:
    """The margin's prediction (h_min < 0: the tool leaves the table) against each cell's verdict: not
    stable, and lost contact alone; the cells counted in each case."""
    ok = [r["metrics"] for r in _ok(records) if r["metrics"].get("headroom_min_np") is not None]
    pred = [bool(m["margin_predicts_loss"]) for m in ok]
    unstable = [m["verdict"] != V.STABLE for m in ok]
    lost = [m["verdict"] in (V.LOST, V.DIVERGED) for m in ok]
    agree_unstable = sum(p == u for p, u in zip(pred, unstable, strict=True))
    agree_lost = sum(p == lo for p, lo in zip(pred, lost, strict=True))
    return {
        "cells": len(ok),
        "agree_unstable": agree_unstable,
        "agree_lost": agree_lost,
        "agree_unstable_share": agree_unstable / len(ok) if ok else None,
        "agree_lost_share": agree_lost / len(ok) if ok else None,
        "stable": len(ok) - sum(unstable),
        "predicted_loss": sum(pred),
        "unstable": sum(unstable),
        "lost": sum(lost),
        "oscillating": sum(m["verdict"] == V.OSCILLATING for m in ok),
        "missed": sum(u and not p for p, u in zip(pred, unstable, strict=True)),  # unstable, predicted to keep contact
        "false_alarms": sum(p and not u for p, u in zip(pred, unstable, strict=True)),
        "stopped_at_loss": sum(bool(m.get("stopped_at_loss")) for m in ok),
    }


def tolerance_rows(records: list[dict]) -> list[dict]:
    """Per μ: the swivels mapped, how many are stable without latency, the most latency any tolerates
    and where (the report's table)."""
    rows = []
    for mu, row in tolerance(records).items():
        vals = [v for v in row.values() if v is not None]
        most = max(vals) if vals else None
        rows.append(
            {
                "mu": mu,
                "swivels": len(row),
                "stable_at_0": sum(v >= 0 for v in vals),
                "most": most,
                "at": ", ".join(f"{s:+.0f}°" for s, v in row.items() if most is not None and v == most),
            }
        )
    return rows


def marked_postures() -> dict:
    """Where each objective's posture lies on the loop at the polish start pose (the model's figures,
    not the runs'): W_j holds the start, W_a and W_d end where their flow from it ends, and the two
    planned paths' swivel spans over the strokes; plus the swivels outside the joint limits."""
    import robots
    from app.headless.experiments.polish_report import scan_at_start
    from app.headless.sweep.overlays import planned_swivels, wa_basins
    from app.scenarios.polish import PolishScenario

    summary = scan_at_start()["summary"]
    facts: dict = {
        "robot": robots.load(robots.chosen("rizon4s")).name,
        "W_j_deg": float(PolishScenario().start_swivel_deg),
        "W_a_deg": float(summary["W_a"]["flow_from_start_deg"]),
        "W_a_minima_deg": [float(d) for d in wa_basins()["minima"]],  # the flow's ends from either side of the ridge
        "W_d_deg": float(summary["W_d"]["flow_from_start_deg"]),
        "infeasible": wa_basins()["infeasible"],
        "plans": {},
    }
    try:
        facts["plans"] = {c: {"lo_deg": p["lo"], "hi_deg": p["hi"]} for c, p in planned_swivels().items()}
    except ValueError:  # an arm whose table was moved to its reach: the planned cases plan on the paper's table
        pass
    return facts


def write_json(path: Path, records: list[dict], facts: dict | None, run: dict | None = None) -> dict:
    """`stability_map.json`: per μ and swivel the tolerated latency, every cell (module docstring), and
    `run`: the sweep's figures the report prints (agreement, time)."""
    ok = _ok(records)
    doc = {
        "format": FORMAT,
        "robot": (facts or {}).get("robot"),
        "latency_unit": "control periods (1 ms): F/T reading age + drive delay",
        "tolerated_means": "the largest total latency L such that every cell of total latency <= L is stable by "
        "the one verdict; -1: unstable without latency; null: a total below it has no finished cell",
        "mu": sorted({float(r["params"][MU]) for r in ok}),
        "swivel_deg": sorted({float(r["params"][SWIVEL]) for r in ok}),
        "latency": latency_sorted({str(r["params"][LATENCY]) for r in ok}),
        "tolerated": [
            {"mu": mu, "swivel_deg": sorted(row), "tolerated_periods": [row[s] for s in sorted(row)]}
            for mu, row in tolerance(records).items()
        ],
        "cells": [
            {
                "swivel_deg": float(r["params"][SWIVEL]),
                "mu": float(r["params"][MU]),
                "latency": str(r["params"][LATENCY]),
                "verdict": r["metrics"]["verdict"],
                "headroom_min_np": r["metrics"].get("headroom_min_np"),
                "margin_predicts_loss": r["metrics"].get("margin_predicts_loss"),
            }
            for r in ok
        ],
        "postures": facts or {},
        "run": run or {},
    }
    Path(path).write_text(json.dumps(doc, indent=1, allow_nan=False))
    return doc


def figure(path: Path, records: list[dict], facts: dict | None) -> None:
    """`stability_map.png` (module docstring)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Patch

    ok = _ok(records)
    mus = sorted({float(r["params"][MU]) for r in ok})
    swivels = sorted({float(r["params"][SWIVEL]) for r in ok})
    lats = latency_sorted({str(r["params"][LATENCY]) for r in ok})
    if not ok:
        return
    at = {(float(r["params"][MU]), float(r["params"][SWIVEL]), str(r["params"][LATENCY])): r["metrics"] for r in ok}
    ncol = min(2, len(mus))
    nrow = math.ceil(len(mus) / ncol)
    width = min(4.0 + 0.17 * len(swivels), 10.0)
    fig, axes = plt.subplots(nrow, ncol, figsize=(width * ncol, (1.4 + 0.32 * len(lats)) * nrow), squeeze=False)
    # the cells' width: the grid's spacing (≤ 10°, also while only some swivels are finished)
    step = min(float(np.min(np.diff(swivels))), 10.0) if len(swivels) > 1 else 10.0
    facts = facts or {}
    for k, mu in enumerate(mus):
        ax = axes[k // ncol][k % ncol]
        for j, lat in enumerate(lats):
            for s in swivels:
                m = at.get((mu, s, lat))
                if m is None:
                    continue
                ax.add_patch(
                    plt.Rectangle((s - step / 2, j - 0.5), step, 1.0, color=COLOURS.get(m["verdict"], "#9e9e9e"), lw=0)
                )
                if m.get("margin_predicts_loss"):
                    ax.plot(s, j, "o", color="k", ms=3)
        for lo, hi in facts.get("infeasible", []):
            ax.axvspan(lo, hi, color="0.6", alpha=0.35, lw=0)
        for name, style in (("W_j_deg", ":"), ("W_d_deg", "--")):
            if facts.get(name) is not None:
                ax.axvline(facts[name], color="#1565c0", lw=1.6, ls=style)
        for deg in facts.get("W_a_minima_deg", [facts["W_a_deg"]] if facts.get("W_a_deg") is not None else []):
            ax.axvline(deg, color="#1565c0", lw=1.6, ls="-")
        for p in facts.get("plans", {}).values():  # a plan that keeps one swivel: a band of 3° around it
            lo, hi = min(p["lo_deg"], p["hi_deg"] - 1.5), max(p["hi_deg"], p["lo_deg"] + 1.5)
            ax.axvspan(lo, hi, facecolor="none", edgecolor="#6a1b9a", hatch="////", lw=0.8)
        ax.set_xlim(-180.0, 180.0)
        ax.set_xticks(range(-180, 181, 60))
        ax.set_ylim(-0.5, len(lats) - 0.5)
        ax.set_yticks(range(len(lats)), [f"{lat} ({sum(latency_parts(lat))})" for lat in lats], fontsize=7)
        ax.set_xlabel("held swivel (°)", fontsize=8)
        ax.set_ylabel("latency reading+drive (total), periods", fontsize=7)
        ax.set_title(f"μ = {mu:g}", fontsize=9)
        ax.tick_params(axis="x", labelsize=7)
    for k in range(len(mus), nrow * ncol):
        axes[k // ncol][k % ncol].axis("off")
    from matplotlib.lines import Line2D

    handles: list = [Patch(color=c, label=v) for v, c in COLOURS.items()]
    handles += [
        Line2D([], [], marker="o", color="k", ls="none", ms=4, label="margin predicts contact loss (h_min < 0)"),
        Line2D([], [], color="#1565c0", ls=":", label="W_j (the start)"),
        Line2D([], [], color="#1565c0", ls="-", label="W_a minima (its flow's ends)"),
        Line2D([], [], color="#1565c0", ls="--", label="W_d flow's end"),
        Patch(facecolor="none", edgecolor="#6a1b9a", hatch="////", label="planned paths"),
        Patch(color="0.6", alpha=0.35, label="outside the joint limits"),
    ]
    fig.legend(handles=handles, loc="upper center", ncol=5, fontsize=7, frameon=False, bbox_to_anchor=(0.5, 0.0))
    fig.suptitle("Stability map: the one verdict per cell, the margin's prediction as dots", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)


def section(out: Path, records: list[dict], facts: dict | None, invocations: list[dict]) -> str:
    """Write the map's figure and JSON into `out`; the report's HTML about them."""
    from app.headless.sweep.report import _img, _table

    out = Path(out)
    ok = _ok(records)
    if not ok:
        return "<p>No finished cell yet.</p>"
    png, js = out / "stability_map.png", out / "stability_map.json"
    a = agreement(records)
    wall = sum(float(i.get("wall_s", 0.0)) for i in invocations)
    cpu = [float(r.get("cpu_s") or 0.0) for r in ok]
    rows = tolerance_rows(records)
    starts = [float(r["finished_at"]) - float(r.get("wall_s") or 0.0) for r in ok if r.get("finished_at")]
    ends = [float(r["finished_at"]) for r in ok if r.get("finished_at")]
    span = max(ends) - min(starts) if ends else 0.0  # an interrupted invocation records no wall time of its own
    figure(png, records, facts)
    run = {
        "agreement": a,
        "wall_s": wall,
        "cells_span_s": span,
        "invocations": len(invocations),
        "cpu_s_mean": float(np.mean(cpu)),
        "cpu_s_max": max(cpu),
        "tolerance_by_mu": rows,
    }
    write_json(js, records, facts, run)
    text = (
        f"<p>{len(ok)} cells finished; {wall:.1f} s of wall time in {len(invocations)} completed invocation(s), "
        f"{span:.1f} s from the first cell's start to the last cell's end; "
        f"CPU per cell {run['cpu_s_mean']:.2f} s on average (max {run['cpu_s_max']:.2f} s), counting the forked "
        f"copy each cell runs in. {a['stopped_at_loss']} cells stopped at their first lost contact.</p>"
        f"<p>Verdicts: {a['stable']} stable, {a['oscillating']} oscillating, {a['lost']} lost "
        f"contact or diverged. The margin (stroke headroom h_min at the calm pass's postures) predicts contact "
        f"loss in {a['predicted_loss']} cells. Its sign agrees with the verdict (stable or not) in "
        f"{a['agree_unstable']} of {a['cells']} cells ({100.0 * a['agree_unstable_share']:.0f} %): "
        f"{a['missed']} not stable but predicted to keep contact, {a['false_alarms']} predicted to lose it "
        f"but stable. Against lost contact alone, the event it predicts, it agrees in {a['agree_lost']} of "
        f"{a['cells']} ({100.0 * a['agree_lost_share']:.0f} %).</p>"
    )
    facts = facts or {}
    marks = [f"W_j {facts['W_j_deg']:+.0f}°"] if facts.get("W_j_deg") is not None else []
    marks += [f"{n} {facts[k]:+.0f}°" for n, k in (("W_a", "W_a_deg"), ("W_d", "W_d_deg")) if facts.get(k) is not None]
    others = [d for d in facts.get("W_a_minima_deg", []) if abs(d - float(facts.get("W_a_deg") or 1e9)) > 1.0]
    if others:
        marks.append("W_a's other minima " + ", ".join(f"{d:+.0f}°" for d in others))
    marks += [f"planned ({c}) {p['lo_deg']:+.0f}°…{p['hi_deg']:+.0f}°" for c, p in facts.get("plans", {}).items()]
    if marks:
        text += "<p>Marked on the swivel axis (the model's loop at the start pose): " + ", ".join(marks) + ".</p>"
    text += _table(
        ["μ", "swivels", "stable without latency", "most latency tolerated (periods)", "at swivels"],
        [
            [f"{r['mu']:g}", r["swivels"], r["stable_at_0"], r["most"] if r["most"] is not None else "-", r["at"]]
            for r in rows
        ],
    )
    text += _img(png)
    text += (
        f"<p>Tolerated latency per μ and swivel, and every cell: <code>{html.escape(js.name)}</code> beside "
        "this report.</p>"
    )
    return text
