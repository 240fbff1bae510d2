"""The force-loop stability margin (control.margin) against short closed-loop simulations."""

from __future__ import annotations

import numpy as np
import pytest

from app.core.session import Session
from app.headless.experiments.polish import peak_speed
from app.scenarios import polish as P
from app.scenarios import polish_stroke as PS
from control.coupling import POLISH_SUBSPACES
from control.gains import MotionForceGains
from control.margin import ContactLoop, force_loop_margin, posture_margin, step_matrix
from control.model import RobotModel

STRETCH = PS.friction_direction(1.5 * PS.SEGMENT_DURATION_S)
RETRACT = PS.friction_direction(0.5 * PS.SEGMENT_DURATION_S)


def _lambda(rizon, swivel_deg: float) -> np.ndarray:
    model = RobotModel(rizon.model)
    q = P.PolishScenario(hold_swivel_deg=swivel_deg).initial_q(rizon)
    return model.compute(q, np.zeros(7)).Lambda


def test_without_friction_the_loop_is_the_lagged_force_loop_and_the_sign_of_p_d_matters(rizon):
    """μ = 0: the margin does not depend on the posture's coupling (the K_f^p lag alone sets the
    critical K_f^d, ≈ 65 N s/m here); with μ = 1 the stretching direction (P_d·f̂ > 0) needs more
    K_f^d than the retracting one (P_d·f̂ < 0) at the Fig. 6a start."""
    L = _lambda(rizon, 0.0)
    crit0 = [
        force_loop_margin(L, POLISH_SUBSPACES, MotionForceGains(), ContactLoop(mu=0.0), d).kd_critical
        for d in (STRETCH, RETRACT)
    ]
    assert crit0[0] == pytest.approx(crit0[1], abs=1.0) and 30.0 < crit0[0] < 120.0
    s = force_loop_margin(L, POLISH_SUBSPACES, MotionForceGains(), ContactLoop(mu=1.0), STRETCH)
    r = force_loop_margin(L, POLISH_SUBSPACES, MotionForceGains(), ContactLoop(mu=1.0), RETRACT)
    assert s.directional_coupling > 0.5 > -0.5 > r.directional_coupling
    assert s.kd_critical is not None and r.kd_critical is not None and s.kd_critical > r.kd_critical + 100.0
    # the step map is the simulation's: a stable map has spectral radius < 1 exactly when rate > 0
    phi = step_matrix(L, POLISH_SUBSPACES, MotionForceGains(), ContactLoop(mu=1.0), STRETCH)
    assert phi.shape == (15, 15) and (np.max(np.abs(np.linalg.eigvals(phi))) < 1.0) == (s.rate_per_s > 0)


def _advance_reference(L, gains, loop, f_hat, state):
    """One closed-loop step of the linearised polish loop for one state (δx, δẋ, y_{k−1}), written
    out per state: the reference the column-at-once `step_matrix` is checked against."""
    from control.coupling import coupling_terms

    sub = POLISH_SUBSPACES
    f_hat = f_hat / np.linalg.norm(f_hat)
    v0 = -loop.speed_m_s * f_hat
    s = np.sqrt(v0 @ v0 + loop.v_eps_m_per_s**2)
    dFt_dv = -loop.mu * loop.normal_force_n * (np.eye(2) / s - np.outer(v0, v0) / s**3)
    dFt_dFn = -loop.mu * v0 / s
    L_inv = np.linalg.inv(L)
    implicit = np.linalg.inv(np.eye(2) - loop.dt * dFt_dv @ L_inv[:2, :2])  # backward-Euler friction
    dFt_dv, dFt_dFn = implicit @ dFt_dv, implicit @ dFt_dFn
    terms = coupling_terms(L, L_inv, sub, exact_inverse=False)
    m_idx, f_idx = list(sub.motion_axes), list(sub.force_axes)
    kp = np.asarray(gains.motion_kp)[m_idx]
    kd = 2.0 * np.asarray(gains.motion_zeta)[m_idx] * np.sqrt(kp * np.diag(terms.A))
    alpha = 1.0 - np.exp(-2.0 * np.pi * loop.sensor_cutoff_hz * loop.dt)
    x, dx, y_prev = state[:6], state[6:12], state[12:15]
    f_env = np.zeros(6)
    f_env[2] = -loop.stiffness_n_per_m * x[2]
    f_env[:2] = dFt_dFn * f_env[2] + dFt_dv @ dx[:2]
    y = y_prev + alpha * (f_env[:3] - y_prev)
    u_m = -kp * x[m_idx] - kd * dx[m_idx]
    F = np.zeros(6)
    F[m_idx] = u_m
    F[f_idx] = gains.force_kp * y[2] - gains.force_kd * dx[2]
    if gains.shaping:
        y_m = np.zeros(len(m_idx))
        y_m[m_idx.index(0)], y_m[m_idx.index(1)] = y[0], y[1]
        F[f_idx] += terms.P_d @ (u_m + y_m)
    dx_new = dx + loop.dt * (L_inv @ (F + f_env))
    return np.concatenate([x + loop.dt * dx_new, dx_new, y])


