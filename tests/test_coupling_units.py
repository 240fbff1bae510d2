"""W_f, W_a, W_d in task coordinates that share units (`control.coupling.task_scale`)."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from control import coupling as c
from control.model import RobotModel
from tests.conftest import random_configurations


def _lengths_scaled(model: pin.Model, factor: float) -> pin.Model:
    """The same arm with every length times `factor`: joint and frame placements, centres of mass;
    masses kept, so rotational inertias (links and rotor armature, kg·m²) go with factor²."""
    out = model.copy()
    for i in range(1, out.njoints):
        placement = out.jointPlacements[i]
        out.jointPlacements[i] = pin.SE3(placement.rotation, placement.translation * factor)
        inertia = out.inertias[i]
        out.inertias[i] = pin.Inertia(inertia.mass, inertia.lever * factor, inertia.inertia * factor**2)
    for k in range(len(out.frames)):
        frame = out.frames[k]
        frame.placement = pin.SE3(frame.placement.rotation, frame.placement.translation * factor)
        out.frames[k] = frame
    out.armature = out.armature * factor**2
    out.rotorInertia = out.rotorInertia * factor**2
    return out


def _values(model: RobotModel, q: np.ndarray, sub: c.Subspaces, scale: np.ndarray) -> np.ndarray:
    _, values = c.terms_and_values(model.compute(q, np.zeros(len(q))), sub, scale)
    return np.array(values)


@pytest.mark.parametrize("unit_m", [0.1, 0.0254], ids=["dm", "inch"])
@pytest.mark.parametrize("axes", [("pz",), ("pz", "rx")])
def test_normalised_W_is_invariant_to_the_length_unit(rizon, axes, unit_m):
    """Lengths counted in another unit (robot and L_c × 1 m/unit): W_f, W_a, W_d keep their values
    within 1e-9 relative; in SI units W_d moves by more than 25 % (its rotational columns are 1/m).
    (Units much smaller than these shrink the rotational block of Λx⁻¹ below the snapshot's
    absolute singularity threshold, whose damping is not unit-free.)"""
    sub = c.Subspaces.from_force_axes(axes)
    factor, length_m, mass_kg = 1.0 / unit_m, 0.25, 4.0
    model = RobotModel(rizon.model)
    scaled = RobotModel(_lengths_scaled(rizon.model, factor))
    for q in random_configurations(rizon, 4, seed=31):
        assert not scaled.compute(q, np.zeros(7)).near_singular
        W = _values(model, q, sub, c.task_scale(length_m, mass_kg))
        W_scaled = _values(scaled, q, sub, c.task_scale(length_m * factor, mass_kg))
        np.testing.assert_allclose(W_scaled, W, rtol=1e-9)
        W_si, W_si_scaled = _values(model, q, sub, c.task_scale()), _values(scaled, q, sub, c.task_scale())
        assert abs(np.log10(W_si_scaled[2] / W_si[2])) > 0.1  # SI W_d moves by more than 25 %


def test_normalisation_off_is_W_as_T22(rizon):
    """L_c = 0 and m_c = 1 kg: the same W's as ‖P‖²_F, bit for bit, and the same gradients; so does
    L_c = 1 m."""
    model = RobotModel(rizon.model)
    sub = c.POLISH_SUBSPACES
    off = c.task_scale(0.0, 1.0)
    assert np.array_equal(off, np.ones(6))
    for q in random_configurations(rizon, 3, seed=32):
        dyn = model.compute(q, np.zeros(7))
        terms, values = c.terms_and_values(dyn, sub, off)
        assert values == tuple(float(np.sum(P * P)) for P in (terms.P_f, terms.P_a, terms.P_d))
        for objective in "fad":
            W, grad = c.coupling_gradient_direct(model, dyn, terms, sub, objective)
            W_off, grad_off = c.coupling_gradient_direct(model, dyn, terms, sub, objective, off)
            assert W_off == W and np.array_equal(grad_off, grad)
        _, one_metre = c.terms_and_values(dyn, sub, c.task_scale(1.0, 1.0))
        assert one_metre == values  # L_c = 1 m, m_c = 1 kg: the SI values


def test_normalised_W_d_weights_rotational_columns_by_L_squared(rizon):
    """W_d = Σ P_d² over translational columns + L_c² Σ P_d² over rotational ones (m_c drops out)."""
    model = RobotModel(rizon.model)
    sub = c.POLISH_SUBSPACES  # motion px py rx ry rz
    q = random_configurations(rizon, 1, seed=33)[0]
    terms, (_, _, W_d) = c.terms_and_values(model.compute(q, np.zeros(7)), sub, c.task_scale(0.3, 7.0))
    P = terms.P_d[0]
    assert W_d == pytest.approx(P[0] ** 2 + P[1] ** 2 + 0.09 * float(P[2:] @ P[2:]), rel=1e-12)


def test_bad_characteristic_units_are_refused():
    with pytest.raises(ValueError, match="characteristic length"):
        c.task_scale(-0.1)
    with pytest.raises(ValueError, match="characteristic mass"):
        c.task_scale(0.2, 0.0)
