"""The force-loop margin with K_f^i and latency (control.margin): the delay machinery against a known
analytic limit, the direction of each effect, and the map against a step-by-step simulation."""

from __future__ import annotations

import math
from collections import deque
from dataclasses import replace

import numpy as np
import pytest

from app.scenarios import polish as P
from app.scenarios import polish_stroke as PS
from control.coupling import POLISH_SUBSPACES, coupling_terms
from control.gains import MotionForceGains
from control.margin import ContactLoop, SampledLoop, delayed_loop, force_loop_margin, step_matrix
from control.model import RobotModel

STRETCH = PS.friction_direction(1.5 * PS.SEGMENT_DURATION_S)


def _lambda(rizon, swivel_deg: float) -> np.ndarray:
    q = P.PolishScenario(hold_swivel_deg=swivel_deg).initial_q(rizon)
    return RobotModel(rizon.model).compute(q, np.zeros(7)).Lambda


def _integrator_loop(gain: float) -> SampledLoop:
    """x_{k+1} = x_k + a_k, a = −g m̂: the scalar pure-delay loop."""
    one, none = np.ones((1, 1)), np.zeros((0, 0))
    return SampledLoop(one, one, one, np.zeros((1, 1)), -gain * one, none, np.zeros((0, 1)), np.zeros((1, 0)))


def _critical_gain(delay: int, where: str) -> float:
    lo, hi = 0.0, 2.5
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        ds, da = (delay, 0) if where == "sensing" else (0, delay)
        rho = np.max(np.abs(np.linalg.eigvals(delayed_loop(_integrator_loop(mid), ds, da))))
        lo, hi = (mid, hi) if rho < 1.0 else (lo, mid)
    return lo


@pytest.mark.parametrize("where", ["sensing", "actuation"])
@pytest.mark.parametrize("delay", [0, 1, 2, 4])
def test_pure_delay_integrator_loop_is_stable_up_to_its_analytic_gain(delay, where):
    """x_{k+1} = x_k − g x_{k−d} (characteristic z^d (z − 1) + g) is stable exactly for
    0 < g < 2 sin(π / (2 (2d + 1))): 2, 1, 0.618, 0.347 for d = 0, 1, 2, 4, whichever side of the
    loop the delay sits on; the map's size is 1 + d."""
    assert delayed_loop(_integrator_loop(0.1), delay, 0).shape == (1 + delay, 1 + delay)
    assert _critical_gain(delay, where) == pytest.approx(2.0 * math.sin(math.pi / (2 * (2 * delay + 1))), abs=1e-9)


def test_integral_gain_and_each_delay_reduce_the_margin(rizon):
    """At the Fig. 6a start, μ = 1, stretching at the segments' peak speed: K_f^i = 10/s, one period
    of sensing delay and one of actuation delay each lower the decay rate and raise the critical
    K_f^d; sensing and actuation delay of one period each act alike to within 10 %."""
    L = _lambda(rizon, 0.0)
    loop = ContactLoop(mu=1.0, speed_m_s=PS.PEAK_SPEED_M_S)
    g = MotionForceGains()
    base = force_loop_margin(L, POLISH_SUBSPACES, g, loop, STRETCH)
    ki = force_loop_margin(L, POLISH_SUBSPACES, replace(g, force_ki=10.0), loop, STRETCH)
    sense = force_loop_margin(L, POLISH_SUBSPACES, g, replace(loop, sensing_delay_steps=1), STRETCH)
    act = force_loop_margin(L, POLISH_SUBSPACES, g, replace(loop, actuation_delay_steps=1), STRETCH)
    assert base.kd_critical is not None
    for m in (ki, sense, act):
        assert m.rate_per_s < base.rate_per_s - 0.1
        assert m.kd_critical is None or m.kd_critical > base.kd_critical + 1.0
    assert sense.kd_critical is not None and act.kd_critical is not None
    assert sense.kd_critical - base.kd_critical > 0.5 * (act.kd_critical - base.kd_critical)
    two = force_loop_margin(L, POLISH_SUBSPACES, g, replace(loop, sensing_delay_steps=2), STRETCH)
    assert two.rate_per_s < sense.rate_per_s


