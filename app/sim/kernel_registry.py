"""The simulator's compiled functions, each with its plain-numpy reference and sample inputs.

`SIM_KERNELS[name]` is a `control.kernel_registry.KernelPair` keyed by the dispatcher's dotted name
(`app.sim.world.track_stop_depth`): the same table as the controller's `KERNELS`, for the compiled
steps of the world, the table contact and the F/T sensor. `tests/test_kernel_registry.py` finds
every numba dispatcher of an `app.sim` module and fails for one that is not here; each pair is held
equal on its samples (outputs and every argument array written).
"""

from __future__ import annotations

import numpy as np

from app.sim import contact, sensor, world
from control.kernel_registry import KernelPair

NV = 9  # degrees of freedom of the samples' model: the arm's 7 among others (a free body, a rope)


def _stops(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(qpos indices of 7 joints among 9, stops (4, 7): lower, upper, recent and peak depth), one
    joint endless (±inf stops), the depths partly unset (−inf)."""
    adr = np.array([0, 2, 3, 4, 6, 7, 8], dtype=np.int64)
    lo, hi = rng.uniform(-3, -2, 7), rng.uniform(2, 3, 7)
    lo[5], hi[5] = -np.inf, np.inf
    recent = np.where(rng.random(7) < 0.5, -np.inf, rng.uniform(-0.1, 0.1, 7))
    return adr, np.array([lo, hi, recent, np.maximum(recent, rng.uniform(-0.1, 0.1, 7))])


def _track_samples(rng: np.random.Generator) -> list[tuple]:
    out = []
    for _ in range(6):
        adr, stops = _stops(rng)
        out.append((rng.uniform(-3.2, 3.2, NV), adr, stops))
    return out


def _clip_samples(rng: np.random.Generator) -> list[tuple]:
    out = []
    for k in range(6):
        adr, stops = _stops(rng)
        upper = rng.uniform(10, 80, 7)
        tau = rng.normal(0, 60, 7)
        tau[k % 7] = (np.nan, np.inf, -np.inf, 0.0)[k % 4]  # NaN stays NaN, ±inf clip to the limit
        out.append((tau, np.array([-upper, upper]), rng.uniform(-3.2, 3.2, NV), adr, stops))
    return out


def _inverse_mass(rng: np.random.Generator) -> np.ndarray:
    G = rng.standard_normal((2, 2))
    return G @ G.T + 0.2 * np.eye(2)


def _implicit_samples(rng: np.random.Generator) -> list[tuple]:
    """Penetration depths of 0.01-2 mm, tangential speeds from 0.1 to 100 v_ε, G = 0 (explicit) once."""
    out = []
    for k in range(6):
        v = rng.standard_normal(2) * 10.0 ** rng.uniform(-3.5, -0.5)
        G = np.zeros((2, 2)) if k == 0 else _inverse_mass(rng)
        out.append((rng.uniform(1e-5, 2e-3), v, G, 12000.0, rng.uniform(0.1, 1.0), 0.004, 1e-3))
    return out


def _contact_samples(rng: np.random.Generator) -> list[tuple]:
    """In contact (implicit and explicit) and out of it, with `contact._NO_SOLVE` as the app passes
    it when there is no M⁻¹ J_pᵀ."""
    out = []
    for k in range(6):
        implicit = k % 2 == 0
        depth = -1e-3 if k == 5 else rng.uniform(1e-5, 2e-3)
        jacp = rng.standard_normal((3, NV))
        solved = rng.standard_normal((3, NV)) if implicit else contact._NO_SOLVE.copy()
        qvel = rng.standard_normal(NV) * 10.0 ** rng.uniform(-3, 0)
        out.append((depth, jacp, qvel, solved, implicit and depth > 0, 12000.0, rng.uniform(0.1, 1.0), 0.004, 1e-3))
    return out


def _reading_samples(rng: np.random.Generator) -> list[tuple]:
    """Filtered and unfiltered, with and without the sinusoid, at α of 25 Hz at 1 kHz."""
    alpha = 1.0 - np.exp(-2.0 * np.pi * 25.0 * 1e-3)
    std = np.array([np.sqrt(5.0)] * 3 + [np.sqrt(0.05)] * 3)
    return [
        (rng.standard_normal(6), std, rng.normal(0, 20, 6), bool(k & 1), float(rng.uniform(-2, 2)), bool(k & 2),
         alpha, rng.normal(0, 20, 6))
        for k in range(4)
    ]  # fmt: skip


SIM_KERNELS: dict[str, KernelPair] = {
    "app.sim.world.track_stop_depth": KernelPair(
        world.track_stop_depth, world.track_stop_depth_reference, _track_samples
    ),
    "app.sim.world.clip_torque_track_stops": KernelPair(
        world.clip_torque_track_stops, world.clip_torque_track_stops_reference, _clip_samples
    ),
    "app.sim.contact.implicit_contact": KernelPair(
        contact.implicit_contact, contact.implicit_contact_reference, _implicit_samples
    ),
    "app.sim.contact.contact_step": KernelPair(contact.contact_step, contact.contact_step_reference, _contact_samples),
    "app.sim.sensor._reading": KernelPair(sensor._reading, sensor.reading_reference, _reading_samples),
}