@pytest.mark.parametrize("shaping", [True, False])
def test_step_matrix_columns_are_single_state_steps(rizon, shaping):
    """Φ's column j is one loop step from the unit state e_j (relative 1e-12), at two postures and
    random states: Φ s equals the step from s."""
    gains = MotionForceGains(shaping=shaping)
    loop = ContactLoop(mu=0.7)
    rng = np.random.default_rng(3)
    for swivel in (0.0, -60.0):
        L = _lambda(rizon, swivel)
        phi = step_matrix(L, POLISH_SUBSPACES, gains, loop, STRETCH)
        for s in [*np.eye(15)[::4], *rng.normal(size=(3, 15))]:
            ref = _advance_reference(L, gains, loop, STRETCH, s)
            assert np.max(np.abs(phi @ s - ref)) <= 1e-12 * np.max(np.abs(ref))


def _loses_contact(swivel_deg: float, kd: float, delay: int) -> bool:
    """Hold the posture (W_j on it), press 20 N at μ = 1 with the F/T reading `delay` periods old,
    then S1 (retract) and S2 (stretch)."""
    session = Session(P.PolishScenario(mu=1.0, hold_swivel_deg=swivel_deg), seed=0)
    session.set_param("motion_force", "force_kd", kd)
    session.set_param("sensor", "reading_delay_steps", delay)
    clock = session.environment.clock  # type: ignore[attr-defined]
    lost = []
    session.run(PS.CONTACT_TIME_S + 0.3, record=lambda r: lost.append(r.signals["contact_force_n"] <= 0 and r.t > 0.5))
    clock.start_now(session.world.time)
    res = session.run(2 * PS.SEGMENT_DURATION_S, record=lambda r: lost.append(r.signals["contact_force_n"] <= 0))
    return res.stop == "diverged" or any(lost)


@pytest.mark.parametrize(("swivel_deg", "delay"), [(0.0, 0), (-82.3, 0), (0.0, 1)])
def test_margin_sign_predicts_contact_loss_within_15_percent_of_the_boundary(rizon, swivel_deg, delay):
    """Sweep K_f^d through the predicted boundary at two postures (the Fig. 6a start, where the
    stretching segment decides, and the mirror W_a minimum, where the rest at the segment ends
    decides), with the same-step reading and, at the start, one period of sensing delay (the
    boundary moves up with it): 15 % below it the short run loses contact, 15 % above it it stays
    on the table."""
    L = _lambda(rizon, swivel_deg)
    loop = ContactLoop(mu=1.0, speed_m_s=peak_speed(), sensing_delay_steps=delay)
    boundary = posture_margin(L, POLISH_SUBSPACES, MotionForceGains(), loop, [STRETCH, RETRACT]).kd_critical
    assert 100.0 < boundary < 300.0
    assert _loses_contact(swivel_deg, 0.85 * boundary, delay)
    assert not _loses_contact(swivel_deg, 1.15 * boundary, delay)