def _simulate(L, gains: MotionForceGains, loop: ContactLoop, f_hat, z0: float, steps: int) -> np.ndarray:
    """δz over `steps` of the linearised polish loop written out period by period (reading queue,
    command queue, force integral), from δz = z0 at rest with empty queues: the reference."""
    sub = POLISH_SUBSPACES
    f_hat = f_hat / np.linalg.norm(f_hat)
    v0 = -loop.speed_m_s * f_hat
    s = np.sqrt(v0 @ v0 + loop.v_eps_m_per_s**2)
    dFt_dv = -loop.mu * loop.normal_force_n * (np.eye(2) / s - np.outer(v0, v0) / s**3)
    dFt_dFn = -loop.mu * v0 / s
    L_inv = np.linalg.inv(L)
    implicit = np.linalg.inv(np.eye(2) - loop.dt * dFt_dv @ L_inv[:2, :2])
    dFt_dv, dFt_dFn = implicit @ dFt_dv, implicit @ dFt_dFn
    terms = coupling_terms(L, L_inv, sub, exact_inverse=False)
    m_idx = list(sub.motion_axes)
    kp = np.asarray(gains.motion_kp)[m_idx]
    kd = 2.0 * np.asarray(gains.motion_zeta)[m_idx] * np.sqrt(kp * np.diag(terms.A))
    alpha = 1.0 - np.exp(-2.0 * np.pi * loop.sensor_cutoff_hz * loop.dt)
    x, dx, y, integral = np.zeros(6), np.zeros(6), np.zeros(3), 0.0
    x[2] = z0
    readings = deque([np.zeros(3)] * loop.sensing_delay_steps)
    commands = deque([np.zeros(6)] * loop.actuation_delay_steps)
    out = []
    for _ in range(steps):
        out.append(x[2])
        f_env = np.zeros(6)
        f_env[2] = -loop.stiffness_n_per_m * x[2]
        f_env[:2] = dFt_dFn * f_env[2] + dFt_dv @ dx[:2]
        y = y + alpha * (f_env[:3] - y)
        readings.append(y.copy())
        used = readings.popleft()
        integral += loop.dt * used[2]
        u_m = -kp * x[m_idx] - kd * dx[m_idx]
        F = np.zeros(6)
        F[m_idx] = u_m
        F[2] = gains.force_kp * used[2] - gains.force_kd * dx[2] + gains.force_ki * integral
        if gains.shaping:
            F[2] += terms.P_d[0] @ (u_m + np.array([used[0] if a == 0 else used[1] if a == 1 else 0.0 for a in m_idx]))
        commands.append(F)
        dx = dx + loop.dt * (L_inv @ (commands.popleft() + f_env))
        x = x + loop.dt * dx
    return np.array(out)


@pytest.mark.parametrize(("ki", "ds", "da"), [(0.0, 1, 0), (10.0, 2, 1), (5.0, 0, 3)])
def test_step_matrix_matches_a_period_by_period_simulation_and_its_growth(rizon, ki, ds, da):
    """Φ^k ξ_0 gives the δz of the loop simulated period by period with its queues (relative 1e-9 over
    600 periods), and the simulated envelope decays or grows at the rate σ = −ln ρ(Φ)/Δt (late
    window, ±15 % or ±0.5/s)."""
    L = _lambda(rizon, 0.0)
    gains = MotionForceGains(force_ki=ki)
    loop = ContactLoop(mu=1.0, speed_m_s=0.05, sensing_delay_steps=ds, actuation_delay_steps=da)
    phi = step_matrix(L, POLISH_SUBSPACES, gains, loop, STRETCH)
    assert phi.shape[0] == 15 + (ki > 0) + 3 * ds + 6 * da
    steps = 600
    ref = _simulate(L, gains, loop, STRETCH, 1e-4, steps)
    xi = np.zeros(phi.shape[0])
    xi[2] = 1e-4
    mine = []
    for _ in range(steps):
        mine.append(xi[2])
        xi = phi @ xi
    assert np.max(np.abs(np.array(mine) - ref)) <= 1e-9 * np.max(np.abs(ref))
    sigma = force_loop_margin(L, POLISH_SUBSPACES, gains, loop, STRETCH, find_kd=False).rate_per_s
    late = np.abs(_simulate(L, gains, loop, STRETCH, 1e-4, 3000)[1500:])
    peaks = [np.max(w) for w in np.split(late, 6)]  # envelope every 0.25 s
    slope = -np.polyfit(np.arange(6) * 0.25, np.log(peaks), 1)[0]
    assert slope == pytest.approx(sigma, rel=0.15, abs=0.5)
