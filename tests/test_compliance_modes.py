"""Compliance modes [C] §IV-E: Γ₀ = I lets the joints yield to a TCP push while the TCP holds."""

from __future__ import annotations

import numpy as np
import pytest

from app.headless.experiments.c_common import qp_session
from app.scenarios.compliance import ComplianceScenario


def _tcp_push(mode: str) -> tuple[float, float]:
    """(max TCP displacement m, max posture deviation rad) over the first push (0.5–1.0 s) + 0.3 s."""
    scenario = ComplianceScenario(mode)
    session = qp_session(scenario)
    session.reset()
    p0 = session.target_fn(0.0).position.copy()
    q0 = session.world.q
    disp = post = 0.0
    for _ in range(1300):
        rec = session.step()
        disp = max(disp, float(np.linalg.norm(session.dyn.tcp_position_world - p0)))
        post = max(post, float(np.linalg.norm(rec.q - q0)))
    return disp, post


def test_nullspace_compliance_moves_the_joints_not_the_tcp():
    d_stiff, p_stiff = _tcp_push("stiff")
    d_null, p_null = _tcp_push("nullspace")
    assert d_stiff < 1e-3 and d_null < 1e-3  # the pose task holds (Γ = 0) in both
    assert p_null > 20 * p_stiff  # but with Γ₀ = I the posture yields (Γ = I: tests/test_compliance_qp.py)


def test_unknown_mode_is_rejected():
    with pytest.raises(ValueError, match="mode"):
        ComplianceScenario("floppy")
