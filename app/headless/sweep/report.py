"""`DIR/report.html` of a sweep: maps over the first two grid axes, lines over a single axis.

Each headline metric gets a heat map over (axis 1 → x, axis 2 → y), the mean over seeds in
each cell, one panel per combination of any further axes; an × marks a cell whose seeds
disagree on stability, a ! a cell with a failed run. A single-axis grid gets line plots (mean
± sd over seeds). Figures are PNGs written beside the report and embedded in it.
An experiment may add layers to its maps (`SweepExperiment.overlay`) and a note.
"""

from __future__ import annotations

import base64
import html
import itertools
import math
from collections.abc import Callable
from pathlib import Path

import numpy as np

from app.core.provenance import code_text
from app.headless.sweep.grid import Axis

STABLE = "stable"  # the per-cell stability flag, mapped as the fraction of stable seeds


def _value(rec: dict, metric: str) -> float:
    if rec.get("status") != "ok":
        return math.nan
    v = rec.get("stable") if metric == STABLE else (rec.get("metrics") or {}).get(metric)
    if isinstance(v, bool):
        return float(v)
    if isinstance(v, int | float) and math.isfinite(v):
        return float(v)
    return math.nan


def _label(v) -> str:
    if isinstance(v, bool):
        return "on" if v else "off"
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)


def _by_params(records: list[dict], names: list[str]) -> dict[tuple, list[dict]]:
    out: dict[tuple, list[dict]] = {}
    for r in records:
        out.setdefault(tuple(r["params"][n] for n in names), []).append(r)
    return out


def _cell_summary(recs: list[dict], metric: str) -> tuple[float, float, bool, bool]:
    """(mean, sd over seeds, seeds disagree on stability, a run failed)."""
    vals = np.array([_value(r, metric) for r in recs])
    vals = vals[np.isfinite(vals)]
    mean = float(np.mean(vals)) if vals.size else math.nan
    sd = float(np.std(vals, ddof=1)) if vals.size > 1 else 0.0
    flags = {r.get("stable") for r in recs if r.get("status") == "ok"}
    return mean, sd, len(flags) > 1, any(r.get("status") != "ok" for r in recs)


