"""The rows of the polish experiment's Table III ([T] §IV-B): the paper's values, what each row runs
(objective, start, shaping) and the run specs of the table and of the armature sensitivity (item 6)."""

from __future__ import annotations

from typing import Any

from app.scenarios import polish as scenario_module

PAPER_TABLE_III = {  # [T] Table III: force error MA / PTP / STD (N)
    0.25: {"j": (2.3, 18.2, 2.8), "f": (2.5, 17.4, 3.1), "a": (1.5, 10.5, 1.8), "d": (1.6, 12.2, 2.0)},
    1.0: {"j": (5.9, 72.4, 9.3), "f": (7.4, 74.0, 12.0), "a": (1.6, 10.8, 2.0), "d": (1.8, 14.1, 2.1)},
}
OBJECTIVE_NAMES = {
    "j": "W_j",
    "f": "W_f",
    "a": "W_a",
    "d": "W_d",
    "planned": "planned max(P_d·f̂, 0)²",
    "planned_a": "planned W_a",
}
MIRROR_START_DEG = scenario_module.MIRROR_START_DEG
ARMATURE_SCALES = (0.0, 0.5, 1.0, 2.0)  # item 6: the armature is not published (robots/rizon4s.toml)
ROWS: dict[str, dict[str, Any]] = {
    **{o: {"row": OBJECTIVE_NAMES[o], "objective": o} for o in ("j", "f", "a", "d")},
    "mirror": {"row": f"W_a from {MIRROR_START_DEG:+.0f}°", "objective": "a", "start_swivel_deg": MIRROR_START_DEG},
    "noshaping": {"row": "W_j, no shaping", "objective": "j", "shaping": False},
    "planned_a": {"row": OBJECTIVE_NAMES["planned_a"], "objective": "planned_a"},
    "planned": {"row": OBJECTIVE_NAMES["planned"], "objective": "planned"},
}
ROW_KEYS = tuple(ROWS)
# [T] Table III again at total latencies of one and two control periods: (F/T reading age in periods,
# torque delay in ms), the 1 ms torque delay being one period of the 1 kHz loop. The table's own runs
# are one of them (the defaults: 1 + 0); the others are the group "table_latency".
TABLE_LATENCIES = ((1, 0.0), (0, 1.0), (1, 1.0))
TABLE_LATENCY_KEYS = ("j", "f", "a", "d")


def table_specs(
    mus: list[float],
    seeds: int,
    quick: bool,
    sander: bool = False,
    only: list[str] | None = None,
    first_seed: int = 0,
) -> list[dict]:
    """Every run of the table: (row, μ, seed); `only` picks rows by key (`ROW_KEYS`)."""
    keys = list(only) if only else (["j", "f", "a", "d"] if quick else list(ROW_KEYS))
    bad = [k for k in keys if k not in ROWS]
    if bad:
        raise ValueError(f"unknown row(s) {', '.join(bad)}; choose from {', '.join(ROW_KEYS)}")
    rows = [ROWS[k] for k in keys]
    n_seeds = 1 if quick else max(1, int(seeds))
    base = {"sander": bool(sander), "start_swivel_deg": 0.0, "shaping": True, "armature_scale": 1.0, "group": "table"}
    seeds_used = range(first_seed, first_seed + n_seeds)
    return [{**base, **row, "mu": mu, "seed": s} for row in rows for mu in mus for s in seeds_used]


def table_latency_specs(
    mus: list[float],
    seeds: int,
    own: tuple[int, float],
    only: list[str] | None = None,
    first_seed: int = 0,
) -> list[dict]:
    """Table III's four paper rows (W_j, W_f, W_a, W_d; `only` keeps those among its keys) at each latency
    of `TABLE_LATENCIES` but `own`, the latency the table's runs have: (row, μ, seed) as `table_specs`,
    each with its F/T reading age and torque delay, in the group "table_latency"."""
    keys = [k for k in TABLE_LATENCY_KEYS if not only or k in only]
    base = {"sander": False, "start_swivel_deg": 0.0, "shaping": True, "armature_scale": 1.0, "group": "table_latency"}
    return [
        {**base, **ROWS[k], "mu": mu, "seed": s, "reading_delay_steps": d, "torque_delay_ms": ms}
        for d, ms in TABLE_LATENCIES
        if (d, ms) != (int(own[0]), float(own[1]))
        for k in keys
        for mu in mus
        for s in range(first_seed, first_seed + max(1, int(seeds)))
    ]


def armature_specs(mu: float = 1.0) -> list[dict]:
    """Item 6: W_j/W_f/W_a/W_d from the Fig. 6a start at μ = 1 with the armature scaled (×1 is in the table)."""
    return [
        {
            "row": f"{OBJECTIVE_NAMES[o]}, armature ×{scale:g}",
            "objective": o,
            "mu": mu,
            "seed": 0,
            "sander": False,
            "start_swivel_deg": 0.0,
            "shaping": True,
            "armature_scale": scale,
            "group": "armature",
        }
        for scale in ARMATURE_SCALES
        if scale != 1.0
        for o in ("j", "f", "a", "d")
    ]
