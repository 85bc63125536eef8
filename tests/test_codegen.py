"""Generated-code checks against independent evaluations (sympy itself, numpy formulas)."""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp

from vnhc_gym.mechanics import ConstrainedSystem, MechanicalSystem, VelocityConstraint
from vnhc_gym.systems import CURRENTS, make_usv


def test_powers_in_denominators_are_parenthesised() -> None:
    """Regression: ``a / b**2`` was once printed as ``a/b*b``."""
    x, v = sp.symbols("x v", real=True)
    k = sp.Symbol("k", positive=True)
    system = MechanicalSystem(name="powtest", q=(x,), qd=(v,), mass_matrix=sp.Matrix([[1]]),
                              control_forces=sp.Matrix([1]), params={k: 2.0})
    # phi chosen so that C, G and phi contain x / (1 + x^2)^2 and x^3 / k^4 terms.
    phi = sp.Matrix([v * x / (1 + x**2) ** 2 + x**3 / k**4 - v / k**3])
    model = ConstrainedSystem(system, VelocityConstraint(phi))
    rng = np.random.default_rng(0)
    f_phi = sp.lambdify([x, v, k], phi[0])
    for _ in range(20):
        s = rng.normal(size=2) * 2
        np.testing.assert_allclose(model.phi(s)[0], f_phi(s[0], s[1], 2.0), rtol=1e-13)
        c, g = model.decoupling(s)
        dphi_dv = sp.diff(phi[0], v).subs({x: s[0], v: s[1], k: 2.0})
        dphi_dx = sp.diff(phi[0], x).subs({x: s[0], v: s[1], k: 2.0})
        np.testing.assert_allclose(c[0, 0], float(dphi_dv), rtol=1e-12)
        np.testing.assert_allclose(g[0], float(dphi_dx) * s[1], rtol=1e-12)


@pytest.mark.parametrize("name", sorted(CURRENTS))
def test_usv_current_outputs_match_the_current_library(name: str) -> None:
    """The compiled current (and Jacobian) at the boat equals the library's numpy evaluation."""
    model = make_usv(name)
    field = CURRENTS[name]
    params = {k[2:]: v for k, v in zip(model.param_names, model.default_params, strict=True) if k.startswith("c_")}
    rng = np.random.default_rng(1)
    states = rng.normal(size=(16, 6)) * 3
    out = model.outputs(states)
    # Independent Jacobian: central differences of the library's value().
    h = 1e-6
    for row, s in zip(out, states, strict=True):
        c = field.value(s[0], s[1], params)
        jx = (field.value(s[0] + h, s[1], params) - field.value(s[0] - h, s[1], params)) / (2 * h)
        jy = (field.value(s[0], s[1] + h, params) - field.value(s[0], s[1] - h, params)) / (2 * h)
        np.testing.assert_allclose(row[:2], c, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(row[2:], [jx[0], jy[0], jx[1], jy[1]], rtol=1e-6, atol=1e-7)