def _heatmaps(overlay: Callable | None, metric: str, axes: list[Axis], records: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ax_x, ax_y, rest = axes[0], axes[1], axes[2:]
    panels = list(itertools.product(*(a.values for a in rest))) or [()]
    ncol = min(3, len(panels))
    nrow = math.ceil(len(panels) / ncol)
    width = min(5.2 + 0.18 * len(ax_x), 9.0)
    fig, grid = plt.subplots(nrow, ncol, figsize=(width * ncol, 0.6 + (1.6 + 0.35 * len(ax_y)) * nrow), squeeze=False)
    groups = _by_params(records, [a.name for a in axes])
    all_vals = [v for r in records if math.isfinite(v := _value(r, metric))]
    vmin, vmax = (0.0, 1.0) if metric == STABLE else (min(all_vals, default=0.0), max(all_vals, default=1.0))
    if vmin == vmax:
        vmin, vmax = vmin - 0.5, vmax + 0.5
    cmap = "RdYlGn" if metric == STABLE else "viridis"
    image = None
    for idx, combo in enumerate(panels):
        ax = grid[idx // ncol][idx % ncol]
        z = np.full((len(ax_y), len(ax_x)), np.nan)
        marks = []
        for i, yv in enumerate(ax_y.values):
            for j, xv in enumerate(ax_x.values):
                recs = groups.get((xv, yv, *combo), [])
                if not recs:
                    continue
                mean, _, disagree, failed = _cell_summary(recs, metric)
                z[i, j] = mean
                if disagree:
                    marks.append((j, i, "x"))
                if failed:
                    marks.append((j, i, "!"))
        image = ax.imshow(z, origin="lower", aspect="auto", cmap=cmap, vmin=vmin, vmax=vmax, interpolation="nearest")
        if len(ax_x) * len(ax_y) <= 64:
            for i in range(len(ax_y)):
                for j in range(len(ax_x)):
                    if np.isfinite(z[i, j]):
                        light = (z[i, j] - vmin) / (vmax - vmin) > 0.6 if metric != STABLE else True
                        color = "k" if light else "w"
                        ax.text(j, i, f"{z[i, j]:.3g}", ha="center", va="center", fontsize=7, color=color)
        for j, i, m in marks:
            if m == "x":
                ax.plot(j, i, marker="x", color="k", ms=9, mew=2)
            else:
                ax.text(j + 0.3, i + 0.25, "!", color="red", fontsize=11, fontweight="bold")
        step = max(1, len(ax_x) // 12)
        ax.set_xticks(range(0, len(ax_x), step), [_label(v) for v in ax_x.values[::step]], fontsize=8)
        ax.set_yticks(range(len(ax_y)), [_label(v) for v in ax_y.values], fontsize=8)
        ax.set_xlabel(ax_x.name)
        ax.set_ylabel(ax_y.name)
        title = ", ".join(f"{a.name} = {_label(v)}" for a, v in zip(rest, combo, strict=True))
        ax.set_title(title or metric, fontsize=9)
        if overlay is not None:
            overlay(ax, axes, [r for r in records if tuple(r["params"][a.name] for a in rest) == tuple(combo)])
    for idx in range(len(panels), nrow * ncol):
        grid[idx // ncol][idx % ncol].axis("off")
    if image is not None:
        fig.colorbar(image, ax=grid.ravel().tolist(), label=metric, shrink=0.9)
    fig.suptitle(f"{metric} (mean over seeds; × seeds disagree on stability, ! a run failed)", fontsize=10, y=1.03)
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)


def _lines(metric: str, axis: Axis, records: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    groups = _by_params(records, [axis.name])
    numeric = all(isinstance(v, int | float) and not isinstance(v, bool) for v in axis.values)
    xs = list(axis.values) if numeric else list(range(len(axis)))
    stats = [_cell_summary(groups.get((v,), []), metric) for v in axis.values]
    fig, ax = plt.subplots(figsize=(6.4, 3.8))
    means = [s[0] for s in stats]
    ax.errorbar(xs, means, yerr=[s[1] for s in stats], marker="o", capsize=3, lw=1.2)
    for x, (m, _, disagree, failed) in zip(xs, stats, strict=True):
        if disagree:
            ax.plot(x, m, marker="x", color="k", ms=10, mew=2)
        if failed:
            ax.annotate("!", (x, m), color="red", fontweight="bold")
    if not numeric:
        ax.set_xticks(xs, [_label(v) for v in axis.values])
    ax.set_xlabel(axis.name)
    ax.set_ylabel(metric)
    ax.set_title(f"{metric}: mean ± sd over seeds (× seeds disagree on stability)", fontsize=9)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _img(path: Path) -> str:
    data = base64.b64encode(path.read_bytes()).decode()
    return f"<figure><img src='data:image/png;base64,{data}' alt='{html.escape(path.name)}'></figure>"


def _table(header: list[str], rows: list[list]) -> str:
    head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
    body = "".join(
        "<tr>" + "".join(f"<td>{html.escape(v if isinstance(v, str) else _label(v))}</td>" for v in r) + "</tr>"
        for r in rows
    )
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def write_report(
    out: Path,
    experiment,
    axes: list[Axis],
    seeds: int,
    records: list[dict],
    invocations: list[dict],
    facts: dict | None = None,
) -> Path:
    """Figures and `out/report.html` for the grid's finished cells; `facts`: the model's figures the
    experiment's notes print, as sweep.json keeps them (`SweepExperiment.model_facts`)."""
    out = Path(out)
    figures = []
    for metric in experiment.map_metrics:
        path = out / f"map_{metric}.png"
        if len(axes) >= 2:
            _heatmaps(experiment.overlay, metric, axes, records, path)
        else:
            _lines(metric, axes[0], records, path)
        figures.append((metric, path))
    ok = [r for r in records if r.get("status") == "ok"]
    failed = [r for r in records if r.get("status") != "ok"]
    cpu = sum(float(r.get("cpu_s") or 0.0) for r in records)
    cell_wall = sum(float(r.get("wall_s") or 0.0) for r in records)
    wall = sum(float(i.get("wall_s", 0.0)) for i in invocations)
    workers = sorted({r.get("worker", "?") for r in records})
    # older records carry the source hash alone ("code"), newer ones the commit beside it
    codes = sorted(
        {
            code_text({"commit": r["commit"], "source": r["code"]} if "commit" in r else r["code"])
            for r in records
            if r.get("code")
        }
    )
    total = math.prod(len(a) for a in axes) * seeds
    grid_rows = [[a.name, len(a), ", ".join(_label(v) for v in a.values)] for a in axes]
    runs_rows = [
        [
            i.get("started", ""),
            i.get("engine", ""),
            i.get("ran", 0),
            i.get("failed", 0),
            i.get("skipped", 0),
            f"{i.get('wall_s', 0.0):.1f}",
        ]
        for i in invocations
    ]
    means = experiment.stable_means
    stable_means = means if isinstance(means, str) else means(records)
    setup = (
        f"<p>Experiment <b>{html.escape(experiment.name)}</b>, {total} cells "
        f"({' × '.join(str(len(a)) for a in axes)} grid × {seeds} seed{'s' if seeds > 1 else ''}); "
        f"{len(ok)} finished, {len(failed)} failed, {total - len(records)} not run. "
        f"Stable means: {html.escape(stable_means)}."
        + ("" if experiment.seeded else " This experiment does not depend on the seed: seeds repeat the same run.")
        + "</p>"
        f"<p>Total CPU time of the cells {cpu:.1f} s (their wall time {cell_wall:.1f} s); wall time of the sweep "
        f"{wall:.1f} s over {len(invocations)} invocation(s); {len(workers)} worker process(es); code version(s): "
        f"{html.escape('; '.join(codes) or 'not recorded')}.</p>"
    )
    sections = [
        ("Setup", setup),
        ("Grid", _table(["parameter", "values", ""], grid_rows)),
        ("Invocations", _table(["started (UTC)", "engine", "ran", "failed", "resumed", "wall s"], runs_rows)),
    ]
    sections += [(f"Map: {m}" if len(axes) >= 2 else f"Line: {m}", _img(p)) for m, p in figures]
    if experiment.report_notes is not None:
        sections.append(("Notes", experiment.report_notes(axes, records, facts)))
    if getattr(experiment, "report_files", None) is not None:
        sections.append(("The map", experiment.report_files(out, records, facts, invocations)))
    if failed:
        rows = [
            [", ".join(f"{k}={_label(v)}" for k, v in r["params"].items()), r["seed"], r.get("error", "")]
            for r in failed
        ]
        sections.append(("Failed cells (re-run with --retry-failed)", _table(["parameters", "seed", "error"], rows)))
    parts = [
        "<!doctype html><html><head><meta charset='utf-8'>",
        f"<title>sweep {html.escape(experiment.name)}</title>",
        "<style>body{font-family:sans-serif;max-width:1200px;margin:2em auto;line-height:1.45}"
        "table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #ccc;padding:3px 8px}"
        "th{background:#f4f4f4}img{max-width:100%}</style></head><body>",
        f"<h1>Sweep: {html.escape(experiment.name)}</h1>",
    ]
    parts += [f"<h2>{html.escape(h)}</h2>{b}" for h, b in sections]
    parts.append("</body></html>")
    path = out / "report.html"
    path.write_text("\n".join(parts))
    return path
