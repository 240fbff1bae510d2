"""The polish experiment's friction-regularisation check: a W_j hold re-measured at each v_ε."""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from app.scenarios import polish_stroke as stroke_module
from app.scenarios.polish import PolishScenario

V_EPS_CHECK_M_PER_S = (0.001, 0.002, 0.01)  # friction regularisation re-measured each run (W_j hold, μ = 1)
V_EPS_HOLD_S = 3.0
V_EPS_MU = 1.0  # the friction coefficient of that check


def v_eps_check(v_eps: float, seed: int = 0, settings: Iterable[Iterable] = ()) -> dict:
    """Force-error STD (true contact force) of a W_j hold at μ = V_EPS_MU with friction regularised at v_ε;
    `settings` (group, field, value) are set first (the experiment's --set)."""
    from app.core.session import Session

    session = Session(PolishScenario(mu=V_EPS_MU), seed=seed)
    for group, field, value in settings:
        session.set_param(group, field, value)
    session.set_param("nullspace", "objective", "j")
    session.set_param("contact", "v_eps_m_per_s", v_eps)
    f: list[float] = []
    res = session.run(
        stroke_module.CONTACT_TIME_S + V_EPS_HOLD_S,
        record=lambda r: f.append(r.signals["contact_force_n"]) if r.t >= stroke_module.CONTACT_TIME_S else None,
    )
    arr = np.asarray(f)
    return {
        "v_eps_m_per_s": v_eps,
        "force_std_n": float(np.std(arr)),
        "lost_ms": int(np.sum(arr <= 0)),
        "stop": res.stop,
        "mu": float(session.params()["contact"].mu),  # type: ignore[attr-defined]
        "hold_s": V_EPS_HOLD_S,
        "objective": "j",
        "implicit_friction": bool(session.environment.contact.implicit),  # type: ignore[attr-defined]
    }
